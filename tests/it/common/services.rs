//! The real programs on the other side (Orthanc, Prometheus, Mosquitto, the asyncua client):
//! a private network namespace to run them in, the test venv's Python, a printer that keeps the
//! daemon waiting, and a wait that says what never came.

use layerwise::config::{Config, TriggerConfig};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// Moves this test's thread (and so every process it starts) into a new network namespace
/// with loopback up. Needs root (CI runs as root).
pub fn private_network() {
    // SAFETY: unshare only changes the calling thread's namespaces.
    let rc = unsafe { libc::unshare(libc::CLONE_NEWNET) };
    assert_eq!(
        rc,
        0,
        "unshare(CLONE_NEWNET) failed ({}): the tests against real servers need root, as CI \
         runs them, to keep those servers reachable from this machine alone",
        std::io::Error::last_os_error()
    );
    let up = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .status()
        .expect("ip (iproute2) runs");
    assert!(up.success(), "ip link set lo up failed");
}

/// The test venv's Python (tests/run.sh makes it; `LAYERWISE_TEST_PYTHON` names another).
pub fn python() -> PathBuf {
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-venv/bin/python");
    let python = std::env::var_os("LAYERWISE_TEST_PYTHON")
        .map(PathBuf::from)
        .unwrap_or(venv);
    assert!(
        python.exists(),
        "{}: run `bash tests/run.sh`, which makes the test venv",
        python.display()
    );
    python
}

/// Waits until `done` says yes, looking every 50 ms; fails naming `what` after `timeout`.
pub fn wait_until(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !done() {
        assert!(Instant::now() < deadline, "{what}: not within {timeout:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// A printer for the mock trigger: `layers` layers (pre, then post), `pause_ms` between signals,
/// then `hold_ms` with no signal (the daemon waits as between real layers, until stopped).
pub fn printer_script(config: &mut Config, dir: &Path, layers: u32, pause_ms: u64, hold_ms: u64) {
    let script: String = (1..=layers)
        .map(|n| format!("LAYER {n} PRE\nWAIT {pause_ms}\nLAYER {n} POST\nWAIT {pause_ms}\n"))
        .collect::<String>()
        + &format!("WAIT {hold_ms}\n");
    mock_printer(config, dir, &script);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
}

/// The mock trigger's printer plays `script` (`LAYER n PRE|POST`, `WAIT ms` lines), written to
/// `dir/printer.txt`; returns that path.
pub fn mock_printer(config: &mut Config, dir: &Path, script: &str) -> PathBuf {
    let path = dir.join("printer.txt");
    std::fs::write(&path, script).expect("printer script");
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.script = Some(path.clone());
    }
    path
}

/// The largest resident memory a process has had, in bytes (`VmHWM`).
pub fn peak_memory(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map_or(0, |kb| kb * 1024)
}
