//! The live DICOM series, checked by tools no one here wrote: dicom3tools (dciodvfy, dcentvfy),
//! dcmtk (dcmftest, dcmdump, dcmconv, dcmj2pnm), pydicom and SimpleITK (tests/dicom_check.py in
//! the venv that tests/run.sh makes). The README's test command installs all of them.

use crate::common::*;
use layerwise::acquisition::RunOptions;
use layerwise::config::Config;
use layerwise::dicom::Compression;
use layerwise::rectify::Calibration;
use layerwise::series::{series_dir, LayerHeights, LiveSeries, SeriesSettings};
use layerwise::shot::{Light, Phase, Shot, View};
use std::path::{Path, PathBuf};
use std::process::Command;

fn tool(name: &str) -> Command {
    let path = std::env::var_os("PATH").unwrap_or_default();
    assert!(
        std::env::split_paths(&path).any(|dir| dir.join(name).is_file()),
        "{name} is needed: the README's test command installs dicom3tools and dcmtk"
    );
    Command::new(name)
}

/// What a dicom3tools program printed, stderr then stdout (they report on either).
fn tool_text(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout)
}

/// dcentvfy finds no error across `files`: one patient, study, series and frame of reference
/// where they should be, no duplicate SOP instance.
fn assert_dcentvfy_clean(files: &[PathBuf]) {
    let text = tool_text(&tool("dcentvfy").args(files).output().unwrap());
    assert!(
        !text.lines().any(|l| l.starts_with("Error")),
        "dcentvfy: {text}"
    );
}

/// dcmtk's copy of `file` in explicit VR little endian (dciodvfy cannot read deflated data sets).
fn explicit_vr_copy(file: &Path, back: &Path) {
    tool("dcmconv").arg("+te").arg(file).arg(back).succeeds();
}

/// What a Python snippet run in the test venv printed; `arg` is its `sys.argv[1]`.
fn python_says(script: &str, arg: &Path) -> String {
    Command::new(python())
        .args(["-c", script])
        .arg(arg)
        .stdout_ok()
}

/// Runs to the end of the mock trigger and processes every frame before returning.
fn drained() -> RunOptions {
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    options
}

/// The files one folder down: the instances of every series in `dir`.
fn series_files(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for series in std::fs::read_dir(dir).unwrap() {
        for f in std::fs::read_dir(series.unwrap().path()).unwrap() {
            out.push(f.unwrap().path());
        }
    }
    out.sort();
    out
}

/// Every live series instance of a build.
fn all_dcm(build: &Path) -> Vec<PathBuf> {
    series_files(&build.join("dicom"))
}

fn dciodvfy_errors(file: &Path) -> Vec<String> {
    let text = tool_text(&tool("dciodvfy").arg("-new").arg(file).output().unwrap());
    text.lines()
        .filter(|l| l.starts_with("Error"))
        .map(String::from)
        .collect()
}

/// Writes what dicom_check.py compares against: the grid contract and rectified pixels.
fn write_expectations(build: &Path, config: &Config, layers: u32, expected: &Path) {
    std::fs::create_dir_all(expected).unwrap();
    let manifest: layerwise::build_dir::BuildManifest =
        serde_json::from_slice(&std::fs::read(build.join("build.json")).unwrap()).unwrap();
    let calibration = Calibration::load(config.calibration.file.as_ref().unwrap()).unwrap();
    let heights = LayerHeights::uniform(config.build.layer_thickness_mm);
    let settings = SeriesSettings::from_config(config).unwrap();
    let live = LiveSeries::new(&manifest, &config.views.all(), &calibration, settings).unwrap();
    let g = config.rectify;
    for view in config.views.all() {
        let z: serde_json::Map<String, serde_json::Value> = (1..=layers)
            .map(|k| (k.to_string(), serde_json::json!(heights.z(k))))
            .collect();
        let spec = serde_json::json!({"x_min": g.x_min, "y_max": g.y_max, "pixel_mm": g.pixel_mm,
            "rows": g.rows(), "columns": g.columns(), "z": z, "thickness": config.build.layer_thickness_mm});
        std::fs::write(expected.join(format!("{view}.json")), spec.to_string()).unwrap();
        for layer in [1, layers] {
            let shot = Shot {
                layer,
                phase: view.phase,
                light: view.light,
            };
            let original = std::fs::read(build.join(format!("raw/{}.jpg", shot.stem()))).unwrap();
            let luma = live.rectified_luma(&original).unwrap();
            let raw: Vec<u8> = luma
                .into_u16()
                .into_iter()
                .flat_map(|v| v.to_le_bytes())
                .collect();
            std::fs::write(expected.join(format!("{view}_L{layer:05}.u16")), raw).unwrap();
        }
    }
}

#[test]
fn live_series_pass_dicom3tools_dcmtk_pydicom_and_simpleitk_and_survive_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let config = calibrated_config(&build, 2, Compression::None);
    run_daemon(&config, drained()).unwrap();
    // Restart: the series continue with the same UIDs and no duplicate instance.
    let config = calibrated_config(&build, 4, Compression::None);
    run_daemon(&config, drained()).unwrap();

    let files = all_dcm(&build);
    assert_eq!(files.len(), 24, "6 views x 4 layers");
    for file in &files {
        let errors = dciodvfy_errors(file);
        assert!(errors.is_empty(), "{}: {errors:?}", file.display());
        let ok = tool("dcmftest").arg(file).output().unwrap();
        assert!(
            String::from_utf8_lossy(&ok.stdout).starts_with("yes"),
            "dcmftest: {}",
            file.display()
        );
        tool("dcmdump").arg(file).succeeds();
    }
    // One study: dcentvfy checks patient, study, series and frame of reference consistency and
    // finds duplicate SOP instances.
    assert_dcentvfy_clean(&files);

    let expected = dir.path().join("expected");
    write_expectations(&build, &config, 4, &expected);
    Command::new(python())
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/dicom_check.py"))
        .arg(build.join("dicom"))
        .arg(&expected)
        .succeeds();

    // Look at it the way a person would: dcmj2pnm renders a post-scan slice with its window;
    // fused metal (speckle) sits where the demo parts are, powder elsewhere.
    let png = dir.path().join("slice.png");
    let slice = series_dir(
        &build,
        View {
            phase: Phase::Post,
            light: Light::Top,
        },
    )
    .join("L00004.dcm");
    tool("dcmj2pnm")
        .args(["+Wi", "1", "+on"])
        .arg(&slice)
        .arg(&png)
        .succeeds();
    let img = image::open(&png).unwrap().to_luma8();
    let grid = config.rectify;
    let patch_std = |x: f64, y: f64| {
        let (r, c) = (
            (grid.y_max - y) / grid.pixel_mm,
            (x - grid.x_min) / grid.pixel_mm,
        );
        let vals: Vec<f64> = (-3..=3)
            .flat_map(|dr| (-3..=3).map(move |dc| (r as i64 + dr, c as i64 + dc)))
            .map(|(r, c)| img.get_pixel(c as u32, r as u32).0[0] as f64)
            .collect();
        let mean = vals.iter().sum::<f64>() / vals.len() as f64;
        (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt()
    };
    let box_center = patch_std(50.0, 50.0); // the 20 x 12 mm box of mock_camera::demo_parts
    let powder = patch_std(0.0, 0.0);
    assert!(
        box_center > 3.0 * powder,
        "box std {box_center} vs powder {powder}: the part is not where the vectors put it"
    );
}

#[test]
fn compressed_series_decode_to_the_same_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let mut variants = vec![Compression::Deflate];
    if cfg!(feature = "jpegls") {
        variants.push(Compression::JpegLs);
    }
    let plain_build = dir.path().join("none");
    let plain = calibrated_config(&plain_build, 1, Compression::None);
    run_daemon(&plain, drained()).unwrap();
    let reference = plain_build.join("dicom/post_top/L00001.dcm");
    let pixels_of = |file: &Path| {
        python_says("import sys, pydicom, hashlib; print(hashlib.sha256(pydicom.dcmread(sys.argv[1]).pixel_array.tobytes()).hexdigest())", file)
            .trim()
            .to_string()
    };
    let want = pixels_of(&reference);
    for compression in variants {
        let build = dir.path().join(format!("{compression:?}"));
        // The same originals: copy them, so only the encoding differs.
        let config = calibrated_config(&build, 1, compression);
        run_daemon(&config, drained()).unwrap();
        let file = build.join("dicom/post_top/L00001.dcm");
        let original_a = std::fs::read(plain_build.join("raw/L00001_post_top.jpg")).unwrap();
        let original_b = std::fs::read(build.join("raw/L00001_post_top.jpg")).unwrap();
        assert_eq!(original_a, original_b, "the mock camera is deterministic");
        assert_eq!(pixels_of(&file), want, "{compression:?} is not lossless");
        // dciodvfy cannot read deflated data sets; dcmtk converts back to explicit VR LE first.
        let checked = if compression == Compression::Deflate {
            let back = dir.path().join("back.dcm");
            explicit_vr_copy(&file, &back);
            back
        } else {
            file.clone()
        };
        let errors = dciodvfy_errors(&checked);
        assert!(errors.is_empty(), "{compression:?}: {errors:?}");
        assert!(
            std::fs::metadata(&file).unwrap().len() < std::fs::metadata(&reference).unwrap().len(),
            "{compression:?} saves nothing"
        );
    }
}

#[test]
fn a_truncated_file_is_named_by_dicom_info() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let config = calibrated_config(&build, 1, Compression::None);
    run_daemon(&config, drained()).unwrap();
    let file = build.join("dicom/pre_front/L00001.dcm");
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..300]).unwrap();
    let err = layerwise()
        .args(["dicom", "info"])
        .arg(build.join("dicom"))
        .fails();
    assert!(
        err.contains("pre_front/L00001.dcm")
            && err.contains(" at byte ")
            && err.contains("cut short or damaged"),
        "{err}"
    );
    // The other series are untouched.
    assert_eq!(all_dcm(&build).len(), 6);
}

/// A vector file with the demo box (20 x 12 mm at (50, 50)) as part 7 over `layers` layers of
/// 0.04 mm starting at z = 0.04.
fn box_vectors(path: &Path, layers: usize) {
    use layerwise::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};
    let mut header = Header::new(Format::Ascii, 0.001);
    header.labels.push((7, "box".into()));
    let mut file = VectorFile {
        header,
        layers: Vec::new(),
    };
    for k in 0..layers {
        let mut layer = Layer::new(k, 0.04 * (k + 1) as f64);
        layer.polylines.push(Polyline {
            part: 7,
            direction: Direction::CounterClockwise,
            points: vec![
                [40.0, 44.0],
                [60.0, 44.0],
                [60.0, 56.0],
                [40.0, 56.0],
                [40.0, 44.0],
            ],
        });
        file.layers.push(layer);
    }
    let mut out = std::fs::File::create(path).unwrap();
    layerwise::vectors::write_ascii(&file, &mut out).unwrap();
}

/// `dir/build`, and its uncompressed calibrated configuration of `layers` layers whose vectors
/// are [`box_vectors`] in `dir/build.cli`.
fn box_build(dir: &Path, layers: u32) -> (PathBuf, Config) {
    let build = dir.join("build");
    let mut config = calibrated_config(&build, layers, Compression::None);
    let vectors = dir.join("build.cli");
    box_vectors(&vectors, layers as usize);
    config.build.vectors = Some(vectors);
    (build, config)
}

#[test]
fn a_part_crop_and_vector_layer_heights_shape_the_series() {
    let dir = tempfile::tempdir().unwrap();
    let (build, mut config) = box_build(dir.path(), 3);
    config.calibration.crop_part = Some(7);
    config.calibration.crop_margin_mm = 5.0;
    run_daemon(&config, drained()).unwrap();
    let series = layerwise()
        .args(["dicom", "info", "--json"])
        .arg(build.join("dicom/post_top"))
        .json_ok();
    // 30 x 22 mm at 0.5 mm around the box, on the plate's pixel lattice.
    assert_eq!(
        (series[0]["columns"].as_u64(), series[0]["rows"].as_u64()),
        (Some(60), Some(44))
    );
    let origin = &series[0]["first_position"];
    assert_eq!(
        (origin[0].as_f64(), origin[1].as_f64()),
        (Some(35.25), Some(60.75))
    );
    assert!((series[0]["z_min"].as_f64().unwrap() - 0.04).abs() < 1e-9);
    assert!((series[0]["z_max"].as_f64().unwrap() - 0.12).abs() < 1e-9);
    for file in all_dcm(&build) {
        assert!(dciodvfy_errors(&file).is_empty(), "{}", file.display());
    }
    // The crop shows the box: its center is fused metal, its margin powder.
    let text = python_says("import sys, pydicom; a = pydicom.dcmread(sys.argv[1]).pixel_array.astype(float); print(a[17:27, 25:35].std(), a[0:6, 0:6].std())", &build.join("dicom/post_top/L00003.dcm"));
    let stds: Vec<f64> = text
        .split_whitespace()
        .filter_map(|v| v.parse().ok())
        .collect();
    assert!(
        stds.len() == 2 && stds[0] > 3.0 * stds[1],
        "box vs margin std: {text}"
    );
}

#[test]
fn export_writes_one_valid_study_idempotently_in_dicom_and_nrrd() {
    let dir = tempfile::tempdir().unwrap();
    let (build, config) = box_build(dir.path(), 2);
    run_daemon(&config, drained()).unwrap();
    let out = dir.path().join("export");
    let export = |extra: &[&str]| {
        layerwise()
            .args(["export", "--build"])
            .arg(&build)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .stdout_ok()
    };
    // Six views of two layers, and the two layers of the rasterized vectors.
    assert!(export(&[]).contains("14 written, 0 already there"));
    assert!(
        export(&[]).contains("0 written, 14 already there"),
        "re-running is idempotent"
    );
    assert!(export(&["--part", "7", "--margin-mm", "5"]).contains("60 x 44 px"));
    let files = series_files(&out);
    assert_eq!(files.len(), 28);
    // Exports are deflated: dicom3tools read the explicit VR copies dcmtk converts them to.
    let plain = dir.path().join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    let mut converted = Vec::new();
    for (i, file) in files.iter().enumerate() {
        let back = plain.join(format!("{i}.dcm"));
        explicit_vr_copy(file, &back);
        assert!(dciodvfy_errors(&back).is_empty(), "{}", file.display());
        converted.push(back);
    }
    // The live series and both exports: one study, one frame of reference, no duplicate instance.
    let mut study = converted;
    study.extend(all_dcm(&build));
    assert_dcentvfy_clean(&study);

    let nrrd = dir.path().join("nrrd");
    layerwise()
        .args(["export", "--format", "nrrd", "--build"])
        .arg(&build)
        .arg("--out")
        .arg(&nrrd)
        .succeeds();
    let text = python_says("import sys, SimpleITK as s; im = s.ReadImage(sys.argv[1]); print(im.GetSize(), im.TransformIndexToPhysicalPoint((0, 0, 1)))", &nrrd.join("post_top.nrrd"));
    assert!(
        text.contains("(550, 550, 2)") && text.contains("(-137.25, 137.25, 0.08"),
        "{text}"
    );
    // SimpleITK stacks an exported DICOM series in the build frame too.
    let text = python_says("import sys, SimpleITK as s; r = s.ImageSeriesReader(); r.SetFileNames(r.GetGDCMSeriesFileNames(sys.argv[1])); im = r.Execute(); print(im.GetSize(), im.TransformIndexToPhysicalPoint((0, 0, 0)), im.TransformIndexToPhysicalPoint((1, 1, 1)))", &out.join("post_top_export"));
    assert!(
        text.contains("(550, 550, 2) (-137.25, 137.25, 0.0")
            && text.contains("(-136.75, 136.75, 0.0"),
        "{text}"
    );
    // locate --mark draws the vectors first (Fig. 9): blue contour pixels in the first tile.
    let mark = dir.path().join("mark.png");
    layerwise()
        .args(["locate", "--point", "40,50,0.08", "--build"])
        .arg(&build)
        .arg("--mark")
        .arg(&mark)
        .succeeds();
    let sheet = image::open(&mark).unwrap().to_rgb8();
    assert_eq!(
        sheet.width(),
        13 * 161 + 14 * 4,
        "vectors + 6 views x (rectified, original), 4 px apart and around"
    );
    // The first tile sits 4 px in, under its label strip.
    let top = 4 + layerwise::raster::sheet::LABEL_PX;
    let first_tile_blue = (4..4 + 161)
        .flat_map(|x| (top..top + 161).map(move |y| (x, y)))
        .any(|(x, y)| sheet.get_pixel(x, y).0 == [0, 0, 255]);
    assert!(first_tile_blue, "the vectors tile shows the box's contour");
    // The vectors keep their colours in NRRD: contours blue where the box's outline is.
    let text = python_says("import sys, SimpleITK as s; im = s.ReadImage(sys.argv[1]); print(im.GetNumberOfComponentsPerPixel(), im.GetSize(), im.GetPixel(im.TransformPhysicalPointToIndex((40.0, 50.0, 0.04))))", &nrrd.join("vectors.nrrd"));
    assert!(text.starts_with("3 (550, 550, 2) (0, 0, 255)"), "{text}");
}
