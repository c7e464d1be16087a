//! 3x3 matrices of plane projective maps: products, the inverse (with a scale-free measure of how
//! singular a matrix is), projection of a point, normalisation to `H[2][2] = 1`, and the 4-point DLT.

// `!(x > y)` is deliberate: a NaN must fail the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

/// Point correspondences from which no homography follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("point correspondences are degenerate (three collinear or repeated points)")]
pub struct DegeneratePoints;

/// Row-major 3x3 matrix.
pub type Mat3 = [[f64; 3]; 3];

/// `a · b`.
pub fn mul(a: &Mat3, b: &Mat3) -> Mat3 {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    m
}

/// Inverse through the adjugate, plus a scale-free singularity measure:
/// `|det| / (|row0|·|row1|·|row2|)`, which lies in [0, 1] (Hadamard) and is
/// 1 for orthogonal rows, so one threshold works for pixels and millimetres.
pub fn inverse(h: &Mat3) -> (Mat3, f64) {
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| h[r0][c0] * h[r1][c1] - h[r0][c1] * h[r1][c0];
    let adj = [
        [c(1, 2, 1, 2), -c(0, 2, 1, 2), c(0, 1, 1, 2)],
        [-c(1, 2, 0, 2), c(0, 2, 0, 2), -c(0, 1, 0, 2)],
        [c(1, 2, 0, 1), -c(0, 2, 0, 1), c(0, 1, 0, 1)],
    ];
    let det = h[0][0] * adj[0][0] + h[0][1] * adj[1][0] + h[0][2] * adj[2][0];
    let norms: f64 = h
        .iter()
        .map(|r| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt())
        .product();
    let measure = if norms > 0.0 {
        (det / norms).abs()
    } else {
        0.0
    };
    let mut inv = [[0.0; 3]; 3];
    for (i, row) in inv.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = adj[i][j] / det;
        }
    }
    (inv, measure)
}

/// Applies a homography to (u, v); `None` where w ≤ 0 (beyond the horizon) or not finite.
pub fn project(m: &Mat3, u: f64, v: f64) -> Option<(f64, f64)> {
    let w = m[2][0] * u + m[2][1] * v + m[2][2];
    if !(w.abs() > 0.0) {
        return None;
    }
    let x = (m[0][0] * u + m[0][1] * v + m[0][2]) / w;
    let y = (m[1][0] * u + m[1][1] * v + m[1][2]) / w;
    (w > 0.0 && x.is_finite() && y.is_finite()).then_some((x, y))
}

/// `a · b` (the same as [`mul`]).
pub fn mat_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    mul(a, b)
}

/// Inverse through the adjugate; `None` when singular (see [`singularity`]) or not finite.
pub fn mat_inv(h: &Mat3) -> Option<Mat3> {
    if !(singularity(h) > 1e-15) {
        return None;
    }
    let (inv, _) = inverse(h);
    inv.iter().flatten().all(|v| v.is_finite()).then_some(inv)
}

/// Scale-free singularity measure |det| / (|row0|·|row1|·|row2|) in [0, 1] : 0 for singular matrices, NaN-safe (NaN compares false).
pub fn singularity(h: &Mat3) -> f64 {
    let det = h[0][0] * (h[1][1] * h[2][2] - h[1][2] * h[2][1])
        - h[0][1] * (h[1][0] * h[2][2] - h[1][2] * h[2][0])
        + h[0][2] * (h[1][0] * h[2][1] - h[1][1] * h[2][0]);
    let norms: f64 = h
        .iter()
        .map(|r| (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt())
        .product();
    if norms > 0.0 {
        (det / norms).abs()
    } else {
        0.0
    }
}

/// Scales H so that H[2][2] = 1 (docs/frames.md).
pub fn normalise_h(h: &Mat3) -> Option<Mat3> {
    let s = h[2][2];
    let scale = h.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if !(s.abs() > 1e-12 * scale) {
        return None;
    }
    let mut out = *h;
    for v in out.iter_mut().flatten() {
        *v /= s;
    }
    out[2][2] = 1.0;
    out.iter().flatten().all(|v| v.is_finite()).then_some(out)
}

/// The grid's pixel → build map: (c, r, 1) ↦ (x, y, 1) (docs/frames.md).
pub fn grid_matrix(grid: &crate::geometry::Grid) -> Mat3 {
    let p = grid.pixel_mm;
    [
        [p, 0.0, grid.x_min + 0.5 * p],
        [0.0, -p, grid.y_max - 0.5 * p],
        [0.0, 0.0, 1.0],
    ]
}

/// Homography (`H[2][2]` = 1) mapping each `image[i]` (u, v) to `build[i]` (x, y),
/// by the direct linear transform on Hartley-normalised points.
///
/// Errors if three of the points are collinear (no unique solution).
pub fn homography_from_points(
    image: [[f64; 2]; 4],
    build: [[f64; 2]; 4],
) -> Result<[[f64; 3]; 3], DegeneratePoints> {
    let ti = normaliser(&image)?;
    let tb = normaliser(&build)?;
    let apply = |t: &Mat3, p: [f64; 2]| [t[0][0] * p[0] + t[0][2], t[1][1] * p[1] + t[1][2]];
    // Rows of A·h = b with h = (h00 h01 h02 h10 h11 h12 h20 h21), h22 = 1.
    let mut a = [[0.0_f64; 9]; 8];
    for k in 0..4 {
        let [u, v] = apply(&ti, image[k]);
        let [x, y] = apply(&tb, build[k]);
        a[2 * k] = [u, v, 1.0, 0.0, 0.0, 0.0, -u * x, -v * x, x];
        a[2 * k + 1] = [0.0, 0.0, 0.0, u, v, 1.0, -u * y, -v * y, y];
    }
    let h = solve8(a).ok_or(DegeneratePoints)?;
    let hn = [[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]];
    let (tb_inv, _) = inverse(&tb);
    let mut out = mul(&tb_inv, &mul(&hn, &ti));
    let s = out[2][2];
    if !s.is_finite() || s == 0.0 {
        return Err(DegeneratePoints);
    }
    for v in out.iter_mut().flatten() {
        *v /= s;
    }
    // Collinear triples give a rank-deficient map even when the solve succeeds.
    let (_, measure) = inverse(&out);
    if measure < 1e-10 || out.iter().flatten().any(|v| !v.is_finite()) {
        return Err(DegeneratePoints);
    }
    Ok(out)
}

/// Similarity moving the centroid to 0 and the mean distance to √2.
fn normaliser(p: &[[f64; 2]; 4]) -> Result<Mat3, DegeneratePoints> {
    let (cx, cy) = (
        p.iter().map(|q| q[0]).sum::<f64>() / 4.0,
        p.iter().map(|q| q[1]).sum::<f64>() / 4.0,
    );
    let d = p
        .iter()
        .map(|q| ((q[0] - cx).powi(2) + (q[1] - cy).powi(2)).sqrt())
        .sum::<f64>()
        / 4.0;
    if !(d.is_finite() && d > 0.0) {
        return Err(DegeneratePoints);
    }
    let s = std::f64::consts::SQRT_2 / d;
    Ok([[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]])
}

/// Gaussian elimination with partial pivoting on an augmented 8x9 system.
fn solve8(mut a: [[f64; 9]; 8]) -> Option<[f64; 8]> {
    for col in 0..8 {
        let piv = (col..8).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if a[piv][col].abs().is_nan() || a[piv][col].abs() <= 1e-12 {
            return None;
        }
        a.swap(col, piv);
        let pivot_row = a[col];
        for (r, row) in a.iter_mut().enumerate() {
            if r != col {
                let f = row[col] / pivot_row[col];
                for (v, p) in row.iter_mut().zip(pivot_row).skip(col) {
                    *v -= f * p;
                }
            }
        }
    }
    let mut x = [0.0; 8];
    for (i, v) in x.iter_mut().enumerate() {
        *v = a[i][8] / a[i][i];
    }
    Some(x)
}
