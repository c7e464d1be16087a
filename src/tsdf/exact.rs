//! Exact 3D distance to a stack of prisms, column by column.
//!
//! The solid is S = ∪ₗ Fₗ × Iₗ: layer l's filled cross-section Fₗ over its slab Iₗ, every
//! layer, whether or not a voxel center falls in its slab. The distance from p = (x, z) to a prism F × I is exact and separable:
//! d² = d₂(x, F)² + d₁(z, I)². So for an outside voxel
//!   d² = min over layers l of gₗ + d₁(z, Iₗ)², gₗ = 0 if x ∈ Fₗ else d₂(x, ∂Fₗ)²,
//! and for an inside voxel the same over the complement (Fₗᶜ × Iₗ and the empty z ranges),
//! with g'ₗ = d₂(x, ∂Fₗ)² if x ∈ Fₗ else 0. The 2D distances are the exact per-layer ones,
//! computed into the volume's memory first. Outside its own interval, d₁(z, I)² is a parabola centered on the
//! nearer end of I, so each column is the lower envelope of parabolas at the interval ends
//! (Felzenszwalb & Huttenlocher), evaluated at the voxel centers, plus the own slice's term:
//! O(nz) per column, exact up to rounding.
//!
//! Columns are independent: processed in parallel, one xz plane (all columns of one y row)
//! per task, copied into a scratch block so that the column walks stay in cache.

use rayon::prelude::*;

use super::volume::Volume;

/// A parabola center: an end of one or two slabs.
#[derive(Debug, Clone, Copy)]
struct Center {
    /// z relative to the first voxel center, mm.
    q: f64,
    /// The slab ending here, and the one starting here.
    below: Option<usize>,
    above: Option<usize>,
}

/// Input: planes 0..L of `data` hold the signed 2D distances of the L slabs (`bounds[l]` =
/// (bottom, top) in mm, increasing, not overlapping); `slice_slab[k]` is the slab holding the
/// center of voxel slice k (whose z is `z0 + k·h`). Output: planes 0..nz hold the signed exact
/// 3D distance, clamped to ±`trunc`. `data` must have max(L, nz) planes.
#[allow(clippy::too_many_arguments)]
pub(crate) fn transform(
    data: &mut [f32],
    dims: [usize; 3],
    bounds: &[(f64, f64)],
    slice_slab: &[Option<usize>],
    z0: f64,
    h: f64,
    trunc: f32,
) {
    let [nx, ny, nz] = dims;
    let nl = bounds.len();
    assert!(data.len() >= nx * ny * nz.max(nl), "volume size");
    assert_eq!(slice_slab.len(), nz, "slices");
    let centers = centers(bounds, z0);
    let col = Column {
        nl,
        nz,
        centers: &centers,
        zc: (0..nz).map(|k| k as f64 * h).collect(),
        slice_slab,
        trunc,
    };
    // Each task reads and writes only the rows (j, ·) of its own j.
    let vol = Volume::new(data, nx, ny);
    (0..ny).into_par_iter().for_each_init(
        || Scratch::new(nx, nl, nz, centers.len()),
        |s, j| {
            for l in 0..nl {
                // SAFETY: rows (j, ·) belong to this task only.
                let row = unsafe { vol.row_mut(j, l) };
                s.input[l * nx..(l + 1) * nx].copy_from_slice(row);
            }
            for i in 0..nx {
                col.run(s, i, nx);
            }
            for k in 0..nz {
                // SAFETY: as above.
                let row = unsafe { vol.row_mut(j, k) };
                row.copy_from_slice(&s.output[k * nx..(k + 1) * nx]);
            }
        },
    );
}

struct Scratch {
    input: Vec<f32>,
    output: Vec<f32>,
    /// One column of `input`.
    g: Vec<f32>,
    w: Vec<f64>,
    v: Vec<usize>,
    zb: Vec<f64>,
}

impl Scratch {
    fn new(nx: usize, nl: usize, nz: usize, centers: usize) -> Scratch {
        Scratch {
            input: vec![0.0; nx * nl],
            output: vec![0.0; nx * nz],
            g: vec![0.0; nl],
            w: vec![0.0; centers],
            v: Vec::with_capacity(centers),
            zb: Vec::with_capacity(centers + 1),
        }
    }
}

/// The slab ends in increasing z (relative to the first voxel center), touching ends merged.
fn centers(bounds: &[(f64, f64)], z0: f64) -> Vec<Center> {
    let mut out: Vec<Center> = Vec::new();
    for (l, &(lo, hi)) in bounds.iter().enumerate() {
        let (lo, hi) = (lo - z0, hi - z0);
        match out.last_mut() {
            Some(c) if (c.q - lo).abs() <= 1e-9 && c.above.is_none() => c.above = Some(l),
            _ => out.push(Center {
                q: lo,
                below: None,
                above: Some(l),
            }),
        }
        out.push(Center {
            q: hi,
            below: Some(l),
            above: None,
        });
    }
    out
}

/// What is the same for every column.
struct Column<'a> {
    nl: usize,
    nz: usize,
    centers: &'a [Center],
    /// Voxel center z relative to the first one.
    zc: Vec<f64>,
    slice_slab: &'a [Option<usize>],
    trunc: f32,
}

impl Column<'_> {
    fn run(&self, s: &mut Scratch, i: usize, nx: usize) {
        let (nl, nz, trunc) = (self.nl, self.nz, self.trunc);
        for l in 0..nl {
            s.g[l] = s.input[l * nx + i];
        }
        let inside_at =
            |g: &[f32], k: usize| self.slice_slab[k].is_some_and(|l| g[l].is_sign_negative());
        let any_inside = (0..nz).any(|k| inside_at(&s.g, k));
        // Nothing within reach: an all-outside column whose slabs are all farther than the
        // truncation sideways. (A column inside a slab no voxel center samples has solid
        // right there: it is never skipped.)
        let nearest =
            s.g.iter()
                .map(|&v| if v.is_sign_negative() { 0.0 } else { v })
                .fold(f32::INFINITY, f32::min);
        if !any_inside && nearest >= trunc {
            for k in 0..nz {
                s.output[k * nx + i] = trunc;
            }
            return;
        }
        let trunc2 = (trunc as f64) * (trunc as f64);
        for pass_inside in [false, true] {
            if pass_inside && !any_inside {
                break;
            }
            // Outside pass, g: 0 where the column is inside the slab's section, else the 2D
            // distance squared. Inside pass, g': the 2D distance squared where inside, else 0,
            // and 0 at ends facing an empty z range (which is outside).
            let g = &s.g;
            let weight = |l: usize| -> f64 {
                let v = g[l];
                if v.is_sign_negative() == pass_inside {
                    (v as f64) * (v as f64)
                } else {
                    0.0
                }
            };
            for (m, c) in self.centers.iter().enumerate() {
                s.w[m] = match (c.below.map(weight), c.above.map(weight)) {
                    (Some(b), Some(a)) => b.min(a),
                    (Some(b), None) | (None, Some(b)) => {
                        if pass_inside {
                            0.0
                        } else {
                            b
                        }
                    }
                    (None, None) => f64::INFINITY,
                };
            }
            envelope(self.centers, &s.w, &mut s.v, &mut s.zb);
            let n_env = s.v.len();
            let mut e = 0usize;
            for k in 0..nz {
                let inside = inside_at(&s.g, k);
                if inside != pass_inside {
                    continue;
                }
                let zk = self.zc[k];
                while e + 1 < n_env && s.zb[e + 1] < zk {
                    e += 1;
                }
                // The own slab's wall at this height, then the envelope.
                let mut d2 = match self.slice_slab[k] {
                    Some(l) => (s.g[l] as f64) * (s.g[l] as f64),
                    None => f64::INFINITY,
                };
                if n_env > 0 {
                    let c = s.v[e];
                    let dq = zk - self.centers[c].q;
                    d2 = d2.min(s.w[c] + dq * dq);
                }
                let d = if d2 >= trunc2 {
                    trunc
                } else {
                    (d2.sqrt() as f32).min(trunc)
                };
                s.output[k * nx + i] = if inside { -d } else { d };
            }
        }
    }
}
/// Lower envelope of the parabolas w[m] + (z − q[m])² (q strictly increasing); `v` gets the
/// indices of the parabolas on the envelope, `zb[e]..zb[e + 1]` the range where v[e] is lowest.
fn envelope(centers: &[Center], w: &[f64], v: &mut Vec<usize>, zb: &mut Vec<f64>) {
    v.clear();
    zb.clear();
    for (m, c) in centers.iter().enumerate() {
        if !w[m].is_finite() {
            continue;
        }
        let fm = w[m] + c.q * c.q;
        loop {
            let Some(&last) = v.last() else {
                v.push(m);
                zb.push(f64::NEG_INFINITY);
                break;
            };
            let cl = &centers[last];
            let s = (fm - (w[last] + cl.q * cl.q)) / (2.0 * (c.q - cl.q));
            if s <= zb[zb.len() - 1] {
                v.pop();
                zb.pop();
            } else {
                v.push(m);
                zb.push(s);
                break;
            }
        }
    }
    zb.push(f64::INFINITY);
}
