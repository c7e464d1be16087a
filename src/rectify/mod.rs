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
//! bilinear kernels use AVX2 when the CPU has it (runtime detection, scalar
//! fallback with identical results). With distortion, the first call builds a
//! cached position map (8 bytes per grid pixel, 155 MB for the plate grid).
//! Output buffers are fresh per call unless the `*_into` variants are used.

pub mod calibration;
mod decode;
mod file;
mod frame;
mod luma_decode;
mod os;
mod positions;
#[cfg(feature = "nef")]
pub mod raw;
#[cfg(target_arch = "x86_64")]
mod simd;
#[cfg(test)]
mod tests;
mod warp;

use image::{DynamicImage, GrayImage, ImageBuffer, Luma, Rgb, RgbImage};

pub use crate::geometry::{CameraModel, Grid, RadialDistortion};
pub use calibration::{Calibration, CalibrationError};
pub use decode::{decode_jpeg, luma};
pub use file::{rectify_file, RectifyFileError};
pub use frame::{decode_frame, decode_frame_luma, FrameLuma};
pub use luma_decode::decode_jpeg_luma;
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
    #[error("invalid grid: {0}")]
    InvalidGrid(#[from] crate::geometry::GridError),
    #[error("invalid lens distortion: {0}")]
    InvalidDistortion(#[from] crate::geometry::DistortionError),
    #[error("camera raw frame: {0}")]
    Raw(String),
    #[error("cannot read the picture: {0}")]
    Image(String),
    #[error("JPEG decoding failed: {0}")]
    Jpeg(String),
}

/// Largest frame decoded, in pixels: 128 Mpx, 3.5 times a D810 frame (36 Mpx). A header that
/// claims more is refused before anything is allocated.
pub const MAX_FRAME_PIXELS: usize = 1 << 27;

/// The JPEG without its final end-of-image marker, for the decoder: zune-jpeg, even strict,
/// fills a scan that meets an EOI early with zero bits (a frame cut short and closed by a proper
/// EOI would decode to grey rows); where the data simply ends, strict mode reports the
/// premature end instead. A complete scan needs no EOI to decode.
pub(crate) fn scan_end(bytes: &[u8]) -> &[u8] {
    bytes.strip_suffix(&[0xFF, 0xD9]).unwrap_or(bytes)
}

/// Refuses a frame header whose size no camera frame has.
pub(crate) fn check_frame_size(width: usize, height: usize) -> Result<(), RectifyError> {
    match width.checked_mul(height) {
        Some(n) if n <= MAX_FRAME_PIXELS => Ok(()),
        _ => Err(RectifyError::Jpeg(format!(
            "the header claims {width} x {height} pixels, more than the {} Mpx a camera frame \
             may have (a D810 frame is 36 Mpx): not a frame of this camera, or a damaged file",
            MAX_FRAME_PIXELS >> 20
        ))),
    }
}

impl Rectifier {
    /// Rectifies an 8-bit grey frame onto the grid (see the module docs for
    /// the sampling and border rules).
    pub fn rectify_gray8(&self, src: &GrayImage) -> GrayImage {
        let mut dst = self.blank();
        self.rectify_gray8_into(src, &mut dst);
        dst
    }

    /// Rectifies an 8-bit RGB frame.
    pub fn rectify_rgb8(&self, src: &RgbImage) -> RgbImage {
        let mut dst = self.blank();
        self.rectify_rgb8_into(src, &mut dst);
        dst
    }

    /// Rectifies a 16-bit grey frame.
    pub fn rectify_gray16(&self, src: &Gray16Image) -> Gray16Image {
        let mut dst = self.blank();
        self.rectify_gray16_into(src, &mut dst);
        dst
    }

    /// Rectifies a 16-bit RGB frame.
    pub fn rectify_rgb16(&self, src: &Rgb16Image) -> Rgb16Image {
        let mut dst = self.blank();
        self.rectify_rgb16_into(src, &mut dst);
        dst
    }

    /// As [`Rectifier::rectify_gray8`], writing into `dst` (reallocated only
    /// if its size is not the grid's). Reusing `dst` across frames saves the
    /// page faults of a fresh multi-megabyte buffer per frame.
    pub fn rectify_gray8_into(&self, src: &GrayImage, dst: &mut GrayImage) {
        #[cfg(target_arch = "x86_64")]
        let fast = Some(simd::row_gray8 as warp::RowFn<u8>);
        #[cfg(not(target_arch = "x86_64"))]
        let fast = None;
        self.fit(dst);
        let row_fn = self.row_fn::<u8, 1>(fast);
        self.run_into::<u8, 1>(src.as_raw(), src.width(), src.height(), row_fn, dst);
    }

    /// As [`Rectifier::rectify_rgb8`], writing into `dst`.
    pub fn rectify_rgb8_into(&self, src: &RgbImage, dst: &mut RgbImage) {
        #[cfg(target_arch = "x86_64")]
        let fast = Some(simd::row_rgb8 as warp::RowFn<u8>);
        #[cfg(not(target_arch = "x86_64"))]
        let fast = None;
        self.fit(dst);
        let row_fn = self.row_fn::<u8, 3>(fast);
        self.run_into::<u8, 3>(src.as_raw(), src.width(), src.height(), row_fn, dst);
    }

    /// As [`Rectifier::rectify_gray16`], writing into `dst`.
    pub fn rectify_gray16_into(&self, src: &Gray16Image, dst: &mut Gray16Image) {
        self.fit(dst);
        let row_fn = self.row_fn::<u16, 1>(None);
        self.run_into::<u16, 1>(src.as_raw(), src.width(), src.height(), row_fn, dst);
    }

    /// As [`Rectifier::rectify_rgb16`], writing into `dst`.
    pub fn rectify_rgb16_into(&self, src: &Rgb16Image, dst: &mut Rgb16Image) {
        self.fit(dst);
        let row_fn = self.row_fn::<u16, 3>(None);
        self.run_into::<u16, 3>(src.as_raw(), src.width(), src.height(), row_fn, dst);
    }

    /// Rectifies any image: L8/Rgb8/L16/Rgb16 directly; other formats are
    /// first converted to the nearest of those (alpha dropped, LA8 → L8,
    /// RGBA8 → RGB8, LA16 → L16, RGBA16 and float RGB(A) → RGB16).
    pub fn rectify_dynamic(&self, src: &DynamicImage) -> DynamicImage {
        match src {
            DynamicImage::ImageLuma8(i) => DynamicImage::ImageLuma8(self.rectify_gray8(i)),
            DynamicImage::ImageRgb8(i) => DynamicImage::ImageRgb8(self.rectify_rgb8(i)),
            DynamicImage::ImageLuma16(i) => DynamicImage::ImageLuma16(self.rectify_gray16(i)),
            DynamicImage::ImageRgb16(i) => DynamicImage::ImageRgb16(self.rectify_rgb16(i)),
            DynamicImage::ImageLumaA8(_) => {
                DynamicImage::ImageLuma8(self.rectify_gray8(&src.to_luma8()))
            }
            DynamicImage::ImageRgba8(_) => {
                DynamicImage::ImageRgb8(self.rectify_rgb8(&src.to_rgb8()))
            }
            DynamicImage::ImageLumaA16(_) => {
                DynamicImage::ImageLuma16(self.rectify_gray16(&src.to_luma16()))
            }
            _ => DynamicImage::ImageRgb16(self.rectify_rgb16(&src.to_rgb16())),
        }
    }

    /// A zeroed output image of the grid's size. The zeroed allocation is
    /// mapped lazily by the OS, so its pages are first touched by the worker
    /// threads that fill them, not by a serial memset; asking for huge pages
    /// cuts those first-touch page faults ~500-fold (a 4400² RGB frame is
    /// 58 MB: ~14 000 faults, about a third of the warp time without it).
    fn blank<P: image::Pixel>(&self) -> ImageBuffer<P, Vec<P::Subpixel>> {
        let g = self.grid();
        let mut img: ImageBuffer<P, Vec<P::Subpixel>> =
            ImageBuffer::new(g.columns() as u32, g.rows() as u32);
        os::advise_huge_pages(&mut img);
        img
    }

    /// Makes `dst` the grid's size (keeping its buffer when it already is).
    fn fit<P: image::Pixel>(&self, dst: &mut ImageBuffer<P, Vec<P::Subpixel>>) {
        let g = self.grid();
        if dst.dimensions() != (g.columns() as u32, g.rows() as u32) {
            *dst = self.blank();
        }
    }
}
