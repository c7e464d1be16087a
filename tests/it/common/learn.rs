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
    let out = run_build(&path);
    (dir, String::from_utf8_lossy(&out.stderr).into_owned())
}
