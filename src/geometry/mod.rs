//! Geometry shared by every layer above: the build frame's grids, plane projective maps, lens
//! distortion and 3D rigid/affine transforms (docs/frames.md). Transforms are named by their
//! frames (`build_from_image` maps image pixels to build mm).

pub mod camera;
pub mod clip;
pub mod distortion;
pub mod grid;
pub mod homography;
pub(crate) mod mat3;
pub mod rigid;

pub use camera::{BuildPoint, CameraModel, ImagePoint};
pub use clip::clip_segment;
pub use distortion::{DistortionError, RadialDistortion};
pub use grid::{
    Grid, GridError, Interpolation, DEFAULT_PIXEL_MM, MAX_PIXELS, MAX_SIDE, PLATE_HALF_MM,
};
pub use homography::{homography_from_points, DltError, Homography, PointSet};
pub use mat3::Mat3;
pub use rigid::{Affine3, Rigid3};
