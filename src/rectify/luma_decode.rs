//! JPEG straight to luma: a JFIF JPEG stores Y (BT.601 luma, full range) as its first component,
//! so the views' luma needs neither chroma upsampling nor colour conversion.

use super::RectifyError;
use image::GrayImage;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;
use zune_jpeg::JpegDecoder;

/// Decodes only the luma of a JPEG (grey JPEGs as they are).
pub fn decode_jpeg_luma(bytes: &[u8]) -> Result<GrayImage, RectifyError> {
    let options = DecoderOptions::default()
        .set_max_width(usize::from(u16::MAX))
        .set_max_height(usize::from(u16::MAX))
        // Truncated or corrupt entropy data is an error, not grey rows.
        .set_strict_mode(true)
        .jpeg_set_out_colorspace(ColorSpace::Luma);
    let mut decoder = JpegDecoder::new_with_options(ZCursor::new(super::scan_end(bytes)), options);
    decoder.decode_headers().map_err(RectifyError::JpegData)?;
    let (w, h) = decoder
        .dimensions()
        .ok_or_else(|| RectifyError::Jpeg("no frame header".into()))?;
    super::check_frame_size(w, h)?;
    let pixels = decoder.decode().map_err(RectifyError::JpegData)?;
    GrayImage::from_raw(w as u32, h as u32, pixels).ok_or_else(|| {
        RectifyError::Jpeg(format!("decoder returned a wrong-sized buffer for {w}x{h}"))
    })
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
