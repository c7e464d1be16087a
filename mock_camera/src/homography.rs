//! Image → build homography: the ground truth the mock camera renders through, so calibration
//! code can be checked against it (docs/frames.md: (u, v, 1) ↦ (x, y, 1) up to scale, in mm).

/// Image (u,v) px -> build (x,y) mm, H[2][2] == 1.
///
/// Pixel centers are at integer (u, v); (0, 0) is the center of the top-left pixel. The inverse
/// maps build mm to image px.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Homography {
    /// Row-major 3x3 matrix; `m[2][2] == 1` whenever it could be normalised.
    pub m: [[f64; 3]; 3],
}

/// Distance from the camera's optical center to the plate center used by
/// [`Homography::oblique_view`], in mm. Only the ratio to the plate size matters (perspective
/// strength); 600 mm gives a clearly trapezoidal plate, as a D810 in a chamber window would see.
const CAMERA_DISTANCE_MM: f64 = 600.0;
/// Camera tilt from the plate normal used by [`Homography::oblique_view`].
const CAMERA_TILT_DEG: f64 = 30.0;
/// Half the plate side, mm (ProX320: 275 x 275 mm centered on 0, 0).
const PLATE_HALF_MM: f64 = 137.5;
/// Fraction of the image half-size left free around the plate by [`Homography::oblique_view`].
const VIEW_MARGIN: f64 = 0.05;

impl Homography {
    /// Wraps `m`, scaled so that `m[2][2] == 1` as the frame contract requires. A matrix whose
    /// `m[2][2]` is zero (image origin on the horizon) or not finite cannot be normalised and is
    /// kept as given.
    pub fn new(m: [[f64; 3]; 3]) -> Homography {
        let s = m[2][2];
        if s.is_finite() && s.abs() > f64::MIN_POSITIVE && s != 1.0 {
            let mut n = m;
            for row in n.iter_mut() {
                for v in row.iter_mut() {
                    *v /= s;
                }
            }
            n[2][2] = 1.0;
            Homography { m: n }
        } else {
            Homography { m }
        }
    }

    /// Maps image (u, v) px to build (x, y) mm. `None` when the point maps to infinity (w ≈ 0,
    /// i.e. on the horizon line of the view) or the result is not finite.
    pub fn apply(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let m = &self.m;
        let w = m[2][0] * u + m[2][1] * v + m[2][2];
        let w_scale = (m[2][0] * u).abs() + (m[2][1] * v).abs() + m[2][2].abs();
        if !significant(w, 1e-12 * w_scale) {
            return None;
        }
        let x = (m[0][0] * u + m[0][1] * v + m[0][2]) / w;
        let y = (m[1][0] * u + m[1][1] * v + m[1][2]) / w;
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }

    /// The build → image homography, normalised to `m[2][2] == 1`. `None` if the matrix is
    /// singular, or if its inverse cannot be normalised (build origin on the image's horizon).
    pub fn inverse(&self) -> Option<Homography> {
        let inv = inverse3(&self.m)?;
        let s = inv[2][2];
        if !significant(s, 1e-12 * max_abs(&inv)) {
            return None;
        }
        Some(Homography::new(inv))
    }

    /// A plausible oblique view: the camera 30° off-normal looking at the plate so that the whole
    /// 275 mm plate plus a small margin fills a width x height sensor, with perspective (rows near
    /// the top of the image see the far edge, so the plate appears as a trapezoid). Build it from
    /// 4 point correspondences (plate corners -> image trapezoid corners) solved by a DLT/8x8 linear
    /// solve. Deterministic.
    ///
    /// Pinhole model: the camera sits on the front (−y) side, its optical axis through the plate
    /// center and the image center, image x along build +x, image up toward build +y (far edge).
    /// Sizes below 2 px are treated as 2 px.
    pub fn oblique_view(width: u32, height: u32) -> Homography {
        let (s, c) = CAMERA_TILT_DEG.to_radians().sin_cos();
        let d = CAMERA_DISTANCE_MM;
        // Camera at (0, −d·s, d·c) looking at the origin: for a plate point (x, y, 0) the
        // normalised image coordinates are u' = x / (d + s·y), v' = −c·y / (d + s·y).
        let project = |x: f64, y: f64| (x / (d + s * y), -c * y / (d + s * y));
        let cu = (f64::from(width.max(2)) - 1.0) / 2.0;
        let cv = (f64::from(height.max(2)) - 1.0) / 2.0;
        // The near edge (y = −half) is the widest and lowest part of the trapezoid.
        let (max_u, max_v) = project(PLATE_HALF_MM, -PLATE_HALF_MM);
        let k = (cu * (1.0 - VIEW_MARGIN) / max_u).min(cv * (1.0 - VIEW_MARGIN) / max_v);
        let h = PLATE_HALF_MM;
        let build = [(-h, -h), (h, -h), (h, h), (-h, h)];
        let mut image = [(0.0, 0.0); 4];
        for (img, &(x, y)) in image.iter_mut().zip(build.iter()) {
            let (pu, pv) = project(x, y);
            *img = (cu + k * pu, cv + k * pv);
        }
        Homography::from_correspondences(&image, &build).unwrap_or_else(|| {
            // Unreachable for the fixed, non-degenerate trapezoid above; an affine plate-fills-
            // the-image map keeps this total without a panic path.
            let sx = 2.0 * h / (2.0 * cu);
            let sy = 2.0 * h / (2.0 * cv);
            Homography::new([[sx, 0.0, -h], [0.0, -sy, h], [0.0, 0.0, 1.0]])
        })
    }

    /// The homography mapping each `image_pts[i]` (px) exactly onto `build_pts[i]` (mm), from a
    /// Hartley-normalised DLT (8x8 solve with h33 = 1). `None` for degenerate input (three
    /// collinear points, repeated points, non-finite values) or if the image origin would map to
    /// infinity (then H[2][2] cannot be 1).
    pub fn from_correspondences(
        image_pts: &[(f64, f64); 4],
        build_pts: &[(f64, f64); 4],
    ) -> Option<Homography> {
        let ti = normalising_transform(image_pts)?;
        let tb = normalising_transform(build_pts)?;
        let mut a = [[0.0f64; 8]; 8];
        let mut b = [0.0f64; 8];
        for i in 0..4 {
            let (u, v) = apply_affine(&ti, image_pts[i]);
            let (x, y) = apply_affine(&tb, build_pts[i]);
            // x·(h31 u + h32 v + 1) = h11 u + h12 v + h13, likewise for y.
            a[2 * i] = [u, v, 1.0, 0.0, 0.0, 0.0, -u * x, -v * x];
            b[2 * i] = x;
            a[2 * i + 1] = [0.0, 0.0, 0.0, u, v, 1.0, -u * y, -v * y];
            b[2 * i + 1] = y;
        }
        let h = solve8(a, b)?;
        let hn = [[h[0], h[1], h[2]], [h[3], h[4], h[5]], [h[6], h[7], 1.0]];
        // H = Tb⁻¹ · Hn · Ti
        let tb_inv = inverse3(&tb)?;
        let full = mul3(&mul3(&tb_inv, &hn), &ti);
        if !significant(full[2][2], 1e-12 * max_abs(&full))
            || full.iter().flatten().any(|v| !v.is_finite())
        {
            return None;
        }
        Some(Homography::new(full))
    }
}

/// Similarity transform taking the points' centroid to 0 and their mean distance to √2
/// (Hartley), so the 8x8 system is well conditioned for pixel coordinates in the thousands.
fn normalising_transform(pts: &[(f64, f64); 4]) -> Option<[[f64; 3]; 3]> {
    if pts.iter().any(|(x, y)| !x.is_finite() || !y.is_finite()) {
        return None;
    }
    let cx = pts.iter().map(|p| p.0).sum::<f64>() / 4.0;
    let cy = pts.iter().map(|p| p.1).sum::<f64>() / 4.0;
    let mean_d = pts.iter().map(|p| (p.0 - cx).hypot(p.1 - cy)).sum::<f64>() / 4.0;
    if !significant(mean_d, 0.0) {
        return None;
    }
    let s = std::f64::consts::SQRT_2 / mean_d;
    Some([[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]])
}

/// `|value| > threshold`; false for NaN, so degenerate input is rejected rather than used.
fn significant(value: f64, threshold: f64) -> bool {
    value.abs() > threshold
}

fn apply_affine(t: &[[f64; 3]; 3], p: (f64, f64)) -> (f64, f64) {
    (
        t[0][0] * p.0 + t[0][1] * p.1 + t[0][2],
        t[1][0] * p.0 + t[1][1] * p.1 + t[1][2],
    )
}

/// Gaussian elimination with partial pivoting; `None` if (numerically) singular.
fn solve8(mut a: [[f64; 8]; 8], mut b: [f64; 8]) -> Option<[f64; 8]> {
    for col in 0..8 {
        let pivot = (col..8).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if !significant(a[pivot][col], 1e-10) {
            return None;
        }
        a.swap(col, pivot);
        b.swap(col, pivot);
        for row in col + 1..8 {
            let f = a[row][col] / a[col][col];
            if f != 0.0 {
                let pivot_row = a[col];
                for (dst, src) in a[row].iter_mut().zip(pivot_row.iter()).skip(col) {
                    *dst -= f * src;
                }
                b[row] -= f * b[col];
            }
        }
    }
    let mut x = [0.0f64; 8];
    for row in (0..8).rev() {
        let tail: f64 = (row + 1..8).map(|k| a[row][k] * x[k]).sum();
        x[row] = (b[row] - tail) / a[row][row];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

fn mul3(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn max_abs(m: &[[f64; 3]; 3]) -> f64 {
    m.iter().flatten().fold(0.0, |acc, v| acc.max(v.abs()))
}

/// Adjugate / determinant; `None` if singular relative to the entries' scale or not finite.
fn inverse3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c =
        |r0: usize, c0: usize, r1: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    let adj = [
        [c(1, 1, 2, 2), -c(0, 1, 2, 2), c(0, 1, 1, 2)],
        [-c(1, 0, 2, 2), c(0, 0, 2, 2), -c(0, 0, 1, 2)],
        [c(1, 0, 2, 1), -c(0, 0, 2, 1), c(0, 0, 1, 1)],
    ];
    let det = m[0][0] * adj[0][0] + m[0][1] * adj[1][0] + m[0][2] * adj[2][0];
    let scale = max_abs(m);
    if !det.is_finite() || !significant(det, 1e-14 * scale * scale * scale) {
        return None;
    }
    let mut inv = adj;
    for v in inv.iter_mut().flatten() {
        *v /= det;
    }
    inv.iter().flatten().all(|v| v.is_finite()).then_some(inv)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: (f64, f64), b: (f64, f64), tol: f64) -> bool {
        (a.0 - b.0).abs() <= tol && (a.1 - b.1).abs() <= tol
    }

    #[test]
    fn new_normalises_h33() {
        let h = Homography::new([[2.0, 0.0, 4.0], [0.0, 2.0, 6.0], [0.0, 0.0, 2.0]]);
        assert_eq!(h.m, [[1.0, 0.0, 2.0], [0.0, 1.0, 3.0], [0.0, 0.0, 1.0]]);
        assert_eq!(h.apply(1.0, 1.0), Some((3.0, 4.0)));
    }

    #[test]
    fn apply_is_none_on_the_horizon() {
        // w = 0.01·u + 1 vanishes at u = −100.
        let h = Homography::new([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.01, 0.0, 1.0]]);
        assert_eq!(h.apply(-100.0, 5.0), None);
        assert!(h.apply(-99.0, 5.0).is_some());
    }

    #[test]
    fn from_correspondences_reproduces_the_four_points() {
        let image = [
            (120.0, 80.0),
            (1100.0, 60.0),
            (1180.0, 760.0),
            (30.0, 700.0),
        ];
        let build = [
            (-137.5, 137.5),
            (137.5, 137.5),
            (137.5, -137.5),
            (-137.5, -137.5),
        ];
        let h = Homography::from_correspondences(&image, &build).expect("non-degenerate");
        assert_eq!(h.m[2][2], 1.0);
        for (i, b) in image.iter().zip(build.iter()) {
            let got = h.apply(i.0, i.1).expect("finite");
            assert!(close(got, *b, 1e-9), "{i:?} -> {got:?}, want {b:?}");
        }
    }

    #[test]
    fn from_correspondences_rejects_degenerate_input() {
        let collinear = [(0.0, 0.0), (1.0, 1.0), (2.0, 2.0), (3.0, 3.0)];
        let build = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        assert_eq!(Homography::from_correspondences(&collinear, &build), None);
        let repeated = [(5.0, 5.0); 4];
        assert_eq!(Homography::from_correspondences(&repeated, &build), None);
        let nan = [(f64::NAN, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        assert_eq!(Homography::from_correspondences(&nan, &build), None);
    }

    #[test]
    fn inverse_after_apply_is_identity() {
        let h = Homography::oblique_view(7360, 4912);
        let inv = h.inverse().expect("invertible");
        assert_eq!(inv.m[2][2], 1.0);
        for &(u, v) in &[
            (0.0, 0.0),
            (3679.5, 2455.5),
            (7359.0, 4911.0),
            (1234.5, 4000.25),
        ] {
            let (x, y) = h.apply(u, v).expect("finite");
            let back = inv.apply(x, y).expect("finite");
            assert!(close(back, (u, v), 1e-9 * 7360.0), "{u},{v} -> {back:?}");
        }
        for &(x, y) in &[(0.0, 0.0), (-137.5, 137.5), (100.0, -50.0)] {
            let (u, v) = inv.apply(x, y).expect("finite");
            let back = h.apply(u, v).expect("finite");
            assert!(close(back, (x, y), 1e-9), "{x},{y} -> {back:?}");
        }
    }

    #[test]
    fn singular_matrix_has_no_inverse() {
        let h = Homography::new([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]);
        assert_eq!(h.inverse(), None);
    }

    #[test]
    fn oblique_view_frames_the_plate_with_perspective() {
        for &(w, hgt) in &[(7360u32, 4912u32), (1200, 800), (640, 640)] {
            let h = Homography::oblique_view(w, hgt);
            assert_eq!(h, Homography::oblique_view(w, hgt), "deterministic");
            let inv = h.inverse().expect("invertible");
            let corners = [
                (-137.5, -137.5),
                (137.5, -137.5),
                (137.5, 137.5),
                (-137.5, 137.5),
            ];
            let img: Vec<(f64, f64)> = corners
                .iter()
                .map(|&(x, y)| inv.apply(x, y).expect("finite"))
                .collect();
            for &(u, v) in &img {
                assert!(u >= 0.0 && u <= f64::from(w) - 1.0, "{w}x{hgt}: u {u}");
                assert!(v >= 0.0 && v <= f64::from(hgt) - 1.0, "{w}x{hgt}: v {v}");
            }
            // The plate fills most of the limiting dimension (small margin only).
            let width_near = img[1].0 - img[0].0;
            let height_px = img[0].1 - img[3].1;
            assert!(
                width_near > 0.85 * f64::from(w) || img[0].1 > 0.9 * f64::from(hgt),
                "{w}x{hgt}: plate too small"
            );
            // Far edge (y = +137.5) is at the top of the image and narrower: perspective.
            let width_far = img[2].0 - img[3].0;
            assert!(img[3].1 < img[0].1 && height_px > 0.0);
            assert!(
                width_far < 0.9 * width_near,
                "far {width_far} near {width_near}"
            );
            // The image center looks at the plate center.
            let cu = (f64::from(w) - 1.0) / 2.0;
            let cv = (f64::from(hgt) - 1.0) / 2.0;
            let center = h.apply(cu, cv).expect("finite");
            assert!(close(center, (0.0, 0.0), 1e-6), "center -> {center:?}");
            // Image x runs along build +x; image up runs toward build +y.
            let right = h.apply(cu + 10.0, cv).expect("finite");
            let up = h.apply(cu, cv - 10.0).expect("finite");
            assert!(right.0 > 0.0 && right.1.abs() < 1e-9);
            assert!(up.1 > 0.0 && up.0.abs() < 1e-9);
        }
    }

    #[test]
    fn oblique_view_survives_tiny_sizes() {
        for &(w, hgt) in &[(0u32, 0u32), (1, 1), (2, 1)] {
            let h = Homography::oblique_view(w, hgt);
            assert!(h.m.iter().flatten().all(|v| v.is_finite()));
            assert!(h.inverse().is_some());
        }
    }
}
