//! Camera raw frames (a D810 set to NEF), developed with rawler: black level and white level,
//! demosaic (PPG), the body's default crop, as-shot white balance and the camera's colour matrix
//! to linear sRGB (D65).
//!
//! Pixel frame: the default crop is the area the body's own JPEG shows (a D810: 7360 x 4912 of its
//! 7380 x 4928 photosites, 12 columns in from the left and 8 rows down), at one pixel per
//! photosite, so a calibration made on the body's JPEGs holds for its raw frames too
//! (docs/frames.md).
//!
//! What the views get is linear: the relative luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of the
//! linear sRGB, with the sensor's white level at 65535, so the DICOM values stay proportional to
//! the light the sensor saw (a JPEG's luma is gamma encoded). Pictures for people (PNG, the
//! overlays) get the sRGB transfer curve on top.

use super::{Gray16Image, RectifyError, Rgb16Image};
use rawler::decoders::RawDecodeParams;
use rawler::imgop::develop::{Intermediate, ProcessingStep, RawDevelop};
use rawler::rawsource::RawSource;
use rayon::prelude::*;

/// Whether `bytes` are a camera raw file rawler knows (a TIFF-based raw names its body in the
/// first directory; a plain TIFF does not).
pub fn is_camera_raw(bytes: &[u8]) -> bool {
    let tiff = bytes.starts_with(b"MM\0\x2A") || bytes.starts_with(b"II\x2A\0");
    tiff && std::panic::catch_unwind(|| {
        rawler::get_decoder(&RawSource::new_from_slice(bytes)).is_ok()
    })
    .unwrap_or(false)
}

/// A developed raw frame: linear sRGB, 0..1, row-major, after the body's default crop.
pub struct LinearFrame {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
}

/// Decodes and develops a raw frame. Errors (never panics) on anything rawler cannot take.
pub fn develop(bytes: &[u8]) -> Result<LinearFrame, RectifyError> {
    let failed = |what: String| RectifyError::Raw(what);
    let source = RawSource::new_from_slice(bytes);
    // rawler catches panics in its decoders but not in its developing steps.
    let developed = std::panic::catch_unwind(|| {
        let raw = rawler::decode(&source, &RawDecodeParams::default())
            .map_err(|e| format!("cannot decode the raw data: {e}"))?;
        if raw.cpp != 1 {
            return Err(format!(
                "{} {}: {} colour components per photosite; only Bayer mosaics are supported \
                 (set the camera to a full-size NEF, not sRAW)",
                raw.clean_make, raw.clean_model, raw.cpp
            ));
        }
        let steps = [
            ProcessingStep::Rescale,
            ProcessingStep::Demosaic,
            ProcessingStep::CropActiveArea,
            ProcessingStep::WhiteBalance,
            ProcessingStep::Calibrate,
            ProcessingStep::CropDefault,
        ];
        RawDevelop::new_with(&steps)
            .develop_intermediate(&raw)
            .map_err(|e| format!("cannot develop the raw data: {e}"))
    })
    .map_err(|_| failed("the raw developer gave up on this file (a panic inside rawler)".into()))?
    .map_err(failed)?;
    match developed {
        Intermediate::ThreeColor(pixels) => Ok(LinearFrame {
            width: pixels.width as u32,
            height: pixels.height as u32,
            rgb: pixels.data,
        }),
        _ => Err(failed("the developer did not return an RGB picture".into())),
    }
}

impl LinearFrame {
    /// Linear relative luminance, white = 65535.
    pub fn luminance(&self) -> Gray16Image {
        let y: Vec<u16> = self
            .rgb
            .par_iter()
            .map(|&[r, g, b]| to_u16(0.2126 * r + 0.7152 * g + 0.0722 * b))
            .collect();
        // One value per pixel of a width x height frame.
        Gray16Image::from_raw(self.width, self.height, y).expect("luminance sized for the frame")
    }

    /// sRGB-encoded 16-bit colour, for looking at.
    pub fn display(&self) -> Rgb16Image {
        let rgb: Vec<u16> = self
            .rgb
            .par_iter()
            .flat_map_iter(|p| p.map(|c| to_u16(srgb_encode(c))))
            .collect();
        // Three values per pixel of a width x height frame.
        Rgb16Image::from_raw(self.width, self.height, rgb).expect("colour sized for the frame")
    }
}

fn to_u16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

fn srgb_encode(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mock_camera::nef::{encode_nef, NefCompression, NefOptions};

    fn grey_nef(level: u8, compression: NefCompression) -> Vec<u8> {
        let picture = image::RgbImage::from_pixel(64, 48, image::Rgb([level, level, level]));
        encode_nef(
            &picture,
            &NefOptions {
                compression,
                ..NefOptions::default()
            },
        )
    }

    #[test]
    fn a_d810_frame_develops_to_the_linear_grey_it_was_made_of() {
        for compression in [NefCompression::Uncompressed, NefCompression::Lossless] {
            for level in [40u8, 128, 230] {
                let nef = grey_nef(level, compression);
                assert!(is_camera_raw(&nef));
                let frame = develop(&nef).unwrap();
                // The D810's default crop gives back the picture's size.
                assert_eq!((frame.width, frame.height), (64, 48));
                let expected = mock_camera::nef::srgb_to_linear(level) as f32;
                let y = frame.luminance();
                // Away from the mosaic's border rows and columns.
                for yy in 4..44 {
                    for xx in 4..60 {
                        let got = f32::from(y.get_pixel(xx, yy).0[0]) / 65535.0;
                        assert!(
                            (got - expected).abs() < 0.002 + 0.01 * expected,
                            "{compression:?} grey {level}: Y {got} at ({xx}, {yy}), expected {expected}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn lossless_and_uncompressed_frames_of_a_plate_develop_alike() {
        use mock_camera::{demo_parts, Homography, Illumination, Renderer, Scene};
        let (w, h) = (320, 200);
        let renderer = Renderer::new(w, h, Homography::oblique_view(w, h));
        let fused = demo_parts(5);
        let picture = renderer.render(&Scene {
            layer: 5,
            fused: &fused,
            scanned: true,
            illumination: Illumination::Side,
        });
        let nef = |compression| {
            encode_nef(
                &picture,
                &NefOptions {
                    compression,
                    ..NefOptions::default()
                },
            )
        };
        let (lossless, uncompressed) = (
            nef(NefCompression::Lossless),
            nef(NefCompression::Uncompressed),
        );
        // The photosites: rawler's lossless decoder dithers its output down by one 14-bit step
        // (about three times in four); otherwise the two files hold the same mosaic.
        let mosaic = |bytes: &[u8]| match rawler::decode(
            &RawSource::new_from_slice(bytes),
            &RawDecodeParams::default(),
        )
        .unwrap()
        .data
        {
            rawler::RawImageData::Integer(v) => v,
            rawler::RawImageData::Float(_) => panic!("a NEF decodes to integers"),
        };
        let (a, b) = (mosaic(&lossless), mosaic(&uncompressed));
        assert_eq!(a.len(), (w as usize + 20) * (h as usize + 16));
        assert!(a.iter().zip(&b).all(|(&a, &b)| a == b || a + 1 == b));
        let luminance = |bytes: &[u8]| develop(bytes).unwrap().luminance();
        let (lossless, uncompressed) = (luminance(&lossless), luminance(&uncompressed));
        assert_eq!(lossless.dimensions(), (w, h));
        let mean = lossless
            .pixels()
            .zip(uncompressed.pixels())
            .map(|(a, b)| (f64::from(a.0[0]) - f64::from(b.0[0])).abs())
            .sum::<f64>()
            / f64::from(w * h);
        assert!(
            mean < 10.0,
            "developed frames differ by {mean} / 65535 on average"
        );
        // And the picture is there: luminance follows the picture's linear grey.
        let mut err = 0.0;
        for (p, y) in picture.pixels().zip(uncompressed.pixels()) {
            let expected = mock_camera::nef::srgb_to_linear(p.0[0]);
            err += (f64::from(y.0[0]) / 65535.0 - expected).abs();
        }
        let mean = err / f64::from(w * h);
        assert!(mean < 0.02, "mean |Y - picture| = {mean}");
    }

    #[test]
    fn plain_tiffs_and_garbage_are_not_raw_and_broken_raws_are_errors() {
        let mut tiff = Vec::new();
        image::DynamicImage::ImageLuma8(image::GrayImage::new(4, 4))
            .write_to(
                &mut std::io::Cursor::new(&mut tiff),
                image::ImageFormat::Tiff,
            )
            .unwrap();
        assert!(!is_camera_raw(&tiff));
        assert!(!is_camera_raw(b"\xff\xd8\xff"));
        assert!(develop(b"MM\0\x2Anonsense").is_err());
        let nef = grey_nef(128, NefCompression::Lossless);
        for cut in [16, 200, nef.len() / 2, nef.len() - 40] {
            // A truncated file is an error or a picture, never a panic.
            let _ = develop(&nef[..cut]);
        }
    }
}
