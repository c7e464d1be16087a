//! The soak's rig: the socat pty pair standing in for the serial cable, the follower that reads
//! the journal as it grows, and the sampler of the daemon's resident memory.

use layerwise::build_dir::journal::{IrregularSignal, Record};
use layerwise::shot::Phase;
use std::collections::{BTreeMap, BTreeSet};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

/// A socat pty pair standing in for the serial cable.
pub(super) struct Line {
    pub(super) socat: Child,
    pub(super) printer: PathBuf,
    pub(super) daemon: PathBuf,
    pub(super) port: Option<std::fs::File>,
}

impl Line {
    pub(super) fn start(dir: &Path) -> Line {
        let printer = dir.join("printer");
        let daemon = dir.join("ttyPRINTER");
        let _ = std::fs::remove_file(&printer);
        let _ = std::fs::remove_file(&daemon);
        let socat = Command::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", printer.display()))
            .arg(format!("pty,raw,echo=0,link={}", daemon.display()))
            .stderr(Stdio::null())
            .spawn()
            .expect("socat is needed (apt-get install socat)");
        let deadline = Instant::now() + Duration::from_secs(10);
        while !(printer.exists() && daemon.exists()) {
            assert!(Instant::now() < deadline, "socat made no pty pair");
            std::thread::sleep(Duration::from_millis(10));
        }
        Line {
            socat,
            printer,
            daemon,
            port: None,
        }
    }

    /// A new pair if socat ended (it may when the daemon's end closes).
    pub(super) fn ensure(&mut self, dir: &Path) {
        if !matches!(self.socat.try_wait(), Ok(None)) {
            self.stop();
            *self = Line::start(dir);
        }
    }

    pub(super) fn send(&mut self, text: &[u8]) {
        if self.port.is_none() {
            self.port = Some(
                std::fs::OpenOptions::new()
                    .write(true)
                    .open(&self.printer)
                    .expect("the printer's end"),
            );
        }
        let port = self.port.as_mut().unwrap();
        port.write_all(text).expect("write to the printer's end");
        port.flush().unwrap();
    }

    pub(super) fn stop(&mut self) {
        self.port = None;
        let _ = self.socat.kill();
        let _ = self.socat.wait();
    }
}

impl Drop for Line {
    /// socat ends with the driver, even when it panics.
    fn drop(&mut self) {
        self.stop();
    }
}

/// What the journal said so far, read as it grows.
#[derive(Default)]
pub(super) struct Follower {
    pub(super) offset: u64,
    pub(super) partial: Vec<u8>,
    /// Lights with a frame or a missing record, per (layer, phase).
    pub(super) resolved: BTreeMap<(u32, Phase), BTreeSet<String>>,
    pub(super) retakes: BTreeMap<(u32, Phase), usize>,
    pub(super) events: BTreeSet<(u32, Phase)>,
    pub(super) irregular: Vec<(u32, Phase, IrregularSignal)>,
    pub(super) missing: Vec<(u32, Phase, String)>,
    /// Original file -> (size, sha256) journaled; first record wins.
    pub(super) files: BTreeMap<String, (u64, String)>,
    /// The files of retakes.
    pub(super) retake_files: BTreeSet<String>,
    /// Original file -> (size, mtime, sha256) when the driver first saw it.
    pub(super) seen: BTreeMap<String, (u64, SystemTime, String)>,
    /// Records naming a file already journaled with other contents.
    pub(super) rewritten: Vec<String>,
    pub(super) starts: u32,
}

impl Follower {
    pub(super) fn poll(&mut self, build: &Path) {
        let path = build.join(layerwise::build_dir::JOURNAL);
        let Ok(mut file) = std::fs::File::open(&path) else {
            return;
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return;
        }
        let mut data = Vec::new();
        if file.read_to_end(&mut data).is_err() {
            return;
        }
        self.offset += data.len() as u64;
        self.partial.extend_from_slice(&data);
        let mut lines: Vec<Vec<u8>> = Vec::new();
        while let Some(i) = self.partial.iter().position(|&b| b == b'\n') {
            lines.push(self.partial.drain(..=i).collect());
        }
        for line in lines {
            if let Ok(record) = serde_json::from_slice::<Record>(&line) {
                self.apply(build, record);
            }
        }
    }

    /// After a kill -9: a torn last line is cut by the daemon's next start.
    pub(super) fn forget_partial(&mut self) {
        self.offset -= self.partial.len() as u64;
        self.partial.clear();
    }

    pub(super) fn apply(&mut self, build: &Path, record: Record) {
        match record {
            Record::Start { .. } => self.starts += 1,
            Record::Event { layer, phase, .. } => {
                self.events.insert((layer, phase));
            }
            Record::Frame {
                layer,
                phase,
                light,
                file,
                bytes,
                sha256,
                ..
            } => {
                self.resolved
                    .entry((layer, phase))
                    .or_default()
                    .insert(light.to_string());
                self.original(build, file, bytes, sha256);
            }
            Record::Retake {
                layer,
                phase,
                file,
                bytes,
                sha256,
                ..
            } => {
                *self.retakes.entry((layer, phase)).or_default() += 1;
                self.retake_files.insert(file.clone());
                self.original(build, file, bytes, sha256);
            }
            Record::Missing {
                layer,
                phase,
                light,
                reason,
                ..
            } => {
                self.resolved
                    .entry((layer, phase))
                    .or_default()
                    .insert(light.to_string());
                self.missing
                    .push((layer, phase, format!("{light}: {reason}")));
            }
            Record::Irregular {
                layer,
                phase,
                signal,
                ..
            } => self.irregular.push((layer, phase, signal)),
            _ => {}
        }
    }

    pub(super) fn original(&mut self, build: &Path, file: String, bytes: u64, sha256: String) {
        match self.files.get(&file) {
            Some((b, s)) if (*b, s.as_str()) != (bytes, sha256.as_str()) => {
                self.rewritten.push(file.clone())
            }
            Some(_) => {}
            None => {
                if let Some(state) = file_state(&build.join(&file)) {
                    self.seen.entry(file.clone()).or_insert(state);
                }
                self.files.insert(file, (bytes, sha256));
            }
        }
    }

    pub(super) fn resolved(&self, layer: u32, phase: Phase) -> usize {
        self.resolved.get(&(layer, phase)).map_or(0, BTreeSet::len)
    }

    pub(super) fn count(&self, signal: IrregularSignal, at: Option<(u32, Phase)>) -> usize {
        self.irregular
            .iter()
            .filter(|(l, p, s)| *s == signal && at.is_none_or(|a| a == (*l, *p)))
            .count()
    }
}

pub(super) fn file_state(path: &Path) -> Option<(u64, SystemTime, String)> {
    let data = std::fs::read(path).ok()?;
    let modified = std::fs::metadata(path).ok()?.modified().ok()?;
    Some((
        data.len() as u64,
        modified,
        layerwise::fsutil::sha256_hex(&data),
    ))
}

/// One RSS sample of the daemon.
#[derive(Clone, Copy)]
pub(super) struct Sample {
    pub(super) run: usize,
    pub(super) layer: u32,
    pub(super) rss_kib: u64,
}

pub(super) fn proc_status(pid: u32) -> Option<(u64, u64)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let field = |name: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
    };
    Some((field("VmRSS:")?, field("VmHWM:")?))
}

/// Samples the running daemon's VmRSS every 20 ms, tagged with the layer being signalled.
pub(super) struct Sampler {
    pub(super) pid: Arc<AtomicU32>,
    pub(super) run: Arc<AtomicU32>,
    pub(super) layer: Arc<AtomicU32>,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) samples: Arc<Mutex<Vec<Sample>>>,
    pub(super) thread: Option<std::thread::JoinHandle<()>>,
}

impl Sampler {
    pub(super) fn start() -> Sampler {
        let pid = Arc::new(AtomicU32::new(0));
        let run = Arc::new(AtomicU32::new(0));
        let layer = Arc::new(AtomicU32::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let samples = Arc::new(Mutex::new(Vec::new()));
        let (p, r, l, s, out) = (
            pid.clone(),
            run.clone(),
            layer.clone(),
            stop.clone(),
            samples.clone(),
        );
        let thread = std::thread::spawn(move || {
            while !s.load(Ordering::SeqCst) {
                let (pid, layer) = (p.load(Ordering::SeqCst), l.load(Ordering::SeqCst));
                if pid != 0 && layer != 0 {
                    if let Some((rss_kib, _)) = proc_status(pid) {
                        out.lock().unwrap().push(Sample {
                            run: r.load(Ordering::SeqCst) as usize,
                            layer,
                            rss_kib,
                        });
                    }
                }
                std::thread::sleep(Duration::from_millis(20));
            }
        });
        Sampler {
            pid,
            run,
            layer,
            stop,
            samples,
            thread: Some(thread),
        }
    }

    pub(super) fn finish(mut self) -> Vec<Sample> {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        std::mem::take(&mut *self.samples.lock().unwrap())
    }
}
