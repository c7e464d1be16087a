//! The serial trigger through a real pseudo-terminal pair made by socat: the "printer" writes to
//! one end, the trigger (and the daemon) read the other.

use crate::common::pty::{serial_config, PtyPair};
use crate::common::*;
use layerwise::config::TriggerConfig;
use layerwise::hardware::trigger::{SerialTrigger, Trigger};
use layerwise::shot::Phase;
use std::process::Stdio;
use std::time::{Duration, Instant};

#[test]
fn signals_arrive_garbage_is_skipped_and_a_vanished_port_comes_back() {
    let dir = tempfile::tempdir().unwrap();
    let pair = PtyPair::start(dir.path());
    let trigger = SerialTrigger::new(
        serial_config(&pair.daemon),
        layerwise::clock::SystemClock::shared(),
    )
    .unwrap();
    let health = trigger.health();
    let shutdown = layerwise::shutdown::Shutdown::new();
    let events = layerwise::hardware::trigger::spawn(
        Box::new(trigger) as Box<dyn Trigger>,
        health,
        shutdown.clone(),
    );
    let next = |events: &layerwise::hardware::trigger::Events| -> (u32, Phase) {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            match events.receiver().try_recv() {
                Ok(Ok(e @ layerwise::hardware::trigger::LayerEvent { .. })) => {
                    return (e.layer, e.phase)
                }
                Ok(Err(e)) => panic!("trigger error: {e}"),
                Err(_) => {
                    assert!(Instant::now() < deadline, "no event");
                    std::thread::sleep(Duration::from_millis(10));
                }
            }
        }
    };
    std::thread::sleep(Duration::from_millis(200)); // the trigger opens its end
    pair.send(b"LAYER 1 PRE\n\xff\xfe garbage \x00\x01\nLAYER x POST\n");
    pair.send(&[b'z'; 9000]); // no line break for a long time
    pair.send(b"\r\nLAYER 1 POST\r\n");
    assert_eq!(next(&events), (1, Phase::Pre));
    assert_eq!(next(&events), (1, Phase::Post));

    // The USB-serial adapter is unplugged, then plugged back in.
    let printer_path = pair.printer.clone();
    pair.stop();
    std::thread::sleep(Duration::from_millis(300));
    let pair = PtyPair::start(dir.path());
    assert_eq!(pair.printer, printer_path);
    let deadline = Instant::now() + Duration::from_secs(20);
    let event = loop {
        pair.send(b"LAYER 2 PRE\n");
        std::thread::sleep(Duration::from_millis(100));
        if let Ok(Ok(e)) = events.receiver().try_recv() {
            break (e.layer, e.phase);
        }
        assert!(
            Instant::now() < deadline,
            "the trigger did not reopen the port"
        );
    };
    assert_eq!(event, (2, Phase::Pre));
    // The shutdown ends the trigger's thread while it waits on the port (it looks twice a
    // second).
    let asked = Instant::now();
    shutdown.request(layerwise::shutdown::StopReason::TriggerEnded);
    events.join();
    assert!(
        asked.elapsed() < Duration::from_secs(5),
        "the trigger thread did not stop on the shutdown"
    );
    pair.stop();
}

/// `layerwise run` of a 2-layer demo build whose trigger is the daemon end of a new pty pair.
fn daemon_on_a_pty(dir: &std::path::Path) -> (PtyPair, std::path::PathBuf, std::process::Child) {
    let pair = PtyPair::start(dir);
    let build = dir.join("build");
    let mut config = demo_config(&build, 2);
    config.trigger = TriggerConfig::Serial(serial_config(&pair.daemon));
    let config_path = dir.join("layerwise.toml");
    write_config(&config, &config_path);
    let child = spawn_build(&config_path, Stdio::piped());
    (pair, build, child)
}

#[test]
fn the_daemon_captures_on_serial_signals() {
    let dir = tempfile::tempdir().unwrap();
    let (pair, build, child) = daemon_on_a_pty(dir.path());
    std::thread::sleep(Duration::from_millis(500));
    for line in ["LAYER 1 PRE\n", "hello printer\n", "LAYER 1 POST\n"] {
        pair.send(line.as_bytes());
        std::thread::sleep(Duration::from_millis(150));
    }
    wait_for_originals(&build, 6, Duration::from_secs(30));
    let out = terminate(child);
    assert_success(&out);
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(
        log.contains("does not match the protocol") && log.contains("hello printer"),
        "{log}"
    );
    assert_eq!(originals(&build), expected_originals(1));
    pair.stop();
}

#[test]
fn serial_port_vanished_status_says_so_with_the_right_hint() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = demo_config(&build, 2);
    // A port that is not there (the USB adapter unplugged before the daemon started).
    config.trigger = TriggerConfig::Serial(serial_config(&dir.path().join("ttyUSB-unplugged")));
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let child = spawn_build(&config_path, Stdio::piped());
    let status = status_until(&build, "the lost trigger", |s| {
        s["trigger"]["reopen_attempts"].as_u64().unwrap_or(0) >= 2
    });
    assert_eq!(status["trigger"]["connected"], false);
    // The trigger's health: an error with the operator's warning, the same in the summary.
    let trigger = &status["health"]["trigger"];
    assert_eq!(trigger["state"], "error", "{status:#}");
    assert!(
        trigger["summary"]
            .as_str()
            .unwrap_or_default()
            .contains("NOT CONNECTED, last signal none yet"),
        "{trigger}"
    );
    assert!(trigger["warning"]
        .as_str()
        .unwrap_or_default()
        .contains("not connected"));
    let warning = status["warning"].as_str().unwrap_or_default();
    assert!(
        warning.contains("not connected") && warning.contains("USB adapter plugged in"),
        "{warning}"
    );
    assert!(
        !warning.contains("dialout"),
        "a vanished port is not a permission problem: {warning}"
    );
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("NOT CONNECTED"), "{text}");
    let out = terminate(child);
    assert_success(&out);
}

#[test]
fn relay_lights_send_their_command_strings_and_all_off() {
    use layerwise::config::SerialRelayConfig;
    use layerwise::hardware::lights::{Lights, LightsGuard, SerialRelayLights};
    use layerwise::shot::Light;
    use std::io::Read;
    let dir = tempfile::tempdir().unwrap();
    let pair = PtyPair::start(dir.path());
    let commands = [
        ("front_on", r"A1\r\n"),
        ("front_off", r"A0\r\n"),
        ("all_off", r"\x1bX\r\n"),
    ]
    .iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    let config = SerialRelayConfig {
        port: pair.daemon.display().to_string(),
        baud: 9600,
        commands,
    };
    let mut board = std::fs::File::open(&pair.printer).unwrap();
    {
        let mut lights = LightsGuard::new(
            Box::new(SerialRelayLights::open(&config).unwrap()) as Box<dyn Lights>
        );
        lights.switch(Light::Front, true).unwrap();
        lights.switch(Light::Front, false).unwrap();
        assert!(lights
            .switch(Light::Top, true)
            .unwrap_err()
            .to_string()
            .contains("top_on"));
    } // dropped: all off
    let expected = b"A1\r\nA0\r\n\x1bX\r\n";
    let mut got = vec![0u8; expected.len()];
    board.read_exact(&mut got).unwrap();
    assert_eq!(got, expected);
    pair.stop();
}

#[test]
fn a_trigger_port_that_vanishes_mid_build_is_reported_then_comes_back() {
    let dir = tempfile::tempdir().unwrap();
    let (pair, build, child) = daemon_on_a_pty(dir.path());
    std::thread::sleep(Duration::from_millis(500)); // the trigger opens its end
    pair.send(b"LAYER 1 PRE\n");
    wait_for_originals(&build, 3, Duration::from_secs(30));
    status_until(&build, "the trigger connected", |s| {
        s["health"]["trigger"]["state"] == "ok"
    });
    // The USB-serial adapter is unplugged in the middle of the build.
    pair.stop();
    let lost = status_until(&build, "the trigger lost", |s| {
        s["trigger"]["connected"] == false
            && s["trigger"]["reopen_attempts"].as_u64().unwrap_or(0) >= 2
    });
    let trigger = &lost["health"]["trigger"];
    assert_eq!(trigger["state"], "error", "{lost:#}");
    assert!(trigger["summary"]
        .as_str()
        .unwrap_or_default()
        .contains("NOT CONNECTED, last signal "));
    let warning = lost["warning"].as_str().unwrap_or_default();
    assert!(
        warning.contains("not connected") && warning.contains("USB adapter plugged in"),
        "{warning}"
    );
    assert!(!warning.contains("dialout"), "{warning}");
    // Plugged back in: the trigger reconnects, status is ok again, the next signal is captured.
    let pair = PtyPair::start(dir.path());
    let back = status_until(&build, "the trigger back", |s| {
        s["trigger"]["connected"] == true && s["health"]["trigger"]["state"] == "ok"
    });
    assert!(back["warning"].is_null(), "{back:#}");
    pair.send(b"LAYER 1 POST\n");
    wait_for_originals(&build, 6, Duration::from_secs(30));
    let out = terminate(child);
    assert_success(&out);
    assert_eq!(originals(&build), expected_originals(1));
    pair.stop();
}
