//! The real camera backend (libgphoto2 through the `gphoto2` crate) against libgphoto2's virtual
//! PTP camera (the `vusb` port library shipped in the PyPI `gphoto2` wheel): capture, download,
//! settings and errors go through real libgphoto2 code. `tests/run.sh` installs the wheel in a
//! venv and sets LAYERWISE_VCAM_LIBDIR to its `gphoto2/libgphoto2` folder.

use crate::common::*;
use layerwise::config::{CameraConfig, Config, Gphoto2Config};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Output;

fn vcam_libdir() -> PathBuf {
    // tests/run.sh exports it; otherwise look in the venv it makes.
    let dir = std::env::var_os("LAYERWISE_VCAM_LIBDIR")
        .map(PathBuf::from)
        .or_else(|| {
            let lib = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-venv/lib");
            std::fs::read_dir(lib)
                .ok()?
                .filter_map(|e| e.ok())
                .map(|e| e.path().join("site-packages/gphoto2/libgphoto2"))
                .find(|p| p.is_dir())
        });
    let dir = dir.expect(
        "no libgphoto2 with the vusb virtual camera: run `bash tests/run.sh`, which installs the PyPI gphoto2 wheel \
         in target/test-venv (or set LAYERWISE_VCAM_LIBDIR to its gphoto2/libgphoto2 folder)",
    );
    assert!(
        dir.join("vusb").is_dir(),
        "{} has no vusb/ folder",
        dir.display()
    );
    dir
}

/// Runs `layerwise run` with libgphoto2 replaced by the wheel's, whose vusb port is the camera.
fn run_with_virtual_camera(config: &Config, dir: &Path, frames_dir: &Path) -> Output {
    let lib = vcam_libdir();
    let config_path = dir.join("layerwise.toml");
    write_config(config, &config_path);
    run_command(&config_path)
        .env("LD_LIBRARY_PATH", &lib)
        .env("CAMLIBS", lib.join("camlibs"))
        .env("IOLIBS", lib.join("vusb"))
        .env("VCAMERADIR", frames_dir)
        .output()
        .expect("layerwise runs")
}

fn gphoto_config(build: &Path, layers: u32, settings: &[(&str, &str)], model: &str) -> Config {
    let mut config = demo_config(build, layers);
    config.camera = CameraConfig::Gphoto2(Gphoto2Config {
        model: model.to_string(),
        port: String::new(),
        settings: settings
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect::<BTreeMap<_, _>>(),
    });
    config.capture.call_timeout_s = 30;
    config
}

/// JPEGs the virtual camera serves, rendered by the mock camera.
fn camera_frames(dir: &Path) -> Vec<String> {
    std::fs::create_dir_all(dir).unwrap();
    let renderer =
        mock_camera::Renderer::new(320, 214, mock_camera::Homography::oblique_view(320, 214));
    let mut hashes = Vec::new();
    for layer in 1..=3 {
        let parts = mock_camera::demo_parts(layer);
        let scene = mock_camera::Scene {
            layer,
            fused: &parts,
            scanned: true,
            illumination: mock_camera::Illumination::Top,
        };
        let jpeg = renderer.render_jpeg(&scene, 90);
        hashes.push(layerwise::fsutil::sha256_hex(&jpeg));
        std::fs::write(dir.join(format!("frame{layer}.jpg")), jpeg).unwrap();
    }
    hashes
}

#[test]
fn captures_and_downloads_through_real_libgphoto2() {
    let dir = tempfile::tempdir().unwrap();
    let served = camera_frames(&dir.path().join("vcam"));
    let build = dir.path().join("build");
    let config = gphoto_config(
        &build,
        2,
        &[("capturetarget", "Internal RAM"), ("f-number", "f/2.8")],
        "",
    );
    assert_success(&run_with_virtual_camera(
        &config,
        dir.path(),
        &dir.path().join("vcam"),
    ));
    assert_eq!(originals(&build), expected_originals(2));
    assert_sidecars_match(&build);
    for file in originals(&build) {
        let sha = layerwise::fsutil::sha256_hex(&std::fs::read(build.join(&file)).unwrap());
        assert!(
            served.contains(&sha),
            "{file} is not a frame the camera holds"
        );
        let sidecar = read_json(&build.join(file.replace(".jpg", ".json")));
        assert_eq!(sidecar["camera"]["capturetarget"], "Internal RAM");
        assert!(
            sidecar["camera"]["model"]
                .as_str()
                .unwrap_or("")
                .contains("Nikon"),
            "{sidecar}"
        );
    }
}

/// A one-layer build on the virtual camera with these settings and model: its stderr, after
/// checking that it was refused (exit 1).
fn refused(settings: &[(&str, &str)], model: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    camera_frames(&dir.path().join("vcam"));
    let config = gphoto_config(&dir.path().join("build"), 1, settings, model);
    assert_exit_1(&run_with_virtual_camera(
        &config,
        dir.path(),
        &dir.path().join("vcam"),
    ))
}

#[test]
fn an_unknown_setting_is_named() {
    let err = refused(&[("isospeed", "100")], "");
    assert!(
        err.contains("isospeed") && err.contains("--list-config"),
        "{err}"
    );
}

#[test]
fn a_bad_choice_lists_the_choices() {
    let err = refused(&[("f-number", "f/99")], "");
    assert!(
        err.contains("f-number") && err.contains("choices") && err.contains("f/2.8"),
        "{err}"
    );
}

#[test]
fn a_missing_model_says_what_libgphoto2_sees() {
    let err = refused(&[], "Nikon DSC D810");
    assert!(
        err.contains("Nikon DSC D810") && err.contains("libgphoto2 sees") && err.contains("D750"),
        "{err}"
    );
}
