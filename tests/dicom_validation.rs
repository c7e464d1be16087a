//! The live DICOM series, checked by tools no one here wrote: dicom3tools (dciodvfy, dcentvfy),
//! dcmtk (dcmftest, dcmdump, dcmconv, dcmj2pnm), pydicom and SimpleITK (tests/dicom_check.py in
//! the venv that tests/run.sh makes). The README's test command installs all of them.

mod common;

use common::*;
use layerwise::acquisition::RunOptions;
use layerwise::config::Config;
use layerwise::dicom::Compression;
use layerwise::rectify::Calibration;
use layerwise::series::{series_dir, LayerHeights, LiveSeries, SeriesSettings};
use layerwise::shot::{Light, Phase, Shot, View};
use std::path::{Path, PathBuf};
use std::process::Command;

fn tool(name: &str) -> Command {
    let probe = Command::new("sh")
        .arg("-c")
        .arg(format!("command -v {name}"))
        .output()
        .unwrap();
    assert!(
        probe.status.success(),
        "{name} is needed: the README's test command installs dicom3tools and dcmtk"
    );
    Command::new(name)
}

fn python() -> PathBuf {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-venv/bin/python");
    let python = std::env::var_os("LAYERWISE_TEST_PYTHON")
        .map(PathBuf::from)
        .unwrap_or(venv);
    assert!(
        python.exists(),
        "{}: run `bash tests/run.sh`, which makes the venv with pydicom and SimpleITK",
        python.display()
    );
    python
}

/// Runs to the end of the mock trigger and processes every frame before returning.
fn drained() -> RunOptions {
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    options
}

fn all_dcm(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for view in std::fs::read_dir(dir.join("dicom")).unwrap() {
        for f in std::fs::read_dir(view.unwrap().path()).unwrap() {
            out.push(f.unwrap().path());
        }
    }
    out.sort();
    out
}

fn dciodvfy_errors(file: &Path) -> Vec<String> {
    let out = tool("dciodvfy").arg("-new").arg(file).output().unwrap();
    let text =
        String::from_utf8_lossy(&out.stderr).to_string() + &String::from_utf8_lossy(&out.stdout);
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
    runtime().block_on(run(&config, drained())).unwrap();
    // Restart: the series continue with the same UIDs and no duplicate instance.
    let config = calibrated_config(&build, 4, Compression::None);
    runtime().block_on(run(&config, drained())).unwrap();

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
        let dump = tool("dcmdump").arg(file).output().unwrap();
        assert!(dump.status.success(), "dcmdump: {}", file.display());
    }
    // One study: dcentvfy checks patient, study, series and frame of reference consistency and
    // finds duplicate SOP instances.
    let ent = tool("dcentvfy").args(&files).output().unwrap();
    let text =
        String::from_utf8_lossy(&ent.stderr).to_string() + &String::from_utf8_lossy(&ent.stdout);
    assert!(
        !text.lines().any(|l| l.starts_with("Error")),
        "dcentvfy: {text}"
    );

    let expected = dir.path().join("expected");
    write_expectations(&build, &config, 4, &expected);
    let out = Command::new(python())
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/dicom_check.py"))
        .arg(build.join("dicom"))
        .arg(&expected)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );

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
    let render = tool("dcmj2pnm")
        .args(["+Wi", "1", "+on"])
        .arg(&slice)
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        render.status.success(),
        "{}",
        String::from_utf8_lossy(&render.stderr)
    );
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
    runtime().block_on(run(&plain, drained())).unwrap();
    let reference = plain_build.join("dicom/post_top/L00001.dcm");
    let pixels_of = |file: &Path| {
        let out = Command::new(python())
            .args(["-c", "import sys, pydicom, hashlib; print(hashlib.sha256(pydicom.dcmread(sys.argv[1]).pixel_array.tobytes()).hexdigest())"])
            .arg(file)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    };
    let want = pixels_of(&reference);
    for compression in variants {
        let build = dir.path().join(format!("{compression:?}"));
        // The same originals: copy them, so only the encoding differs.
        let config = calibrated_config(&build, 1, compression);
        runtime().block_on(run(&config, drained())).unwrap();
        let file = build.join("dicom/post_top/L00001.dcm");
        let original_a = std::fs::read(plain_build.join("raw/L00001_post_top.jpg")).unwrap();
        let original_b = std::fs::read(build.join("raw/L00001_post_top.jpg")).unwrap();
        assert_eq!(original_a, original_b, "the mock camera is deterministic");
        assert_eq!(pixels_of(&file), want, "{compression:?} is not lossless");
        // dciodvfy cannot read deflated data sets; dcmtk converts back to explicit VR LE first.
        let checked = if compression == Compression::Deflate {
            let back = dir.path().join("back.dcm");
            let conv = tool("dcmconv")
                .arg("+te")
                .arg(&file)
                .arg(&back)
                .output()
                .unwrap();
            assert!(
                conv.status.success(),
                "dcmconv: {}",
                String::from_utf8_lossy(&conv.stderr)
            );
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
    runtime().block_on(run(&config, drained())).unwrap();
    let file = build.join("dicom/pre_front/L00001.dcm");
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..300]).unwrap();
    let out = layerwise()
        .args(["dicom", "info"])
        .arg(build.join("dicom"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("pre_front/L00001.dcm") && err.contains("not a readable DICOM file"),
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

#[test]
fn a_part_crop_and_vector_layer_heights_shape_the_series() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = calibrated_config(&build, 3, Compression::None);
    let vectors = dir.path().join("build.cli");
    box_vectors(&vectors, 3);
    config.build.vectors = Some(vectors);
    config.calibration.crop_part = Some(7);
    config.calibration.crop_margin_mm = 5.0;
    runtime().block_on(run(&config, drained())).unwrap();
    let out = layerwise()
        .args(["dicom", "info", "--json"])
        .arg(build.join("dicom/post_top"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let series: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
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
    let dump = Command::new(python())
        .args(["-c", "import sys, pydicom; a = pydicom.dcmread(sys.argv[1]).pixel_array.astype(float); print(a[17:27, 25:35].std(), a[0:6, 0:6].std())"])
        .arg(build.join("dicom/post_top/L00003.dcm"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&dump.stdout);
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
    let build = dir.path().join("build");
    let mut config = calibrated_config(&build, 2, Compression::None);
    let vectors = dir.path().join("build.cli");
    box_vectors(&vectors, 2);
    config.build.vectors = Some(vectors);
    runtime().block_on(run(&config, drained())).unwrap();
    let out = dir.path().join("export");
    let export = |extra: &[&str]| {
        let o = layerwise()
            .args(["export", "--build"])
            .arg(&build)
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    // Six views of two layers, and the two layers of the rasterized vectors.
    assert!(export(&[]).contains("14 written, 0 already there"));
    assert!(
        export(&[]).contains("0 written, 14 already there"),
        "re-running is idempotent"
    );
    assert!(export(&["--part", "7", "--margin-mm", "5"]).contains("60 x 44 px"));
    let mut files: Vec<PathBuf> = Vec::new();
    for series in std::fs::read_dir(&out).unwrap() {
        for f in std::fs::read_dir(series.unwrap().path()).unwrap() {
            files.push(f.unwrap().path());
        }
    }
    assert_eq!(files.len(), 28);
    // Exports are deflated: dicom3tools read the explicit VR copies dcmtk converts them to.
    let plain = dir.path().join("plain");
    std::fs::create_dir_all(&plain).unwrap();
    let mut converted = Vec::new();
    for (i, file) in files.iter().enumerate() {
        let back = plain.join(format!("{i}.dcm"));
        let conv = tool("dcmconv")
            .arg("+te")
            .arg(file)
            .arg(&back)
            .output()
            .unwrap();
        assert!(conv.status.success());
        assert!(dciodvfy_errors(&back).is_empty(), "{}", file.display());
        converted.push(back);
    }
    // The live series and both exports: one study, one frame of reference, no duplicate instance.
    let mut study = converted;
    study.extend(all_dcm(&build));
    let ent = tool("dcentvfy").args(&study).output().unwrap();
    let text =
        String::from_utf8_lossy(&ent.stderr).to_string() + &String::from_utf8_lossy(&ent.stdout);
    assert!(
        !text.lines().any(|l| l.starts_with("Error")),
        "dcentvfy: {text}"
    );

    let nrrd = dir.path().join("nrrd");
    let o = layerwise()
        .args(["export", "--format", "nrrd", "--build"])
        .arg(&build)
        .arg("--out")
        .arg(&nrrd)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let check = Command::new(python())
        .args(["-c", "import sys, SimpleITK as s; im = s.ReadImage(sys.argv[1]); print(im.GetSize(), im.TransformIndexToPhysicalPoint((0, 0, 1)))"])
        .arg(nrrd.join("post_top.nrrd"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        text.contains("(550, 550, 2)") && text.contains("(-137.25, 137.25, 0.08"),
        "{text}"
    );
    // SimpleITK stacks an exported DICOM series in the build frame too.
    let check = Command::new(python())
        .args(["-c", "import sys, SimpleITK as s; r = s.ImageSeriesReader(); r.SetFileNames(r.GetGDCMSeriesFileNames(sys.argv[1])); im = r.Execute(); print(im.GetSize(), im.TransformIndexToPhysicalPoint((0, 0, 0)), im.TransformIndexToPhysicalPoint((1, 1, 1)))"])
        .arg(out.join("post_top_export"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        text.contains("(550, 550, 2) (-137.25, 137.25, 0.0")
            && text.contains("(-136.75, 136.75, 0.0"),
        "{text}{}",
        String::from_utf8_lossy(&check.stderr)
    );
    // locate --mark draws the vectors first (Fig. 9): blue contour pixels in the first tile.
    let mark = dir.path().join("mark.png");
    let o = layerwise()
        .args(["locate", "--point", "40,50,0.08", "--build"])
        .arg(&build)
        .arg("--mark")
        .arg(&mark)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let sheet = image::open(&mark).unwrap().to_rgb8();
    assert_eq!(
        sheet.width(),
        13 * 161 + 12 * 4,
        "vectors + 6 views x (rectified, original)"
    );
    let first_tile_blue = (0..161)
        .flat_map(|x| (0..161).map(move |y| (x, y)))
        .any(|(x, y)| sheet.get_pixel(x, y).0 == [0, 0, 255]);
    assert!(first_tile_blue, "the vectors tile shows the box's contour");
    // The vectors keep their colours in NRRD: contours blue where the box's outline is.
    let check = Command::new(python())
        .args(["-c", "import sys, SimpleITK as s; im = s.ReadImage(sys.argv[1]); print(im.GetNumberOfComponentsPerPixel(), im.GetSize(), im.GetPixel(im.TransformPhysicalPointToIndex((40.0, 50.0, 0.04))))"])
        .arg(nrrd.join("vectors.nrrd"))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        text.starts_with("3 (550, 550, 2) (0, 0, 255)"),
        "{text}{}",
        String::from_utf8_lossy(&check.stderr)
    );
}
