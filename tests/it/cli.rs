//! The `layerwise` binary as operators and systemd use it.

use crate::common::*;
use layerwise::config::TriggerConfig;
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

#[test]
fn check_config_accepts_the_examples() {
    for file in ["config/layerwise.toml", "config/demo.toml"] {
        let out = layerwise().args(["check-config", file]).stdout_ok();
        assert!(out.contains("valid"), "{file}: {out}");
    }
}

#[test]
fn check_config_names_file_key_and_expectation() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "typo.toml",
            "[camera]",
            "[camera]\nshutter = \"1/4\"",
            &["typo.toml", "line", "shutter", "expected one of"][..],
        ),
        (
            "type.toml",
            "settle_ms = 0",
            "settle_ms = -3",
            &["type.toml", "capture.settle_ms", "u64"][..],
        ),
        (
            "kind.toml",
            "kind = \"mock\"\nlayers",
            "kind = \"usb\"\nlayers",
            &["kind.toml", "trigger.kind", "serial", "gpio", "mock"][..],
        ),
        (
            "grid.toml",
            "pixel_mm = 0.25",
            "pixel_mm = 0.0",
            &["grid.toml", "rectify", "pixel_mm > 0"][..],
        ),
    ];
    for (name, from, to, expect) in cases {
        let text = layerwise::config::DEMO_CONFIG.replacen(from, to, 1);
        assert_ne!(
            text,
            layerwise::config::DEMO_CONFIG,
            "{name}: the edit must apply"
        );
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        let err = layerwise().arg("check-config").arg(&path).fails();
        for word in expect {
            assert!(err.contains(word), "{name}: {word:?} not in {err}");
        }
    }
    let err = layerwise()
        .args(["check-config", "/nonexistent/layerwise.toml"])
        .fails();
    assert!(
        err.contains("/nonexistent/layerwise.toml: cannot read"),
        "{err}"
    );
}

#[test]
fn kill_9_mid_build_then_restart_keeps_every_frame_once() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = demo_config(&build, 8);
    config.storage.fsync = true;
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 60;
    }
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);

    for kill_at in [10, 29] {
        let mut child = spawn_build(&config_path, Stdio::null());
        wait_for_originals(&build, kill_at, Duration::from_secs(60));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
    }
    run_build(&config_path);

    assert_eq!(originals(&build), expected_originals(8));
    let records = frame_records(&build);
    assert_eq!(records.len(), 48);
    assert!(
        records.values().all(|&n| n == 1),
        "duplicated frames: {records:?}"
    );
    assert!(temporaries(&build).is_empty());
    assert_sidecars_match(&build);
    let replay = replay(&build);
    assert_eq!(replay.last_event, Some((8, layerwise::shot::Phase::Post)));
    assert!(replay.missing.is_empty(), "{:?}", replay.missing);
    assert_eq!(replay.starts, 3);

    let status = layerwise()
        .args(["status", "--json", "--build"])
        .arg(&build)
        .json_ok();
    assert_eq!(status["frames"], 48);
    assert_eq!(status["frames_missing"], 0);
    assert_eq!(status["layer"], 8);
    assert_eq!(status["state"], "stopped");
    assert_eq!(status["waiting_for_processing"], 0);
}

#[test]
fn sigterm_stores_the_frame_in_hand_and_stops_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = demo_config(&build, 50);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 30;
    }
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let child = spawn_build(&config_path, Stdio::piped());
    wait_for_originals(&build, 8, Duration::from_secs(60));
    assert_success(&terminate(child));
    assert!(temporaries(&build).is_empty());
    let stored = originals(&build).len();
    assert!(stored < 300, "stopped early");
    assert_eq!(
        frame_records(&build).len(),
        stored,
        "every stored frame is journaled"
    );
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("daemon     stopped"), "{text}");
    assert!(
        text.contains(&format!("frames     {stored} stored")),
        "{text}"
    );
}

#[test]
fn status_of_a_directory_that_is_not_a_build() {
    let dir = tempfile::tempdir().unwrap();
    let err = layerwise()
        .args(["status", "--build"])
        .arg(dir.path())
        .fails();
    assert!(err.contains("not a layerwise build directory"), "{err}");
}

#[test]
fn status_warns_when_the_disk_will_not_last() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 2);
    run_daemon(&config, layerwise::acquisition::RunOptions::new()).unwrap();
    // Pretend the build has a million layers still to come.
    let manifest_path = dir.path().join("build.json");
    let mut manifest = read_json(&manifest_path);
    manifest["layers_expected"] = serde_json::json!(100_000_000u64);
    std::fs::write(&manifest_path, serde_json::to_vec(&manifest).unwrap()).unwrap();
    let text = layerwise()
        .args(["status", "--build"])
        .arg(dir.path())
        .stdout_ok();
    assert!(
        text.contains("WARNING") && text.contains("needs about"),
        "{text}"
    );
}

#[test]
fn demo_runs_on_the_embedded_config() {
    let dir = tempfile::tempdir().unwrap();
    let out_dir = dir.path().join("demo");
    let out = layerwise()
        .args(["demo", "--layers", "2", "--out"])
        .arg(&out_dir)
        .stdout_ok();
    assert_eq!(originals(&out_dir), expected_originals(2));
    assert!(out.contains("12 frames stored"), "{out}");
}

/// The log of a 2-layer demo as a pipe gets it (stderr), with `-v` or `RUST_LOG` if given.
fn demo_log(dir: &Path, name: &str, verbose: bool, rust_log: Option<&str>) -> String {
    let mut command = layerwise();
    if verbose {
        command.arg("-v");
    }
    command
        .args(["demo", "--layers", "2", "--out"])
        .arg(dir.join(name))
        // Eight lanes on any machine: a layer's line must wait for its frames on other lanes.
        .env("RAYON_NUM_THREADS", "8")
        .env_remove("RUST_LOG");
    if let Some(filter) = rust_log {
        command.env("RUST_LOG", filter);
    }
    String::from_utf8_lossy(&command.succeeds().stderr).into_owned()
}

#[test]
fn operator_log_has_signal_and_layer_lines_debug_on_request_and_no_ansi_or_debug_formatting() {
    let dir = tempfile::tempdir().unwrap();
    let log = demo_log(dir.path(), "plain", false, None);
    let lines = |what: &str| log.lines().filter(|l| l.contains(what)).count();
    // Each layer signal, each layer's capture and each layer's processing: one line each.
    assert_eq!(lines("layer signal layer="), 4, "{log}");
    let done: Vec<&str> = log.lines().filter(|l| l.contains("layer done")).collect();
    assert_eq!(done.len(), 4, "{log}");
    for key in [
        "layer=",
        "phase=",
        "frames=3",
        "missing=0",
        "capture_ms=",
        "backlog=",
    ] {
        assert!(done.iter().all(|l| l.contains(key)), "{key}: {done:#?}");
    }
    let processed: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("layer processed"))
        .collect();
    assert_eq!(processed.len(), 4, "{log}");
    let order: Vec<String> = processed
        .iter()
        .map(|l| {
            let field = |k: &str| l.split(k).nth(1).and_then(|r| r.split(' ').next());
            format!(
                "{} {}",
                field(" layer=").unwrap_or("?"),
                field(" phase=").unwrap_or("?")
            )
        })
        .collect();
    assert_eq!(
        order,
        ["1 pre", "1 post", "2 pre", "2 post"],
        "{processed:#?}"
    );
    for key in [
        "frames=3",
        "failed=0",
        "processing_ms=",
        "lag_ms=",
        "backlog=",
    ] {
        assert!(
            processed.iter().all(|l| l.contains(key)),
            "{key}: {processed:#?}"
        );
    }
    // Fields journald keeps as LAYER=, PHASE=, LIGHT= (tracing-journald upper-cases them).
    assert!(
        log.lines().any(|l| l.contains("frame stored")
            && l.contains(" layer=1 ")
            && l.contains(" phase=pre ")
            && l.contains(" light=")),
        "{log}"
    );
    // A pipe is no terminal: no colour codes; no Rust Debug formatting in a message.
    assert!(
        !log.contains('\u{1b}'),
        "escape codes in a piped log:\n{log}"
    );
    for debug in ["Some(", "None", "((", "\\\""] {
        assert!(!log.contains(debug), "{debug} in the log:\n{log}");
    }
    // Lights and camera calls only on request: -v or RUST_LOG.
    for quiet in ["lights: switch", "camera: capture"] {
        assert!(!log.contains(quiet), "{quiet} without -v:\n{log}");
    }
    let verbose = demo_log(dir.path(), "verbose", true, None);
    let filtered = demo_log(dir.path(), "filtered", false, Some("layerwise=debug"));
    for log in [&verbose, &filtered] {
        assert!(
            log.contains("lights: switch") && log.contains("light=front"),
            "{log}"
        );
        assert!(log.contains("camera: capture"), "{log}");
        assert!(!log.contains('\u{1b}'), "{log}");
    }
}

#[test]
fn vectors_info_json_agrees_with_each_real_file_header() {
    let dir = shared_cli_dir();
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).expect("shared/data/cli beside the checkout") {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "cli") {
            continue;
        }
        seen += 1;
        let info = layerwise()
            .args(["vectors", "info", "--json"])
            .arg(&path)
            .json_ok();
        for key in VECTORS_INFO_KEYS {
            assert!(info.get(key).is_some(), "{}: no `{key}`", path.display());
        }
        assert_eq!(
            info["layers"],
            info["declared_layers"],
            "{}",
            path.display()
        );
        let declared = info["declared_dimension_mm"].as_array().unwrap();
        let bbox = info["parts"][0]["bbox"].as_array().unwrap();
        let unit = info["units"].as_f64().unwrap();
        for (i, d) in [0usize, 1, 3, 4].iter().enumerate() {
            let (got, want) = (bbox[i].as_f64().unwrap(), declared[*d].as_f64().unwrap());
            assert!(
                (got - want).abs() <= unit + 1e-9,
                "{}: bbox {got} vs $$DIMENSION {want}",
                path.display()
            );
        }
    }
    assert_eq!(seen, 4, "the four real CLI files");
    let dir = tempfile::tempdir().unwrap();
    let broken = dir.path().join("broken.cli");
    std::fs::write(&broken, "$$HEADERSTART\n$$ASCII\n$$UNITS/1\n$$HEADEREND\n$$GEOMETRYSTART\n$$LAYER/0.1\n$$POLYLINE/1,1,3,0,0,x,1\n").unwrap();
    let err = layerwise().args(["vectors", "info"]).arg(&broken).fails();
    assert!(
        err.contains("broken.cli") && err.contains("line 7"),
        "{err}"
    );
}

#[test]
fn rectify_one_frame_to_png_and_dicom_and_refuse_garbage() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let frame = dir.path().join("frame.jpg");
    std::fs::write(&frame, view.jpeg()).unwrap();
    for out in ["top.png", "top.dcm"] {
        let out = dir.path().join(out);
        assert_success(&view.rectify(&frame, &out));
        assert!(std::fs::metadata(&out).unwrap().len() > 1000);
    }
    // A bare file name writes into the working directory.
    layerwise()
        .current_dir(dir.path())
        .arg("rectify")
        .arg("--calibration")
        .arg(&view.calibration)
        .arg("--config")
        .arg(&view.config)
        .args(["--image", "frame.jpg", "--out", "here.dcm"])
        .succeeds();
    assert!(dir.path().join("here.dcm").is_file());
    let png = image::open(dir.path().join("top.png")).unwrap();
    assert_eq!((png.width(), png.height()), (550, 550));
    // One grid: without --config/--build the grid is the built-in [rectify] default, and an
    // older calibration's own [grid] is named as ignored.
    let plate = dir.path().join("plate.png");
    let out = layerwise()
        .arg("rectify")
        .arg("--calibration")
        .arg(&view.calibration)
        .arg("--image")
        .arg(&frame)
        .arg("--out")
        .arg(&plate)
        .output()
        .unwrap();
    assert_success(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("[grid]") && stderr.contains("is ignored"),
        "{stderr}"
    );
    assert_eq!(image::image_dimensions(&plate).unwrap(), (4400, 4400));
    let series = layerwise()
        .args(["dicom", "info", "--json"])
        .arg(dir.path())
        .json_ok();
    assert_eq!(series[0]["rows"], 550);
    assert_eq!(series[0]["first_position"][0], -137.25);
    let bad = dir.path().join("bad.jpg");
    std::fs::write(&bad, b"\xff\xd8not a jpeg at all").unwrap();
    let err = assert_exit_1(&view.rectify(&bad, &dir.path().join("x.png")));
    assert!(err.contains("bad.jpg"), "{err}");
}

#[test]
fn optics_json_keys_and_values_for_the_paper_setup() {
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("dof.svg");
    let r = layerwise()
        .args([
            "optics",
            "--focal-mm",
            "45",
            "--f-number",
            "32",
            "--pixel-um",
            "4.88",
            "--sensor",
            "7360x4912",
        ])
        .args([
            "--distance-mm",
            "500",
            "--angle-deg",
            "30",
            "--plate-mm",
            "275",
            "--json",
            "--plot",
        ])
        .arg(&svg)
        .json_ok();
    // By hand from eq. 1-4: M = 45/455; d/M; H = (45/32)·45/0.00488 + 45; near/far from eq. 3, 4.
    let m = 45.0 / 455.0;
    let h = (45.0 / 32.0) * 45.0 / 0.00488 + 45.0;
    let near = 500.0 * (h - 45.0) / (h + 500.0 - 90.0);
    let far = 500.0 * (h - 45.0) / (h - 500.0);
    let close = |key: &str, want: f64| {
        let got = r[key].as_f64().unwrap_or(f64::NAN);
        assert!(
            (got - want).abs() <= 1e-6 * want.abs().max(1.0),
            "{key}: {got} vs {want}"
        );
    };
    close("magnification", m);
    close("resolution_center_um", 4.88 / m);
    close("hyperfocal_mm", h);
    close("near_mm", near);
    close("far_mm", far);
    assert_eq!(r["plate_in_focus_without_tilt"], false);
    // Scheimpflug: tan α = M tan 30°.
    close(
        "scheimpflug_tilt_deg",
        (m * 30f64.to_radians().tan()).atan().to_degrees(),
    );
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg") && text.contains("Scheimpflug"));
    // Beyond the hyperfocal distance the far limit is infinite: null.
    let r = layerwise()
        .args(["optics", "--distance-mm", "20000", "--json"])
        .json_ok();
    assert!(r["far_mm"].is_null());
    let err = layerwise().args(["optics", "--distance-mm", "30"]).fails();
    assert!(err.contains("focal length"), "{err}");
}

#[test]
fn locate_finds_a_point_in_every_view_and_marks_it() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("demo");
    layerwise()
        .args(["demo", "--layers", "2", "--out"])
        .arg(&build)
        .succeeds();
    // The cylinder's center of mock_camera::demo_parts, in layer 2 (z in (0.03, 0.06]).
    let mark = dir.path().join("mark.png");
    let loc = layerwise()
        .args(["locate", "--json", "--point", "-60,40,0.05", "--build"])
        .arg(&build)
        .arg("--mark")
        .arg(&mark)
        .json_ok();
    assert_eq!(loc["layer"], 2);
    let views = loc["views"].as_array().unwrap();
    assert_eq!(views.len(), 6);
    // The demo grid is the plate at 0.25 mm: row = (137.5 − 40)/0.25 − 0.5, column = (−60 + 137.5)/0.25 − 0.5.
    let truth = mock_camera::Homography::oblique_view(1472, 982)
        .inverse()
        .unwrap();
    let (u, v) = truth.apply(-60.0, 40.0).unwrap();
    for view in views {
        assert_eq!(view["rectified_pixel"], serde_json::json!([389.5, 309.5]));
        let [iu, iv] = [
            view["image_pixel"][0].as_f64().unwrap(),
            view["image_pixel"][1].as_f64().unwrap(),
        ];
        assert!(
            (iu - u).abs() < 1e-6 && (iv - v).abs() < 1e-6,
            "{iu},{iv} vs {u},{v}"
        );
        assert!(view["dicom"].as_str().unwrap().ends_with("L00002.dcm"));
        assert!(view["original"].as_str().unwrap().ends_with(".jpg"));
    }
    let sheet = image::open(&mark).unwrap().to_rgb8();
    // One row of labelled 161 px tiles, 4 px apart and around.
    assert_eq!(sheet.height(), 161 + layerwise::raster::sheet::LABEL_PX + 8);
    // Each tile's label strip holds black text.
    assert!(
        (0..sheet.width()).any(|x| sheet.get_pixel(x, 6).0 == [0, 0, 0]),
        "no label drawn"
    );
    assert!(
        sheet.pixels().any(|p| p.0 == [0, 255, 0]),
        "no marker drawn"
    );
    // Above the 2-layer build: refused, with the build's top (it reported layer 167 before).
    let err = layerwise()
        .args(["locate", "--point", "10,10,5", "--build"])
        .arg(&build)
        .fails();
    assert!(
        err.contains("above the last layer of the build") && err.contains("layer 2"),
        "{err}"
    );
    // Off the plate: the original frame's pixel is flagged as outside the frame.
    let text = layerwise()
        .args(["locate", "--point", "300,0,0.05", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("outside the 1472 x 982 frame"), "{text}");
    layerwise()
        .args(["locate", "--point", "1,2", "--build"])
        .arg(&build)
        .fails();
    let err = layerwise()
        .args(["locate", "--point", "1,2,3", "--build"])
        .arg(dir.path())
        .fails();
    assert!(err.contains("not a layerwise build directory"), "{err}");
}

#[test]
fn vectors_raster_writes_each_kind_and_names_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let file = shared_cli("frustrum_ASCII.cli");
    for (kind, channels) in [("mask", 1u8), ("rgb", 3), ("exemplar", 1)] {
        let out = dir.path().join(format!("{kind}.png"));
        layerwise()
            .args(["vectors", "raster"])
            .arg(&file)
            .args(["--layer", "10", "--extent", "--kind", kind, "--out"])
            .arg(&out)
            .succeeds();
        let img = image::open(&out).unwrap();
        assert_eq!(img.color().channel_count(), channels, "{kind}");
        // The frustum's layer 10 is about 20 x 20 mm: on the 62.5 µm grid with a 2 mm margin.
        assert!(
            img.width() > 300 && img.width() < 420,
            "{kind}: {}",
            img.width()
        );
    }
    let rgb = image::open(dir.path().join("rgb.png")).unwrap().to_rgb8();
    assert!(rgb.pixels().any(|p| p.0 == [0, 0, 255]), "contours in blue");
    assert!(rgb.pixels().any(|p| p.0 == [255, 0, 0]), "hatches in red");
    let mask = image::open(dir.path().join("mask.png")).unwrap().to_luma8();
    assert!(
        mask.pixels().filter(|p| p.0[0] == 255).count() > 10_000,
        "the layer is filled"
    );
    let err = layerwise()
        .args(["vectors", "raster"])
        .arg(&file)
        .args(["--layer", "101", "--out"])
        .arg(dir.path().join("x.png"))
        .fails();
    assert!(
        err.contains("no vectors for printer layer 101") && err.contains("printer layers 1 to 100"),
        "{err}"
    );
    // Without --extent the layer is drawn on the plate grid, where the rectified views are.
    let plate = dir.path().join("plate.png");
    layerwise()
        .args(["vectors", "raster"])
        .arg(&file)
        .args(["--layer", "10", "--out"])
        .arg(&plate)
        .succeeds();
    assert_eq!(image::image_dimensions(&plate).unwrap(), (4400, 4400));
}

#[test]
fn check_takes_one_test_shot_per_light_through_the_real_path() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(&dir.path().join("build"), 1);
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let shots = dir.path().join("shots");
    let report = layerwise()
        .args(["check", "--json", "--config"])
        .arg(&config_path)
        .arg("--out")
        .arg(&shots)
        .json_ok();
    let layerwise::config::CameraConfig::Mock(mock) = &config.camera else {
        panic!("the demo camera is the mock")
    };
    let (w, h) = (u64::from(mock.width), u64::from(mock.height));
    assert_eq!(report["camera"], format!("mock_camera {w}x{h}"));
    assert_eq!(report["trigger"], "simulated printer");
    let shots_json = report["shots"].as_array().unwrap();
    assert_eq!(shots_json.len(), 3);
    let mut means = Vec::new();
    for (shot, light) in shots_json.iter().zip(["front", "side", "top"]) {
        assert_eq!(shot["light"], light);
        assert!(shot["error"].is_null(), "{shot}");
        assert_eq!(
            (shot["width"].as_u64(), shot["height"].as_u64()),
            (Some(w), Some(h))
        );
        assert!(shots.join(format!("check_{light}.jpg")).exists());
        means.push(shot["mean"].as_f64().unwrap());
    }
    // Each lamp lights the plate differently: the lights were really switched.
    assert!(
        (means[0] - means[1]).abs() > 1e-3 && (means[1] - means[2]).abs() > 1e-3,
        "{means:?}"
    );
    assert!(
        !dir.path().join("build").join("journal.jsonl").exists(),
        "no build was started"
    );
    let text = layerwise()
        .args(["check", "--config"])
        .arg(&config_path)
        .stdout_ok();
    assert!(
        text.contains("light front ok") && text.contains("light top   ok"),
        "{text}"
    );
}
