//! Fast sweeping (Zhao 2005) for |∇d| = 1 on a voxel grid, in place.
//!
//! The volume holds signed values; the sweeps work on magnitudes (the unsigned distance to
//! the surface obeys the same equation on both sides) and keep each voxel's sign bit, so the
//! inside/outside decision of the stack is never touched. Updates only lower a value
//! (Gauss–Seidel with `min`), so initial values act as upper bounds.
//!
//! Parallelism without copies: in a sweep with directions (sx, sy, sz), the x-rows (j, k) on
//! one anti-diagonal j' + k' = const (in sweep order) do not neighbour each other; each row
//! depends only on rows of the previous anti-diagonal. Rows of one anti-diagonal are updated
//! in parallel, anti-diagonals in order, which gives exactly the result of the sequential
//! sweep.

use rayon::prelude::*;

use super::volume::Volume;

/// Godunov upwind solution of |∇u| = 1 from the smallest neighbour per axis (a, b, c), h the
/// spacing.
#[inline]
fn godunov(mut a: f32, mut b: f32, mut c: f32, h: f32) -> f32 {
    if a > b {
        std::mem::swap(&mut a, &mut b);
    }
    if b > c {
        std::mem::swap(&mut b, &mut c);
    }
    if a > b {
        std::mem::swap(&mut a, &mut b);
    }
    let u = a + h;
    if u <= b {
        return u;
    }
    let d = a - b;
    let u = 0.5 * (a + b + (2.0 * h * h - d * d).max(0.0).sqrt());
    if u <= c {
        return u;
    }
    let s = a + b + c;
    let q = a * a + b * b + c * c - h * h;
    (s + (s * s - 3.0 * q).max(0.0).sqrt()) / 3.0
}

/// Runs the 8 sweep orders once over `data` (`dims` = [nx, ny, nz], x fastest). Voxels whose
/// neighbours are all at least `cutoff` away are left alone: their value would exceed the
/// truncation anyway.
pub(crate) fn sweep(data: &mut [f32], dims: [usize; 3], h: f32, cutoff: f32) {
    let [nx, ny, nz] = dims;
    assert_eq!(data.len(), nx * ny * nz, "volume size");
    if data.is_empty() {
        return;
    }
    // Rows of one anti-diagonal are handed out concurrently (disjoint), their neighbours
    // are on the adjacent anti-diagonals, which are not written meanwhile.
    let vol = Volume::new(data, nx, ny);
    for order in 0..8 {
        let (sx, sy, sz) = (order & 1 == 0, order & 2 == 0, order & 4 == 0);
        for diag in 0..(ny + nz - 1) {
            let k_lo = diag.saturating_sub(ny - 1);
            let k_hi = diag.min(nz - 1);
            let work = |kk: usize| {
                let jj = diag - kk;
                let j = if sy { jj } else { ny - 1 - jj };
                let k = if sz { kk } else { nz - 1 - kk };
                // SAFETY: (j, k) is on this anti-diagonal and handed to this closure only;
                // the neighbour rows are on the adjacent anti-diagonals, not written now.
                unsafe { update_row(&vol, j, k, ny, nz, sx, h, cutoff) };
            };
            if (k_hi - k_lo + 1) * nx < 4096 {
                (k_lo..=k_hi).for_each(work);
            } else {
                (k_lo..k_hi + 1)
                    .into_par_iter()
                    .with_min_len(4)
                    .for_each(work);
            }
        }
    }
}

/// # Safety
/// Row (j, k) must be exclusively this call's, and rows (j±1, k), (j, k±1) unwritten for the
/// duration.
#[allow(clippy::too_many_arguments)]
unsafe fn update_row(
    vol: &Volume<'_>,
    j: usize,
    k: usize,
    ny: usize,
    nz: usize,
    forward: bool,
    h: f32,
    cutoff: f32,
) {
    let nx = vol.nx;
    let row = vol.row_mut(j, k);
    let ym = (j > 0).then(|| vol.row(j - 1, k));
    let yp = (j + 1 < ny).then(|| vol.row(j + 1, k));
    let zm = (k > 0).then(|| vol.row(j, k - 1));
    let zp = (k + 1 < nz).then(|| vol.row(j, k + 1));
    let pair = |a: Option<&[f32]>, b: Option<&[f32]>, i: usize| -> f32 {
        let x = a.map_or(f32::INFINITY, |r| r[i].abs());
        let y = b.map_or(f32::INFINITY, |r| r[i].abs());
        x.min(y)
    };
    // The smallest possible Godunov value is m + h/√3 (all three neighbours equal to m).
    let step_min = h / 3f32.sqrt();
    let mut visit = |i: usize| {
        let cur = row[i].abs();
        let left = if i > 0 {
            row[i - 1].abs()
        } else {
            f32::INFINITY
        };
        let right = if i + 1 < nx {
            row[i + 1].abs()
        } else {
            f32::INFINITY
        };
        let a = left.min(right);
        let b = pair(ym, yp, i);
        let c = pair(zm, zp, i);
        let m = a.min(b).min(c);
        if m >= cutoff || cur <= m + step_min {
            return;
        }
        let u = godunov(a, b, c, h);
        if u < cur {
            row[i] = u.copysign(row[i]);
        }
    };
    if forward {
        (0..nx).for_each(&mut visit);
    } else {
        (0..nx).rev().for_each(&mut visit);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn godunov_is_exact_for_planes() {
        // u = n·x for a unit normal n, evaluated at the upwind neighbours.
        let h = 0.1f32;
        for n in [[1.0f32, 0.0, 0.0], [0.6, 0.8, 0.0], [0.48, 0.6, 0.64]] {
            let u0 = 3.0f32;
            let got = godunov(u0 - h * n[0], u0 - h * n[1], u0 - h * n[2], h);
            assert!((got - u0).abs() < 1e-5, "{n:?}: {got}");
        }
        assert_eq!(godunov(1.0, f32::INFINITY, f32::INFINITY, 0.5), 1.5);
    }

    #[test]
    fn point_source_sweeps_close_to_euclidean_and_keep_signs() {
        let n = 24;
        let h = 0.5f32;
        let mut data = vec![f32::INFINITY; n * n * n];
        let c = 11usize;
        let idx = |i: usize, j: usize, k: usize| i + n * (j + n * k);
        data[idx(c, c, c)] = 0.0;
        // Mark one far voxel as "inside" (negative) to see its sign survive.
        data[idx(2, 3, 4)] = f32::NEG_INFINITY;
        sweep(&mut data, [n, n, n], h, f32::INFINITY);
        let mut worst = 0f32;
        for k in 0..n {
            for j in 0..n {
                for i in 0..n {
                    let d = ((i as f32 - c as f32).powi(2)
                        + (j as f32 - c as f32).powi(2)
                        + (k as f32 - c as f32).powi(2))
                    .sqrt()
                        * h;
                    let got = data[idx(i, j, k)].abs();
                    worst = worst.max((got - d).abs() / d.max(h));
                }
            }
        }
        // First-order scheme around a point: a few tenths of the distance at worst.
        assert!(worst < 0.35, "worst relative error {worst}");
        assert!(data[idx(2, 3, 4)] < 0.0);
        assert!(data[idx(2, 3, 4)].is_finite());
    }
}
