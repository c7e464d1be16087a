//! Camera raw frames (the D810 set to NEF), through the same paths as JPEG frames: the daemon
//! stores the NEF originals and its live series hold their linear luminance; `layerwise rectify`
//! takes a NEF; a broken NEF is named. The NEFs come from mock_camera (a D810 file layout, both
//! 14-bit modes), so nothing binary is checked in.

use crate::common::*;
use dicom_dictionary_std::tags;
use layerwise::config::{CameraConfig, Config, MockFrameFormat};
use layerwise::dicom::Compression;
use std::path::Path;

fn build_with(dir: &Path, format: MockFrameFormat) -> std::path::PathBuf {
    let build = dir.join(format!("{format:?}"));
    let mut config: Config = calibrated_config(&build, 2, Compression::None);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.format = format;
    }
    let config_path = dir.join(format!("{format:?}.toml"));
    write_config(&config, &config_path);
    run_build(&config_path);
    build
}

/// Pixel values, window center and derivation of one slice.
fn slice(path: &Path) -> (Vec<u16>, f64, String) {
    let obj = dicom_object::open_file(path).unwrap();
    let bytes = obj
        .element(tags::PIXEL_DATA)
        .unwrap()
        .to_bytes()
        .unwrap()
        .to_vec();
    let pixels = bytes
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let text = |tag| {
        obj.element(tag)
            .unwrap()
            .to_str()
            .unwrap()
            .trim()
            .to_string()
    };
    let center = text(tags::WINDOW_CENTER).parse().unwrap();
    (pixels, center, text(tags::DERIVATION_DESCRIPTION))
}

#[test]
fn a_raw_build_keeps_nefs_and_its_views_hold_the_linear_light_of_the_jpeg_build() {
    let dir = tempfile::tempdir().unwrap();
    let jpeg = build_with(dir.path(), MockFrameFormat::Jpeg);
    let nef = build_with(dir.path(), MockFrameFormat::Nef);

    // Originals: the NEF as the camera gave it, with a sidecar whose sha256 matches.
    let expected: Vec<String> = expected_originals(2)
        .into_iter()
        .map(|name| name.replace(".jpg", ".nef"))
        .collect();
    assert_eq!(originals(&nef), expected);
    assert_sidecars_match(&nef);
    let first = std::fs::read(nef.join("raw/L00001_pre_front.nef")).unwrap();
    assert!(first.starts_with(b"MM\0\x2A"));

    // The same mock world seen through JPEG and through NEF: the NEF views are the JPEG views'
    // luma with the sRGB curve undone (up to JPEG loss and the demosaic).
    let to_linear = |v: u16| mock_camera::nef::srgb_to_linear(v as u8) * 65535.0;
    for view in ["pre_front", "post_side", "post_top"] {
        for layer in [1, 2] {
            let name = format!("dicom/{view}/L{layer:05}.dcm");
            let (from_jpeg, jpeg_center, _) = slice(&jpeg.join(&name));
            let (from_nef, nef_center, derivation) = slice(&nef.join(&name));
            assert_eq!(from_jpeg.len(), from_nef.len());
            assert_eq!((jpeg_center, nef_center), (128.0, 32768.0));
            assert!(derivation.contains("linear luminance"), "{derivation}");
            assert!(from_jpeg.iter().all(|&v| v <= 255));
            let (mut bias, mut spread, mut n) = (0.0, 0.0, 0usize);
            for (&j, &r) in from_jpeg.iter().zip(&from_nef) {
                // Grid pixels outside the frame are fill (0) in both.
                if j > 0 || r > 0 {
                    let d = f64::from(r) - to_linear(j);
                    bias += d;
                    spread += d.abs();
                    n += 1;
                }
            }
            let (bias, spread) = (bias / n as f64, spread / n as f64);
            eprintln!(
                "{name}: {n} pixels, NEF - JPEG: mean {bias:.1}, mean |.| {spread:.1} / 65535"
            );
            assert!(n > 100_000, "{name}: only {n} pixels inside the frame");
            // No offset or gain between the two (a wrong black level, white level or white
            // balance shows here), and the texture differs only by JPEG loss and demosaicing.
            assert!(
                bias.abs() < 0.002 * 65535.0 && spread < 0.015 * 65535.0,
                "{name}: NEF and linearised JPEG views differ by {bias:.0} on average, {spread:.0} in magnitude"
            );
        }
    }
}

#[test]
fn rectify_takes_a_nef_and_names_a_broken_one() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let nef =
        mock_camera::nef::encode_nef(&view.picture(), &mock_camera::nef::NefOptions::default());
    let frame = dir.path().join("frame.nef");
    std::fs::write(&frame, &nef).unwrap();
    let rectify = |image: &Path, out: &str| view.rectify(image, &dir.path().join(out));
    for out in ["top.png", "top.dcm"] {
        assert_success(&rectify(&frame, out));
    }
    // The picture: 16-bit colour on the grid, and the plate where the JPEG path puts it.
    let png = image::open(dir.path().join("top.png")).unwrap();
    assert_eq!(png.color(), image::ColorType::Rgb16);
    assert_eq!((png.width(), png.height()), (550, 550));
    let jpeg_frame = dir.path().join("frame.jpg");
    std::fs::write(&jpeg_frame, view.jpeg()).unwrap();
    assert_success(&rectify(&jpeg_frame, "top_jpeg.png"));
    let from_jpeg = image::open(dir.path().join("top_jpeg.png"))
        .unwrap()
        .to_luma8();
    let from_nef = png.to_luma8();
    let diffs: Vec<f64> = from_jpeg
        .pixels()
        .zip(from_nef.pixels())
        .map(|(a, b)| f64::from(b.0[0]) - f64::from(a.0[0]))
        .collect();
    let bias = diffs.iter().sum::<f64>() / diffs.len() as f64;
    let spread = diffs.iter().map(|d| d.abs()).sum::<f64>() / diffs.len() as f64;
    eprintln!("rectified pictures, NEF - JPEG: mean {bias:.2}, mean |.| {spread:.2} grey levels");
    assert!(
        bias.abs() < 0.5 && spread < 4.0,
        "NEF and JPEG pictures differ by {bias:.2} on average, {spread:.2} in magnitude"
    );

    let (pixels, center, _) = slice(&dir.path().join("top.dcm"));
    assert_eq!((pixels.len(), center), (550 * 550, 32768.0));

    // A NEF cut short: exit 1, the file named, nothing written.
    let broken = dir.path().join("broken.nef");
    std::fs::write(&broken, &nef[..nef.len() / 3]).unwrap();
    let stderr = assert_exit_1(&rectify(&broken, "broken.png"));
    assert!(
        stderr.contains("broken.nef") && stderr.contains("raw"),
        "{stderr}"
    );
    assert!(!dir.path().join("broken.png").exists());
}
