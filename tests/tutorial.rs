//! The README's tutorial, run as written: the lines between `<!-- tutorial -->` and
//! `<!-- /tutorial -->` are extracted and run by bash in an empty folder with this build's
//! `layerwise` first on the PATH, so the README cannot drift from what works.

mod common;

use std::path::Path;

fn tutorial_script() -> String {
    let readme = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md"))
        .expect("README.md");
    let start = readme
        .find("<!-- tutorial -->")
        .expect("tutorial start marker");
    let end = readme
        .find("<!-- /tutorial -->")
        .expect("tutorial end marker");
    readme[start..end]
        .lines()
        .filter(|l| !l.starts_with("```") && !l.starts_with("<!--"))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn the_readme_tutorial_runs_as_written() {
    let script = tutorial_script();
    assert!(script.contains("layerwise register images"), "{script}");
    let dir = tempfile::tempdir().unwrap();
    let bin = Path::new(env!("CARGO_BIN_EXE_layerwise")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let out = std::process::Command::new("bash")
        .args(["-euo", "pipefail", "-c", &script])
        .current_dir(dir.path())
        .env("PATH", path)
        .output()
        .expect("bash runs");
    common::assert_success(&out);
    let build = dir.path().join("demo-build");
    for file in [
        "my-calibration.toml",
        "overlay.png",
        "L00003_post_top.png",
        "L00003_vectors.png",
        "located.png",
    ] {
        assert!(build.join(file).is_file(), "{file} missing");
    }
    // The rectified frame and the vectors share the build's grid (demo [rectify]: 0.25 mm).
    assert_eq!(
        image::image_dimensions(build.join("L00003_post_top.png")).unwrap(),
        image::image_dimensions(build.join("L00003_vectors.png")).unwrap()
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("(layer 3): correlation"), "{stdout}");
    assert!(stdout.contains("layer         3"), "{stdout}");
}
