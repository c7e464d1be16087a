//! Whether a radial lens distortion can be told apart from the homography on the frames given.
//!
//! The registration sees the image only near the parts' contours. A radial distortion moves a
//! contour point `p` by `(p − c)·(k1 r² + k2 r⁴)` (r = |p − c| / focal); over a small region
//! near the image center that displacement is almost a homography, which the fit absorbs, so k1
//! and k2 are then free to run away (measured: k1 = −2.5, k2 = 83 from three small central
//! parts). This module measures, over the contour points of every frame's layer mapped through
//! the start homography, what part of each distortion term's displacement **no** homography can
//! reproduce (the least-squares residual of the term's displacement field after projecting out
//! the 8 fields of a homography perturbation), in pixels per unit k. A term is fitted only when
//! a modest coefficient (`PROBE_K`) moves the contours by at least `MIN_VISIBLE_PX` beyond what
//! the homography absorbs, and k2 only when it is also distinct from k1.

use crate::geometry::{Homography, RadialDistortion};
use crate::vectors::Layer;
use nalgebra::{DMatrix, DVector};

/// The coefficient whose effect must be visible: a mild barrel or pincushion lens.
pub const PROBE_K: f64 = 0.05;
/// The displacement (RMS over the contour points, px) `PROBE_K` must cause beyond a homography.
pub const MIN_VISIBLE_PX: f64 = 0.25;
/// Above this correlation of their unexplained fields, k1 and k2 cannot be separated.
pub const MAX_K_CORRELATION: f64 = 0.995;

/// What the frames can tell about the distortion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DistortionVisibility {
    /// RMS displacement (px) of the contours by k1 = `PROBE_K` that no homography reproduces.
    pub k1_px: f64,
    /// The same for k2.
    pub k2_px: f64,
    /// Correlation of the two unexplained fields (1: indistinguishable).
    pub correlation: f64,
    /// Contour points measured.
    pub points: usize,
    /// Their largest distance from the image center as a fraction of the half diagonal.
    pub max_radius: f64,
}

impl DistortionVisibility {
    pub fn k1_identifiable(&self) -> bool {
        self.k1_px >= MIN_VISIBLE_PX
    }

    pub fn k2_identifiable(&self) -> bool {
        self.k1_identifiable()
            && self.k2_px >= MIN_VISIBLE_PX
            && self.correlation.abs() <= MAX_K_CORRELATION
    }
}

/// Contour points (every ~1 mm) of `layers`, in image pixels through `image_from_build`.
fn contour_pixels(layers: &[&Layer], image_from_build: &Homography) -> Vec<[f64; 2]> {
    let mut out = Vec::new();
    for layer in layers {
        for p in &layer.polylines {
            for w in p.points.windows(2) {
                let (a, b) = (w[0], w[1]);
                let steps = ((b[0] - a[0]).hypot(b[1] - a[1])).ceil().clamp(1.0, 1000.0) as usize;
                for s in 0..steps {
                    let t = s as f64 / steps as f64;
                    let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
                    if let Some(q) = image_from_build.apply(x, y) {
                        out.push([q.0, q.1]);
                    }
                }
            }
        }
    }
    // Bound the work: an even subsample of at most 20,000 points.
    let stride = out.len().div_ceil(20_000).max(1);
    out.into_iter().step_by(stride).collect()
}

/// Measures how visible the distortion `lens` (its center and focal length; k ignored) is on
/// the contours of `layers` seen through `image_from_build`, in an image of `size` pixels.
pub fn visibility(
    layers: &[&Layer],
    image_from_build: &Homography,
    lens: &RadialDistortion,
    size: (u32, u32),
) -> DistortionVisibility {
    let points = contour_pixels(layers, image_from_build);
    let n = points.len();
    let f = lens.focal_px;
    let [cx, cy] = lens.center;
    let half_diagonal = 0.5 * f64::from(size.0).hypot(f64::from(size.1));
    let mut max_radius = 0.0f64;
    // Rows 2i (u) and 2i+1 (v); coordinates normalised by the focal length for conditioning.
    let mut a = DMatrix::<f64>::zeros(2 * n, 8);
    let mut b = DMatrix::<f64>::zeros(2 * n, 2);
    for (i, p) in points.iter().enumerate() {
        let (x, y) = ((p[0] - cx) / f, (p[1] - cy) / f);
        max_radius = max_radius.max((p[0] - cx).hypot(p[1] - cy) / half_diagonal);
        let r2 = x * x + y * y;
        // A homography perturbation of the image plane, linearised at the identity.
        let u_row = [x, y, 1.0, 0.0, 0.0, 0.0, -x * x, -x * y];
        let v_row = [0.0, 0.0, 0.0, x, y, 1.0, -x * y, -y * y];
        for j in 0..8 {
            a[(2 * i, j)] = u_row[j];
            a[(2 * i + 1, j)] = v_row[j];
        }
        // Displacement per unit k1 and k2 (in focal units).
        b[(2 * i, 0)] = x * r2;
        b[(2 * i + 1, 0)] = y * r2;
        b[(2 * i, 1)] = x * r2 * r2;
        b[(2 * i + 1, 1)] = y * r2 * r2;
    }
    let none = DistortionVisibility {
        k1_px: 0.0,
        k2_px: 0.0,
        correlation: 1.0,
        points: n,
        max_radius,
    };
    if n < 8 {
        return none;
    }
    let svd = a.clone().svd(true, false);
    let Some(u) = svd.u else {
        return none;
    };
    // Project out the column space of `a` (its numerically nonzero singular directions).
    let smax = svd.singular_values.max();
    let keep: Vec<usize> = (0..svd.singular_values.len())
        .filter(|&k| svd.singular_values[k] > 1e-10 * smax)
        .collect();
    let residual = |col: usize| -> DVector<f64> {
        let mut r = b.column(col).into_owned();
        for &k in &keep {
            let uk = u.column(k);
            let c = uk.dot(&r);
            r -= uk * c;
        }
        r
    };
    let (e1, e2) = (residual(0), residual(1));
    let rms_px = |e: &DVector<f64>| (e.norm_squared() / n as f64).sqrt() * f * PROBE_K;
    let correlation = if e1.norm() > 0.0 && e2.norm() > 0.0 {
        e1.dot(&e2) / (e1.norm() * e2.norm())
    } else {
        1.0
    };
    DistortionVisibility {
        k1_px: rms_px(&e1),
        k2_px: rms_px(&e2),
        correlation,
        points: n,
        max_radius,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vectors::{Direction, Polyline};

    fn square_layer(centers: &[(f64, f64)], half: f64) -> Layer {
        let mut layer = Layer::new(0, 0.03);
        for (k, &(x, y)) in centers.iter().enumerate() {
            layer.polylines.push(Polyline {
                part: k as i64 + 1,
                direction: Direction::CounterClockwise,
                points: vec![
                    [x - half, y - half],
                    [x + half, y - half],
                    [x + half, y + half],
                    [x - half, y + half],
                    [x - half, y - half],
                ],
            });
        }
        layer
    }

    fn lens() -> RadialDistortion {
        RadialDistortion {
            center: [735.5, 490.5],
            focal_px: 1840.0,
            k1: 0.0,
            k2: 0.0,
        }
    }

    /// Build mm → image px of a 1472 x 982 frame: 0.2 mm per pixel, plate center at the middle.
    fn image_from_build() -> Homography {
        Homography::from_matrix([[5.0, 0.0, 735.5], [0.0, -5.0, 490.5], [0.0, 0.0, 1.0]])
    }

    #[test]
    fn parts_spread_over_the_frame_make_the_distortion_visible() {
        let layer = square_layer(
            &[
                (-120.0, -80.0),
                (120.0, -80.0),
                (-120.0, 80.0),
                (120.0, 80.0),
                (0.0, 0.0),
            ],
            10.0,
        );
        let v = visibility(&[&layer], &image_from_build(), &lens(), (1472, 982));
        assert!(v.k1_identifiable(), "{v:?}");
        assert!(v.k1_px > 0.5, "{v:?}");
    }

    #[test]
    fn small_parts_at_the_center_hide_it() {
        let layer = square_layer(&[(-8.0, 0.0), (8.0, 4.0), (0.0, -8.0)], 3.0);
        let v = visibility(&[&layer], &image_from_build(), &lens(), (1472, 982));
        assert!(!v.k1_identifiable(), "{v:?}");
        assert!(!v.k2_identifiable(), "{v:?}");
        // Fewer than 8 points: nothing can be said.
        let empty = Layer::new(0, 0.03);
        let v = visibility(&[&empty], &image_from_build(), &lens(), (1472, 982));
        assert_eq!((v.k1_px, v.points), (0.0, 0));
    }
}
