//! 3x3 matrices of plane projective maps, the arithmetic under [`Homography`]: products, the
//! inverse (with a scale-free measure of how singular a matrix is), projection of a point, and
//! the grid's pixel → build matrix. Code outside `geometry` names its maps with [`Homography`];
//! inner loops (the rectifier, the IC-LM) may keep a bare [`Mat3`].
//!
//! [`Homography`]: super::Homography

// `!(x > y)` is deliberate: a NaN must fail the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

/// Row-major 3x3 matrix.
pub type Mat3 = [[f64; 3]; 3];

/// The 3x3 identity.
pub const IDENTITY: Mat3 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

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

/// The adjugate and the determinant (cofactor expansion along row 0).
fn adjugate(h: &Mat3) -> (Mat3, f64) {
    let c =
        |r0: usize, r1: usize, c0: usize, c1: usize| h[r0][c0] * h[r1][c1] - h[r0][c1] * h[r1][c0];
    let adj = [
        [c(1, 2, 1, 2), -c(0, 2, 1, 2), c(0, 1, 1, 2)],
        [-c(1, 2, 0, 2), c(0, 2, 0, 2), -c(0, 1, 0, 2)],
        [c(1, 2, 0, 1), -c(0, 2, 0, 1), c(0, 1, 0, 1)],
    ];
    let det = h[0][0] * adj[0][0] + h[0][1] * adj[1][0] + h[0][2] * adj[2][0];
    (adj, det)
}

/// `|det| / (|row0|·|row1|·|row2|)`: in [0, 1] (Hadamard), 1 for orthogonal rows, 0 for
/// singular (or all-zero) matrices.
fn measure(h: &Mat3, det: f64) -> f64 {
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

/// Inverse through the adjugate, plus the scale-free singularity measure of [`singularity`],
/// so one threshold works for pixels and millimetres. Not checked: see [`mat_inv`].
pub fn inverse(h: &Mat3) -> (Mat3, f64) {
    let (adj, det) = adjugate(h);
    let mut inv = [[0.0; 3]; 3];
    for (i, row) in inv.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = adj[i][j] / det;
        }
    }
    (inv, measure(h, det))
}

/// Inverse through the adjugate; `None` when singular (see [`singularity`]) or not finite.
pub fn mat_inv(h: &Mat3) -> Option<Mat3> {
    let (inv, m) = inverse(h);
    if !(m > 1e-15) {
        return None;
    }
    inv.iter().flatten().all(|v| v.is_finite()).then_some(inv)
}

/// Scale-free singularity measure |det| / (|row0|·|row1|·|row2|) in [0, 1]: 0 for singular
/// matrices, NaN-safe (NaN compares false).
pub fn singularity(h: &Mat3) -> f64 {
    measure(h, adjugate(h).1)
}

/// Applies `m` to (u, v); `None` where w ≤ 0 (beyond the horizon) or the result is not finite.
pub fn project(m: &Mat3, u: f64, v: f64) -> Option<(f64, f64)> {
    let w = m[2][0] * u + m[2][1] * v + m[2][2];
    if !(w > 0.0) {
        return None;
    }
    let x = (m[0][0] * u + m[0][1] * v + m[0][2]) / w;
    let y = (m[1][0] * u + m[1][1] * v + m[1][2]) / w;
    (x.is_finite() && y.is_finite()).then_some((x, y))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_product_and_singularity() {
        let m = [[2.0, 0.1, 3.0], [0.2, 1.5, -1.0], [1e-3, 2e-3, 1.0]];
        let inv = mat_inv(&m).expect("regular");
        let id = mul(&m, &inv);
        for (i, row) in id.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
            }
        }
        let singular = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]];
        assert!(mat_inv(&singular).is_none());
        assert_eq!(singularity(&singular), 0.0);
        assert_eq!(singularity(&IDENTITY), 1.0);
        assert_eq!(singularity(&[[0.0; 3]; 3]), 0.0);
        let nan = [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(mat_inv(&nan).is_none());
        // The measure of `inverse` is the one `singularity` reports.
        assert_eq!(inverse(&m).1, singularity(&m));
    }

    #[test]
    fn project_refuses_the_horizon_and_non_finite_results() {
        let m = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.02, 1.0]];
        assert_eq!(project(&m, 0.0, 0.0), Some((0.0, 0.0)));
        assert!(project(&m, 0.0, -50.0).is_none()); // w = 0
        assert!(project(&m, 0.0, -60.0).is_none()); // w < 0
        assert!(project(&m, f64::NAN, 0.0).is_none());
        let huge = [[1e308, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1e-10]];
        assert!(project(&huge, 10.0, 0.0).is_none());
    }
}
