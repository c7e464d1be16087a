//! The runnable blocks of the docs, run as written: the code blocks between
//! `<!-- tutorial NAME -->` and `<!-- /tutorial -->` markers are extracted
//! (`common::tutorial_script`) and run by bash in an empty folder with this build's `layerwise`
//! first on the PATH, so the docs cannot drift from what works: the engineer's tutorial of
//! docs/tutorial.md (`<!-- tutorial -->`) and the README's five-minute tour
//! (`<!-- tutorial tour -->`). Every other `layerwise` line of the docs is checked against the
//! binary's parser by doc_commands.rs.

use crate::common;
use std::path::Path;

/// The runnable regions there are: (file, name). A marker of any other name, or in another
/// file, is run by no test, and fails `every_marked_block_is_run`.
const RUN: [(&str, &str); 2] = [("docs/tutorial.md", ""), ("README.md", "tour")];

/// Runs `script` with bash (`-euo pipefail`) in a new empty folder, this build's `layerwise`
/// first on the PATH; checks it succeeded and returns the folder and what it printed.
fn run_script(script: &str) -> (tempfile::TempDir, String) {
    let dir = tempfile::tempdir().unwrap();
    let bin = Path::new(env!("CARGO_BIN_EXE_layerwise")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out = std::process::Command::new("bash")
        .args(["-euo", "pipefail", "-c", script])
        .current_dir(dir.path())
        .env("PATH", path)
        .output()
        .expect("bash runs");
    common::assert_success(&out);
    (dir, String::from_utf8_lossy(&out.stdout).into_owned())
}

/// Checks that each of `files` (paths under `dir`, separated by spaces) was written.
fn assert_files(dir: &Path, files: &str) {
    for file in files.split(' ') {
        assert!(dir.join(file).is_file(), "{file} missing");
    }
}

#[test]
fn every_marked_block_is_run() {
    for (file, text) in common::markdown_docs() {
        for name in common::tutorial_names(&text) {
            assert!(
                RUN.contains(&(file.as_str(), name.as_str())),
                "{file}: <!-- tutorial {name} --> is run by no test (tests/it/tutorial.rs RUN)"
            );
        }
    }
    for (file, name) in RUN {
        assert!(
            common::tutorial_names(&common::markdown(file)).contains(&name.to_string()),
            "{file} has no <!-- tutorial {name} --> region"
        );
    }
}

#[test]
fn the_readme_tour_runs_as_written() {
    let script = common::tutorial_script(&common::markdown("README.md"), "tour");
    for step in ["layerwise demo", "layerwise alarm ack", "layerwise flaws"] {
        assert!(script.contains(step), "{script}");
    }
    let (dir, stdout) = run_script(&script);
    assert!(stdout.contains("alarm RAISED since layer 5"), "{stdout}");
    assert!(stdout.contains("under_fusion"), "{stdout}");
    assert!(stdout.contains("alarm acknowledged by ana at"), "{stdout}");
    let build = dir.path().join("tour-build");
    let written = "my-calibration.toml overlay.png ct.toml flaws/flaws.json flaw1.png";
    assert_files(&build, written);
    assert_files(&build, "flaws/contact_sheet.png");
    assert!(build.join("export/ct_part_3").is_dir());
    let flaws: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(build.join("flaws/flaws.json")).unwrap())
            .unwrap();
    assert_eq!(flaws["flaws"].as_array().unwrap().len(), 2, "{flaws:#}");
}

#[test]
fn the_tutorial_runs_as_written() {
    let script = common::tutorial_script(&common::markdown("docs/tutorial.md"), "");
    assert!(script.contains("layerwise register images"), "{script}");
    let (dir, stdout) = run_script(&script);
    let build = dir.path().join("demo-build");
    let written = "my-calibration.toml overlay.png ct.toml ct-surface.ply located.png flaw1.png";
    assert_files(&build, written);
    assert_files(&build, "L00003_post_top.png L00003_vectors.png");
    // The rectified frame and the vectors share the build's grid (demo [rectify]: 0.25 mm).
    assert_eq!(
        image::image_dimensions(build.join("L00003_post_top.png")).unwrap(),
        image::image_dimensions(build.join("L00003_vectors.png")).unwrap()
    );
    assert!(stdout.contains("(layer 3): correlation"), "{stdout}");
    assert!(
        stdout.contains("wrote the CT surface coloured by distance to ct-surface.ply"),
        "{stdout}"
    );
    assert!(
        !stdout.contains("not determined"),
        "the box has no free rotation: {stdout}"
    );

    // The registration finds the CT's true placement (ct/box-truth.toml, written with the CT).
    let table = |name: &str| -> toml::Table {
        std::fs::read_to_string(build.join(name))
            .unwrap()
            .parse()
            .unwrap()
    };
    let matrix = |t: &toml::Table| -> Vec<Vec<f64>> {
        t["transform"]
            .as_array()
            .unwrap()
            .iter()
            .map(|r| r.as_array().unwrap().iter().map(as_f64).collect())
            .collect()
    };
    let (ct, truth) = (table("ct.toml"), table("ct/box-truth.toml"));
    let (found, expected) = (matrix(&ct), matrix(&truth));
    let apply = |m: &[Vec<f64>], p: [f64; 3]| {
        [0, 1, 2].map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3])
    };
    // Over the box's corners (CT mm from the truth's inverse), the two transforms agree to 20 µm.
    for corner in [
        [40.0, 44.0, 0.0],
        [60.0, 44.0, 0.6],
        [60.0, 56.0, 0.0],
        [40.0, 56.0, 0.6],
    ] {
        let d: Vec<f64> = (0..3).map(|i| corner[i] - expected[i][3]).collect();
        let c = [0, 1, 2].map(|j| (0..3).map(|i| expected[i][j] * d[i]).sum::<f64>());
        let b = apply(&found, c);
        let miss = (0..3)
            .map(|i| (b[i] - corner[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(miss < 0.02, "corner {corner:?} lands {miss} mm off");
    }
    let mean_um = as_f64(&ct["mean_abs_distance_um"]);
    assert!(mean_um < 15.0, "mean |distance| {mean_um} µm");

    // The export holds the CT in the build's study, cropped to the box.
    assert!(build.join("export/ct_part_3").is_dir());
    assert!(stdout.contains("ct_part_3"), "{stdout}");

    // flaws finds the two pores where the CT has them, in their layers, and nothing else.
    let flaws: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(build.join("flaws/flaws.json")).unwrap())
            .unwrap();
    let found = flaws["flaws"].as_array().unwrap();
    let pores = truth["pores"].as_array().unwrap();
    assert_eq!(found.len(), pores.len(), "{flaws:#}");
    for pore in pores {
        let c: Vec<f64> = pore["center_mm"]
            .as_array()
            .unwrap()
            .iter()
            .map(as_f64)
            .collect();
        let layer = pore["layer"].as_integer().unwrap() as u64;
        let f = found
            .iter()
            .find(|f| {
                let p = &f["centroid_mm"];
                (0..3)
                    .map(|a| (p[a].as_f64().unwrap() - c[a]).powi(2))
                    .sum::<f64>()
                    .sqrt()
                    < 0.03
            })
            .unwrap_or_else(|| panic!("no flaw within 30 µm of the pore at {c:?}: {flaws:#}"));
        let span = f["first_layer"].as_u64().unwrap()..=f["last_layer"].as_u64().unwrap();
        assert!(
            span.contains(&layer),
            "pore in layer {layer}, flaw spans {span:?}"
        );
    }
    assert!(build.join("flaws/contact_sheet.png").is_file());

    // locate: the pore's layer, its CT voxel, and a labelled sheet of vectors, CT and 6 x 2 views.
    assert!(stdout.contains("layer         10"), "{stdout}");
    assert!(stdout.contains("ct            ("), "{stdout}");
    let (w, h) = image::image_dimensions(build.join("located.png")).unwrap();
    let label = layerwise::raster::sheet::LABEL_PX;
    assert_eq!((w, h), (14 * (161 + 4) + 4, 161 + label + 8));
    let sheet = image::open(build.join("located.png")).unwrap().to_rgb8();
    // The CT tile (second) is dark at the pore, bright in the box's material around it.
    let at = |x: u32, y: u32| sheet.get_pixel(4 + 165 + x, 4 + label + y).0[0];
    assert!(
        at(80, 80) < at(80, 70) && at(80, 80) < at(80, 90),
        "pore {} vs material {} {}",
        at(80, 80),
        at(80, 70),
        at(80, 90)
    );
}

fn as_f64(v: &toml::Value) -> f64 {
    v.as_float()
        .or_else(|| v.as_integer().map(|i| i as f64))
        .unwrap()
}
