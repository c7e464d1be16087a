//! The OPC UA server against the PyPI asyncua client (tests/opcua_client.py), each test in a
//! private network namespace: a client browses the printer, reads the current layer as it
//! advances, subscribes to it and to the alarm's condition events, and acknowledges a raised
//! alarm (refused without a name and for a stale event id), which `layerwise alarm show` then
//! reports; a flood of subscriptions and monitored items is refused beyond the limits, and a
//! flood of connections and garbage neither stops capture nor grows memory.

use crate::common::*;
use layerwise::config::{CameraConfig, Config, LightsConfig};
use std::io::Write;
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

const PORT: u16 = 48400;
const USER: &str = "ana";
const PASSWORD: &str = "layer-by-layer";

fn url() -> String {
    format!("opc.tcp://127.0.0.1:{PORT}")
}

/// A calibrated mock build of `layers` layers whose part 3 is left unfused at layer 6 (a
/// critical flag, the alarm raised), served over OPC UA; the printer pauses `pause_ms` between
/// signals and holds the daemon after the last layer.
fn config(tmp: &Path, layers: u32, pause_ms: u64) -> (PathBuf, PathBuf) {
    let dir = tmp.join("build");
    let mut config: Config = calibrated_config(&dir, layers, layerwise::dicom::Compression::None);
    let (w, h) = (640, 427);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = w;
        mock.height = h;
        mock.inject = vec!["no-fusion@6/part=3".parse().expect("injection")];
    }
    config.calibration.file = Some(write_true_calibration(
        tmp,
        &mock_camera::Homography::oblique_view(w, h),
    ));
    let vectors = tmp.join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, layers).expect("vectors");
    config.build.vectors = Some(vectors);
    config.inspection.alarm.output = LightsConfig::Mock;
    config.web.listen = String::new();
    config.opcua.listen = url();
    config.opcua.pki_dir = tmp.join("pki");
    let users = tmp.join("opcua-users");
    std::fs::write(
        &users,
        format!("# who may acknowledge\n{USER}:{PASSWORD}\n"),
    )
    .unwrap();
    config.opcua.users_file = Some(users);
    config.opcua.printer.serial_number = "PX320-0042".into();
    printer_script(&mut config, tmp, layers, pause_ms, 600_000);
    let path = tmp.join("layerwise.toml");
    write_config(&config, &path);
    (path, dir)
}

/// Runs tests/opcua_client.py with `args`; its JSON summary. On a failure, the daemon's log
/// (`log`) is shown with the client's output.
fn client(args: &[&str], log: Option<&Path>) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/opcua_client.py");
    let out = Command::new(python())
        .arg(script)
        .args(args)
        .output()
        .expect("python runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "opcua_client.py {args:?}: {}\n{stdout}\nthe daemon's log:\n{}",
        String::from_utf8_lossy(&out.stderr),
        log.and_then(|l| std::fs::read_to_string(l).ok())
            .unwrap_or_default()
    );
    serde_json::from_str(stdout.lines().last().unwrap_or_default())
        .unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

/// The daemon, killed when the test ends early (so no daemon outlives a failed test).
struct Daemon(Option<std::process::Child>);

impl Daemon {
    fn start(config: &Path, stderr: Stdio) -> Daemon {
        Daemon(Some(spawn_build(config, stderr)))
    }

    fn id(&self) -> u32 {
        self.0.as_ref().map_or(0, |c| c.id())
    }

    fn stop(mut self) {
        assert_success(&terminate(self.0.take().unwrap()));
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Some(mut child) = self.0.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

fn wait_for_server() {
    wait_until(
        "the OPC UA server listening",
        Duration::from_secs(30),
        || TcpStream::connect(("127.0.0.1", PORT)).is_ok(),
    );
}

/// Browse, read as it advances, subscribe, acknowledge: what a SCADA client does.
#[test]
fn the_asyncua_client_reads_the_layer_subscribes_and_acknowledges_the_alarm() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let layers = 10;
    let (config, dir) = config(tmp.path(), layers, 400);
    let log = tmp.path().join("daemon.log");
    let daemon = Daemon::start(&config, Stdio::from(std::fs::File::create(&log).unwrap()));
    wait_for_server();
    let out = client(&["session", &url(), USER, PASSWORD], Some(&log));

    println!("{out}");
    let children: Vec<&str> = out["printer_children"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|c| c.as_str())
        .collect();
    for want in [
        "Identification",
        "Components",
        "Production",
        "Monitoring",
        "InspectionAlarm",
    ] {
        assert!(children.contains(&want), "{want} in {children:?}");
    }
    assert_eq!(out["manufacturer"], "3D Systems", "{out}");
    assert_eq!(out["model"], "ProX320", "{out}");
    assert_eq!(out["camera_model"], "D810", "{out}");
    assert_eq!(out["job_name"], "demo-build", "{out}");
    assert_eq!(out["job_state"], "Running", "{out}");
    let increasing = |key: &str| {
        let values: Vec<u64> = out[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_u64().unwrap())
            .collect();
        assert!(values.len() >= 3, "{key}: {values:?}");
        assert!(values.windows(2).all(|w| w[0] < w[1]), "{key}: {values:?}");
        assert!(
            values.iter().all(|&v| v <= u64::from(layers)),
            "{key}: {values:?}"
        );
    };
    increasing("reads");
    increasing("subscribed");
    assert_eq!(out["alarm_kind"], "under_fusion", "{out}");
    assert_eq!(out["alarm_layer"], 6, "{out}");
    assert!(
        out["raise_event"]["severity"].as_u64().unwrap() >= 800,
        "{out}"
    );
    assert!(
        out["raise_event"]["message"]
            .as_str()
            .unwrap()
            .contains("layer 6: under_fusion"),
        "{out}"
    );
    let raise = &out["raise_event"];
    assert_eq!(raise["active"], true, "{out}");
    assert_eq!(raise["acked"], false, "{out}");
    assert_eq!(raise["retain"], true, "{out}");
    assert_eq!(raise["condition"], "InspectionAlarm", "{out}");
    // What docs/opcua.md says asyncua's default AlarmConditionType filter lacks.
    assert_eq!(
        out["unresolved_fields"],
        serde_json::json!(["(ConditionId)"]),
        "{out}"
    );
    assert_eq!(out["anonymous_ack"], "BadUserAccessDenied", "{out}");
    assert_eq!(out["stale_ack"], "BadEventIdUnknown", "{out}");
    assert_eq!(out["acknowledged_by"], "opcua:ana", "{out}");
    assert_eq!(out["second_ack"], "BadConditionBranchAlreadyAcked", "{out}");

    // The same acknowledgement as `layerwise alarm ack`: the CLI and the daemon see it.
    let shown = layerwise()
        .args(["alarm", "show", "--build"])
        .arg(&dir)
        .output()
        .unwrap();
    let shown = String::from_utf8_lossy(&shown.stdout).to_string();
    assert!(
        shown.contains("acknowledged by opcua:ana") && shown.contains("checked part 3"),
        "{shown}"
    );
    wait_until("the daemon's light off", Duration::from_secs(10), || {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .contains("inspection alarm off: acknowledged by opcua:ana")
    });
    daemon.stop();
}

/// Subscriptions and monitored items beyond the limits are refused; connections that never
/// speak, speak garbage or come by the hundred are dropped; capture goes on through all of it,
/// and the daemon's memory stays bounded.
#[test]
fn floods_and_garbage_are_refused_and_capture_goes_on() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let layers = 12;
    let (config, dir) = config(tmp.path(), layers, 150);
    let daemon = Daemon::start(&config, Stdio::null());
    wait_for_server();
    let before = peak_memory(daemon.id());

    let out = client(&["flood", &url()], None);
    println!("{out}");
    assert_eq!(out["subscriptions"], 10, "{out}");
    assert_eq!(out["refused_subscriptions"], 30, "{out}");
    assert!(out["items"].as_u64().unwrap() <= 1000, "{out}");
    assert!(out["refused_items"].as_u64().unwrap() >= 2000, "{out}");

    // 300 connections: idle, garbage, a HEL announcing huge buffers and messages.
    let mut rng = Rng(0x0c7a);
    let mut sockets = Vec::new();
    for n in 0..300 {
        let Ok(mut socket) = TcpStream::connect(("127.0.0.1", PORT)) else {
            continue;
        };
        socket
            .set_write_timeout(Some(Duration::from_secs(1)))
            .unwrap();
        match n % 3 {
            0 => {}
            1 => {
                let junk: Vec<u8> = (0..64 * 1024).map(|_| rng.next() as u8).collect();
                let _ = socket.write_all(&junk);
            }
            _ => {
                // HEL with a message size of 4 GiB and a chunk count of 4 billion.
                let mut hello = b"HELF".to_vec();
                let url = url();
                hello.extend(((32 + url.len()) as u32).to_le_bytes());
                for v in [0u32, 1 << 30, 1 << 30, u32::MAX, u32::MAX] {
                    hello.extend(v.to_le_bytes());
                }
                hello.extend((url.len() as u32).to_le_bytes());
                hello.extend(url.as_bytes());
                let _ = socket.write_all(&hello);
            }
        }
        sockets.push(socket);
    }
    status_until(&dir, "every layer captured while flooded", |s| {
        s["layer"].as_u64() == Some(u64::from(layers))
    });
    drop(sockets);
    let grown = peak_memory(daemon.id()).saturating_sub(before);
    println!(
        "flooded: {} connections; the daemon's peak memory grew by {:.1} MB",
        300,
        grown as f64 / 1048576.0
    );
    assert!(grown < 200 << 20, "the daemon grew by {} MB", grown >> 20);
    // The server still answers a client.
    let out = client(&["flood", &url()], None);
    assert_eq!(out["subscriptions"], 10, "{out}");
    daemon.stop();
}

/// Beyond loopback (a plant address, 10.77.0.1, given to the test namespace's only interface):
/// no anonymous
/// or unencrypted session; a client's certificate is refused until an engineer moves it from
/// `rejected/` to `trusted/`; then Basic256Sha256 with a user of the users file, and only so.
#[test]
fn beyond_loopback_only_a_trusted_client_with_a_user_gets_in_over_basic256sha256() {
    private_network();
    let ok = Command::new("ip")
        .args(["addr", "add", "10.77.0.1/32", "dev", "lo"])
        .status()
        .unwrap();
    assert!(ok.success(), "ip addr add 10.77.0.1/32 dev lo");
    let tmp = tempfile::tempdir().unwrap();
    let (config_path, _dir) = config(tmp.path(), 40, 500);
    let mut config = layerwise::config::Config::load(&config_path).unwrap();
    let url = format!("opc.tcp://10.77.0.1:{PORT}");
    config.opcua.listen = url.clone();
    write_config(&config, &config_path);
    let log = tmp.path().join("daemon.log");
    let daemon = Daemon::start(
        &config_path,
        Stdio::from(std::fs::File::create(&log).unwrap()),
    );
    wait_until(
        "the OPC UA server listening",
        Duration::from_secs(30),
        || TcpStream::connect(("10.77.0.1", PORT)).is_ok(),
    );
    let certs = tmp.path().join("client-certs");
    std::fs::create_dir_all(&certs).unwrap();
    let pki = tmp.path().join("pki");
    let out = client(
        &[
            "secure",
            &url,
            USER,
            PASSWORD,
            pki.to_str().unwrap(),
            certs.to_str().unwrap(),
        ],
        Some(&log),
    );
    println!("{out}");
    for refused in [
        "anonymous_none",
        "untrusted",
        "trusted_anonymous",
        "wrong_password",
    ] {
        assert_ne!(out[refused], "connected", "{refused}: {out}");
    }
    assert_eq!(out["rejected_files"], 1, "{out}");
    assert!(out["layer"].as_u64().is_some(), "{out}");
    assert!(
        out["policy"].as_str().unwrap().ends_with("#Basic256Sha256"),
        "{out}"
    );
    daemon.stop();
}

/// The server's address is taken by another program: the daemon says so and captures anyway.
#[test]
fn a_busy_port_leaves_capture_going() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let _taken = std::net::TcpListener::bind(("127.0.0.1", PORT)).unwrap();
    let (config, dir) = config(tmp.path(), 2, 50);
    let log = tmp.path().join("daemon.log");
    let daemon = Daemon::start(&config, Stdio::from(std::fs::File::create(&log).unwrap()));
    status_until(&dir, "both layers captured", |s| {
        s["layer"].as_u64() == Some(2)
    });
    daemon.stop();
    let log = std::fs::read_to_string(&log).unwrap();
    assert!(log.contains("no OPC UA server; capture goes on"), "{log}");
}
