//! JPEG straight to luma: a JFIF JPEG stores Y (BT.601 luma, full range) as its first component,
//! so the views' luma needs neither chroma upsampling nor colour conversion.

use super::decode::{zune_decode, Decoded};
use super::{Rectifier, RectifyError};
use image::GrayImage;

/// Decodes only the luma of a JPEG (grey JPEGs as they are): baseline and extended sequential
/// 8-bit frames with our own decoder (`jpeg_luma`), every other JPEG with zune-jpeg.
pub fn decode_jpeg_luma(bytes: &[u8]) -> Result<GrayImage, RectifyError> {
    decode_jpeg_luma_within(bytes, None)
}

/// [`decode_jpeg_luma`] of the pixels `rectifier` reads (its footprint): with our decoder the
/// other blocks are not turned into pixels and are 0; zune-jpeg decodes all of them.
pub fn decode_jpeg_luma_for(
    bytes: &[u8],
    rectifier: &Rectifier,
) -> Result<GrayImage, RectifyError> {
    decode_jpeg_luma_within(bytes, Some(rectifier))
}

fn decode_jpeg_luma_within(
    bytes: &[u8],
    rectifier: Option<&Rectifier>,
) -> Result<GrayImage, RectifyError> {
    if let Some(decoded) = super::jpeg_luma::decode_luma(bytes, rectifier) {
        return decoded;
    }
    let Decoded {
        width,
        height,
        pixels,
        ..
    } = zune_decode(bytes, true)?;
    GrayImage::from_raw(width, height, pixels)
        .ok_or_else(|| RectifyError::Jpeg("decoder returned a wrong-sized buffer".into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_decode_matches_the_luma_of_the_colour_decode() {
        let (w, h) = (97, 61);
        let rgb = image::RgbImage::from_fn(w, h, |x, y| {
            image::Rgb([(x * 2) as u8, (y * 4) as u8, ((x + y) * 3) as u8])
        });
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&rgb)
            .unwrap();
        let direct = decode_jpeg_luma(&jpeg).unwrap();
        let via_rgb = super::super::luma(&super::super::decode_jpeg(&jpeg).unwrap().to_rgb8());
        assert_eq!(direct.dimensions(), (w, h));
        // Equal up to the rounding and clamping of the colour path.
        let diffs: Vec<i32> = direct
            .pixels()
            .zip(via_rgb.pixels())
            .map(|(a, b)| (a.0[0] as i32 - b.0[0] as i32).abs())
            .collect();
        let worst = diffs.iter().max().copied().unwrap_or(0);
        let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
        assert!(
            worst <= 6 && mean < 1.0,
            "luma differs by up to {worst}, {mean} on average"
        );
        assert!(decode_jpeg_luma(b"\xff\xd8garbage").is_err());
    }
}
