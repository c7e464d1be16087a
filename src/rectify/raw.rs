//! Camera raw frames (a D810 set to NEF), decoded with rawler.
//!
//! Pixel frame: the default crop is the area the body's own JPEG shows (a D810: 7360 x 4912 of its
//! 7380 x 4928 photosites, 12 columns in from the left and 8 rows down), at one pixel per
//! photosite, so a calibration made on the body's JPEGs holds for its raw frames too
//! (docs/frames.md).
//!
//! What the views get is linear: the relative luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of the
//! linear sRGB (as-shot white balance, the camera's colour matrix, D65), with the sensor's white
//! level at 65535, so the DICOM values stay proportional to the light the sensor saw (a JPEG's
//! luma is gamma encoded). It is computed straight from the mosaic ([`RawFrame::luminance`]).
//! Pictures for people (PNG, the overlays) are fully developed by rawler (PPG demosaic) and get
//! the sRGB transfer curve on top.

use super::srgb::srgb_encode;
use super::{Gray16Image, RectifyError, Rgb16Image};
use rawler::decoders::RawDecodeParams;
use rawler::imgop::develop::{Intermediate, ProcessingStep, RawDevelop};
use rawler::imgop::matrix::{multiply, normalize, pseudo_inverse};
use rawler::imgop::sensor::SensorType;
use rawler::imgop::xyz::{Illuminant, SRGB_TO_XYZ_D65};
use rawler::imgop::{Dim2, Point, Rect};
use rawler::rawimage::{RawImage, RawImageData, RawPhotometricInterpretation};
use rawler::rawsource::RawSource;
use rayon::prelude::*;

/// Whether `bytes` are a camera raw file rawler knows (a TIFF-based raw names its body in the
/// first directory; a plain TIFF does not). A TIFF whose structure fails the bounds of
/// `tiff_bounds.rs` is never given to rawler (and is not taken for one).
pub fn is_camera_raw(bytes: &[u8]) -> bool {
    let tiff = super::tiff_bounds::is_tiff(bytes) && super::tiff_bounds::check(bytes).is_ok();
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

/// A decoded raw frame: the photosites as the camera recorded them, and what developing needs.
pub struct RawFrame {
    raw: RawImage,
}

/// Decodes a raw frame. Errors (never panics) on anything rawler cannot take.
pub fn decode(bytes: &[u8]) -> Result<RawFrame, RectifyError> {
    super::tiff_bounds::check(bytes)?;
    let source = RawSource::new_from_slice(bytes);
    let raw = std::panic::catch_unwind(|| rawler::decode(&source, &RawDecodeParams::default()))
        .map_err(|_| failed("the raw decoder gave up on this file (a panic inside rawler)"))?
        .map_err(|e| RectifyError::RawData {
            step: "decode",
            source: Box::new(e),
        })?;
    if raw.cpp != 1 {
        return Err(failed(&format!(
            "{} {}: {} colour components per photosite; only Bayer mosaics are supported \
             (set the camera to a full-size NEF, not sRAW)",
            raw.clean_make, raw.clean_model, raw.cpp
        )));
    }
    // rawler's demosaic never ends on a mosaic under 6 photosites wide (found by mutation
    // fuzzing); no camera frame is that small.
    let areas = [
        Some((raw.width, raw.height)),
        raw.active_area.map(|a| (a.width(), a.height())),
        raw.crop_area.map(|a| (a.width(), a.height())),
    ];
    if let Some((w, h)) = areas
        .into_iter()
        .flatten()
        .find(|&(w, h)| w.min(h) < MIN_SIDE)
    {
        return Err(failed(&format!(
            "a mosaic (or its active or cropped area) of {w} x {h} photosites, under the \
             {MIN_SIDE} a side of any camera frame: a damaged file"
        )));
    }
    Ok(RawFrame { raw })
}

/// Fewest photosites a side of a raw frame (a D810's is 7380 x 4928).
const MIN_SIDE: usize = 16;

fn failed(what: &str) -> RectifyError {
    RectifyError::Raw(what.to_string())
}

impl RawFrame {
    /// The full development (PPG demosaic, white balance, colour matrix, default crop), for
    /// pictures people look at.
    pub fn develop(&self) -> Result<LinearFrame, RectifyError> {
        let steps = [
            ProcessingStep::Rescale,
            ProcessingStep::Demosaic,
            ProcessingStep::CropActiveArea,
            ProcessingStep::WhiteBalance,
            ProcessingStep::Calibrate,
            ProcessingStep::CropDefault,
        ];
        // rawler catches panics in its decoders but not in its developing steps.
        let developed = std::panic::catch_unwind(|| {
            RawDevelop::new_with(&steps).develop_intermediate(&self.raw)
        })
        .map_err(|_| failed("the raw developer gave up on this file (a panic inside rawler)"))?
        .map_err(|e| RectifyError::RawData {
            step: "develop",
            source: Box::new(e),
        })?;
        match developed {
            Intermediate::ThreeColor(pixels) => Ok(LinearFrame {
                width: pixels.width as u32,
                height: pixels.height as u32,
                rgb: pixels.data,
            }),
            _ => Err(failed("the developer did not return an RGB picture")),
        }
    }

    /// Linear relative luminance (white = 65535) on the default crop, straight from the mosaic:
    /// what the view series hold. Luminance is one linear combination of the camera's three
    /// channels (white balance, colour matrix and the Rec. 709 weights folded together), so one
    /// bilinear-demosaicing pass over 3 x 3 neighbourhoods gives it, over 10x faster than
    /// developing the colour picture and mixing it down (benches/frame_path.rs). Mosaics this
    /// pass does not know (not a 2 x 2 RGB Bayer pattern, float data, no D65 matrix) go the long
    /// way.
    ///
    /// Where the colour is out of the sRGB gamut or clipped, rawler's development pulls the
    /// colour back in gamut (`clip_euclidean_norm_avg`) before luminance could be taken; this
    /// pass keeps the luminance of the light as recorded, clamped to 0..65535 only.
    pub fn luminance(&self) -> Result<Gray16Image, RectifyError> {
        // rawler's level accessors index their vectors: a malformed file must not panic here.
        let fused = std::panic::catch_unwind(|| BayerLuminance::new(&self.raw).map(|k| k.run()))
            .map_err(|_| {
                failed("malformed levels or layout in the raw file (a panic inside rawler)")
            })?;
        match fused {
            Some(luminance) => Ok(luminance),
            None => Ok(self.develop()?.luminance()),
        }
    }

    /// sRGB-encoded 16-bit colour, for looking at.
    pub fn display(&self) -> Result<Rgb16Image, RectifyError> {
        Ok(self.develop()?.display())
    }
}

/// The fused mosaic-to-luminance pass over a 2 x 2 Bayer mosaic.
///
/// With bilinear demosaicing, each of a photosite's 3 x 3 neighbour classes (itself, the two
/// beside it, the two above and below, the four diagonal) holds one colour, so the luminance is
/// `w0·centre + w1·(left + right) + w2·(up + down) + w3·(diagonals)` with four weights per site
/// of the 2 x 2 pattern, applied to photosites already black-subtracted and scaled to 0..1.
struct BayerLuminance<'a> {
    photosites: &'a [u16],
    /// Photosites per sensor row.
    width: usize,
    /// The photosites that see light (rawler demosaics inside it too); neighbours beyond it are
    /// mirrored back in.
    active: Rect,
    /// The body's default crop, inside `active`: the output.
    crop: Rect,
    /// Per site (row parity · 2 + column parity): [w0, w1, w2, w3].
    weights: [[f32; 4]; 4],
    /// Per site: black level and 1 / (white − black).
    black: [f32; 4],
    scale: [f32; 4],
}

/// Rows per parallel task: each task linearises its rows (plus one above and below) once.
const BAND_ROWS: usize = 32;

impl<'a> BayerLuminance<'a> {
    fn new(raw: &'a RawImage) -> Option<Self> {
        let RawPhotometricInterpretation::Cfa(config) = &raw.photometric else {
            return None;
        };
        let RawImageData::Integer(photosites) = &raw.data else {
            return None;
        };
        let cfa = &config.cfa;
        if !(cfa.is_rgb()
            && config.sensor == SensorType::Bayer
            && cfa.width == 2
            && cfa.height == 2)
        {
            return None;
        }
        let (_, matrix) = raw.color_matrix_find_first([Illuminant::D65])?;
        if matrix.len() < 9 || photosites.len() != raw.width * raw.height || raw.width < 2 {
            return None;
        }
        let xyz_to_cam = [
            [matrix[0], matrix[1], matrix[2]],
            [matrix[3], matrix[4], matrix[5]],
            [matrix[6], matrix[7], matrix[8]],
        ];
        // As rawler's Calibrate step: camera from sRGB with rows normalised (camera white is
        // sRGB white), inverted; white balance applied to the camera channels first.
        let cam_to_srgb = pseudo_inverse(normalize(multiply(&xyz_to_cam, &SRGB_TO_XYZ_D65)));
        // As rawler: no coefficients (NaN) means none applied.
        let wb = if raw.wb_coeffs[0].is_nan() {
            [1.0; 3]
        } else {
            [raw.wb_coeffs[0], raw.wb_coeffs[1], raw.wb_coeffs[2]]
        };
        let rec709 = [0.2126f32, 0.7152, 0.0722];
        let channel_weight: [f32; 3] = std::array::from_fn(|c| {
            (0..3).map(|i| rec709[i] * cam_to_srgb[i][c]).sum::<f32>() * wb[c]
        });
        let black = raw.blacklevel.as_bayer_array();
        let white = raw.whitelevel.as_bayer_array();
        let range: [f32; 4] = std::array::from_fn(|i| white[i] - black[i]);
        if range.iter().any(|r| r.is_nan() || *r <= 0.0) {
            return None;
        }
        // Each channel at a photosite: its own value if it is of that colour, else the mean of
        // its 3 x 3 neighbours of that colour.
        let weights = std::array::from_fn(|site| {
            let (row, col) = (site / 2 + 2, site % 2 + 2);
            let colour = |dy: isize, dx: isize| {
                cfa.color_at((row as isize + dy) as usize, (col as isize + dx) as usize)
            };
            let own = colour(0, 0);
            let count = |c: usize| {
                (-1..=1)
                    .flat_map(|dy| (-1..=1).map(move |dx| (dy, dx)))
                    .filter(|&(dy, dx)| (dy, dx) != (0, 0) && colour(dy, dx) == c)
                    .count() as f32
            };
            let class = |dy: isize, dx: isize| {
                let c = colour(dy, dx);
                if c == own || c > 2 {
                    0.0
                } else {
                    channel_weight[c] / count(c)
                }
            };
            [
                channel_weight[own.min(2)],
                class(0, 1),
                class(1, 0),
                class(1, 1),
            ]
        });
        // A 2 x 2 Bayer pattern has one colour per class; anything else goes the long way.
        let one_colour_per_class = (0..4).all(|site| {
            let (row, col) = (site / 2 + 2, site % 2 + 2);
            let c = |dy: isize, dx: isize| {
                cfa.color_at((row as isize + dy) as usize, (col as isize + dx) as usize)
            };
            c(0, -1) == c(0, 1)
                && c(-1, 0) == c(1, 0)
                && [c(-1, 1), c(1, -1), c(1, 1)]
                    .iter()
                    .all(|&d| d == c(-1, -1))
                && c(0, 0) <= 2
        });
        let full = Rect::new(Point::new(0, 0), Dim2::new(raw.width, raw.height));
        let active = raw.active_area.unwrap_or(full);
        let crop = raw.crop_area.unwrap_or(active);
        let inside = |r: &Rect, outer: &Rect| {
            r.p.x >= outer.p.x
                && r.p.y >= outer.p.y
                && r.p.x + r.d.w <= outer.p.x + outer.d.w
                && r.p.y + r.d.h <= outer.p.y + outer.d.h
        };
        if !one_colour_per_class
            || active.d.w < 2
            || active.d.h < 2
            || crop.d.w == 0
            || crop.d.h == 0
            || !inside(&active, &full)
            || !inside(&crop, &active)
        {
            return None;
        }
        Some(BayerLuminance {
            photosites,
            width: raw.width,
            active,
            crop,
            weights,
            black,
            scale: range.map(|r| 1.0 / r),
        })
    }

    /// Sensor row `r` across the active area, black-subtracted and scaled, mirrored at the
    /// active area's edges (which keeps the colours), with one mirrored photosite on each side:
    /// `line[x - active.x + 1]` is column x.
    fn linearise(&self, r: isize, line: &mut [f32]) {
        let (top, rows) = (self.active.p.y as isize, self.active.d.h as isize);
        let r = mirror(r - top, rows) + top as usize;
        let (left, columns) = (self.active.p.x, self.active.d.w);
        let row = &self.photosites[r * self.width + left..r * self.width + left + columns];
        // Sites of this row, for even and odd sensor columns.
        let site = |column: usize| (r % 2) * 2 + column % 2;
        let (first, second) = (site(left), site(left + 1));
        let (b0, b1) = (self.black[first], self.black[second]);
        let (s0, s1) = (self.scale[first], self.scale[second]);
        let body = &mut line[1..=columns];
        for (out, pair) in body.chunks_mut(2).zip(row.chunks(2)) {
            out[0] = (f32::from(pair[0]) - b0).max(0.0) * s0;
            if let (Some(o), Some(&p)) = (out.get_mut(1), pair.get(1)) {
                *o = (f32::from(p) - b1).max(0.0) * s1;
            }
        }
        line[0] = line[2];
        line[columns + 1] = line[columns - 1];
    }

    fn run(&self) -> Gray16Image {
        let (w, h) = (self.crop.d.w, self.crop.d.h);
        let mut out = vec![0u16; w * h];
        out.par_chunks_mut(w * BAND_ROWS)
            .enumerate()
            .for_each(|(band, lines)| {
                let first = self.crop.p.y + band * BAND_ROWS;
                let mut rows = [0usize, 1, 2].map(|_| vec![0f32; self.active.d.w + 2]);
                self.linearise(first as isize - 1, &mut rows[0]);
                self.linearise(first as isize, &mut rows[1]);
                for (i, line) in lines.chunks_mut(w).enumerate() {
                    let y = first + i;
                    self.linearise(y as isize + 1, &mut rows[2]);
                    let [up, centre, down] = &rows;
                    for (j, out) in line.iter_mut().enumerate() {
                        let column = self.crop.p.x + j;
                        let x = column - self.active.p.x + 1;
                        let [w0, w1, w2, w3] = self.weights[(y % 2) * 2 + column % 2];
                        let y_lin = w0 * centre[x]
                            + w1 * (centre[x - 1] + centre[x + 1])
                            + w2 * (up[x] + down[x])
                            + w3 * (up[x - 1] + up[x + 1] + down[x - 1] + down[x + 1]);
                        *out = to_u16(y_lin);
                    }
                    rows.rotate_left(1);
                }
            });
        // One value per pixel of the crop.
        Gray16Image::from_raw(w as u32, h as u32, out).expect("luminance sized for the crop")
    }
}

/// Index `i` of `0..n` (n >= 2) reflected at both ends without repeating the edge, which keeps
/// the parity and so a photosite's colour.
fn mirror(i: isize, n: isize) -> usize {
    let i = if i < 0 {
        -i
    } else if i >= n {
        2 * n - 2 - i
    } else {
        i
    };
    i.clamp(0, n - 1) as usize
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
            .flat_map_iter(|p| p.map(|c| to_u16(srgb_encode(f64::from(c)) as f32)))
            .collect();
        // Three values per pixel of a width x height frame.
        Rgb16Image::from_raw(self.width, self.height, rgb).expect("colour sized for the frame")
    }
}

fn to_u16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

#[cfg(test)]
mod tests {
    use super::*;
    use mock_camera::nef::{encode_nef, NefCompression, NefOptions};

    /// A grey frame; its four sites have different black levels, so that a black level read
    /// from the wrong site shows.
    fn grey_nef(level: u8, compression: NefCompression) -> Vec<u8> {
        let picture = image::RgbImage::from_pixel(64, 48, image::Rgb([level, level, level]));
        encode_nef(
            &picture,
            &NefOptions {
                compression,
                black_level: [560, 600, 620, 680],
                ..NefOptions::default()
            },
        )
    }

    /// The demo plate after the scan of `layer`, seen obliquely by a w x h camera.
    fn plate_picture(
        w: u32,
        h: u32,
        layer: u32,
        illumination: mock_camera::Illumination,
    ) -> image::RgbImage {
        use mock_camera::{demo_parts, Homography, Renderer, Scene};
        let fused = demo_parts(layer);
        Renderer::new(w, h, Homography::oblique_view(w, h)).render(&Scene {
            layer,
            fused: &fused,
            scanned: true,
            illumination,
        })
    }

    #[test]
    fn a_d810_frame_develops_to_the_linear_grey_it_was_made_of() {
        for compression in [NefCompression::Uncompressed, NefCompression::Lossless] {
            for level in [40u8, 128, 230] {
                let nef = grey_nef(level, compression);
                assert!(is_camera_raw(&nef));
                let frame = decode(&nef).unwrap().develop().unwrap();
                // The D810's default crop gives back the picture's size.
                assert_eq!((frame.width, frame.height), (64, 48));
                let expected = mock_camera::nef::srgb_to_linear(level) as f32;
                let fused = decode(&nef).unwrap().luminance().unwrap();
                // rawler's development is checked away from the crop's edges; the fused pass
                // reads the photosites beyond them, so it holds to the edge.
                for (path, y, margin) in [("developed", frame.luminance(), 4), ("fused", fused, 0)]
                {
                    assert_eq!(y.dimensions(), (64, 48));
                    for yy in margin..48 - margin {
                        for xx in margin..64 - margin {
                            let got = f32::from(y.get_pixel(xx, yy).0[0]) / 65535.0;
                            assert!(
                                (got - expected).abs() < 0.002 + 0.01 * expected,
                                "{compression:?} grey {level}, {path}: Y {got} at ({xx}, {yy}), expected {expected}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn lossless_and_uncompressed_frames_of_a_plate_develop_alike() {
        let (w, h) = (320, 200);
        let picture = plate_picture(w, h, 5, mock_camera::Illumination::Side);
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
        let luminance = |bytes: &[u8]| decode(bytes).unwrap().develop().unwrap().luminance();
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
    fn fused_luminance_matches_the_developed_picture() {
        let (w, h) = (400, 260);
        let picture = plate_picture(w, h, 3, mock_camera::Illumination::Front);
        let nef = encode_nef(&picture, &NefOptions::default());
        let raw = decode(&nef).unwrap();
        let developed = raw.develop().unwrap().luminance();
        let fast = raw.luminance().unwrap();
        assert_eq!(fast.dimensions(), developed.dimensions());
        let (mut bias, mut spread) = (0.0, 0.0);
        for (a, b) in fast.pixels().zip(developed.pixels()) {
            let d = f64::from(a.0[0]) - f64::from(b.0[0]);
            bias += d;
            spread += d.abs();
        }
        let n = f64::from(w * h);
        let (bias, spread) = (bias / n, spread / n);
        eprintln!("fused - developed: mean {bias:.1}, mean |.| {spread:.1} / 65535");
        // Same black level, white balance and colour matrix (no bias); the two demosaicings
        // (bilinear here, PPG there) differ only along edges of the texture.
        assert!(
            bias.abs() < 0.0005 * 65535.0 && spread < 0.01 * 65535.0,
            "fused - developed: mean {bias:.1}, mean |.| {spread:.1} / 65535"
        );
    }

    #[test]
    fn neighbours_beyond_the_edge_mirror_to_the_same_colour() {
        assert_eq!([-1, 0, 4, 5, 6].map(|i| mirror(i, 6)), [1, 0, 4, 5, 4]);
        // Parity (the colour of a 2 x 2 pattern) is kept.
        for n in [2, 5, 6] {
            for i in [-1, n] {
                assert_eq!(mirror(i, n) % 2, i.rem_euclid(2) as usize, "{i} of {n}");
            }
        }
    }

    #[test]
    fn colours_keep_their_luminance() {
        // In-gamut colours: grey alone cannot tell a wrong colour matrix or wrong Rec. 709
        // weights (both keep white white).
        let colours = [
            [200u8, 80, 40],
            [40, 160, 90],
            [60, 80, 200],
            [180, 180, 60],
            [150, 60, 160],
            [90, 190, 200],
        ];
        let patch = 16;
        let picture = image::RgbImage::from_fn(patch * colours.len() as u32, patch, |x, _| {
            image::Rgb(colours[(x / patch) as usize])
        });
        let raw = decode(&encode_nef(&picture, &NefOptions::default())).unwrap();
        let fused = raw.luminance().unwrap();
        let developed = raw.develop().unwrap().luminance();
        for (i, c) in colours.iter().enumerate() {
            let linear = c.map(mock_camera::nef::srgb_to_linear);
            let expected = 0.2126 * linear[0] + 0.7152 * linear[1] + 0.0722 * linear[2];
            // The patch's middle, away from the colour edges.
            let (x, y) = (i as u32 * patch + patch / 2, patch / 2);
            for (path, image) in [("fused", &fused), ("developed", &developed)] {
                let got = f64::from(image.get_pixel(x, y).0[0]) / 65535.0;
                assert!(
                    (got - expected).abs() < 0.003 + 0.01 * expected,
                    "{c:?}, {path}: Y {got:.4}, expected {expected:.4}"
                );
            }
        }
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
        assert!(decode(b"MM\0\x2Anonsense").is_err());
        // A frame too small for any camera (the demosaic's loop never ended under 6 photosites
        // a side; here the mosaic has the D810's margins and its cropped area is 4 x 4).
        let tiny = encode_nef(
            &image::RgbImage::from_pixel(4, 4, image::Rgb([9, 9, 9])),
            &NefOptions::default(),
        );
        let e = decode(&tiny).err().expect("refused");
        assert!(e.to_string().contains("4 x 4 photosites"), "{e}");
        let nef = grey_nef(128, NefCompression::Lossless);
        for cut in [16, 200, nef.len() / 2, nef.len() - 40] {
            // A truncated file is an error or a picture, never a panic.
            if let Ok(raw) = decode(&nef[..cut]) {
                let _ = raw.develop();
                let _ = raw.luminance();
            }
        }
    }
}
