//! Labelled pictures and small models for the tests of `layerwise learn` and of the model's
//! live path (the daemon, the page's verdicts).

use super::*;
use std::path::Path;

/// Class folders of 64 x 64 grey frames, 10 a class named `frame_0000…`: `No_Defect` (grain),
/// `Streaks` (two to four dark vertical bands), `Spots` (bright spots). Brightness and grain
/// level vary inside every class, so only the structure tells them apart.
pub fn class_folders(root: &Path, per_class: usize) {
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

/// `learn train DATA --out OUT` on 64 px frames of 4 px cells with batches of 8, plus `extra`.
pub fn train_small(data: &Path, out: &Path, extra: &[&str]) -> std::process::Command {
    let mut c = layerwise();
    c.args(["learn", "train", "--data"])
        .arg(data)
        .arg("--out")
        .arg(out)
        .args(["--frame-px", "64", "--cell-px", "4", "--batch", "8"])
        .args(extra);
    c
}

/// A finished 3-layer calibrated mock build in `tmp/build` whose daemon ran a small model
/// (trained on [`class_folders`], 1 mm cells) on every view with `min_probability = 0`, so its
/// tiles of a defect class are flags. Returns the build directory and the daemon's stderr.
pub fn model_build(tmp: &Path) -> (std::path::PathBuf, String) {
    let data = tmp.join("classes");
    class_folders(&data, 5);
    let model = tmp.join("model.safetensors");
    train_small(
        &data,
        &model,
        &["--channels", "4,8", "--epochs", "2", "--cell-mm", "1.0"],
    )
    .succeeds();
    let dir = tmp.join("build");
    let mut config = calibrated_config(&dir, 3, layerwise::dicom::Compression::None);
    config.inspection.model = Some(
        toml::from_str(&format!(
            "file = {:?}\nmin_probability = 0.0",
            model.display().to_string()
        ))
        .unwrap(),
    );
    let path = tmp.join("layerwise.toml");
    write_config(&config, &path);
    // Eight lanes on any machine: a layer's views are processed beside the next layer's, and
    // a layer's record must still wait for the model's scans of its views on other lanes.
    let out = run_command(&path).env("RAYON_NUM_THREADS", "8").succeeds();
    (dir, String::from_utf8_lossy(&out.stderr).into_owned())
}

/// A `layerwise flaws --build` output in `root` as `learn` reads it: `labels.json` (COCO
/// `images` with `file_name`, `kind`, `layer`, `flaw_id`, `grid`) and 17 x 17 16-bit patches,
/// per layer 1..=`layers` three views of the flaw `(layer + 1) / 2` (a dark pore of 2 to 3 px
/// radius near the centre; each flaw spans two layers) and three flaw-free controls (which,
/// as in `flaws`, carry the id of the flaw they are the control of). Level and grain vary in
/// both classes.
pub fn flaws_output(root: &Path, layers: u32) {
    let mut rng = Rng(0xF1A5);
    std::fs::create_dir_all(root.join("patches")).unwrap();
    std::fs::create_dir_all(root.join("controls")).unwrap();
    let mut images = Vec::new();
    for layer in 1..=layers {
        for (kind, dir) in [("flaw", "patches"), ("control", "controls")] {
            for view in ["pre_top", "post_top", "post_side"] {
                let base = 25_000.0 + rng.below(15_000) as f64;
                let grain = 300.0 + rng.below(900) as f64;
                let (cx, cy) = (7 + rng.below(3), 7 + rng.below(3));
                let radius = 2.0 + rng.below(2) as f64;
                let img =
                    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(17, 17, |x, y| {
                        let mut v = base + grain * (rng.below(1000) as f64 / 500.0 - 1.0);
                        let d = ((x as f64 - cx as f64).powi(2) + (y as f64 - cy as f64).powi(2))
                            .sqrt();
                        if kind == "flaw" && d <= radius {
                            v *= 0.55;
                        }
                        image::Luma([v.clamp(0.0, 65_535.0) as u16])
                    });
                let flaw_id = layer.div_ceil(2);
                let name = format!(
                    "{dir}/{}{flaw_id:04}_L{layer:05}_{view}.png",
                    &kind[..1].to_uppercase()
                );
                img.save(root.join(&name)).unwrap();
                let grid = layerwise::geometry::Grid {
                    x_min: 0.0,
                    x_max: 17.0 * 0.0625,
                    y_min: 0.0,
                    y_max: 17.0 * 0.0625,
                    pixel_mm: 0.0625,
                };
                images.push(serde_json::json!({
                    "id": images.len() + 1, "file_name": name, "width": 17, "height": 17,
                    "kind": kind, "layer": layer, "view": view, "flaw_id": flaw_id,
                    "grid": grid, "value_scale": 1,
                }));
            }
        }
    }
    let labels = serde_json::json!({"images": images, "annotations": [], "categories": []});
    std::fs::write(root.join("labels.json"), labels.to_string()).unwrap();
}

/// The model file's JSON header (safetensors metadata `layerwise.model`).
pub fn header_of(bytes: &[u8]) -> serde_json::Value {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let st: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    serde_json::from_str(st["__metadata__"]["layerwise.model"].as_str().unwrap()).unwrap()
}

/// `layerwise ARGS --model MODEL --data DATA` (eval, compare).
pub fn learn_on(args: &[&str], model: &Path, data: &Path) -> std::process::Command {
    let mut c = layerwise();
    c.args(args)
        .arg("--model")
        .arg(model)
        .arg("--data")
        .arg(data);
    c
}
