//! `layerwise learn cv` through the binary on generated class folders: every picture is held out
//! once, by blocks of its sequence with the neighbouring frames left out; each fold's figures and
//! the pooled confusion matrix come out as text and as JSON; `--refit` refits each fold's model on
//! all it was given; a fold count the data cannot give is refused with the range.

use crate::common::*;

/// `learn cv` with the small network of the other learn tests (a larger selection tail: a fold's
/// given frames are fewer).
fn cv(data: &std::path::Path, extra: &[&str]) -> std::process::Command {
    let mut c = layerwise();
    c.args(["learn", "cv", "--data"])
        .arg(data)
        .args(["--frame-px", "64", "--cell-px", "4", "--batch", "8"])
        .args(["--channels", "6,12", "--epochs", "40", "--patience", "40"])
        .args(["--val-fraction", "0.3"])
        .args(extra);
    c
}

#[test]
fn cross_validation_holds_out_every_picture_once_by_sequence_blocks() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    class_folders(&data, 30);

    let report = cv(&data, &["--folds", "3", "--json"]).json_ok();
    assert_eq!(report["rule"], "sequence-blocks", "{report}");
    assert_eq!(report["refit"], false, "{report}");
    assert_eq!(report["never_held_out"], 0, "{report}");
    let folds = report["folds"].as_array().unwrap();
    assert_eq!(folds.len(), 3, "{report}");
    // Three sequences of 30 frames: blocks of 10, two frames left out on each side of a block.
    for ((fold, held), left) in folds.iter().zip([30, 30, 30]).zip([6, 12, 6]) {
        assert_eq!(fold["held_out"], held, "{fold}");
        assert_eq!(fold["left_out"], left, "{fold}");
        assert_eq!(fold["given"], 90 - held - left, "{fold}");
        assert!(fold["refit_on"].is_null(), "{fold}");
        let m = &fold["metrics"];
        let total: u64 = m["confusion"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|r| r.as_array().unwrap())
            .map(|v| v.as_u64().unwrap())
            .sum();
        assert_eq!(total, held as u64, "{fold}");
    }
    // The pooled table is the folds' tables added up: every picture once.
    let pooled = &report["pooled"];
    let mut sum = vec![vec![0u64; 3]; 3];
    for fold in folds {
        for (t, row) in fold["metrics"]["confusion"]
            .as_array()
            .unwrap()
            .iter()
            .enumerate()
        {
            for (p, v) in row.as_array().unwrap().iter().enumerate() {
                sum[t][p] += v.as_u64().unwrap();
            }
        }
    }
    assert_eq!(pooled["confusion"], serde_json::json!(sum), "{report}");
    for c in ["No_Defect", "Spots", "Streaks"] {
        assert_eq!(pooled["per_class"][c]["support"], 30, "{pooled}");
    }
    // Each fold's model learns from the 27 to 36 frames a class it is given, choosing its epoch
    // on the tail of them (9 or 10 a class, --val-fraction 0.3): far better than chance (1/3)
    // on frames it never saw, not as good as a model given them all (a small network, 40 short
    // epochs).
    assert!(pooled["accuracy"].as_f64().unwrap() >= 0.5, "{pooled}");

    // As text: one line per fold, then the pooled table; the same figures (same seed).
    let text = cv(&data, &["--folds", "3"]).stdout_ok();
    assert!(
        text.contains("fold 2/3: given 48, held out 30, left out 12"),
        "{text}"
    );
    let pooled_line = format!(
        "90 images: accuracy {:.3}",
        pooled["accuracy"].as_f64().unwrap()
    );
    assert!(text.contains("pooled over 3 folds"), "{text}");
    assert!(text.contains(&pooled_line), "{pooled_line} in {text}");

    // --refit: each fold's model, its epoch chosen, is trained again on all it was given, and
    // still classifies only the block it never saw.
    let refit = cv(&data, &["--folds", "3", "--json", "--refit"]).json_ok();
    assert_eq!(refit["refit"], true, "{refit}");
    for (fold, plain) in refit["folds"].as_array().unwrap().iter().zip(folds) {
        assert_eq!(fold["refit_on"], plain["given"], "{fold}");
        assert_eq!(fold["held_out"], plain["held_out"], "{fold}");
        assert_eq!(
            fold["best_epoch"], plain["best_epoch"],
            "the same selection run: {fold}"
        );
    }
    assert!(
        refit["pooled"]["accuracy"].as_f64().unwrap() >= 0.5,
        "{refit}"
    );

    let refused = cv(&data, &["--folds", "31"]).fails();
    assert!(refused.contains("31 folds need 2 to 30"), "{refused}");
    assert!(refused.contains("--folds"), "{refused}");
    assert!(refused.contains(&data.display().to_string()), "{refused}");
}
