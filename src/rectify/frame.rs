//! A camera frame as the body delivered it: a JPEG (zune-jpeg), a camera raw frame (a NEF,
//! developed by rawler, see [`super::raw`]) or any picture the image crate reads (PNG, TIFF).

use super::luma_decode::decode_jpeg_luma_for;
use super::srgb::srgb_encode;
use super::{decode_jpeg, decode_jpeg_luma, Gray16Image, Rectifier, RectifyError};
use image::{DynamicImage, GrayImage};

/// What the views hold of a frame.
pub enum FrameLuma {
    /// BT.601 luma of a JPEG or another picture, gamma encoded as the picture was, 8 bits.
    Gamma8(GrayImage),
    /// Linear relative luminance of a developed raw frame, the sensor's white level at 65535.
    Linear16(Gray16Image),
}

impl FrameLuma {
    /// The same luma on the calibration's grid.
    pub fn rectified(&self, rectifier: &Rectifier) -> FrameLuma {
        match self {
            FrameLuma::Gamma8(g) => FrameLuma::Gamma8(rectifier.rectify_gray8(g)),
            FrameLuma::Linear16(g) => FrameLuma::Linear16(rectifier.rectify_gray16(g)),
        }
    }

    /// Done with this luma: an 8-bit frame's buffer is kept for the next frame's decode (see
    /// `reuse.rs`), so that its pages need not be zeroed again.
    pub fn recycle(self) {
        if let FrameLuma::Gamma8(g) = self {
            super::reuse::give_back(g.into_raw());
        }
    }

    /// The samples a DICOM slice stores, as they are (8-bit luma is stored in 16 bits).
    pub fn samples(&self) -> crate::dicom::Samples<'_> {
        match self {
            FrameLuma::Gamma8(g) => crate::dicom::Samples::Gray8(g.as_raw()),
            FrameLuma::Linear16(g) => crate::dicom::Samples::Gray16(g.as_raw()),
        }
    }

    /// The values a DICOM slice stores (16 bits allocated).
    pub fn into_u16(self) -> Vec<u16> {
        match self {
            FrameLuma::Gamma8(g) => g.into_raw().into_iter().map(u16::from).collect(),
            FrameLuma::Linear16(g) => g.into_raw(),
        }
    }

    /// Window (center, width) that shows the whole range of the values.
    pub fn window(&self) -> (f64, f64) {
        match self {
            FrameLuma::Gamma8(_) => (128.0, 256.0),
            FrameLuma::Linear16(_) => (32768.0, 65536.0),
        }
    }

    /// How the values were derived, for DerivationDescription.
    pub fn derivation(&self) -> &'static str {
        match self {
            FrameLuma::Gamma8(_) => {
                "camera frame luma (BT.601), rectified to the build plane through the calibration homography"
            }
            FrameLuma::Linear16(_) => {
                "camera raw frame developed (white balance as shot, camera matrix) to linear luminance (Rec. 709 Y, white level 65535), rectified to the build plane through the calibration homography"
            }
        }
    }

    /// An 8-bit picture for looking at (raw frames get the sRGB transfer curve).
    pub fn to_display8(&self) -> GrayImage {
        match self {
            FrameLuma::Gamma8(g) => g.clone(),
            FrameLuma::Linear16(g) => {
                // One entry per 16-bit value: quantising the linear value first would leave
                // gaps in the shadows, where the curve is steep.
                static SRGB8: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
                let lut = SRGB8.get_or_init(|| {
                    (0..=65535u32)
                        .map(|v| (srgb_encode(f64::from(v) / 65535.0) * 255.0).round() as u8)
                        .collect()
                });
                let pixels = g.as_raw().iter().map(|&v| lut[usize::from(v)]).collect();
                // One byte per pixel of the same size.
                GrayImage::from_raw(g.width(), g.height(), pixels).expect("same size")
            }
        }
    }
}

/// The luma the views hold, decoded the fastest way for each kind of frame.
pub fn decode_frame_luma(bytes: &[u8]) -> Result<FrameLuma, RectifyError> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        return decode_jpeg_luma(bytes).map(FrameLuma::Gamma8);
    }
    if let Some(raw) = camera_raw(bytes)? {
        return raw.luminance().map(FrameLuma::Linear16);
    }
    Ok(FrameLuma::Gamma8(decode_picture(bytes)?.to_luma8()))
}

/// [`decode_frame_luma`] for `rectifier`: of a JPEG, only the pixels it reads are decoded (the
/// rest are 0), so the result is for that rectifier alone.
pub fn decode_frame_luma_for(
    bytes: &[u8],
    rectifier: &Rectifier,
) -> Result<FrameLuma, RectifyError> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        return decode_jpeg_luma_for(bytes, rectifier).map(FrameLuma::Gamma8);
    }
    decode_frame_luma(bytes)
}

/// The frame in colour, for pictures and for registration (raw frames: sRGB-encoded, 16 bits).
pub fn decode_frame(bytes: &[u8]) -> Result<DynamicImage, RectifyError> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        return decode_jpeg(bytes);
    }
    if let Some(raw) = camera_raw(bytes)? {
        return raw.display().map(DynamicImage::ImageRgb16);
    }
    decode_picture(bytes)
}

/// Most the image crate may reserve for one picture: a camera-size frame at 16-bit RGBA
/// ([`super::MAX_FRAME_PIXELS`] x 8 bytes).
const PICTURE_MAX_ALLOC: u64 = (super::MAX_FRAME_PIXELS as u64) * 8;

/// A PNG or TIFF picture through the image crate, its size checked against a camera frame's
/// before the decoder reserves its pixels, and every reservation bounded.
fn decode_picture(bytes: &[u8]) -> Result<DynamicImage, RectifyError> {
    let image_error = |e| RectifyError::Image(Box::new(e));
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| image_error(image::ImageError::IoError(e)))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(u32::from(u16::MAX));
    limits.max_image_height = Some(u32::from(u16::MAX));
    limits.max_alloc = Some(PICTURE_MAX_ALLOC);
    reader.limits(limits);
    let decoder = reader.into_decoder().map_err(image_error)?;
    let (w, h) = image::ImageDecoder::dimensions(&decoder);
    super::check_frame_size(u64::from(w), u64::from(h))?;
    // The png crate panics on some damaged files (a palette shorter than its indices reach,
    // found by mutation fuzzing); such a panic is this file's error, not the process's.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        DynamicImage::from_decoder(decoder)
    }))
    .map_err(|_| RectifyError::ImagePanic)?
    .map_err(image_error)
}

/// A camera raw frame (a TIFF-based file rawler knows), its structure walked first
/// (`tiff_bounds.rs`) so that no decoder meets a loop or an unbounded reservation.
#[cfg(feature = "nef")]
fn camera_raw(bytes: &[u8]) -> Result<Option<super::raw::RawFrame>, RectifyError> {
    super::tiff_bounds::check(bytes)?;
    if super::raw::is_camera_raw(bytes) {
        super::raw::decode(bytes).map(Some)
    } else {
        Ok(None)
    }
}

/// Without the raw developer, a raw frame must not be taken for the small TIFF picture that
/// opens it.
#[cfg(not(feature = "nef"))]
fn camera_raw(bytes: &[u8]) -> Result<Option<NoRawDeveloper>, RectifyError> {
    super::tiff_bounds::check(bytes)?;
    let big_endian = bytes.starts_with(b"MM\0\x2A");
    let tiff = super::tiff_bounds::is_tiff(bytes);
    let head = &bytes[..bytes.len().min(65536)];
    // A directory entry PhotometricInterpretation (0x0106), SHORT, count 1, = CFA (32803): the
    // raw mosaic's. A Nikon TIFF (RGB) frame has none.
    let cfa_entry: [u8; 10] = if big_endian {
        [0x01, 0x06, 0, 3, 0, 0, 0, 1, 0x80, 0x23]
    } else {
        [0x06, 0x01, 3, 0, 1, 0, 0, 0, 0x23, 0x80]
    };
    let nikon = head.windows(5).any(|w| w == b"NIKON");
    if tiff && nikon && head.windows(10).any(|w| w == cfa_entry) {
        return Err(RectifyError::Raw(
            "this is a Nikon raw frame (NEF) and layerwise was built without the `nef` feature: \
             rebuild with `--features nef` (it is on by default)"
                .into(),
        ));
    }
    Ok(None)
}

#[cfg(not(feature = "nef"))]
enum NoRawDeveloper {}

#[cfg(not(feature = "nef"))]
impl NoRawDeveloper {
    fn luminance(&self) -> Result<Gray16Image, RectifyError> {
        match *self {}
    }

    fn display(&self) -> Result<super::Rgb16Image, RectifyError> {
        match *self {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_frames_show_every_grey_level() {
        let ramp = Gray16Image::from_fn(256, 256, |x, y| image::Luma([(y * 256 + x) as u16]));
        let shown = FrameLuma::Linear16(ramp).to_display8();
        let levels = shown.as_raw();
        assert!(levels.windows(2).all(|w| w[0] <= w[1]), "not monotonic");
        let mut seen = [false; 256];
        levels.iter().for_each(|&v| seen[usize::from(v)] = true);
        let missing: Vec<usize> = (0..256).filter(|&v| !seen[v]).collect();
        assert!(missing.is_empty(), "grey levels never shown: {missing:?}");
        // Linear mid-grey (18%) shows as sRGB's 118.
        assert_eq!(levels[(0.18f64 * 65535.0).round() as usize], 118);
    }
}
