use super::*;
use jpeg_encoder::{ColorType, Encoder, SamplingFactor};

/// A picture with edges, gradients and noise (many non-zero AC coefficients).
fn picture(w: u16, h: u16, seed: u32) -> Vec<u8> {
    let mut s = seed | 1;
    let mut out = Vec::with_capacity(usize::from(w) * usize::from(h) * 3);
    for y in 0..u32::from(h) {
        for x in 0..u32::from(w) {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            let edge = if (x / 7 + y / 5) % 3 == 0 { 90 } else { 0 };
            let n = s % 40;
            out.push(((x * 3 + edge + n) % 256) as u8);
            out.push(((y * 5 + n) % 256) as u8);
            out.push(((x + y + edge) % 256) as u8);
        }
    }
    out
}

fn encode(
    w: u16,
    h: u16,
    grey: bool,
    sampling: SamplingFactor,
    restart: u16,
    quality: u8,
) -> Vec<u8> {
    let rgb = picture(w, h, u32::from(w) * 31 + u32::from(h));
    let mut out = Vec::new();
    let mut enc = Encoder::new(&mut out, quality);
    enc.set_sampling_factor(sampling);
    enc.set_restart_interval(restart);
    if grey {
        let luma: Vec<u8> = rgb
            .chunks_exact(3)
            .map(|p| p[0] / 2 + p[1] / 3 + p[2] / 6)
            .collect();
        enc.encode(&luma, w, h, ColorType::Luma).unwrap();
    } else {
        enc.encode(&rgb, w, h, ColorType::Rgb).unwrap();
    }
    out
}

/// Our luma (which must be ours, not the fallback's), single-thread or pipelined.
fn ours(jpeg: &[u8], threaded: bool) -> Result<GrayImage, RectifyError> {
    let header = header::parse(jpeg).expect("a frame this decoder handles");
    decode(jpeg, &header, threaded, None)
}

fn worst_difference(a: &[u8], b: &[u8]) -> i32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(&x, &y)| (i32::from(x) - i32::from(y)).abs())
        .max()
        .unwrap_or(0)
}

#[test]
fn luma_is_zunes_within_one_for_every_sampling_size_and_restart_interval() {
    let samplings = [
        SamplingFactor::F_1_1,
        SamplingFactor::F_2_1,
        SamplingFactor::F_2_2,
        SamplingFactor::F_1_2,
        SamplingFactor::F_4_1,
        SamplingFactor::F_2_4,
    ];
    let sizes = [
        (1, 1),
        (7, 5),
        (17, 9),
        (33, 47),
        (97, 61),
        (130, 77),
        (259, 141),
    ];
    let (mut decoded, mut fallbacks, mut zune_failures) = (0, 0, 0);
    for &(w, h) in &sizes {
        for (i, &sampling) in samplings.iter().enumerate() {
            for restart in [0, 1, 3] {
                for grey in [false, true] {
                    if grey && i > 0 {
                        continue;
                    }
                    let quality = if (w + restart) % 2 == 0 { 95 } else { 100 };
                    let jpeg = encode(w, h, grey, sampling, restart, quality);
                    let what = format!("{w}x{h} {sampling:?} restart {restart} grey {grey}");
                    if header::parse(&jpeg).is_none() {
                        // jpeg-encoder writes 4x1 and 2x4 sampling as one scan per component:
                        // left to zune.
                        assert!(jpeg.windows(2).filter(|w| w == &[0xFF, 0xDA]).count() > 1);
                        fallbacks += 1;
                        continue;
                    }
                    decoded += 1;
                    let mine = ours(&jpeg, false).unwrap_or_else(|e| panic!("{what}: {e}"));
                    assert_eq!(mine.dimensions(), (u32::from(w), u32::from(h)), "{what}");
                    let theirs = crate::rectify::decode::zune_decode(&jpeg, true);
                    let d = match theirs {
                        Ok(theirs) => worst_difference(mine.as_raw(), &theirs.pixels),
                        Err(e) => {
                            // zune 0.5, strict and given no EOI, refuses valid frames of 1x2
                            // sampling ("premature end of buffer") and some with restart markers
                            // ("exhausted data"): libjpeg-turbo's luma instead, exactly.
                            eprintln!("{what}: zune: {e:?}");
                            zune_failures += 1;
                            2 * worst_difference(mine.as_raw(), &djpeg_luma(&jpeg, w, h))
                        }
                    };
                    assert!(
                        d <= 1,
                        "{what}: differs by {d} (from zune; from djpeg counted twice)"
                    );
                    // The public entry point takes this decoder.
                    assert_eq!(decode_jpeg_luma_raw(&jpeg), mine.into_raw(), "{what}");
                }
            }
        }
    }
    assert_eq!(
        (decoded, fallbacks),
        (sizes.len() * 3 * 5, sizes.len() * 3 * 2)
    );
    assert!(zune_failures < decoded / 3, "{zune_failures} of {decoded}");
}

/// libjpeg-turbo's luma (djpeg -grayscale) of `jpeg`.
fn djpeg_luma(jpeg: &[u8], w: u16, h: u16) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let (jpg, pgm) = (dir.path().join("in.jpg"), dir.path().join("out.pgm"));
    std::fs::write(&jpg, jpeg).unwrap();
    let djpeg = std::process::Command::new("djpeg")
        .args(["-grayscale", "-pnm", "-outfile"])
        .arg(&pgm)
        .arg(&jpg)
        .status()
        .expect("djpeg (Debian's libjpeg-turbo-progs, as tests/it/bounded_inputs.rs)");
    assert!(djpeg.success());
    let theirs = std::fs::read(&pgm).unwrap();
    theirs[theirs.len() - usize::from(w) * usize::from(h)..].to_vec()
}

fn decode_jpeg_luma_raw(jpeg: &[u8]) -> Vec<u8> {
    crate::rectify::decode_jpeg_luma(jpeg).unwrap().into_raw()
}

#[test]
fn the_pipeline_gives_the_single_thread_result() {
    for (sampling, restart) in [(SamplingFactor::F_2_1, 0), (SamplingFactor::F_2_2, 5)] {
        let jpeg = encode(517, 403, false, sampling, restart, 95);
        let one = ours(&jpeg, false).unwrap();
        let two = ours(&jpeg, true).unwrap();
        assert_eq!(one.as_raw(), two.as_raw());
    }
}

/// Offset of the entropy-coded data (after the SOS segment) and of the final EOI.
fn scan_bounds(jpeg: &[u8]) -> (usize, usize) {
    let start = header::parse(jpeg).unwrap().data_start;
    assert!(jpeg.ends_with(&[0xFF, 0xD9]));
    (start, jpeg.len() - 2)
}

#[test]
fn a_cut_file_is_an_error_not_grey_rows() {
    for restart in [0, 2] {
        let jpeg = encode(259, 141, false, SamplingFactor::F_2_2, restart, 95);
        let (start, end) = scan_bounds(&jpeg);
        for cut in [start + 1, (start + end) / 2, end - 40, end - 3] {
            let bare = &jpeg[..cut];
            let mut closed = bare.to_vec();
            closed.extend_from_slice(&[0xFF, 0xD9]);
            for (name, file) in [("bare", bare), ("closed with an EOI", &closed[..])] {
                for threaded in [false, true] {
                    let e = ours(file, threaded).err().unwrap_or_else(|| {
                        panic!("restart {restart}, cut at {cut} of {end}, {name}: decoded")
                    });
                    assert!(e.to_string().contains("cut short"), "{e}");
                }
            }
        }
        // Whole, with or without its EOI, it decodes.
        ours(&jpeg, false).unwrap();
        ours(&jpeg[..end], false).unwrap();
    }
}

#[test]
fn corrupt_entropy_data_is_an_error() {
    let jpeg = encode(97, 61, false, SamplingFactor::F_2_1, 0, 95);
    let (start, end) = scan_bounds(&jpeg);
    // All ones is no code of any table (a stuffed 0xFF is 0xFF 0x00).
    let mut ones = jpeg[..start].to_vec();
    for _ in start..end {
        ones.extend_from_slice(&[0xFF, 0x00]);
    }
    ones.extend_from_slice(&[0xFF, 0xD9]);
    let e = ours(&ones, false).unwrap_err().to_string();
    assert!(e.contains("no Huffman code"), "{e}");
    // Random damage: an error or some picture, never a panic.
    let mut s = 7u32;
    for _ in 0..300 {
        let mut bad = jpeg.clone();
        for _ in 0..4 {
            s = s.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            let at = start + (s >> 8) as usize % (end - start);
            bad[at] = (s >> 3) as u8;
        }
        let _ = decode_jpeg_luma_raw_result(&bad);
    }
}

fn decode_jpeg_luma_raw_result(jpeg: &[u8]) -> Result<GrayImage, RectifyError> {
    crate::rectify::decode_jpeg_luma(jpeg)
}

#[test]
fn restart_markers_out_of_sequence_are_an_error() {
    let mut jpeg = encode(97, 61, false, SamplingFactor::F_2_2, 1, 95);
    let (start, _) = scan_bounds(&jpeg);
    let rst = start
        + jpeg[start..]
            .windows(2)
            .position(|w| w == [0xFF, 0xD0])
            .unwrap();
    jpeg[rst + 1] = 0xD3;
    let e = ours(&jpeg, false).unwrap_err().to_string();
    assert!(e.contains("out of sequence"), "{e}");
}

#[test]
fn progressive_and_oversized_frames_are_left_to_zune_or_refused() {
    let rgb = picture(97, 61, 3);
    let mut jpeg = Vec::new();
    let mut enc = Encoder::new(&mut jpeg, 90);
    enc.set_progressive(true);
    enc.encode(&rgb, 97, 61, ColorType::Rgb).unwrap();
    assert!(header::parse(&jpeg).is_none());
    let luma = crate::rectify::decode_jpeg_luma(&jpeg).unwrap();
    assert_eq!(luma.dimensions(), (97, 61));
    // A baseline header claiming 65535 x 65535 pixels is refused before anything is allocated.
    let mut big = encode(17, 9, false, SamplingFactor::F_2_2, 0, 90);
    let sof = big.windows(2).position(|w| w == [0xFF, 0xC0]).unwrap();
    big[sof + 5..sof + 9].copy_from_slice(&[0xFF; 4]);
    let e = ours(&big, false).unwrap_err();
    assert!(matches!(e, RectifyError::TooLarge { .. }), "{e}");
}

#[test]
fn libjpeg_turbo_files_decode_to_its_luma() {
    // cjpeg writes the camera's kind of file (and its own Huffman tables); djpeg's greyscale
    // output is libjpeg-turbo's luma, which ours matches exactly (the same integer IDCT).
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (203u16, 117u16);
    let ppm = dir.path().join("in.ppm");
    let mut data = format!("P6\n{w} {h}\n255\n").into_bytes();
    data.extend(picture(w, h, 11));
    std::fs::write(&ppm, data).unwrap();
    for args in [
        &["-sample", "2x1"][..],
        &["-sample", "2x2", "-restart", "1"],
        &["-optimize", "-restart", "3B"],
        // Blocks whose last coefficient is not zero (no end-of-block code: the next bits are the
        // next block's DC, which the two-symbol lookup must not take for a coefficient).
        &["-quality", "100", "-sample", "1x1"],
    ] {
        let jpg = dir.path().join("out.jpg");
        let status = std::process::Command::new("cjpeg")
            .args(["-quality", "95"])
            .args(args)
            .arg("-outfile")
            .arg(&jpg)
            .arg(&ppm)
            .status()
            .expect("cjpeg (Debian's libjpeg-turbo-progs, as tests/it/bounded_inputs.rs)");
        assert!(status.success());
        let jpeg = std::fs::read(&jpg).unwrap();
        let mine = ours(&jpeg, true).unwrap();
        assert_eq!(
            worst_difference(mine.as_raw(), &djpeg_luma(&jpeg, w, h)),
            0,
            "{args:?}"
        );
    }
}

#[test]
fn decoding_only_what_the_rectifier_reads_changes_no_rectified_pixel() {
    use crate::geometry::{CameraModel, Grid, Homography, Interpolation};
    let (w, h) = (736u16, 491u16);
    let truth = mock_camera::Homography::oblique_view(u32::from(w), u32::from(h));
    let camera = CameraModel::pinhole(Homography::from_matrix(truth.m));
    let grid = Grid {
        pixel_mm: 0.5,
        ..Grid::plate()
    };
    for sampling in [
        SamplingFactor::F_1_1,
        SamplingFactor::F_2_1,
        SamplingFactor::F_1_2,
        SamplingFactor::F_2_2,
    ] {
        for restart in [0, 7] {
            let jpeg = encode(w, h, false, sampling, restart, 90);
            let header = header::parse(&jpeg).expect("a frame this decoder handles");
            let full = ours(&jpeg, false).unwrap();
            for interpolation in [Interpolation::Bilinear, Interpolation::Bicubic] {
                let r = Rectifier::new(&camera, grid, interpolation, 0).unwrap();
                for threaded in [false, true] {
                    let part = decode(&jpeg, &header, threaded, Some(&r)).unwrap();
                    let case = format!(
                        "{sampling:?}, restart {restart}, {interpolation:?}, threaded {threaded}"
                    );
                    assert_eq!(r.rectify_gray8(&part), r.rectify_gray8(&full), "{case}");
                    // Pixels beside the plate were left out (0), the others are the frame's.
                    let left_out = part.as_raw().iter().filter(|&&v| v == 0).count();
                    let share = left_out as f64 / part.as_raw().len() as f64;
                    assert!((0.2..0.7).contains(&share), "{case}: {share:.2} left out");
                    let kept_differ = part
                        .as_raw()
                        .iter()
                        .zip(full.as_raw())
                        .filter(|(&p, &f)| p != 0 && p != f)
                        .count();
                    assert_eq!(kept_differ, 0, "{case}");
                    // Into the buffer of another frame: the same pixels, zeros included.
                    let stale = vec![0xA5u8; part.as_raw().len()];
                    let reused = decode_into(&jpeg, &header, threaded, Some(&r), Some(stale));
                    assert!(reused.unwrap() == part, "{case}: a reused buffer");
                }
            }
        }
    }
}
