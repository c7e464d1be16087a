//! Each part's health through the binary: `status --json` holds a state, a summary and the
//! warning for the trigger, camera, lights, processing and disk, and systemd's STATUS= carries
//! the same one-line summary.

mod common;

use common::*;
use std::os::unix::net::UnixDatagram;
use std::time::Duration;

#[test]
fn status_health_fields_and_a_failed_camera_warning_in_status_and_sd_notify() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = calibrated_config(&build, 2, layerwise::dicom::Compression::Deflate);
    config.rectify.pixel_mm = 2.0;
    // The last frame of the build fails for good: the camera's error stands at the end.
    add_fault(&mut config, "fail", 2, "post", "top", 0, 0);
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    // systemd's notification socket, as the service manager gives it.
    let socket_path = dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&socket_path).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    // Read as systemd does, while the daemon runs (a full socket queue would block it).
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let reader = {
        let done = done.clone();
        std::thread::spawn(move || {
            let mut messages = Vec::new();
            let mut buf = vec![0u8; 65536];
            loop {
                match socket.recv(&mut buf) {
                    Ok(n) => messages.push(String::from_utf8_lossy(&buf[..n]).into_owned()),
                    Err(_) if done.load(std::sync::atomic::Ordering::SeqCst) => break,
                    Err(_) => {}
                }
            }
            messages
        })
    };
    let out = run_command(&config_path)
        .env("NOTIFY_SOCKET", &socket_path)
        .output()
        .unwrap();
    done.store(true, std::sync::atomic::Ordering::SeqCst);
    let messages = reader.join().unwrap();
    assert_success(&out);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("1 missing"),
        "{}",
        report(&out)
    );
    let statuses: Vec<&str> = messages
        .iter()
        .flat_map(|m| m.lines())
        .filter_map(|l| l.strip_prefix("STATUS="))
        .collect();
    assert!(
        statuses
            .iter()
            .any(|s| s.starts_with("running: layer 1 pre") && s.ends_with("all parts ok")),
        "{statuses:#?}"
    );
    let last = statuses.last().expect("STATUS= sent");
    assert!(
        last.contains("camera ERROR: camera failed on L00002_post_top"),
        "{last}"
    );

    let status = layerwise()
        .args(["status", "--json", "--build"])
        .arg(&build)
        .json_ok();
    for part in ["trigger", "camera", "lights", "processing", "disk"] {
        let health = &status["health"][part];
        assert!(
            ["ok", "warning", "error"].contains(&health["state"].as_str().unwrap_or_default()),
            "{part}: {health}"
        );
        assert!(!health["summary"].as_str().unwrap_or_default().is_empty());
    }
    let camera = &status["health"]["camera"];
    assert_eq!(camera["state"], "error");
    assert!(camera["summary"]
        .as_str()
        .unwrap()
        .contains("1 failed this run"));
    assert!(status["warning"]
        .as_str()
        .unwrap_or_default()
        .contains("camera failed on L00002_post_top"));
    assert_eq!(status["health"]["trigger"]["state"], "ok");
    assert!(status["health"]["trigger"]["summary"]
        .as_str()
        .unwrap()
        .contains("connected, last signal "));
    assert_eq!(status["health"]["disk"]["state"], "ok");
    assert_eq!(status["disk"]["state"], "ok");
    // The forecast counts every kind a layer writes, measured on this build.
    let kinds = &status["bytes_by_kind"];
    for kind in ["originals", "dicom", "journal"] {
        assert!(kinds[kind].as_u64().unwrap() > 0, "{kinds}");
    }
    let per_layer = status["bytes_per_layer"].as_u64().unwrap();
    let written: u64 = ["originals", "dicom", "inspection", "push_log", "journal"]
        .iter()
        .map(|k| kinds[*k].as_u64().unwrap())
        .sum();
    assert_eq!(
        per_layer,
        written.div_ceil(2),
        "two layers captured and processed"
    );
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("camera     ERROR"), "{text}");
}
