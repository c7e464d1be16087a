//! `layerwise learn` through the binary on generated pictures: training is deterministic for a
//! seed (on 1 thread or 2), eval's JSON has its contract, predict names the class and draws the
//! heat map; a flaws output (labels.json) trains a patch model; damaged, foreign, newer and
//! mismatched model files are refused with their own message, by predict and by check-config.
//! The real-data training (../shared/data/real/pblm) is `examples/learn_pblm.sh`, not a test.

use crate::common::*;
use std::path::{Path, PathBuf};

/// Class folders of 64 x 64 grey frames, 10 a class named `frame_0000…`: `No_Defect` (grain),
/// `Streaks` (two to four dark vertical bands), `Spots` (bright spots). Brightness and grain
/// level vary inside every class, so only the structure tells them apart.
fn class_folders(root: &Path, per_class: usize) {
    let mut rng = Rng(0x5EED);
    for class in ["No_Defect", "Streaks", "Spots"] {
        let dir = root.join(class);
        std::fs::create_dir_all(&dir).unwrap();
        for k in 0..per_class {
            let base = 80.0 + rng.below(60) as f64;
            let grain = 2.0 + rng.below(6) as f64;
            let mut px = vec![0f64; 64 * 64];
            for v in px.iter_mut() {
                *v = base + grain * (rng.below(1000) as f64 / 500.0 - 1.0);
            }
            match class {
                "Streaks" => {
                    for _ in 0..2 + rng.below(3) {
                        let x = 4 + rng.below(56);
                        for y in 0..64 {
                            for dx in 0..2 {
                                px[y * 64 + (x + dx).min(63)] -= 35.0;
                            }
                        }
                    }
                }
                "Spots" => {
                    for _ in 0..3 + rng.below(3) {
                        let (cx, cy) = (4 + rng.below(56), 4 + rng.below(56));
                        for y in cy.saturating_sub(2)..(cy + 3).min(64) {
                            for x in cx.saturating_sub(2)..(cx + 3).min(64) {
                                px[y * 64 + x] += 60.0;
                            }
                        }
                    }
                }
                _ => {}
            }
            let img = image::GrayImage::from_fn(64, 64, |x, y| {
                image::Luma([px[(y * 64 + x) as usize].clamp(0.0, 255.0) as u8])
            });
            img.save(dir.join(format!("frame_{k:04}.png"))).unwrap();
        }
    }
}

/// `learn train` on the class folders with a small network: 64 px frames, 16 x 16 cells.
fn train(data: &Path, out: &Path, seed: u64, threads: &str) -> std::process::Output {
    layerwise()
        .args(["learn", "train", "--data"])
        .arg(data)
        .arg("--out")
        .arg(out)
        .args(["--frame-px", "64", "--cell-px", "4", "--channels", "6,12", "--epochs", "14"])
        .args(["--seed", &seed.to_string(), "--batch", "8", "--patience", "14"])
        .env("RAYON_NUM_THREADS", threads)
        .succeeds()
}

/// The model file's JSON header (safetensors metadata `layerwise.model`).
fn header_of(bytes: &[u8]) -> serde_json::Value {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let st: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    serde_json::from_str(st["__metadata__"]["layerwise.model"].as_str().unwrap()).unwrap()
}

/// The model file with its header changed by `edit` (lengths and padding redone).
fn with_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut st: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let mut header = header_of(bytes);
    edit(&mut header);
    st["__metadata__"]["layerwise.model"] = serde_json::Value::String(header.to_string());
    let mut text = st.to_string().into_bytes();
    while text.len() % 8 != 0 {
        text.push(b' ');
    }
    let mut out = (text.len() as u64).to_le_bytes().to_vec();
    out.extend(text);
    out.extend_from_slice(&bytes[8 + n..]);
    out
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
    assert!(stderr.contains("epoch 1/14") && stderr.contains("val acc"), "{stderr}");
    assert!(stderr.contains("24 for training, 6 for validation, 3 left out"), "{stderr}");

    // The same seed on one thread: the same file, byte for byte.
    let again = tmp.path().join("again.safetensors");
    train(&data, &again, 3, "1");
    let (a, b) = (std::fs::read(&model).unwrap(), std::fs::read(&again).unwrap());
    assert_eq!(header_of(&a)["weights_sha256"], header_of(&b)["weights_sha256"]);
    let h = header_of(&a);
    assert_eq!(h["classes"], serde_json::json!(["No_Defect", "Spots", "Streaks"]));
    assert_eq!(h["normal_class"], "No_Defect");
    assert_eq!(h["training"]["data"]["counts"]["Spots"], 10);
    assert_eq!(h["training"]["split"]["val"]["Spots"], 2);
    assert_eq!(h["training"]["data"]["sha256"].as_str().unwrap().len(), 64);

    let eval = layerwise()
        .args(["learn", "eval", "--json", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .json_ok();
    for c in ["No_Defect", "Spots", "Streaks"] {
        let m = &eval["per_class"][c];
        assert_eq!(m["support"], 10, "{eval}");
        assert!(m["recall"].as_f64().unwrap() >= 0.7, "{c}: {eval}");
        assert!(m["precision"].as_f64().is_some(), "{eval}");
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
    let val = layerwise()
        .args(["learn", "eval", "--part", "val", "--model"])
        .arg(&model)
        .arg("--data")
        .arg(&data)
        .stdout_ok();
    assert!(val.starts_with("6 images: accuracy"), "{val}");

    let streak = data.join("Streaks/frame_0009.png");
    let heat = tmp.path().join("heat.png");
    let said = layerwise()
        .args(["learn", "predict", "--model"])
        .arg(&model)
        .arg(&streak)
        .arg("--heatmap")
        .arg(&heat)
        .stdout_ok();
    assert!(said.contains(": Streaks ("), "{said}");
    let picture = image::open(&heat).unwrap();
    assert_eq!((picture.width(), picture.height()), (64, 64));
    let info = layerwise().args(["learn", "info", "--model"]).arg(&model).stdout_ok();
    assert!(info.contains("trained on") && info.contains("confusion"), "{info}");
}

#[test]
fn damaged_foreign_newer_and_mismatched_model_files_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    class_folders(&data, 5);
    let model = tmp.path().join("m.safetensors");
    layerwise()
        .args(["learn", "train", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(&model)
        .args(["--frame-px", "64", "--cell-px", "4", "--channels", "4,8", "--epochs", "1"])
        .succeeds();
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
            bad("newer", &with_header(&bytes, |h| h["version"] = 2.into())),
            "written by a newer layerwise (model format 2, this one reads 1)",
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
    assert!(said.contains("[inspection.model] file") && said.contains("checksum"), "{said}");
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
    let said = run_build(&config_for(&cases[2].0, "cell_mm = 2.0"));
    let stderr = assert_exit_1(&said);
    assert!(stderr.contains("checksum"), "{stderr}");
}
