//! A camera frame as the body delivered it: a JPEG (zune-jpeg), a camera raw frame (a NEF,
//! developed by rawler, see [`super::raw`]) or any picture the image crate reads (PNG, TIFF).

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
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            FrameLuma::Gamma8(g) => g.dimensions(),
            FrameLuma::Linear16(g) => g.dimensions(),
        }
    }

    /// The same luma on the calibration's grid.
    pub fn rectified(&self, rectifier: &Rectifier) -> FrameLuma {
        match self {
            FrameLuma::Gamma8(g) => FrameLuma::Gamma8(rectifier.rectify_gray8(g)),
            FrameLuma::Linear16(g) => FrameLuma::Linear16(rectifier.rectify_gray16(g)),
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
                let lut: Vec<u8> = (0..=255u32)
                    .map(|i| (srgb_encode(i as f64 / 255.0) * 255.0).round() as u8)
                    .collect();
                GrayImage::from_fn(g.width(), g.height(), |x, y| {
                    let v = g.get_pixel(x, y).0[0];
                    // Linear to 8 bits first would crush the shadows: interpolate the curve.
                    let linear = f64::from(v) / 65535.0;
                    if linear < 1.0 / 255.0 {
                        image::Luma([(srgb_encode(linear) * 255.0).round() as u8])
                    } else {
                        image::Luma([lut[(linear * 255.0).round() as usize]])
                    }
                })
            }
        }
    }
}

fn srgb_encode(v: f64) -> f64 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
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
    let picture = image::load_from_memory(bytes).map_err(|e| RectifyError::Image(e.to_string()))?;
    Ok(FrameLuma::Gamma8(picture.to_luma8()))
}

/// The frame in colour, for pictures and for registration (raw frames: sRGB-encoded, 16 bits).
pub fn decode_frame(bytes: &[u8]) -> Result<DynamicImage, RectifyError> {
    if bytes.starts_with(&[0xFF, 0xD8]) {
        return decode_jpeg(bytes);
    }
    if let Some(raw) = camera_raw(bytes)? {
        return raw.display().map(DynamicImage::ImageRgb16);
    }
    image::load_from_memory(bytes).map_err(|e| RectifyError::Image(e.to_string()))
}

#[cfg(feature = "nef")]
fn camera_raw(bytes: &[u8]) -> Result<Option<super::raw::RawFrame>, RectifyError> {
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
    let tiff = bytes.starts_with(b"MM\0\x2A") || bytes.starts_with(b"II\x2A\0");
    let head = &bytes[..bytes.len().min(4096)];
    if tiff && head.windows(5).any(|w| w == b"NIKON") {
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
