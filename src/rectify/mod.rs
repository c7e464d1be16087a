//! Camera frame → top-down build-plate view.
//!
//! Conventions (docs/frames.md):
//! - image pixel frame (u, v) = (column, row), pixel centers at integers,
//!   (0, 0) the center of the top-left pixel;
//! - the homography H (`H[2][2]` = 1) maps undistorted image (u, v, 1) to build
//!   (x, y, 1) in mm, up to scale;
//! - [`Grid`] pixel (r, c) has its center at
//!   (x_min + (c + ½)·pixel_mm, y_max − (r + ½)·pixel_mm);
//! - optional [`RadialDistortion`] maps undistorted pixels to where the camera
//!   records them.
//!
//! Rectifying walks grid pixel → build point → H⁻¹ → (distortion) → sample.
//!
//! # Sampling and borders
//! Source positions are rounded to 1/2048 px; bilinear is then exact integer
//! arithmetic (within ±1 grey level of an f64 bilinear, and of OpenCV's
//! `warpPerspective(INTER_LINEAR)`). A grid pixel is *inside* iff its rounded
//! position lies in the closed rectangle of source pixel centers,
//! `0 ≤ u ≤ W−1`, `0 ≤ v ≤ H−1` (its whole 2x2 neighbourhood is in the
//! image); every other grid pixel gets `fill`, unblended. OpenCV's
//! `BORDER_CONSTANT` blends with the border value up to one pixel beyond that
//! rectangle instead, so the two differ only in that one-pixel band. Points
//! beyond the horizon (homogeneous w ≤ 0) and past the fold of the distortion
//! polynomial are outside too. Sources wider or taller than
//! [`MAX_SOURCE_SIDE`] are treated as entirely outside.
//!
//! # Performance
//! Rows are split over rayon; per row the mapping is incremental and the 8-bit
//! bilinear kernels use AVX2, or AVX-512 when the CPU has it (runtime detection, scalar
//! fallback with identical results). With distortion, the first call builds a
//! cached position map (8 bytes per grid pixel, 155 MB for the plate grid).
//! Output buffers are fresh per call unless the `*_into` variants are used.

pub mod calibration;
mod decode;
mod file;
mod footprint;
mod frame;
mod jpeg_luma;
mod jpeg_scan;
mod kernel;
mod luma_decode;
mod os;
mod positions;
#[cfg(feature = "nef")]
pub mod raw;
mod reuse;
mod row;
#[cfg(target_arch = "x86_64")]
mod simd;
mod srgb;
#[cfg(test)]
mod tests;
mod tiff_bounds;
mod warp;

use image::{ImageBuffer, Luma, Rgb};

pub use crate::geometry::{CameraModel, Grid, RadialDistortion};
pub use calibration::{Calibration, CalibrationError};
pub use decode::{decode_jpeg, luma};
pub use file::{rectify_file, RectifyFileError};
pub use frame::{decode_frame, decode_frame_luma, decode_frame_luma_for, FrameLuma};
pub use luma_decode::{decode_jpeg_luma, decode_jpeg_luma_for};
pub use warp::{Rectifier, MAX_SOURCE_SIDE};

/// 16-bit single-channel image.
pub type Gray16Image = ImageBuffer<Luma<u16>, Vec<u16>>;
/// 16-bit RGB image.
pub type Rgb16Image = ImageBuffer<Rgb<u16>, Vec<u16>>;

/// Resampling kernel (defined with the grid it samples onto).
pub use crate::geometry::Interpolation;

#[derive(Debug, thiserror::Error)]
pub enum RectifyError {
    #[error("homography has a non-finite entry")]
    NonFiniteHomography,
    #[error("homography has H[2][2] = 0, so it cannot be normalised to H[2][2] = 1")]
    ZeroH22,
    #[error(
        "homography is singular or nearly so (|det| / product of row norms = {0:e}, needs > 1e-12)"
    )]
    SingularHomography(f64),
    #[error("invalid grid")]
    InvalidGrid(#[from] crate::geometry::GridError),
    #[error("invalid lens distortion")]
    InvalidDistortion(#[from] crate::geometry::DistortionError),
    /// A camera raw frame that cannot be used, for the reason given.
    #[error("camera raw frame: {0}")]
    Raw(String),
    /// rawler could not decode or develop a camera raw frame.
    #[cfg(feature = "nef")]
    #[error("camera raw frame: cannot {step} the raw data")]
    RawData {
        /// "decode" or "develop".
        step: &'static str,
        #[source]
        source: Box<rawler::RawlerError>,
    },
    /// A picture (PNG, TIFF, …) the image crate could not read.
    #[error("cannot read the picture")]
    Image(#[source] Box<image::ImageError>),
    /// The image crate's decoder panicked on a picture.
    #[error(
        "cannot read the picture: its decoder gave up on it (a panic inside the decoder), so \
         the file is damaged; take the frame again"
    )]
    ImagePanic,
    /// A JPEG refused before or after decoding, for the reason given.
    #[error("JPEG decoding failed: {0}")]
    Jpeg(String),
    /// A JPEG the decoder refused.
    #[error("JPEG decoding failed")]
    JpegData(#[source] zune_jpeg::errors::DecodeErrors),
    /// A TIFF-based frame (NEF, TIFF) whose structure no decoder may be given, for the reason
    /// given (see `tiff_bounds.rs`).
    #[error("TIFF structure: {0}")]
    Tiff(String),
    /// A header that claims a picture larger than any camera frame, refused before anything is
    /// allocated for it.
    #[error(
        "the header claims {width} x {height} pixels, more than the {} Mpx a camera frame may \
         have (a D810 frame is 36 Mpx): not a frame of this camera, or a damaged file",
        MAX_FRAME_PIXELS >> 20
    )]
    TooLarge { width: u64, height: u64 },
}

/// Largest frame decoded, in pixels: 128 Mpx, 3.5 times a D810 frame (36 Mpx). A header that
/// claims more is refused before anything is allocated.
pub const MAX_FRAME_PIXELS: usize = 1 << 27;

/// Refuses a frame header whose size no camera frame has.
pub(crate) fn check_frame_size(width: u64, height: u64) -> Result<(), RectifyError> {
    match width.checked_mul(height) {
        Some(n) if n <= MAX_FRAME_PIXELS as u64 => Ok(()),
        _ => Err(RectifyError::TooLarge { width, height }),
    }
}
