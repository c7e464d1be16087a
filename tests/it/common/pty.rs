//! A pseudo-terminal pair made by socat, standing in for a serial cable: the "printer" (or relay
//! board) writes to and reads from one end, layerwise opens the other.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The serial trigger on `port` with the default protocol and a quick reopen back-off.
pub fn serial_config(port: &Path) -> layerwise::config::SerialTriggerConfig {
    layerwise::config::SerialTriggerConfig {
        port: port.display().to_string(),
        baud: 115200,
        pattern: layerwise::config::DEFAULT_LINE_PATTERN.to_string(),
        pre: "PRE".into(),
        post: "POST".into(),
        reopen_backoff_ms: [20, 200],
    }
}

/// A pty pair: `printer` and `daemon` are symlinks to the two slave ends.
pub struct PtyPair {
    socat: Child,
    pub printer: PathBuf,
    pub daemon: PathBuf,
}

impl PtyPair {
    pub fn start(dir: &Path) -> PtyPair {
        let printer = dir.join("printer");
        let daemon = dir.join("daemon");
        let socat = Command::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", printer.display()))
            .arg(format!("pty,raw,echo=0,link={}", daemon.display()))
            .stderr(Stdio::null())
            .spawn()
            .expect("socat is needed for this test: the README's test command installs it (apt-get install socat)");
        let deadline = Instant::now() + Duration::from_secs(10);
        while !(printer.exists() && daemon.exists()) {
            assert!(Instant::now() < deadline, "socat made no pty pair");
            std::thread::sleep(Duration::from_millis(10));
        }
        PtyPair {
            socat,
            printer,
            daemon,
        }
    }

    pub fn send(&self, bytes: &[u8]) {
        let mut port = std::fs::OpenOptions::new()
            .write(true)
            .open(&self.printer)
            .expect("printer end");
        port.write_all(bytes).expect("write to the printer end");
        port.flush().unwrap();
    }

    pub fn stop(mut self) {
        let _ = self.socat.kill();
        let _ = self.socat.wait();
        let _ = std::fs::remove_file(&self.printer);
        let _ = std::fs::remove_file(&self.daemon);
    }
}

/// Collects what arrives at one end of a pty, on its own thread.
pub struct PtyReader(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl PtyReader {
    pub fn start(end: &Path) -> PtyReader {
        use std::io::Read;
        let mut file = std::fs::File::open(end).expect("pty end");
        let got = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let sink = got.clone();
        std::thread::spawn(move || {
            let mut chunk = [0u8; 256];
            while let Ok(n) = file.read(&mut chunk) {
                if n == 0 {
                    break;
                }
                sink.lock().unwrap().extend_from_slice(&chunk[..n]);
            }
        });
        PtyReader(got)
    }

    /// What arrived so far.
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.0.lock().unwrap()).into_owned()
    }

    /// Waits until `pattern` has arrived, failing after `timeout`.
    pub fn wait_for(&self, pattern: &str, timeout: Duration) -> String {
        let deadline = Instant::now() + timeout;
        loop {
            let text = self.text();
            if text.contains(pattern) {
                return text;
            }
            assert!(
                Instant::now() < deadline,
                "no {pattern:?} within {timeout:?}, got {text:?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}
