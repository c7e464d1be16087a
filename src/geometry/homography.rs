//! [`Homography`]: a plane projective map, named in code by its frames (`build_from_image` maps
//! image pixels to build mm, docs/frames.md), and the one direct linear transform (DLT) that
//! estimates it from point correspondences.

// `!(x > y)` is deliberate: a NaN must fail the check.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use nalgebra::{DMatrix, Matrix3};

use super::mat3::{self, Mat3};
use super::Grid;

/// A plane projective map: (a, b, 1) ↦ (p, q, 1) up to scale, as a 3x3 matrix.
///
/// Name values by their frames, `to_from_from`: `build_from_image` maps image pixels to build
/// mm, `image_from_build` is its inverse, `build_from_grid` the grid's pixel → mm map. Then
/// `build_from_image.compose(&image_from_grid)` reads as it chains (inner frames match).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography(Mat3);

impl Default for Homography {
    fn default() -> Self {
        Homography::IDENTITY
    }
}

impl Homography {
    pub const IDENTITY: Homography = Homography(mat3::IDENTITY);

    /// The map of `m` (row-major, acting on column vectors), taken as is: not normalised.
    pub const fn from_matrix(m: Mat3) -> Homography {
        Homography(m)
    }

    /// The matrix, row-major.
    pub const fn matrix(&self) -> Mat3 {
        self.0
    }

    /// The grid's pixel → build map, `build_from_grid`: (c, r) ↦ the center of pixel (r, c)
    /// (docs/frames.md).
    pub fn build_from_grid(grid: &Grid) -> Homography {
        Homography(mat3::grid_matrix(grid))
    }

    /// Whether every entry is finite.
    pub fn is_finite(&self) -> bool {
        self.0.iter().flatten().all(|v| v.is_finite())
    }

    /// Scale-free singularity measure `|det| / (|row0|·|row1|·|row2|)` in [0, 1].
    pub fn singularity(&self) -> f64 {
        mat3::singularity(&self.0)
    }

    /// The inverse map (adjugate); `None` when (nearly) singular or not finite.
    pub fn inverse(&self) -> Option<Homography> {
        mat3::mat_inv(&self.0).map(Homography)
    }

    /// `self ∘ first`: maps by `first`, then by `self` (the matrix product `self · first`).
    /// `b_from_a = b_from_c.compose(&c_from_a)`.
    pub fn compose(&self, first: &Homography) -> Homography {
        Homography(mat3::mul(&self.0, &first.0))
    }

    /// `next ∘ self`: maps by `self`, then by `next` (the matrix product `next · self`).
    /// `b_from_a = c_from_a.then(&b_from_c)`.
    pub fn then(&self, next: &Homography) -> Homography {
        next.compose(self)
    }

    /// The image of (a, b); `None` beyond the horizon (w ≤ 0) or where the result is not finite.
    pub fn apply(&self, a: f64, b: f64) -> Option<(f64, f64)> {
        mat3::project(&self.0, a, b)
    }

    /// The same map scaled so that `H[2][2] = 1` (docs/frames.md); `None` when `H[2][2]` is 0
    /// (or negligible against the other entries) or the result is not finite.
    pub fn normalised(&self) -> Option<Homography> {
        let h = &self.0;
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
        let out = Homography(out);
        out.is_finite().then_some(out)
    }

    /// The map taking each `from[i]` to `to[i]` (`H[2][2] = 1`), by the normalized DLT
    /// (Hartley & Zisserman, algorithm 4.2): both sets moved to centroid 0 and mean distance
    /// √2, the 2n x 9 system solved by SVD, then denormalised. Exact for 4 points, least
    /// squares (algebraic) for more.
    ///
    /// Refuses fewer than 4 points, sets of different lengths, duplicates (in either set),
    /// three collinear points of four, all points collinear, or a rank-deficient system.
    pub fn from_correspondences(
        from: &[[f64; 2]],
        to: &[[f64; 2]],
    ) -> Result<Homography, DltError> {
        let n = from.len();
        if to.len() != n {
            return Err(DltError::LengthMismatch {
                from: n,
                to: to.len(),
            });
        }
        if n < 4 {
            return Err(DltError::TooFew { count: n });
        }
        if from.iter().chain(to).flatten().any(|v| !v.is_finite()) {
            return Err(DltError::NonFinite);
        }
        for (set, pts) in [(PointSet::From, from), (PointSet::To, to)] {
            check_spread(set, pts)?;
        }
        let tf = normaliser(from);
        let tt = normaliser(to);
        let apply = |t: &Mat3, p: [f64; 2]| [t[0][0] * p[0] + t[0][2], t[1][1] * p[1] + t[1][2]];
        // At least 9 rows so the SVD yields the full 9 x 9 V even for n = 4 (extra rows are 0).
        let rows = (2 * n).max(9);
        let mut a = DMatrix::<f64>::zeros(rows, 9);
        for k in 0..n {
            let [u, v] = apply(&tf, from[k]);
            let [x, y] = apply(&tt, to[k]);
            // x' × (H x) = 0 with x = (u, v, 1), x' = (x, y, 1).
            let r0 = [-u, -v, -1.0, 0.0, 0.0, 0.0, x * u, x * v, x];
            let r1 = [0.0, 0.0, 0.0, -u, -v, -1.0, y * u, y * v, y];
            for c in 0..9 {
                a[(2 * k, c)] = r0[c];
                a[(2 * k + 1, c)] = r1[c];
            }
        }
        let svd = a.svd(false, true);
        let v_t = svd.v_t.as_ref().ok_or(DltError::SvdFailed)?;
        let sv = &svd.singular_values;
        let mut order: Vec<usize> = (0..sv.len()).collect();
        order.sort_by(|&i, &j| sv[i].total_cmp(&sv[j]));
        let (smallest, second) = (order[0], order[1]);
        // A second (near-)zero singular value: the points do not pin down one homography.
        if !(sv[second] > 1e-9 * sv[order[sv.len() - 1]]) {
            return Err(DltError::RankDeficient);
        }
        let h = v_t.row(smallest);
        let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
        let to_na = |m: &Mat3| Matrix3::from_fn(|r, c| m[r][c]);
        let tt_inv = to_na(&tt).try_inverse().ok_or(DltError::Singular)?;
        let full = tt_inv * hn * to_na(&tf);
        let s = full[(2, 2)];
        if !(s.abs() > 1e-12 * full.abs().max()) {
            return Err(DltError::OriginAtInfinity);
        }
        let mut out = [[0.0; 3]; 3];
        for (r, row) in out.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = full[(r, c)] / s;
            }
        }
        let out = Homography(out);
        if !out.is_finite() || !(out.singularity() > 1e-12) {
            return Err(DltError::Singular);
        }
        Ok(out)
    }
}

/// The exact map of four correspondences (a convenience over
/// [`Homography::from_correspondences`]): `image[i]` (u, v) ↦ `build[i]` (x, y), i.e.
/// `build_from_image`.
pub fn homography_from_points(
    image: [[f64; 2]; 4],
    build: [[f64; 2]; 4],
) -> Result<Homography, DltError> {
    Homography::from_correspondences(&image, &build)
}

/// Which side of the correspondences a [`DltError`] is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PointSet {
    /// The points mapped from (the image, for `build_from_image`).
    From,
    /// The points mapped to (the build plate, for `build_from_image`).
    To,
}

impl std::fmt::Display for PointSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            PointSet::From => "source",
            PointSet::To => "target",
        })
    }
}

/// Point correspondences from which no homography follows. Indices are 0-based positions in
/// the slices given.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DltError {
    #[error("{count} correspondence(s); a homography needs at least 4")]
    TooFew { count: usize },
    #[error("{from} source points but {to} target points")]
    LengthMismatch { from: usize, to: usize },
    #[error("a point has a non-finite coordinate")]
    NonFinite,
    #[error("points {first} and {second}: duplicate {set} points")]
    Duplicate {
        set: PointSet,
        first: usize,
        second: usize,
    },
    #[error("points {}, {} and {}: the {set} points are collinear", .points[0], .points[1], .points[2])]
    Collinear { set: PointSet, points: [usize; 3] },
    #[error("all {set} points lie on one line")]
    AllCollinear { set: PointSet },
    #[error("singular value decomposition failed")]
    SvdFailed,
    #[error("the correspondences are rank-deficient (degenerate configuration)")]
    RankDeficient,
    #[error("the source origin maps to infinity: H[2][2] would be 0")]
    OriginAtInfinity,
    #[error("the correspondences give a singular homography")]
    Singular,
}

/// Refuses duplicates and (for four points) collinear triples, or (for more) one line.
fn check_spread(set: PointSet, p: &[[f64; 2]]) -> Result<(), DltError> {
    let n = p.len();
    let (_, _, spread) = centroid_spread(p);
    for i in 0..n {
        for j in i + 1..n {
            let d = (p[i][0] - p[j][0]).hypot(p[i][1] - p[j][1]);
            if !(d > 1e-6 * spread) {
                return Err(DltError::Duplicate {
                    set,
                    first: i,
                    second: j,
                });
            }
        }
    }
    if n == 4 {
        for skip in 0..4 {
            let idx: Vec<usize> = (0..4).filter(|&k| k != skip).collect();
            if collinear(p[idx[0]], p[idx[1]], p[idx[2]]) {
                return Err(DltError::Collinear {
                    set,
                    points: [idx[0], idx[1], idx[2]],
                });
            }
        }
    } else if all_collinear(p) {
        return Err(DltError::AllCollinear { set });
    }
    Ok(())
}

/// Centroid and mean distance to it (Hartley normalisation's figures).
pub fn centroid_spread(p: &[[f64; 2]]) -> (f64, f64, f64) {
    let n = p.len() as f64;
    let cx = p.iter().map(|q| q[0]).sum::<f64>() / n;
    let cy = p.iter().map(|q| q[1]).sum::<f64>() / n;
    let d = p.iter().map(|q| (q[0] - cx).hypot(q[1] - cy)).sum::<f64>() / n;
    (cx, cy, d)
}

/// Similarity moving the centroid to 0 and the mean distance to √2 (Hartley normalisation).
fn normaliser(p: &[[f64; 2]]) -> Mat3 {
    let (cx, cy, d) = centroid_spread(p);
    let s = std::f64::consts::SQRT_2 / d;
    [[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]]
}

/// Three points on (nearly) one line: the triangle's height over its longest side is below
/// 1e-3 of that side (a user's four clicks need a real spread, not just a nonzero one).
fn collinear(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> bool {
    let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let longest2 = [(a, b), (b, c), (c, a)]
        .iter()
        .map(|(p, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
        .fold(0.0, f64::max);
    // height = |cross| / longest, compared with 1e-3·longest.
    !(cross.abs() > 1e-3 * longest2)
}

/// All points on (nearly) one line: the smaller principal axis of their scatter is tiny.
fn all_collinear(p: &[[f64; 2]]) -> bool {
    let (cx, cy, _) = centroid_spread(p);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for q in p {
        let (dx, dy) = (q[0] - cx, q[1] - cy);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
    let (big, small) = (tr / 2.0 + disc, tr / 2.0 - disc);
    !(small > 1e-6 * big)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Homography {
        Homography::from_matrix([
            [0.21, 0.013, -150.0],
            [-0.004, -0.25, 120.0],
            [1.1e-5, -6.0e-5, 1.0],
        ])
    }

    fn mapped(uv: &[[f64; 2]]) -> Vec<[f64; 2]> {
        uv.iter()
            .map(|p| {
                let (x, y) = truth().apply(p[0], p[1]).expect("in front");
                [x, y]
            })
            .collect()
    }

    #[test]
    fn dlt_recovers_the_map_from_4_and_from_many() {
        let four = [
            [100.0, 80.0],
            [1300.0, 90.0],
            [1250.0, 900.0],
            [60.0, 850.0],
        ];
        let many = [four.as_slice(), &[[700.0, 500.0], [400.0, 300.0]]].concat();
        for pts in [four.to_vec(), many] {
            let h = Homography::from_correspondences(&pts, &mapped(&pts)).expect("regular");
            assert_eq!(h.matrix()[2][2], 1.0);
            for (got, want) in h
                .matrix()
                .iter()
                .flatten()
                .zip(truth().matrix().iter().flatten())
            {
                assert!((got - want).abs() <= 1e-9 * want.abs().max(1e-3), "{h:?}");
            }
        }
        let four_arr: [[f64; 2]; 4] = four;
        let b = mapped(&four);
        let h = homography_from_points(four_arr, [b[0], b[1], b[2], b[3]]).expect("regular");
        for p in four {
            let (x, y) = h.apply(p[0], p[1]).expect("front");
            let (ex, ey) = truth().apply(p[0], p[1]).expect("front");
            assert!((x - ex).abs() < 1e-9 && (y - ey).abs() < 1e-9);
        }
    }

    #[test]
    fn dlt_names_degenerate_sets() {
        let h = |from: &[[f64; 2]]| Homography::from_correspondences(from, &mapped(from));
        assert_eq!(
            h(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]),
            Err(DltError::TooFew { count: 3 })
        );
        assert_eq!(
            h(&[[0.0, 0.0], [10.0, 10.0], [20.0, 20.0], [0.0, 50.0]]),
            Err(DltError::Collinear {
                set: PointSet::From,
                points: [0, 1, 2]
            })
        );
        assert_eq!(
            h(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 0.0]]),
            Err(DltError::Duplicate {
                set: PointSet::From,
                first: 1,
                second: 3
            })
        );
        assert_eq!(
            h(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0]]),
            Err(DltError::AllCollinear {
                set: PointSet::From
            })
        );
        let from = [[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]];
        let mut to = mapped(&from);
        to[3] = to[0];
        assert!(matches!(
            Homography::from_correspondences(&from, &to),
            Err(DltError::Duplicate {
                set: PointSet::To,
                ..
            })
        ));
        assert!(matches!(
            Homography::from_correspondences(&from, &to[..3]),
            Err(DltError::LengthMismatch { .. })
        ));
    }

    #[test]
    fn compose_then_inverse_and_normalised() {
        let a = truth();
        let b = Homography::from_matrix([[2.0, 0.0, 5.0], [0.0, 3.0, -1.0], [0.0, 0.0, 1.0]]);
        let (u, v) = (321.0, 456.0);
        let (x, y) = a.apply(u, v).unwrap();
        let want = b.apply(x, y).unwrap();
        // b ∘ a: a first.
        let c = b.compose(&a);
        assert_eq!(c, a.then(&b));
        let got = c.apply(u, v).unwrap();
        assert!((got.0 - want.0).abs() < 1e-9 && (got.1 - want.1).abs() < 1e-9);
        let back = a.inverse().unwrap().apply(x, y).unwrap();
        assert!((back.0 - u).abs() < 1e-9 && (back.1 - v).abs() < 1e-9);
        assert!(Homography::from_matrix([[0.0; 3]; 3]).inverse().is_none());
        let n = Homography::from_matrix([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 4.0]])
            .normalised()
            .unwrap();
        assert_eq!(n.matrix()[2][2], 1.0);
        assert_eq!(n.matrix()[0][0], 0.5);
        let zero22 = Homography::from_matrix([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]]);
        assert!(zero22.normalised().is_none());
    }

    #[test]
    fn build_from_grid_follows_the_frame_contract() {
        let grid = Grid {
            x_min: -10.0,
            x_max: 10.0,
            y_min: -5.0,
            y_max: 5.0,
            pixel_mm: 0.5,
        };
        let g = Homography::build_from_grid(&grid);
        for (r, c) in [(0.0, 0.0), (3.0, 7.0), (19.0, 39.0)] {
            let (x, y) = g.apply(c, r).expect("affine");
            let (ex, ey) = grid.center_of(r, c);
            assert!((x - ex).abs() < 1e-12 && (y - ey).abs() < 1e-12);
        }
    }
}
