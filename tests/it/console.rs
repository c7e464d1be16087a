//! The operator's console through the binary: every state a person reads (`status`, `alarm`,
//! the page's `/api/status`) is derived from the build's files and the clock when it is shown;
//! a folder that is not a build is an error; a damaged file never hides the alarm.

use crate::common::*;
use layerwise::build_dir::alarm::{AlarmEvent, AlarmLog};
use layerwise::build_dir::inspection::{FlagKind, Severity};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A finished two-layer mock build in `tmp/build`.
fn finished(tmp: &Path) -> PathBuf {
    let dir = tmp.join("build");
    let config_path = tmp.join("layerwise.toml");
    write_config(
        &calibrated_config(&dir, 2, layerwise::dicom::Compression::None),
        &config_path,
    );
    run_build(&config_path);
    dir
}

/// The alarm raised at layer 2, as the daemon's alarm thread appends it.
fn raise_alarm(build: &Path) {
    let path = build.join(layerwise::build_dir::ALARM);
    AlarmLog::append_only(&path)
        .unwrap()
        .append(&AlarmEvent::Raised {
            at: chrono::Utc::now(),
            layer: 2,
            kind: FlagKind::UnderFusion,
            severity: Severity::Critical,
            message: "part 3: 91% of its core unfused".into(),
        })
        .unwrap();
}

/// Rewrites status.json through `change`, as a daemon would have left it.
fn edit_status(build: &Path, change: impl FnOnce(&mut serde_json::Value)) {
    let path = build.join(layerwise::build_dir::STATUS);
    let mut status = read_json(&path);
    change(&mut status);
    std::fs::write(&path, serde_json::to_vec_pretty(&status).unwrap()).unwrap();
}

fn status_text(build: &Path) -> String {
    layerwise()
        .args(["status", "--build"])
        .arg(build)
        .stdout_ok()
}

fn status_json(build: &Path) -> serde_json::Value {
    layerwise()
        .args(["status", "--json", "--build"])
        .arg(build)
        .json_ok()
}

/// A process id that belonged to a process that has ended.
fn dead_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn alarm_show_and_ack_refuse_a_folder_that_is_not_a_build() {
    let tmp = tempfile::tempdir().unwrap();
    let missing = tmp.path().join("no-such-build");
    let err = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&missing)
        .fails();
    assert!(err.contains("not a layerwise build directory"), "{err}");
    let err = layerwise()
        .args(["alarm", "ack", "--build"])
        .arg(tmp.path())
        .fails();
    assert!(err.contains("not a layerwise build directory"), "{err}");
    assert!(!err.contains("not raised"), "{err}");
    // A build without an alarm: nothing to acknowledge, and show says off.
    let build = finished(tmp.path());
    let err = layerwise()
        .args(["alarm", "ack", "--build"])
        .arg(&build)
        .fails();
    assert!(err.contains("the alarm is not raised (it is off)"), "{err}");
    let shown = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&build)
        .stdout_ok();
    assert_eq!(shown.trim(), "alarm off");
    // Control characters in a note are refused (one line of text, nothing for a terminal).
    raise_alarm(&build);
    let err = layerwise()
        .args(["alarm", "ack", "--note", "ok\u{1b}]0;pwned\u{7}", "--build"])
        .arg(&build)
        .fails();
    assert!(err.contains("control characters"), "{err}");
}

/// What an alarm note or message may hold when alarm.jsonl was written by hand or by another
/// tool: a title change, a clear screen, a right-to-left override, a line break.
const HOSTILE: &str = "ok\u{1b}]0;pwned\u{7}\u{1b}[2J\u{202e}gpj.exe\r\nforged line";

/// Checks that no line of `shown` holds a character a terminal acts on (or hides), and that
/// the hostile text is there, written out.
fn printed_escaped(what: &str, shown: &str) {
    for line in shown.lines() {
        assert!(
            !line.chars().any(layerwise::logging::is_hidden_char),
            "{what} printed a raw control or bidirectional character: {line:?}"
        );
    }
    assert!(
        shown.contains("ok\\u{1b}]0;pwned\\u{7}\\u{1b}[2J\\u{202e}gpj.exe\\r\\nforged line"),
        "{what}: {shown}"
    );
    assert!(
        !shown.lines().any(|l| l.starts_with("forged line")),
        "{what}: {shown}"
    );
}

/// The finding: alarm notes reached the terminal raw through `status` and `alarm show`, escape
/// sequences included. A message and a note written into alarm.jsonl (as another tool or a
/// hand edit could) are printed escaped, one line each.
#[test]
fn alarm_notes_with_escape_sequences_are_printed_escaped_by_alarm_show_and_status() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    let path = build.join(layerwise::build_dir::ALARM);
    let raised = AlarmEvent::Raised {
        at: chrono::Utc::now(),
        layer: 2,
        kind: FlagKind::UnderFusion,
        severity: Severity::Critical,
        message: HOSTILE.into(),
    };
    let line = |event: &AlarmEvent| serde_json::to_string(event).unwrap() + "\n";
    std::fs::write(&path, line(&raised)).unwrap();
    let show = || {
        layerwise()
            .args(["alarm", "show", "--build"])
            .arg(&build)
            .stdout_ok()
    };
    printed_escaped("alarm show (raised)", &show());
    printed_escaped("status (raised)", &status_text(&build));
    let acknowledged = AlarmEvent::Acknowledged {
        at: chrono::Utc::now(),
        by: "op\u{1b}[31m".into(),
        note: Some(HOSTILE.into()),
    };
    std::fs::write(&path, line(&raised) + &line(&acknowledged)).unwrap();
    let shown = show();
    printed_escaped("alarm show (acknowledged)", &shown);
    assert!(shown.contains("op\\u{1b}[31m"), "{shown}");
    printed_escaped("status (acknowledged)", &status_text(&build));
}

#[test]
fn status_with_a_damaged_alarm_log_still_shows_the_alarm() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    raise_alarm(&build);
    let path = build.join(layerwise::build_dir::ALARM);
    let mut text = std::fs::read_to_string(&path).unwrap();
    text.push_str("{\"event\":\"acknowl\u{0}\n");
    text.push_str(&std::fs::read_to_string(&path).unwrap());
    std::fs::write(&path, text).unwrap();

    let out = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .output()
        .unwrap();
    let err = assert_exit_1(&out);
    let shown = String::from_utf8_lossy(&out.stdout);
    assert!(
        shown.contains("alarm      UNKNOWN, treat it as RAISED")
            && shown.contains("alarm.jsonl line 2 is damaged"),
        "{shown}"
    );
    assert!(shown.contains("DAMAGED    "), "{shown}");
    assert!(
        shown.contains("frames     12 stored"),
        "the rest is shown: {shown}"
    );
    assert!(err.contains("cannot be read"), "{err}");
    let out = layerwise()
        .args(["status", "--json", "--build"])
        .arg(&build)
        .output()
        .unwrap();
    assert_exit_1(&out);
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["alarm"]["state"], "unreadable", "{report:#}");
    assert!(report["warning"]
        .as_str()
        .unwrap()
        .contains("the inspection alarm needs an operator"));
    // alarm show refuses the file as before; the page shows the alarm's state unknown.
    let err = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&build)
        .fails();
    assert!(err.contains("damaged"), "{err}");
    let (_served, addr) = serve(&build, &[]);
    let page = get_json(addr, "/api/status");
    assert_eq!(page["alarm"]["state"], "unreadable", "{page:#}");
}

#[test]
fn status_of_a_stopped_daemon_is_never_green_and_its_ages_count_to_now() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    let before = chrono::Utc::now() - chrono::Duration::seconds(250);
    edit_status(&build, |s| {
        s["updated_at"] = serde_json::json!(before);
        s["trigger"]["last_signal_at"] = serde_json::json!(before);
        s["camera"]["last_capture_at"] = serde_json::json!(before);
    });
    let report = status_json(&build);
    assert_eq!(report["state"], "stopped", "{report:#}");
    assert_eq!(report["running"], false, "{report:#}");
    assert!(
        report["last_update"]
            .as_str()
            .unwrap()
            .starts_with("last update "),
        "{report:#}"
    );
    for part in ["trigger", "camera", "lights", "processing"] {
        let h = &report["health"][part];
        assert_eq!(h["state"], "stopped", "{part}: {h}");
        assert!(
            h["summary"].as_str().unwrap().ends_with(", daemon stopped"),
            "{part}: {h}"
        );
    }
    let camera = report["health"]["camera"]["summary"].as_str().unwrap();
    assert!(camera.starts_with("last capture 4 min ago"), "{camera}");
    let trigger = report["health"]["trigger"]["summary"].as_str().unwrap();
    assert!(trigger.contains("last signal 4 min ago"), "{trigger}");
    assert!(report["health"]["disk"]["summary"]
        .as_str()
        .unwrap()
        .ends_with(" free now"));
    let text = status_text(&build);
    assert!(text.contains("4 min ago)"), "{text}");
    assert!(
        text.contains("  camera     stopped last capture 4 min ago"),
        "{text}"
    );
    assert!(!text.contains(" ok      "), "{text}");
}

#[test]
fn status_of_a_killed_daemon_says_it_is_not_running() {
    let tmp = tempfile::tempdir().unwrap();
    let build = tmp.path().join("build");
    let mut config = calibrated_config(&build, 500, layerwise::dicom::Compression::None);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 200;
    }
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let mut child = spawn_build(&config_path, std::process::Stdio::null());
    let running = status_until(&build, "a few frames", |s| {
        s["frames"].as_u64().unwrap_or(0) >= 6 && s["health"]["camera"]["state"] == "ok"
    });
    assert_eq!(running["state"], "running");
    child.kill().unwrap();
    child.wait().unwrap();
    let report = status_json(&build);
    assert!(
        report["state"]
            .as_str()
            .unwrap()
            .starts_with("not running (the daemon stopped without a clean shutdown)"),
        "{report:#}"
    );
    assert!(
        report["warning"]
            .as_str()
            .unwrap()
            .contains("the daemon is not running"),
        "{report:#}"
    );
    for part in ["trigger", "camera", "lights", "processing"] {
        assert_ne!(report["health"][part]["state"], "ok", "{part}: {report:#}");
    }
}

#[test]
fn status_after_a_full_disk_freed_shows_the_space_measured_now() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    // The daemon died while it waited for space (1.2 MB free); the disk was freed since.
    let pid = dead_pid();
    edit_status(&build, |s| {
        s["state"] = "running".into();
        s["pid"] = pid.into();
        s["disk"] = serde_json::json!({
            "state": "full", "free_bytes": 1_200_000u64, "min_free_bytes": 0,
            "need_bytes": 400_000_000u64, "since": chrono::Utc::now(), "frames_missed": 3,
            "derived_paused": true, "journal_held": 0
        });
        s["health"]["disk"] = serde_json::json!({
            "state": "error", "summary": "full, 3 frames missed",
            "warning": "waiting for disk space: 1.2 MB free, need 400.0 MB; 3 frames missed so far; free space on the build disk now"
        });
    });
    let text = status_text(&build);
    assert!(!text.contains("waiting for disk space"), "{text}");
    assert!(!text.contains("1.2 MB"), "{text}");
    let disk = text
        .lines()
        .find(|l| l.starts_with("  disk "))
        .unwrap_or_else(|| panic!("no disk health line: {text}"));
    assert!(
        disk.contains(" free now") && !disk.contains("ERROR"),
        "{disk}\n{text}"
    );
    assert!(text.contains("daemon     not running"), "{text}");
}

#[test]
fn serve_clears_the_alarm_banner_after_alarm_ack_without_a_restart() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    raise_alarm(&build);
    let (_served, addr) = serve(&build, &[]);
    assert_eq!(get_json(addr, "/api/status")["alarm"]["state"], "raised");
    layerwise()
        .args(["alarm", "ack", "--by", "ana", "--build"])
        .arg(&build)
        .succeeds();
    let acked = Instant::now();
    loop {
        let alarm = get_json(addr, "/api/status")["alarm"].clone();
        if alarm["state"] == "acknowledged" {
            assert_eq!(alarm["by"], "ana");
            break;
        }
        assert!(
            acked.elapsed() < Duration::from_secs(2),
            "the page still shows {alarm} 2 s after the acknowledgement"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A page's acknowledgement names the raise it showed (its layer and time): a page that had not
/// yet shown the alarm raised again does not switch that one off unseen; and a page under another
/// name than the machine's own is refused (DNS rebinding).
#[test]
fn a_page_acknowledgement_of_an_earlier_raise_does_not_acknowledge_the_new_one() {
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    raise_alarm(&build);
    let (_served, addr) = serve(&build, &[]);
    assert_eq!(get_json(addr, "/api/status")["alarm"]["layer"], 2);
    let (code, body) = http(addr, "POST", "/api/alarm/ack", br#"{"by":"ana","layer":1}"#);
    let text = String::from_utf8_lossy(&body);
    assert_eq!(code, 409, "{text}");
    assert!(
        text.contains("raised again (layer 2, at") && text.contains("raise of layer 1"),
        "{text}"
    );
    assert_eq!(get_json(addr, "/api/status")["alarm"]["state"], "raised");
    // A site whose name resolves to 127.0.0.1 (DNS rebinding) is refused, without a token too.
    let ack = br#"{"by":"mallory","layer":2}"#;
    for path in ["/api/status", "/api/alarm/ack"] {
        let method = if path.ends_with("ack") { "POST" } else { "GET" };
        let (code, _, body) = http_with(addr, method, path, "Host: evil.example:80\r\n", ack);
        let text = String::from_utf8_lossy(&body);
        assert_eq!(code, 403, "{path}: {text}");
        assert!(text.contains("DNS rebinding"), "{text}");
    }
    let port = format!("Host: 127.0.0.1:{}\r\n", addr.port());
    assert_eq!(http_with(addr, "GET", "/api/status", &port, b"").0, 200);
    // The name a reverse proxy sends, when allowed.
    let (_proxied, behind) = serve(&build, &["--allowed-host", "printer-7.shop.example"]);
    let proxy = "Host: Printer-7.shop.example:443\r\n";
    assert_eq!(http_with(behind, "GET", "/api/status", proxy, b"").0, 200);
    let other = "Host: evil.example\r\n";
    assert_eq!(http_with(behind, "GET", "/api/status", other, b"").0, 403);
    // The same layer raised at another time is another raise.
    let earlier = br#"{"by":"ana","layer":2,"raised_at":"2020-01-01T00:00:00Z"}"#;
    let (code, body) = http(addr, "POST", "/api/alarm/ack", earlier);
    assert_eq!(code, 409, "{}", String::from_utf8_lossy(&body));
    let at = get_json(addr, "/api/status")["alarm"]["at"].clone();
    let ack = serde_json::json!({"by": "ana", "layer": 2, "raised_at": at}).to_string();
    let (code, body) = http(addr, "POST", "/api/alarm/ack", ack.as_bytes());
    assert_eq!(code, 200, "{}", String::from_utf8_lossy(&body));
    assert_eq!(get_json(addr, "/api/status")["alarm"]["by"], "ana");
}

#[test]
fn push_forget_drops_a_mistaken_destination_from_status() {
    use layerwise::build_dir::pushlog::{log_path, PushLog, PushRecord};
    let tmp = tempfile::tempdir().unwrap();
    let build = finished(tmp.path());
    // Two mistaken destinations, as a push to them left them: nothing confirmed, an error.
    let url = "http://10.0.0.99:8042/dicom-web";
    let url_name = layerwise::pacs::Destination::resolve(url, &[])
        .unwrap()
        .name;
    for name in ["orthanc-typo", url_name.as_str()] {
        let (mut log, _) = PushLog::open(&log_path(&build, name)).unwrap();
        log.append(&PushRecord::Error {
            // An archive's answer that would retitle and clear the operator's terminal.
            message: "connection refused\u{1b}]0;pwned\u{7}\u{1b}[2J".into(),
            at: chrono::Utc::now(),
        })
        .unwrap();
    }
    let before = status_text(&build);
    assert!(
        !before.contains('\u{1b}') && !before.contains('\u{7}'),
        "{before:?}"
    );
    assert!(
        before.contains("connection refused\\u{1b}]0;pwned"),
        "{before}"
    );
    assert!(
        before.contains("pacs       orthanc-typo: 0 pushed, 12 pending"),
        "{before}"
    );
    let err = layerwise()
        .args(["push", "forget", "--to", "orthanc", "--build"])
        .arg(&build)
        .fails();
    assert!(
        err.contains("no push log for orthanc") && err.contains("orthanc-typo"),
        "{err}"
    );
    let said = layerwise()
        .args(["push", "forget", "--to", "orthanc-typo", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(
        said.starts_with("forgot orthanc-typo (0 pushed, 12 pending)"),
        "{said}"
    );
    layerwise()
        .args(["push", "forget", "--to", url, "--build"])
        .arg(&build)
        .succeeds();
    let after = status_text(&build);
    assert!(!after.contains("pacs "), "{after}");
    let kept = std::fs::read_dir(build.join("pacs/forgotten"))
        .unwrap()
        .count();
    assert_eq!(kept, 2, "the logs are kept aside");
    // `push` itself still takes its flags.
    let err = layerwise().args(["push"]).output().unwrap();
    assert!(String::from_utf8_lossy(&err.stderr).contains("--build"));
}

/// A listening socket on a free loopback port, held for the test.
fn taken_port() -> (std::net::TcpListener, String) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    (listener, addr)
}

#[test]
fn demo_and_serve_refuse_a_busy_port_naming_listen() {
    let tmp = tempfile::tempdir().unwrap();
    let (_held, addr) = taken_port();
    let out = tmp.path().join("demo");
    let err = layerwise()
        .args(["demo", "--layers", "2", "--listen", &addr, "--out"])
        .arg(&out)
        .fails();
    assert!(
        err.contains(&format!(
            "cannot listen on {addr}: give --listen a free address"
        )),
        "{err}"
    );
    assert!(
        !out.join(layerwise::build_dir::JOURNAL).exists(),
        "no build without its page"
    );
    let build = finished(tmp.path());
    let err = layerwise()
        .args(["serve", "--listen", &addr, "--build"])
        .arg(&build)
        .fails();
    assert!(err.contains("give --listen a free address"), "{err}");
    assert!(!err.contains("web.listen"), "{err}");
}

#[test]
fn demo_keeps_its_page_open_after_the_last_layer_until_sigterm() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("demo");
    let mut child = layerwise()
        .args(["demo", "--layers", "2", "--listen", "127.0.0.1:0", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    // The demo's own words up to its last line, "the page stays at …", while the page is up.
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for line in std::io::BufReader::new(stdout)
            .lines()
            .map_while(Result::ok)
        {
            let _ = tx.send(line);
        }
    });
    let mut lines = Vec::new();
    while !lines
        .last()
        .is_some_and(|l: &String| l.starts_with("the page stays at"))
    {
        let line = rx
            .recv_timeout(Duration::from_secs(120))
            .unwrap_or_else(|_| panic!("the demo said only {lines:?}"));
        lines.push(line);
    }
    let addr: std::net::SocketAddr = lines
        .iter()
        .find_map(|l| l.strip_prefix("operator page: http://"))
        .and_then(|a| a.strip_suffix('/'))
        .expect("the page's address")
        .parse()
        .unwrap();
    assert!(
        lines.iter().any(|l| l.contains("12 frames stored")),
        "{lines:?}"
    );
    let status = lines
        .iter()
        .find(|l| l.starts_with("status: "))
        .expect("the closing hint");
    // The hint names a command that runs from here (the test's binary is not on the PATH).
    assert!(
        status.starts_with(&format!(
            "status: {} status --build",
            env!("CARGO_BIN_EXE_layerwise")
        )),
        "{status}"
    );
    // The page follows the files within its watch (a quarter second, the status at most once a
    // second).
    let ended = Instant::now();
    loop {
        let report = get_json(addr, "/api/status");
        if report["frames"] == 12 && report["state"] == "stopped" {
            break;
        }
        assert!(ended.elapsed() < Duration::from_secs(3), "{report:#}");
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = terminate(child);
    assert_success(&out);
}

#[test]
fn config_errors_point_at_the_bad_keys_own_line_and_builds_dir_needs_no_output_dir() {
    let tmp = tempfile::tempdir().unwrap();
    let demo = layerwise::config::DEMO_CONFIG;
    let check = |text: &str| {
        let path = tmp.path().join("layerwise.toml");
        std::fs::write(&path, text).unwrap();
        let mut command = layerwise();
        command.arg("check-config").arg(&path);
        command
    };
    // The error names the bad key's own line: (changed text, the line's start, what it says).
    let cases = [
        // An unknown key in a section chosen by its kind (the parser names only the section).
        (
            demo.replacen("seed = 7\n", "seed = 7\nisoo = 100\n", 1),
            "isoo",
            "key `camera`: unknown field `isoo`",
        ),
        // A value a section's check refuses.
        (
            demo.replacen("queue_capacity = 16", "queue_capacity = 0", 1),
            "queue_capacity",
            "key `storage.queue_capacity`",
        ),
    ];
    for (text, start, says) in cases {
        let line = 1 + text
            .lines()
            .position(|l| l.starts_with(start))
            .unwrap_or_else(|| panic!("no {start}"));
        let err = check(&text).fails();
        assert!(err.contains(&format!("line {line}: {says}")), "{err}");
    }
    // builds_dir alone: no output_dir wanted.
    let builds = demo
        .replacen("output_dir = \"demo-build\"\n", "", 1)
        .replacen("[build]\n", "[build]\nbuilds_dir = \"/srv/builds\"\n", 1);
    let said = check(&builds).stdout_ok();
    assert!(said.contains("builds in /srv/builds"), "{said}");
}

/// Headless Chromium, two windows on `serve` behind a token (tests/console_browser.py): a link
/// `#layer=N` opens layer N, next/previous flag step between the flagged layers, the alarm
/// acknowledged on one page clears the banner of the other within 2 s and shows in the history;
/// the acknowledgement is the one `alarm show` reads. On the layer with three flags no two
/// labels overlap and each flag says what to do; a view zooms to 1:1 and 2:1; a link to a view
/// and a flag opens it. Screenshots are kept in target/test-artifacts: console-alarm.png,
/// console-acknowledged.png, console-flags.png and console-zoom.png.
#[test]
fn a_browser_acknowledges_the_alarm_and_steps_between_flags() {
    let chromedriver = chromedriver();
    let tmp = tempfile::tempdir().unwrap();
    let build = tmp.path().join("build");
    let (first, second) = (3, 6);
    // Layer `first` has three flags or more on one view, two labels close together: the
    // unfused box with spatter just above its far edge (part 3 is the 20 x 12 mm box at 40..60,
    // 44..56 mm), and the unfused cylinder (part 1).
    let inject = [
        format!("no-fusion@{first}/part=3"),
        format!("spatter@{first}/n=3/x=47/y=58.5/r=0.8"),
        format!("no-fusion@{first}/part=1"),
        format!("no-fusion@{second}/part=3"),
    ];
    let inject: Vec<&str> = inject.iter().map(String::as_str).collect();
    // 14 layers: the trends' baseline band needs 10 (inspection.drift_min_layers).
    let config = crate::web::injected_config(&build, 14, &inject);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    run_build(&config_path);
    let shown = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(shown.contains("RAISED"), "{shown}");
    let token = tmp.path().join("token");
    std::fs::write(&token, "console-token-0123456789\n").unwrap();
    let (served, addr) = serve(&build, &["--token-file", token.to_str().unwrap()]);
    // Without the token the page refuses an acknowledgement.
    let (code, _) = http(addr, "POST", "/api/alarm/ack", br#"{"by":"mallory"}"#);
    assert_eq!(code, 401);
    let artifacts = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-artifacts");
    std::fs::create_dir_all(&artifacts).unwrap();
    let out = std::process::Command::new("python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/console_browser.py"))
        .arg(format!("http://{addr}/?token=console-token-0123456789"))
        .arg(chromedriver)
        .arg(&artifacts)
        .args([first, second].map(|l| l.to_string()))
        .arg(served.pid().to_string())
        .arg(&build)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", report(&out));
    println!("{}", String::from_utf8_lossy(&out.stdout));
    let shown = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(
        shown.contains("acknowledged by ana") && shown.contains("checking part 3"),
        "{shown}"
    );
}
