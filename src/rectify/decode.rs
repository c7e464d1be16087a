//! JPEG decoding and luma conversion.

use image::{DynamicImage, GrayImage, RgbImage};
use rayon::prelude::*;
use zune_jpeg::zune_core::bytestream::ZCursor;
use zune_jpeg::zune_core::colorspace::ColorSpace;
use zune_jpeg::zune_core::options::DecoderOptions;
use zune_jpeg::JpegDecoder;

use super::RectifyError;

/// A JPEG decoded by zune-jpeg: its size, samples, and whether they are one channel.
pub(crate) struct Decoded {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) pixels: Vec<u8>,
    pub(crate) grey: bool,
}

/// Decodes a JPEG with zune-jpeg, strict, to luma only (`luma_only`) or to its own colour
/// (RGB, or luma for a grey JPEG). The frame size is checked before the decoder allocates;
/// progressive and baseline frames alike (see `jpeg_scan.rs`).
pub(crate) fn zune_decode(bytes: &[u8], luma_only: bool) -> Result<Decoded, RectifyError> {
    // JPEG dimensions are 16-bit; lift zune's default 16384 cap to that.
    let options = DecoderOptions::default()
        .set_max_width(usize::from(u16::MAX))
        .set_max_height(usize::from(u16::MAX))
        // Truncated or corrupt entropy data is an error, not grey rows.
        .set_strict_mode(true);
    let input = super::jpeg_scan::decoder_input(bytes)?;
    let mut dec = JpegDecoder::new_with_options(ZCursor::new(input), options);
    dec.decode_headers().map_err(RectifyError::JpegData)?;
    let grey = luma_only || matches!(dec.input_colorspace(), Some(ColorSpace::Luma));
    let out_cs = if grey {
        ColorSpace::Luma
    } else {
        ColorSpace::RGB
    };
    dec.set_options(options.jpeg_set_out_colorspace(out_cs));
    let (w, h) = dec
        .dimensions()
        .ok_or_else(|| RectifyError::Jpeg("no frame header".into()))?;
    super::check_frame_size(w as u64, h as u64)?;
    let pixels = dec.decode().map_err(RectifyError::JpegData)?;
    let channels = if grey { 1 } else { 3 };
    if pixels.len() != w * h * channels {
        return Err(RectifyError::Jpeg(format!(
            "decoder returned a wrong-sized buffer for {w}x{h}"
        )));
    }
    Ok(Decoded {
        width: w as u32,
        height: h as u32,
        pixels,
        grey,
    })
}

/// Decodes a JPEG to RGB8 (colour input) or L8 (greyscale input).
///
/// Uses zune-jpeg directly: the fastest pure-Rust decoder measured in the
/// decode bench (libjpeg-turbo was compared too; see the bench). Errors,
/// never panics, on malformed input.
pub fn decode_jpeg(bytes: &[u8]) -> Result<DynamicImage, RectifyError> {
    let Decoded {
        width,
        height,
        pixels,
        grey,
    } = zune_decode(bytes, false)?;
    // The sizes were checked by zune_decode.
    let wrong = || RectifyError::Jpeg("decoder returned a wrong-sized buffer".into());
    Ok(if grey {
        DynamicImage::ImageLuma8(GrayImage::from_raw(width, height, pixels).ok_or_else(wrong)?)
    } else {
        DynamicImage::ImageRgb8(RgbImage::from_raw(width, height, pixels).ok_or_else(wrong)?)
    })
}

/// BT.601 luma `Y = 0.299 R + 0.587 G + 0.114 B`, rounded to nearest
/// (halves up), as the DICOM views store it.
///
/// Computed exactly in integers: `(299 R + 587 G + 114 B + 500) / 1000`.
pub fn luma(rgb: &RgbImage) -> GrayImage {
    let (w, h) = rgb.dimensions();
    let row_len = w as usize;
    let mut out = vec![0u8; row_len * h as usize];
    if row_len > 0 {
        out.par_chunks_mut(row_len)
            .zip(rgb.as_raw().par_chunks(row_len * 3))
            .for_each(|(dst, src)| {
                for (y, p) in dst.iter_mut().zip(src.chunks_exact(3)) {
                    let s = 299 * u32::from(p[0]) + 587 * u32::from(p[1]) + 114 * u32::from(p[2]);
                    *y = ((s + 500) / 1000) as u8;
                }
            });
    }
    // The buffer has exactly w·h bytes.
    GrayImage::from_raw(w, h, out).expect("luma buffer sized for the image")
}
