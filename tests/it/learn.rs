//! `layerwise learn` through the binary on generated pictures: training is deterministic for a
//! seed (on 1 thread or 2), eval's JSON has its contract, predict names the class and draws the
//! heat map; a flaws output (labels.json) trains a patch model on held-out layers, and so do the
//! CT-labelled patches of `demo --pores` (the pores told from controls on held-out layers); compare
//! tabulates the model beside the classical inspection; damaged, foreign, newer and mismatched
//! model files are refused with their own message, by predict and by check-config; verdicts
//! given on the page train a model of the build (`--refit` and `--average`: learn_options.rs).
//! The real-data training (../shared/data/real/pblm) is measured in docs/learning.md, not a test.

use crate::common::*;
use std::path::{Path, PathBuf};

/// `learn train` on the class folders with a small network: 64 px frames, 16 x 16 cells.
fn train(data: &Path, out: &Path, seed: u64, threads: &str) -> std::process::Output {
    train_small(
        data,
        out,
        &[
            "--seed",
            &seed.to_string(),
            "--channels",
            "6,12",
            "--epochs",
            "40",
            "--patience",
            "40",
        ],
    )
    .env("RAYON_NUM_THREADS", threads)
    .succeeds()
}

/// The model file with its header changed by `edit` (lengths and padding redone).
fn with_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut st: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let mut header = header_of(bytes);
    edit(&mut header);
    st["__metadata__"]["layerwise.model"] = serde_json::Value::String(header.to_string());
    let mut text = st.to_string().into_bytes();
    while !text.len().is_multiple_of(8) {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend_from_slice(&bytes[8 + n..]);
    out
}

/// A small model of `tmp/data` (5 frames a class) in `tmp/m.safetensors`, trained `epochs`
/// epochs: the data, the model and `learn train`'s output.
fn small_model(tmp: &Path, epochs: &str) -> (PathBuf, PathBuf, std::process::Output) {
    let data = tmp.join("data");
    class_folders(&data, 5);
    let model = tmp.join("m.safetensors");
    let out = train_small(&data, &model, &["--channels", "4,8", "--epochs", epochs]).succeeds();
    (data, model, out)
}

fn predict_fails(model: &Path, image: &Path) -> String {
    layerwise()
        .args(["learn", "predict", "--model"])
        .arg(model)
        .arg(image)
        .fails()
}

#[test]
fn train_eval_and_predict_on_generated_classes_deterministically() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    class_folders(&data, 10);
    let model = tmp.path().join("m.safetensors");
    let out = train(&data, &model, 3, "2");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("validation (sequence-tail)"), "{text}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("epoch 1/40") && stderr.contains("val acc"),
        "{stderr}"
    );
    assert!(
        stderr.contains("21 for training, 6 for validation, 3 left out"),
        "{stderr}"
    );

    // The same seed on one thread: the same file, byte for byte.
    let again = tmp.path().join("again.safetensors");
    train(&data, &again, 3, "1");
    let (a, b) = (
        std::fs::read(&model).unwrap(),
        std::fs::read(&again).unwrap(),
    );
    assert_eq!(
        header_of(&a)["weights_sha256"],
        header_of(&b)["weights_sha256"]
    );
    let h = header_of(&a);
    assert_eq!(
        h["classes"],
        serde_json::json!(["No_Defect", "Spots", "Streaks"])
    );
    assert_eq!(h["normal_class"], "No_Defect");
    assert_eq!(h["training"]["data"]["counts"]["Spots"], 10);
    assert_eq!(h["training"]["split"]["val"]["Spots"], 2);
    assert_eq!(h["training"]["data"]["sha256"].as_str().unwrap().len(), 64);

    let eval = learn_on(&["learn", "eval", "--json"], &model, &data).json_ok();
    for c in ["No_Defect", "Spots", "Streaks"] {
        let m = &eval["per_class"][c];
        assert_eq!(m["support"], 10, "{eval}");
        assert!(m["recall"].as_f64().unwrap() >= 0.7, "{c}: {eval}");
        assert!(m["precision"].as_f64().is_some(), "{eval}");
        // The recall's 95 % interval holds the recall and is wide on 10 pictures.
        let recall = m["recall"].as_f64().unwrap();
        let ci: Vec<f64> = m["recall_ci95"]
            .as_array()
            .unwrap_or_else(|| panic!("{c}: no recall_ci95 in {eval}"))
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert!(
            ci.len() == 2 && ci[0] <= recall && recall <= ci[1],
            "{c}: {eval}"
        );
        assert!(ci[1] - ci[0] > 0.15, "{c}: {eval}");
    }
    assert!(eval["accuracy"].as_f64().unwrap() >= 0.8, "{eval}");
    let confusion = eval["confusion"].as_array().unwrap();
    assert_eq!(confusion.len(), 3);
    let total: u64 = confusion
        .iter()
        .flat_map(|r| r.as_array().unwrap())
        .map(|v| v.as_u64().unwrap())
        .sum();
    assert_eq!(total, 30);
    let val = learn_on(&["learn", "eval", "--part", "val"], &model, &data).stdout_ok();
    assert!(val.starts_with("6 images: accuracy"), "{val}");

    // Every streak frame, one line each, as `learn eval` counted them (recall 0.7 or more).
    let streaks: Vec<PathBuf> = (0..10)
        .map(|k| data.join(format!("Streaks/frame_{k:04}.png")))
        .collect();
    let said = layerwise()
        .args(["learn", "predict", "--model"])
        .arg(&model)
        .args(&streaks)
        .stdout_ok();
    let right = said.lines().filter(|l| l.contains(": Streaks (")).count();
    let recall = eval["per_class"]["Streaks"]["recall"].as_f64().unwrap();
    assert_eq!(right, (recall * 10.0).round() as usize, "{said}");
    assert_eq!(
        said.lines().filter(|l| l.contains("Spots ")).count(),
        10,
        "{said}"
    );
    let heat = tmp.path().join("heat.png");
    layerwise()
        .args(["learn", "predict", "--model"])
        .arg(&model)
        .arg(&streaks[9])
        .arg("--heatmap")
        .arg(&heat)
        .stdout_ok();
    let picture = image::open(&heat).unwrap();
    assert_eq!((picture.width(), picture.height()), (64, 64));
    let info = layerwise()
        .args(["learn", "info", "--model"])
        .arg(&model)
        .stdout_ok();
    assert!(
        info.contains("trained on") && info.contains("confusion"),
        "{info}"
    );
}

#[test]
fn damaged_foreign_newer_and_mismatched_model_files_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, model, _) = small_model(tmp.path(), "1");
    let bytes = std::fs::read(&model).unwrap();
    let image = data.join("Spots/frame_0000.png");
    let bad = |name: &str, content: &[u8]| -> PathBuf {
        let p = tmp.path().join(name);
        std::fs::write(&p, content).unwrap();
        p
    };
    let cases: Vec<(PathBuf, &str)> = vec![
        (bad("truncated", &bytes[..bytes.len() / 2]), "damaged or not a safetensors file"),
        (bad("text", b"not a model at all"), "damaged or not a safetensors file"),
        (
            bad("flipped", &{
                let mut b = bytes.clone();
                let last = b.len() - 3;
                b[last] ^= 0x40;
                b
            }),
            "the weights do not match their checksum",
        ),
        (
            bad("newer", &with_header(&bytes, |h| h["version"] = 4.into())),
            "written by a newer layerwise (model format 4, this one reads 3)",
        ),
        (
            bad("older", &with_header(&bytes, |h| h["version"] = 0.into())),
            "retrain it",
        ),
        (
            bad("foreign", &with_header(&bytes, |h| h["format"] = "other".into())),
            "not a layerwise model",
        ),
        (
            bad("header", &with_header(&bytes, |h| h["input"]["cells"] = "many".into())),
            "header is damaged at `input.cells`",
        ),
        (
            bad("recipe", &with_header(&bytes, |h| h["input"]["normalisation"] = "sharpen".into())),
            "header is damaged at `input.normalisation`",
        ),
        (
            bad("framing", &with_header(&bytes, |h| h["input"]["framing"] = "crop".into())),
            "header is damaged at `input.framing`",
        ),
        // Sizes the loader would otherwise allocate by or divide by (the header is not covered
        // by the weights' checksum).
        (
            bad("cell_px", &with_header(&bytes, |h| h["input"]["cell_px"] = 0.into())),
            "header is damaged at `input.cell_px`: 0 px a cell; 1 to 64",
        ),
        (
            bad("frame_px", &with_header(&bytes, |h| h["input"]["frame_px"] = 4_294_967_296u64.into())),
            "header is damaged at `input.frame_px`",
        ),
        (
            bad("cells", &with_header(&bytes, |h| h["input"]["cells"] = serde_json::json!([1u64 << 40, 1u64 << 40]))),
            "header is damaged at `input.cells`",
        ),
        (
            bad("stride", &with_header(&bytes, |h| h["input"]["map_stride_cells"] = 0.into())),
            "header is damaged at `input.map_stride_cells`",
        ),
        (
            bad("cell_mm", &with_header(&bytes, |h| h["input"]["cell_mm"] = (-1.0).into())),
            "header is damaged at `input.cell_mm`",
        ),
        (
            bad(
                "channels",
                &with_header(&bytes, |h| {
                    h["arch"]["in_channels"] = 3.into();
                    h["input"]["channels"] = serde_json::json!(["mean", "texture", "range"]);
                }),
            ),
            "does not match its architecture: conv0.weight is F32 [4, 2, 3, 3], expected F32 [4, 3, 3, 3]",
        ),
    ];
    for (path, message) in &cases {
        let said = predict_fails(path, &image);
        assert!(said.contains(message), "{}: {said}", path.display());
        assert!(said.contains(&path.display().to_string()), "{said}");
    }

    // The daemon's configuration: check-config refuses a bad model, and a model of camera
    // frames (no scale) without [inspection.model] cell_mm.
    let config_for = |file: &Path, extra: &str| {
        let mut config = demo_config(&tmp.path().join("build"), 2);
        config.inspection.model = Some(
            toml::from_str(&format!("file = {:?}\n{extra}", file.display().to_string())).unwrap(),
        );
        let path = tmp.path().join("layerwise.toml");
        write_config(&config, &path);
        path
    };
    let said = layerwise()
        .arg("check-config")
        .arg(config_for(&cases[2].0, ""))
        .fails();
    assert!(
        said.contains("[inspection.model] file") && said.contains("checksum"),
        "{said}"
    );
    let said = layerwise()
        .arg("check-config")
        .arg(config_for(&model, ""))
        .fails();
    assert!(said.contains("the model has no scale"), "{said}");
    let fine = layerwise()
        .arg("check-config")
        .arg(config_for(&model, "cell_mm = 2.0"))
        .stdout_ok();
    assert!(fine.contains("runs on every layer"), "{fine}");
    let stderr = run_command(&config_for(&cases[2].0, "cell_mm = 2.0")).fails();
    assert!(stderr.contains("checksum"), "{stderr}");
}

#[test]
fn a_model_file_says_how_its_epoch_was_chosen_and_files_from_before_still_load() {
    let tmp = tempfile::tempdir().unwrap();
    let (data, model, out) = small_model(tmp.path(), "2");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("  balanced "), "{stderr}");
    let bytes = std::fs::read(&model).unwrap();
    let h = header_of(&bytes);
    assert_eq!(h["arch"]["kind"], "cnn-cam-lme");
    let said = h["training"]["selection"].as_str().unwrap();
    assert!(
        said.starts_with("balanced validation accuracy, then"),
        "{h}"
    );
    let plateau = h["training"]["plateau"].as_str().unwrap();
    assert!(plateau.starts_with("epochs without progress"), "{h}");
    let image = data.join("Spots/frame_0000.png");

    // Written before: no selection recorded, class maps pooled by their mean.
    let old = tmp.path().join("old.safetensors");
    let before = with_header(&bytes, |h| {
        h["training"].as_object_mut().unwrap().remove("selection");
        h["training"].as_object_mut().unwrap().remove("plateau");
        for m in h["validation"]["per_class"]
            .as_object_mut()
            .unwrap()
            .values_mut()
        {
            m.as_object_mut().unwrap().remove("recall_ci95");
        }
        h["arch"]["kind"] = "cnn-cam".into();
    });
    std::fs::write(&old, before).unwrap();
    let info = layerwise()
        .args(["learn", "info", "--model"])
        .arg(&old)
        .stdout_ok();
    assert!(info.contains("by the mean validation loss"), "{info}");
    assert!(
        info.contains("cuts and stop counting epochs without a better epoch;"),
        "{info}"
    );
    let predicted = layerwise()
        .args(["learn", "predict", "--json", "--model"])
        .arg(&old)
        .arg(&image)
        .stdout_ok();
    let p: serde_json::Value = serde_json::from_str(predicted.trim()).unwrap();
    let total: f64 = p["probabilities"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v[1].as_f64().unwrap())
        .sum();
    assert!((total - 1.0).abs() < 1e-3, "{p}");

    let foreign = tmp.path().join("foreign.safetensors");
    std::fs::write(
        &foreign,
        with_header(&bytes, |h| h["arch"]["kind"] = "cnn-other".into()),
    )
    .unwrap();
    assert!(predict_fails(&foreign, &image).contains("is not a cnn-cam this layerwise builds"));
}

#[test]
fn the_daemon_runs_the_model_on_every_layer_after_the_classical_checks() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, stderr) = model_build(tmp.path());
    let records = layerwise::build_dir::inspection::InspectionLog::read(
        &dir.join(layerwise::build_dir::INSPECTION),
    )
    .unwrap();
    assert_eq!(records.len(), 3, "{records:?}");
    let classes = ["Spots", "Streaks"];
    let mut model_flags = 0;
    for r in &records {
        assert!(r.plate.contains_key("model_ms"), "{r:?}");
        assert_eq!(r.plate.get("model_views"), Some(&6.0), "layer {}", r.layer);
        for view in layerwise::config::ViewsConfig::default().all() {
            let heat = layerwise::learn::live::heatmap_path(&dir, &view.to_string(), r.layer);
            let png = image::open(&heat).unwrap_or_else(|e| panic!("{}: {e}", heat.display()));
            // 550 px views of 0.5 mm, cells of 1 mm, tiles of 2 cells (one pool): 137 a side.
            assert_eq!((png.width(), png.height()), (137, 137));
        }
        // The classical flags first, then the model's.
        let first_model = r.flags.iter().position(|f| f.class.is_some());
        if let Some(k) = first_model {
            assert!(r.flags[k..].iter().all(|f| f.class.is_some()), "{r:?}");
        }
        for f in r.flags.iter().filter(|f| f.class.is_some()) {
            model_flags += 1;
            assert_eq!(f.kind.name(), "model");
            assert!(classes.contains(&f.class.as_deref().unwrap()), "{f:?}");
            assert!(
                f.bbox_mm[0] < f.bbox_mm[2] && f.bbox_mm[1] < f.bbox_mm[3],
                "{f:?}"
            );
            assert!(f.message.starts_with("model: "), "{f:?}");
        }
    }
    assert!(model_flags > 0, "no model flag: {records:?}");
    assert!(stderr.contains("the model runs on every layer"), "{stderr}");
    assert!(
        stderr.contains("WARN") && stderr.contains("model: "),
        "{stderr}"
    );
}

#[test]
fn a_flaws_output_trains_a_patch_model_on_held_out_layers() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("flaws");
    flaws_output(&data, 10);
    let model = tmp.path().join("patches.safetensors");
    let out = train(&data, &model, 1, "2");
    let stderr = String::from_utf8_lossy(&out.stderr);
    // Layers 9-10 are validation, layer 8 the guard band: 42 patches train, 12 validate.
    assert!(
        stderr.contains(
            "(flaws): 60 pictures in 2 classes; 42 for training, 12 for validation, 6 left out"
        ),
        "{stderr}"
    );
    let h = header_of(&std::fs::read(&model).unwrap());
    assert_eq!(h["classes"], serde_json::json!(["control", "flaw"]));
    assert_eq!(h["normal_class"], "control");
    assert_eq!(h["training"]["split"]["rule"], "layer-tail");
    // Patches carry their scale: the grid's pixel, cells of one pixel.
    assert_eq!(h["input"]["cell_mm"], 0.0625);
    assert_eq!(h["input"]["cell_px"], 1);
    assert!(h["input"]["frame_px"].is_null(), "{h}");

    let eval = learn_on(&["learn", "eval", "--json", "--part", "val"], &model, &data).json_ok();
    assert_eq!(eval["per_class"]["flaw"]["support"], 6, "{eval}");
    for c in ["control", "flaw"] {
        assert!(
            eval["per_class"][c]["recall"].as_f64().unwrap() >= 0.8,
            "{c}: {eval}"
        );
    }
    let said = layerwise()
        .args(["learn", "predict", "--model"])
        .arg(&model)
        .arg(data.join("patches/F0005_L00010_pre_top.png"))
        .stdout_ok();
    assert!(said.contains(": flaw ("), "{said}");
    // A patch model is not for whole frames: compare says so.
    let frames = tmp.path().join("frames");
    class_folders(&frames, 5);
    let err = learn_on(&["learn", "compare"], &model, &frames).fails();
    assert!(err.contains("not whole frames"), "{err}");
}

#[test]
fn compare_tabulates_the_model_beside_the_classical_inspection() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    class_folders(&data, 10);
    let model = tmp.path().join("m.safetensors");
    train(&data, &model, 3, "2");
    let table = learn_on(&["learn", "compare"], &model, &data).stdout_ok();
    let lines: Vec<&str> = table.lines().collect();
    assert!(
        lines[0].starts_with(
            "| class | frames | model: flagged | model: right class | classical: flagged"
        ),
        "{table}"
    );
    // One row per class, the validation part (the last 2 of each sequence of 10).
    for class in ["No_Defect", "Spots", "Streaks"] {
        let row = lines
            .iter()
            .find(|l| l.starts_with(&format!("| {class} | 2 |")))
            .unwrap_or_else(|| panic!("no row of 2 {class} frames: {table}"));
        let what = if class == "No_Defect" {
            "false alarms"
        } else {
            "found"
        };
        assert_eq!(row.matches(what).count(), 2, "{row}");
    }
    let all = learn_on(&["learn", "compare", "--part", "all"], &model, &data).stdout_ok();
    assert!(all.contains("| Streaks | 10 |"), "{all}");
}

/// A shop's own model from its own builds: operators confirm the unfused part's flags and
/// dismiss the spatter flags on the page (`POST /api/layers/N/verdicts`), then `learn train
/// --data BUILD` trains on those verdicts (confirmed: their kind; dismissed: normal), and the
/// model file says what it learnt from.
#[test]
fn verdicts_given_on_the_page_train_a_model_of_the_build() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let layers = 14;
    let inject: Vec<String> = (1..=layers)
        .flat_map(|l| {
            [
                format!("no-fusion@{l}/part=3"),
                format!("spatter@{l}/n=3/x=20/y=90/r=0.8"),
            ]
        })
        .collect();
    let inject: Vec<&str> = inject.iter().map(String::as_str).collect();
    let config = crate::web::injected_config(&dir, layers, &inject);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    run_build(&config_path);
    let (_served, addr) = serve(&dir, &[]);
    let mut given = std::collections::BTreeMap::<&str, usize>::new();
    for layer in 1..=layers {
        let detail = get_json(addr, &format!("/api/layers/{layer}"));
        for flag in detail["inspection"].as_array().unwrap() {
            let verdict = match flag["kind"].as_str().unwrap() {
                "under_fusion" => "confirm",
                "spatter" => "false_alarm",
                _ => continue,
            };
            let body = serde_json::json!({
                "view": flag["view"], "verdict": verdict, "who": "ana",
                "flag": {"kind": flag["kind"], "bbox_mm": flag["bbox_mm"]},
            })
            .to_string();
            let path = format!("/api/layers/{layer}/verdicts");
            let (status, answer) = http(addr, "POST", &path, body.as_bytes());
            assert_eq!(status, 200, "{}", String::from_utf8_lossy(&answer));
            *given.entry(verdict).or_default() += 1;
        }
    }
    assert!(
        given.get("confirm") >= Some(&10) && given.get("false_alarm") >= Some(&10),
        "{given:?}"
    );
    let model = tmp.path().join("shop.safetensors");
    let said = layerwise()
        .args(["learn", "train", "--epochs", "3", "--out"])
        .arg(&model)
        .arg("--data")
        .arg(&dir)
        .stdout_ok();
    assert!(said.contains("under_fusion"), "{said}");
    let info: serde_json::Value = serde_json::from_str(
        &layerwise()
            .args(["learn", "info", "--json", "--model"])
            .arg(&model)
            .stdout_ok(),
    )
    .unwrap();
    let classes: Vec<&str> = info["classes"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c.as_str())
        .collect();
    assert_eq!(classes, ["normal", "under_fusion"], "{info:#}");
    let data = &info["training"]["data"];
    assert_eq!(data["kind"], "verdicts", "{info:#}");
    assert_eq!(data["counts"]["under_fusion"], given["confirm"], "{info:#}");
    assert_eq!(data["counts"]["normal"], given["false_alarm"], "{info:#}");
    println!("{given:?}; {}", info["training"]);
}

/// The model through the path an operator and an engineer take: its critical flags raise the
/// daemon's alarm (`alarm show` names the model), and `inspect --build --model` runs it again
/// on the stored build with the same flags.
#[test]
fn a_model_flag_raises_the_alarm_and_inspect_runs_the_model_on_a_stored_build() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("classes");
    class_folders(&data, 5);
    let model = tmp.path().join("model.safetensors");
    train_small(
        &data,
        &model,
        &["--channels", "4,8", "--epochs", "2", "--cell-mm", "1.0"],
    )
    .succeeds();
    let dir = tmp.path().join("build");
    let mut config = calibrated_config(&dir, 3, layerwise::dicom::Compression::None);
    config.inspection.model = Some(
        toml::from_str(&format!(
            "file = {:?}\nmin_probability = 0.0\ncritical_probability = 0.0",
            model.display().to_string()
        ))
        .unwrap(),
    );
    config.inspection.alarm.output = layerwise::config::LightsConfig::Mock;
    let path = tmp.path().join("layerwise.toml");
    write_config(&config, &path);
    run_build(&path);
    let shown = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&dir)
        .stdout_ok();
    assert!(
        shown.contains("RAISED since layer 1") && shown.contains("model"),
        "{shown}"
    );

    let live = layerwise::build_dir::inspection::InspectionLog::read(
        &dir.join(layerwise::build_dir::INSPECTION),
    )
    .unwrap();
    let model_flags = |records: &[layerwise::build_dir::inspection::InspectionRecord]| {
        records
            .iter()
            .map(|r| r.flags.iter().filter(|f| f.class.is_some()).count())
            .collect::<Vec<_>>()
    };
    let out = layerwise()
        .args(["inspect", "--json", "--build"])
        .arg(&dir)
        .arg("--model")
        .arg(&model)
        .stdout_ok();
    let again: Vec<layerwise::build_dir::inspection::InspectionRecord> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(again.len(), 3, "{out}");
    assert!(model_flags(&again).iter().all(|&n| n > 0), "{out}");
    assert_eq!(model_flags(&again), model_flags(&live), "{out}");
}

/// The demo's CT-labelled patches, through the binary as a user gets them: `demo --pores`, `register
/// ct` from the demo's clicks, `flaws --phase PHASE`, `learn train` (the last layers held out),
/// `learn eval --part val --json`.
fn eval_of_demo_patches(build: &Path, phase: &str) -> serde_json::Value {
    let flaws = build.join(format!("flaws-{phase}"));
    let said = layerwise()
        .current_dir(build)
        .args([
            "flaws",
            "--registration",
            "ct.toml",
            "--part",
            "3",
            "--build",
            ".",
        ])
        .args(["--patch-px", "17", "--phase", phase, "--out"])
        .arg(&flaws)
        .stdout_ok();
    assert!(said.contains("14 flaws in"), "{said}");
    let labels = std::fs::read_to_string(flaws.join("labels.csv")).unwrap();
    assert!(
        labels
            .lines()
            .skip(1)
            .all(|l| l.contains(&format!(",{phase}_"))),
        "{labels}"
    );
    let model = build.join(format!("model-{phase}.safetensors"));
    layerwise()
        .args(["learn", "train", "--data"])
        .arg(&flaws)
        .arg("--out")
        .arg(&model)
        .args(["--seed", "1"])
        .succeeds();
    learn_on(
        &["learn", "eval", "--part", "val", "--json"],
        &model,
        &flaws,
    )
    .json_ok()
}

#[test]
fn a_model_trained_on_the_demo_pores_separates_them_from_controls_on_held_out_layers() {
    let tmp = tempfile::tempdir().unwrap();
    let build = tmp.path().join("demo");
    let refused = layerwise()
        .args(["demo", "--layers", "10", "--pores", "3", "--out"])
        .arg(&build)
        .fails();
    assert!(
        refused.contains("--pores needs --layers 20 or more"),
        "{refused}"
    );
    assert!(!build.exists(), "nothing written");
    layerwise()
        .args(["demo", "--layers", "40", "--pores", "14", "--out"])
        .arg(&build)
        .succeeds();
    layerwise()
        .current_dir(&build)
        .args([
            "register",
            "ct",
            "--vectors",
            "demo-vectors.cli",
            "--part",
            "3",
        ])
        .args([
            "--ct",
            "ct/box.pcr",
            "--init",
            "ct/box-points.txt",
            "--out",
            "ct.toml",
        ])
        .succeeds();
    // The post-scan views show each pore as unfused powder in the layers it spans: measured
    // 0.815 (control) and 0.933 (flaw) recall on 57 held-out patches of layers 28-32 (the
    // controls it takes for flaws: one reaching past the box's edge, where the powder beside the
    // part is unfused too, and one of metal darker by chance).
    let post = eval_of_demo_patches(&build, "post");
    for (class, least) in [("control", 0.75), ("flaw", 0.85)] {
        let m = &post["per_class"][class];
        assert!(m["support"].as_u64().unwrap() >= 20, "{post}");
        assert!(m["recall"].as_f64().unwrap() >= least, "{class}: {post}");
    }
    assert!(post["accuracy"].as_f64().unwrap() >= 0.83, "{post}");
    // The pre-scan views of the same layers show the fresh powder over the pores: nothing to
    // learn from, so the same chain does not separate them (as it would not if the camera did
    // not see the pores).
    let pre = eval_of_demo_patches(&build, "pre");
    assert!(pre["accuracy"].as_f64().unwrap() < 0.7, "{pre}");
}
