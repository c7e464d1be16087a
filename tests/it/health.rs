//! Each part's health through the binary: `status --json` holds a state, a summary and the
//! warning for the trigger, camera, lights, processing and disk, and systemd's STATUS= carries
//! the same one-line summary.

use crate::common;
use crate::common::*;
use std::os::unix::net::UnixDatagram;
use std::time::Duration;

/// systemd's notification socket, as the service manager gives it, read as systemd does while
/// the daemon runs (a full socket queue would block it).
struct NotifySocket {
    path: std::path::PathBuf,
    done: std::sync::Arc<std::sync::atomic::AtomicBool>,
    reader: std::thread::JoinHandle<Vec<String>>,
}

impl NotifySocket {
    fn bind(dir: &std::path::Path) -> NotifySocket {
        let path = dir.join("notify.sock");
        let socket = UnixDatagram::bind(&path).unwrap();
        socket
            .set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
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
        NotifySocket { path, done, reader }
    }

    /// Every message received, once the daemon has ended.
    fn messages(self) -> Vec<String> {
        self.done.store(true, std::sync::atomic::Ordering::SeqCst);
        self.reader.join().unwrap()
    }
}

/// The STATUS= lines of systemd notifications.
fn statuses(messages: &[String]) -> Vec<&str> {
    messages
        .iter()
        .flat_map(|m| m.lines())
        .filter_map(|l| l.strip_prefix("STATUS="))
        .collect()
}

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
    let notify = NotifySocket::bind(dir.path());
    let out = run_command(&config_path)
        .env("NOTIFY_SOCKET", &notify.path)
        .output()
        .unwrap();
    let messages = notify.messages();
    assert_success(&out);
    assert!(
        String::from_utf8_lossy(&out.stdout).contains("1 missing"),
        "{}",
        report(&out)
    );
    let statuses = statuses(&messages);
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
            // The run ended: no part is ok any more (issue 27: never green for a daemon that
            // is not running); the disk is measured when shown.
            if part == "disk" {
                &["ok", "warning"][..]
            } else {
                &["stopped", "warning", "error"][..]
            }
            .contains(&health["state"].as_str().unwrap_or_default()),
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
    assert_eq!(status["health"]["trigger"]["state"], "stopped");
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

#[test]
fn status_min_free_gb_defaults_to_the_builds_configuration() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = demo_config(&build, 1);
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    run_build(&config_path);
    let warning = |extra: &[&str]| {
        let status = layerwise()
            .args(["status", "--json", "--build"])
            .arg(&build)
            .args(extra)
            .json_ok();
        status["warning"].as_str().unwrap_or_default().to_string()
    };
    // The build ran with storage.min_free_gb = 0: no disk warning, whatever the disk holds.
    assert!(!warning(&[]).contains("free"), "{}", warning(&[]));
    // The build's configuration (its config.toml snapshot) asks for more than any disk has.
    config.storage.min_free_gb = 1e6;
    write_config(&config, &build.join(layerwise::build_dir::CONFIG_SNAPSHOT));
    let low = warning(&[]);
    assert!(
        low.contains("GB free") || low.contains("GB are free"),
        "{low}"
    );
    assert!(
        low.contains("1000000.0 GB") || low.contains("only"),
        "{low}"
    );
    // The flag overrides it.
    assert!(!warning(&["--min-free-gb", "0"]).contains("free"));
    // A bad flag is refused with what was expected.
    let err = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .arg("--min-free-gb=-1")
        .fails();
    assert!(err.contains("--min-free-gb"), "{err}");
}

#[test]
fn lights_that_fail_mid_build_show_in_status_and_sd_notify() {
    use crate::common::pty::PtyPair;
    let dir = tempfile::tempdir().unwrap();
    let (printer_dir, relay_dir) = (dir.path().join("printer"), dir.path().join("relay"));
    std::fs::create_dir_all(&printer_dir).unwrap();
    std::fs::create_dir_all(&relay_dir).unwrap();
    let printer = PtyPair::start(&printer_dir);
    // The relay board on a serial line of its own; it is unplugged after the first signal.
    let relay = PtyPair::start(&relay_dir);
    let board = common::pty::PtyReader::start(&relay.printer);
    let build = dir.path().join("build");
    let mut config = demo_config(&build, 2);
    config.trigger =
        layerwise::config::TriggerConfig::Serial(common::pty::serial_config(&printer.daemon));
    let commands = ["front", "side", "top"]
        .iter()
        .flat_map(|l| {
            [
                (format!("{l}_on"), format!("{l}1\\n")),
                (format!("{l}_off"), format!("{l}0\\n")),
            ]
        })
        .chain([("all_off".to_string(), "X\\n".to_string())])
        .collect();
    config.lights =
        layerwise::config::LightsConfig::SerialRelay(layerwise::config::SerialRelayConfig {
            port: relay.daemon.display().to_string(),
            baud: 9600,
            commands,
        });
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let notify = NotifySocket::bind(dir.path());
    let child = run_command(&config_path)
        .env("NOTIFY_SOCKET", &notify.path)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(500)); // the trigger opens its end
    printer.send(b"LAYER 1 PRE\n");
    wait_for_originals(&build, 3, Duration::from_secs(30));
    board.wait_for("top0", Duration::from_secs(10));
    let ok = status_until(&build, "the lights switching", |s| {
        s["health"]["lights"]["state"] == "ok"
    });
    assert_eq!(ok["health"]["lights"]["summary"], "switching");
    relay.stop();
    printer.send(b"LAYER 1 POST\n");
    let status = status_until(&build, "the lights failing", |s| {
        s["health"]["lights"]["state"] == "error"
    });
    let lights = &status["health"]["lights"];
    assert_eq!(lights["summary"], "switching failed", "{lights}");
    let warning = lights["warning"].as_str().unwrap_or_default();
    assert!(
        warning.starts_with("lights: ") && warning.contains("check the relay board"),
        "{warning}"
    );
    assert!(
        status["warning"]
            .as_str()
            .unwrap_or_default()
            .contains("check the relay board"),
        "{status:#}"
    );
    // The frames the lights could not light are missing, with the reason.
    let missing = status_until(&build, "the missing frames", |s| s["frames_missing"] == 3);
    assert!(missing["missing"][0]
        .as_str()
        .unwrap_or_default()
        .contains("light did not switch on"));
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("lights     ERROR"), "{text}");
    let out = terminate(child);
    assert_success(&out);
    let messages = notify.messages();
    let last = *statuses(&messages).last().expect("STATUS= sent");
    assert!(last.contains("lights ERROR"), "{last}");
    printer.stop();
}

/// The simulated camera, failing every capture of a shot it has taken once (each retake).
struct FailsRetakes {
    inner: Box<dyn layerwise::hardware::camera::Camera>,
    taken: std::collections::BTreeSet<layerwise::shot::Shot>,
}

impl layerwise::hardware::camera::Camera for FailsRetakes {
    fn capture(
        &mut self,
        shot: &layerwise::shot::Shot,
    ) -> Result<layerwise::hardware::camera::Frame, layerwise::hardware::camera::CameraError> {
        use layerwise::hardware::camera::{CameraError, DriverError};
        if !self.taken.insert(*shot) {
            return Err(CameraError::Failed(DriverError::said("shutter stuck")));
        }
        self.inner.capture(shot)
    }
    fn reopen(&mut self) -> Result<(), layerwise::hardware::camera::CameraError> {
        self.inner.reopen()
    }
    fn settings(&self) -> std::collections::BTreeMap<String, String> {
        self.inner.settings()
    }
    fn describe(&self) -> String {
        self.inner.describe()
    }
}

#[test]
fn a_retake_the_camera_fails_is_not_counted_missing_by_the_run_or_the_plant() {
    use layerwise::hardware::camera::CameraError;
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 1);
    // Layer 1's post signal comes twice: its three views are taken again, and fail.
    mock_printer(
        &mut config,
        dir.path(),
        "LAYER 1 PRE\nLAYER 1 POST\nLAYER 1 POST\n",
    );
    let mut options = layerwise::acquisition::RunOptions::new();
    options.drain_at_end = true;
    let summary = run_daemon_with(&config, options, |machine, _| {
        let open = std::mem::replace(
            &mut machine.camera,
            Box::new(|| Err(CameraError::Lost("replaced".into()))),
        );
        machine.camera = Box::new(move || {
            Ok(Box::new(FailsRetakes {
                inner: open()?,
                taken: Default::default(),
            }) as Box<_>)
        });
    })
    .unwrap();
    // Before, the run's summary (its last log line, STATUS=) and the plant counted 3 missing
    // frames that `status` did not: each shot has its frame.
    assert_eq!(
        (summary.stored, summary.retakes, summary.missing),
        (6, 0, 0)
    );
    let status = layerwise()
        .args(["status", "--json", "--build"])
        .arg(dir.path())
        .json_ok();
    assert_eq!(status["frames_missing"], 0, "{status}");
    // The failed retakes are journaled all the same.
    let text = std::fs::read_to_string(dir.path().join("journal.jsonl")).unwrap();
    assert_eq!(text.matches(r#""kind":"missing""#).count(), 3, "{text}");
}
