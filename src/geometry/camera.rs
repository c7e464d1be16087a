//! The camera as the rectifier, the registration overlay and `locate` see it: a homography from
//! undistorted image pixels to build mm, and an optional radial lens distortion on the image
//! side (docs/frames.md). Points crossing module boundaries are typed by frame:
//! [`ImagePoint`] (u, v) pixels, [`BuildPoint`] (x, y) mm.

use super::{Homography, RadialDistortion};

/// A point in the image pixel frame: (u, v) = (column, row), pixel centers at integers.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImagePoint {
    pub u: f64,
    pub v: f64,
}

/// A point of the build plate in mm (the laser vectors' x, y).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct BuildPoint {
    pub x: f64,
    pub y: f64,
}

impl ImagePoint {
    pub const fn new(u: f64, v: f64) -> ImagePoint {
        ImagePoint { u, v }
    }

    /// Euclidean distance, pixels.
    pub fn distance(&self, other: &ImagePoint) -> f64 {
        (self.u - other.u).hypot(self.v - other.v)
    }
}

impl BuildPoint {
    pub const fn new(x: f64, y: f64) -> BuildPoint {
        BuildPoint { x, y }
    }

    /// Euclidean distance, mm.
    pub fn distance(&self, other: &BuildPoint) -> f64 {
        (self.x - other.x).hypot(self.y - other.y)
    }
}

/// Image pixels ↔ build mm through one camera pose: `build_from_image` maps *undistorted*
/// pixels; the camera records an undistorted pixel p at `distortion.distort(p)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraModel {
    build_from_image: Homography,
    distortion: Option<RadialDistortion>,
    /// `build_from_image⁻¹`, computed once (None when singular).
    image_from_build: Option<Homography>,
}

impl CameraModel {
    pub fn new(build_from_image: Homography, distortion: Option<RadialDistortion>) -> CameraModel {
        CameraModel {
            build_from_image,
            distortion,
            image_from_build: build_from_image.inverse(),
        }
    }

    /// A camera without lens distortion.
    pub fn pinhole(build_from_image: Homography) -> CameraModel {
        CameraModel::new(build_from_image, None)
    }

    /// Where build point `p` lands in the recorded (distorted) image: H⁻¹, then the distortion.
    /// `None` when H is singular, when `p` lies beyond the horizon (w ≤ 0), or past the radius
    /// where the distortion polynomial folds back ([`RadialDistortion::max_r2`]). The image
    /// size is not known here, so points off the frame still return `Some`.
    /// Image pixels → build mm, undistorted pixels on the image side.
    pub fn build_from_image(&self) -> Homography {
        self.build_from_image
    }

    /// The lens distortion, if any.
    pub fn distortion(&self) -> Option<RadialDistortion> {
        self.distortion
    }

    pub fn image_point(&self, p: BuildPoint) -> Option<ImagePoint> {
        let (u, v) = self.image_from_build?.apply(p.x, p.y)?;
        let (u, v) = match &self.distortion {
            None => (u, v),
            Some(d) => d.distort_within_fold(u, v)?,
        };
        Some(ImagePoint { u, v })
    }

    /// The build point a recorded pixel shows: undistort, then H. `None` beyond the horizon,
    /// for a pixel the distortion model cannot produce (past its fold), or non-finite results.
    pub fn build_point(&self, p: ImagePoint) -> Option<BuildPoint> {
        let (u, v) = match &self.distortion {
            None => (p.u, p.v),
            Some(d) => d.undistort(p.u, p.v),
        };
        let (x, y) = self.build_from_image.apply(u, v)?;
        Some(BuildPoint { x, y })
    }

    /// How much of the plate one recorded pixel covers at build point `p`: the larger of the
    /// distances (mm) to the build points of its right and lower neighbours. Nothing finer than
    /// this can be told apart in a rectified view, however fine its grid. `None` where `p` is not
    /// seen (beyond the horizon or the distortion's fold).
    pub fn footprint_mm(&self, p: BuildPoint) -> Option<f64> {
        let at = self.image_point(p)?;
        let here = self.build_point(at)?;
        let step = |du: f64, dv: f64| {
            self.build_point(ImagePoint {
                u: at.u + du,
                v: at.v + dv,
            })
            .map(|q| (q.x - here.x).hypot(q.y - here.y))
        };
        let d = step(1.0, 0.0)?.max(step(0.0, 1.0)?);
        d.is_finite().then_some(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn oblique() -> Homography {
        Homography::from_matrix([
            [0.21, 0.013, -150.0],
            [-0.004, -0.25, 120.0],
            [1.1e-5, -6.0e-5, 1.0],
        ])
    }

    #[test]
    fn image_and_build_points_round_trip_with_and_without_lens() {
        let lens = RadialDistortion {
            center: [700.0, 450.0],
            focal_px: 1800.0,
            k1: -0.08,
            k2: 0.01,
        };
        for cam in [
            CameraModel::pinhole(oblique()),
            CameraModel::new(oblique(), Some(lens)),
        ] {
            for q in [[100.0, 80.0], [1300.0, 90.0], [640.0, 512.0]] {
                let p = ImagePoint::new(q[0], q[1]);
                let b = cam.build_point(p).expect("in front");
                let back = cam.image_point(b).expect("in front");
                assert!(
                    back.distance(&p) < 1e-6,
                    "{cam:?}: {p:?} -> {b:?} -> {back:?}"
                );
            }
        }
    }

    #[test]
    fn horizon_fold_and_singular_maps_give_none() {
        let tilt = Homography::from_matrix([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.02, 1.0]]);
        let cam = CameraModel::pinhole(tilt);
        // y = v / (1 + 0.02 v) < 50 for every v in front of the camera.
        assert!(cam.image_point(BuildPoint::new(0.0, 60.0)).is_none());
        assert!(cam.image_point(BuildPoint::new(0.0, 10.0)).is_some());
        assert!(cam.build_point(ImagePoint::new(0.0, -80.0)).is_none());
        // Strong barrel: the polynomial folds back at r² = 1/(3·0.5) (normalised).
        let fold = RadialDistortion {
            center: [0.0, 0.0],
            focal_px: 100.0,
            k1: -0.5,
            k2: 0.0,
        };
        let cam = CameraModel::new(Homography::IDENTITY, Some(fold));
        assert!(cam.image_point(BuildPoint::new(50.0, 0.0)).is_some());
        assert!(cam.image_point(BuildPoint::new(90.0, 0.0)).is_none());
        assert!(cam.build_point(ImagePoint::new(5000.0, 0.0)).is_none());
        let singular = Homography::from_matrix([[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]);
        assert!(CameraModel::pinhole(singular)
            .image_point(BuildPoint::new(1.0, 1.0))
            .is_none());
    }

    #[test]
    fn footprint_is_the_plate_distance_of_one_pixel() {
        // 0.25 mm per pixel along u, 0.4 along v.
        let h = Homography::from_matrix([[0.25, 0.0, -10.0], [0.0, 0.4, -20.0], [0.0, 0.0, 1.0]]);
        let camera = CameraModel::pinhole(h);
        let f = camera.footprint_mm(BuildPoint { x: 3.0, y: 4.0 }).unwrap();
        assert!((f - 0.4).abs() < 1e-9, "{f}");
    }
}
