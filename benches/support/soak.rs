//! The soak driver: the real `layerwise run` binary through a long mock build (small mock frames)
//! fed by a "printer" on a serial line (a socat pty pair), with a repeated, a skipped and a
//! garbage (plus an out-of-range) signal every few hundred layers, a build disk that fills up and
//! is freed (a tmpfs in a private mount namespace, when run as root), and a `kill -9` every
//! 1,000 layers followed by a restart, as systemd would. It then checks that no original was
//! lost or overwritten, that every injected event is in the journal and that the daemon's
//! resident memory stays flat. `benches/soak.rs` runs it for 10,000 layers; `tests/it/soak.rs` runs
//! it for a few dozen so the driver does not rot.
// The bench and the test each use a part of the report.
#![allow(dead_code)]

#[path = "soak_rig.rs"]
mod rig;
#[path = "tmpfs.rs"]
mod tmpfs;

use rig::{file_state, proc_status, Follower, Line, Sample, Sampler};

use layerwise::build_dir::journal::IrregularSignal;
use layerwise::config::{CameraConfig, Config, SerialTriggerConfig, TriggerConfig, DEMO_CONFIG};
use layerwise::shot::Phase;
use std::collections::BTreeSet;
use std::fmt::Write as _;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// The `layerwise` binary.
    pub binary: PathBuf,
    /// Where the build, config and logs go (the build on a tmpfs below it when filling the disk).
    pub work: PathBuf,
    pub layers: u32,
    /// A repeated, a skipped and a garbage signal once in every this many layers.
    pub inject_every: u32,
    /// `kill -9` and a restart after every this many layers.
    pub kill_every: u32,
    /// Layers per window of the memory report.
    pub window: u32,
    /// Fill the build disk (a tmpfs; needs root) for a few layers, then free it.
    pub fill_disk: bool,
    pub width: u32,
    pub height: u32,
    /// fsync originals and the journal, as in production.
    pub fsync: bool,
    /// Longest wait for the daemon to handle one signal.
    pub timeout: Duration,
}

impl Options {
    pub fn new(binary: PathBuf, work: PathBuf, layers: u32) -> Options {
        Options {
            binary,
            work,
            layers,
            inject_every: 300,
            kill_every: 1000,
            window: 1000,
            fill_disk: is_root(),
            width: 64,
            height: 43,
            fsync: true,
            timeout: Duration::from_secs(60),
        }
    }
}

pub fn is_root() -> bool {
    // SAFETY: geteuid has no preconditions.
    unsafe { libc::geteuid() == 0 }
}

/// Lights the demo configuration uses: frames per (layer, phase).
const LIGHTS: usize = 3;
/// Layers the disk stays full.
const FULL_LAYERS: u32 = 3;

/// What the soak found.
#[derive(Debug, Default)]
pub struct Report {
    pub layers: u32,
    pub seconds: f64,
    pub kills: u32,
    pub starts_journaled: u32,
    pub originals: usize,
    pub retakes: usize,
    pub lost: Vec<String>,
    pub unjournaled: Vec<String>,
    pub overwritten: Vec<String>,
    /// Frames recorded missing that no injection (skip, full disk) explains.
    pub unexpected_missing: Vec<String>,
    pub missing_while_full: usize,
    /// Layers with frames missed for want of space.
    pub full_layers: BTreeSet<u32>,
    pub disk_filled: bool,
    pub survived_full_disk: bool,
    /// (what was injected, how many, how many the journal shows).
    pub events: Vec<(String, usize, usize)>,
    /// Signals sent (in range) without an event record.
    pub signals_unjournaled: usize,
    pub windows: Vec<Window>,
    /// Peak RSS (VmHWM, KiB) of each daemon run, start-up replay included.
    pub run_peaks: Vec<u64>,
}

/// Resident memory of the daemon over one window of layers.
#[derive(Clone, Debug)]
pub struct Window {
    pub first: u32,
    pub last: u32,
    pub runs: BTreeSet<usize>,
    pub samples: usize,
    pub median_kib: u64,
    pub max_kib: u64,
}

impl Report {
    /// RSS of the last window against the first (its first tenth skipped as warm-up): the
    /// relative change of the medians.
    pub fn rss_change(&self) -> Option<f64> {
        let first = self.windows.first()?;
        let last = self.windows.last()?;
        (self.windows.len() > 1)
            .then(|| (last.median_kib as f64 - first.median_kib as f64) / first.median_kib as f64)
    }

    pub fn events_ok(&self) -> bool {
        self.events.iter().all(|(_, want, got)| got >= want) && self.signals_unjournaled == 0
    }

    pub fn rss_ok(&self) -> bool {
        self.rss_change().is_some_and(|c| c.abs() <= 0.10)
    }

    /// Every criterion of the issue but the memory one.
    pub fn data_ok(&self) -> bool {
        self.lost.is_empty()
            && self.unjournaled.is_empty()
            && self.overwritten.is_empty()
            && self.unexpected_missing.is_empty()
            && self.events_ok()
            && self.starts_journaled == self.kills + 1
            && (!self.disk_filled || self.survived_full_disk)
    }

    pub fn passed(&self) -> bool {
        self.data_ok() && self.rss_ok()
    }

    /// A markdown table for the closing note.
    pub fn table(&self) -> String {
        let ok = |b: bool| if b { "pass" } else { "FAIL" };
        let list = |v: &[String]| {
            if v.is_empty() {
                "0".to_string()
            } else {
                format!("{} (e.g. {})", v.len(), v[..v.len().min(3)].join(", "))
            }
        };
        let mut t = String::new();
        let _ = writeln!(
            t,
            "Soak: {} layers in {:.0} s, {} originals + {} retakes, {} kill -9 ({} starts journaled)\n",
            self.layers, self.seconds, self.originals, self.retakes, self.kills, self.starts_journaled
        );
        let _ = writeln!(t, "| criterion | measured | result |\n|---|---|---|");
        let _ = writeln!(
            t,
            "| originals lost (journaled, no file / wrong size or sha) | {} | {} |",
            list(&self.lost),
            ok(self.lost.is_empty())
        );
        let _ = writeln!(
            t,
            "| originals without a journal record | {} | {} |",
            list(&self.unjournaled),
            ok(self.unjournaled.is_empty())
        );
        let _ = writeln!(
            t,
            "| originals overwritten (sha, size or mtime changed since first seen) | {} | {} |",
            list(&self.overwritten),
            ok(self.overwritten.is_empty())
        );
        let _ = writeln!(
            t,
            "| frames missing not explained by a skip or the full disk | {} | {} |",
            list(&self.unexpected_missing),
            ok(self.unexpected_missing.is_empty())
        );
        for (what, want, got) in &self.events {
            let _ = writeln!(
                t,
                "| {what} | {got} journaled of {want} injected | {} |",
                ok(got >= want)
            );
        }
        let _ = writeln!(
            t,
            "| signals without an event record | {} | {} |",
            self.signals_unjournaled,
            ok(self.signals_unjournaled == 0)
        );
        let _ = writeln!(
            t,
            "| restarts after kill -9 | {} kills, {} starts | {} |",
            self.kills,
            self.starts_journaled,
            ok(self.starts_journaled == self.kills + 1)
        );
        let _ = writeln!(
            t,
            "| disk full for {FULL_LAYERS} layers, then freed | {} | {} |",
            if self.disk_filled {
                format!(
                    "{} frames journaled missing for space (layers {}–{}); daemon {}",
                    self.missing_while_full,
                    self.full_layers.first().unwrap_or(&0),
                    self.full_layers.last().unwrap_or(&0),
                    if self.survived_full_disk {
                        "waited and resumed"
                    } else {
                        "exited"
                    }
                )
            } else {
                "not run (needs root for a tmpfs)".into()
            },
            if self.disk_filled {
                ok(self.survived_full_disk)
            } else {
                "skipped"
            }
        );
        let change = self.rss_change();
        let _ = writeln!(
            t,
            "| RSS, last window vs first (medians) | {} | {} |",
            change.map_or("n/a".into(), |c| format!("{:+.1} %", c * 100.0)),
            ok(self.rss_ok())
        );
        let _ = writeln!(
            t,
            "\n| layers | daemon runs | samples | median RSS MiB | max RSS MiB |\n|---|---|---|---|---|"
        );
        for w in &self.windows {
            let runs: Vec<String> = w.runs.iter().map(|r| (r + 1).to_string()).collect();
            let _ = writeln!(
                t,
                "| {}–{} | {} | {} | {:.1} | {:.1} |",
                w.first,
                w.last,
                runs.join(","),
                w.samples,
                w.median_kib as f64 / 1024.0,
                w.max_kib as f64 / 1024.0
            );
        }
        if !self.run_peaks.is_empty() {
            let peaks: Vec<String> = self
                .run_peaks
                .iter()
                .map(|k| format!("{:.1}", *k as f64 / 1024.0))
                .collect();
            let _ = writeln!(
                t,
                "\nPeak RSS (VmHWM) per daemon run, MiB, start-up replay included: {}",
                peaks.join(", ")
            );
        }
        t
    }
}

/// Writes `path` until the disk holding it is full.
fn fill(path: &Path) {
    let mut file = std::fs::File::create(path).expect("ballast");
    let chunk = vec![0x5Au8; 64 * 1024];
    while file
        .write_all(&chunk)
        .and_then(|()| file.sync_data())
        .is_ok()
    {}
}

fn config(options: &Options, build: &Path, port: &Path) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml")).expect("demo config");
    config.build.output_dir = build.to_path_buf();
    config.build.layers = Some(options.layers);
    // The serial trigger's defaults (protocol `LAYER <n> PRE|POST`), reopening quickly after a
    // restart.
    let serial: SerialTriggerConfig = toml::from_str(&format!(
        "port = {:?}\nreopen_backoff_ms = [20, 200]",
        port.display().to_string()
    ))
    .expect("serial trigger config");
    config.trigger = TriggerConfig::Serial(serial);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = options.width;
        mock.height = options.height;
    }
    config.storage.fsync = options.fsync;
    // Low at 8 MB free: the derived data pause before the disk is full.
    config.storage.min_free_gb = 0.008;
    config
}

/// A layer signal as the printer sends it.
fn signal(layer: u32, phase: Phase) -> String {
    format!("LAYER {layer} {}\n", phase.as_str().to_uppercase())
}

/// The injection (if any) planned for a layer.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Inject {
    None,
    /// The layer's POST signal twice.
    Repeat,
    /// The layer never signalled.
    Skip,
    /// A line the protocol cannot parse and a layer 0 signal before the layer.
    Garbage,
}

struct Plan {
    every: u32,
    fill: Option<(u32, u32)>,
    layers: u32,
}

impl Plan {
    fn at(&self, layer: u32) -> Inject {
        let near_fill = self
            .fill
            .is_some_and(|(a, b)| layer + 2 >= a && layer <= b + 2);
        if near_fill || layer <= 1 || layer >= self.layers {
            return Inject::None;
        }
        match layer % self.every {
            r if r == self.every / 3 => Inject::Repeat,
            r if r == 2 * self.every / 3 => Inject::Skip,
            0 => Inject::Garbage,
            _ => Inject::None,
        }
    }

    fn full(&self, layer: u32) -> bool {
        self.fill.is_some_and(|(a, b)| (a..=b).contains(&layer))
    }
}

struct Daemon {
    child: Option<Child>,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// Runs the soak; panics only when the driver itself cannot go on (the daemon died, a signal was
/// never handled), with the daemon log's tail.
pub fn run(options: &Options) -> Report {
    let started = Instant::now();
    std::fs::create_dir_all(&options.work).expect("work dir");
    let disk = options.work.join("disk");
    // About 50 KiB of tmpfs pages per layer (originals and sidecars take a page each) and room.
    let disk_mb = 96 + u64::from(options.layers) * 64 / 1024;
    let disk_filled = options.fill_disk && {
        match tmpfs::mount(&disk, disk_mb) {
            Ok(()) => true,
            Err(e) => {
                eprintln!("soak: no tmpfs for the disk-full part ({e}); running without it");
                false
            }
        }
    };
    let build = disk.join("build");
    let log_path = options.work.join("daemon.log");
    let config_path = options.work.join("soak.toml");
    let mut line = Line::start(&options.work);
    let text = toml::to_string(&config(options, &build, &line.daemon)).expect("config");
    std::fs::write(&config_path, text).expect("config written");

    let fill_at = (options.layers * 45 / 100 / options.kill_every) * options.kill_every
        + options.kill_every / 2
        + 7;
    let plan = Plan {
        every: options.inject_every,
        fill: (disk_filled && fill_at + FULL_LAYERS + 5 < options.layers)
            .then_some((fill_at, fill_at + FULL_LAYERS - 1)),
        layers: options.layers,
    };
    let sampler = Sampler::start();
    let mut follower = Follower::default();
    let mut report = Report {
        layers: options.layers,
        disk_filled: plan.fill.is_some(),
        ..Report::default()
    };
    let mut daemon = Daemon { child: None };
    let mut runs = 0usize;
    let tail = |log: &Path| {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let lines: Vec<&str> = text.lines().collect();
        lines[lines.len().saturating_sub(15)..].join("\n")
    };
    let start_daemon = |daemon: &mut Daemon,
                        follower: &mut Follower,
                        line: &mut Line,
                        runs: usize,
                        sampler: &Sampler| {
        line.ensure(&options.work);
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .expect("log");
        let child = Command::new(&options.binary)
            .arg("run")
            .arg("--config")
            .arg(&config_path)
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .expect("layerwise run starts");
        sampler.pid.store(child.id(), Ordering::SeqCst);
        sampler.run.store(runs as u32, Ordering::SeqCst);
        daemon.child = Some(child);
        let deadline = Instant::now() + options.timeout;
        while follower.starts < runs as u32 + 1 {
            assert!(
                Instant::now() < deadline,
                "the daemon did not start\n{}",
                tail(&log_path)
            );
            std::thread::sleep(Duration::from_millis(5));
            follower.poll(&build);
        }
    };
    start_daemon(&mut daemon, &mut follower, &mut line, runs, &sampler);

    let wait = |follower: &mut Follower,
                daemon: &mut Daemon,
                what: &str,
                timeout: Duration,
                done: &dyn Fn(&Follower) -> bool| {
        let deadline = Instant::now() + timeout;
        loop {
            follower.poll(&build);
            if done(follower) {
                return;
            }
            if let Some(status) = daemon
                .child
                .as_mut()
                .and_then(|c| c.try_wait().ok().flatten())
            {
                panic!(
                    "the daemon ended ({status}) waiting for {what}\n{}",
                    tail(&log_path)
                );
            }
            assert!(
                Instant::now() < deadline,
                "timed out waiting for {what}\n{}",
                tail(&log_path)
            );
            std::thread::sleep(Duration::from_millis(1));
        }
    };

    let (mut repeats, mut skips, mut garbage) = (Vec::new(), Vec::new(), 0usize);
    let mut sent: Vec<(u32, Phase)> = Vec::new();
    let mut full_layers = Vec::new();
    for layer in 1..=options.layers {
        sampler.layer.store(layer, Ordering::SeqCst);
        let inject = plan.at(layer);
        if inject == Inject::Garbage {
            line.send(b"\x00\xff#@!LAYER x PRE\nLAYER 99999999999999 POST\n");
            line.send(b"LAYER 0 PRE\n");
            garbage += 1;
            let want = garbage;
            wait(
                &mut follower,
                &mut daemon,
                "the out-of-range signal",
                options.timeout,
                &|f| f.count(IrregularSignal::OutOfRange, None) >= want,
            );
        }
        if inject == Inject::Skip {
            skips.push(layer + 1);
        } else if plan.full(layer) {
            if Some(layer) == plan.fill.map(|f| f.0) {
                fill(&disk.join("ballast"));
            }
            for phase in [Phase::Pre, Phase::Post] {
                line.send(signal(layer, phase).as_bytes());
                sent.push((layer, phase));
                std::thread::sleep(Duration::from_millis(300));
            }
            full_layers.push(layer);
            if Some(layer) == plan.fill.map(|f| f.1) {
                std::fs::remove_file(disk.join("ballast")).expect("free the disk");
                // The daemon probes a full disk with a back-off of up to 5 s; a printer takes
                // longer than that for a layer, so the next signal comes after it.
                std::thread::sleep(Duration::from_secs(6));
                let full = full_layers.clone();
                wait(
                    &mut follower,
                    &mut daemon,
                    "the frames of the full disk's layers once space returned",
                    Duration::from_secs(180),
                    &|f| {
                        full.iter().all(|&l| {
                            f.resolved(l, Phase::Pre) == LIGHTS
                                && f.resolved(l, Phase::Post) == LIGHTS
                        })
                    },
                );
                report.survived_full_disk = true;
            }
        } else {
            for phase in [Phase::Pre, Phase::Post] {
                line.send(signal(layer, phase).as_bytes());
                sent.push((layer, phase));
                wait(
                    &mut follower,
                    &mut daemon,
                    &format!("layer {layer} {phase}"),
                    options.timeout,
                    &|f| f.resolved(layer, phase) == LIGHTS,
                );
            }
        }
        if inject == Inject::Repeat {
            line.send(signal(layer, Phase::Post).as_bytes());
            repeats.push(layer);
            wait(
                &mut follower,
                &mut daemon,
                &format!("the retakes of layer {layer} post"),
                options.timeout,
                &|f| f.retakes.get(&(layer, Phase::Post)).copied().unwrap_or(0) >= LIGHTS,
            );
        }
        if layer % options.kill_every == 0 && layer < options.layers {
            let mut child = daemon.child.take().expect("daemon running");
            report
                .run_peaks
                .push(proc_status(child.id()).map_or(0, |(_, hwm)| hwm));
            child.kill().expect("kill -9");
            let _ = child.wait();
            report.kills += 1;
            runs += 1;
            // The restart's samples count for the layers it runs.
            sampler.layer.store(layer + 1, Ordering::SeqCst);
            follower.forget_partial();
            start_daemon(&mut daemon, &mut follower, &mut line, runs, &sampler);
        }
    }
    // Processing catches up, then the daemon is stopped as systemd stops it.
    if let Some(child) = daemon.child.take() {
        if let Some((_, hwm)) = proc_status(child.id()) {
            report.run_peaks.push(hwm);
        }
        // SAFETY: kill with a valid pid.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        let output = child.wait_with_output().expect("daemon ends");
        assert!(
            output.status.success(),
            "the daemon failed on SIGTERM\n{}",
            tail(&log_path)
        );
    }
    let samples = sampler.finish();
    line.stop();
    follower.poll(&build);
    report.starts_journaled = follower.starts;

    check_originals(&build, &follower, &mut report);
    for (layer, phase, why) in &follower.missing {
        // The disk guard probes a full disk with a back-off of up to 5 s: the layers signalled
        // before it sees the space again are missed for space too.
        if why.contains("disk is full") {
            report.missing_while_full += 1;
            report.full_layers.insert(*layer);
        } else {
            report
                .unexpected_missing
                .push(format!("L{layer} {phase} {why}"));
        }
    }
    let count = |signal, at| follower.count(signal, at);
    let retakes_got: usize = repeats
        .iter()
        .map(|&l| {
            follower
                .retakes
                .get(&(l, Phase::Post))
                .copied()
                .unwrap_or(0)
                .min(LIGHTS)
        })
        .sum();
    report.events = vec![
        (
            "repeated signal: irregular record".into(),
            repeats.len(),
            repeats
                .iter()
                .filter(|&&l| count(IrregularSignal::Repeated, Some((l, Phase::Post))) > 0)
                .count(),
        ),
        (
            "repeated signal: retake records (one per light)".into(),
            repeats.len() * LIGHTS,
            retakes_got,
        ),
        (
            "skipped layer: irregular record".into(),
            skips.len(),
            skips
                .iter()
                .filter(|&&l| count(IrregularSignal::Skipped, Some((l, Phase::Pre))) > 0)
                .count(),
        ),
        (
            "garbage line + layer 0: out-of-range record".into(),
            garbage,
            count(IrregularSignal::OutOfRange, None),
        ),
    ];
    report.signals_unjournaled = sent.iter().filter(|s| !follower.events.contains(s)).count();
    report.windows = windows(&samples, options.window, options.layers);
    report.seconds = started.elapsed().as_secs_f64();
    if disk_filled {
        tmpfs::unmount(&disk);
    }
    report
}

/// Lost, unjournaled and overwritten originals: every journaled file re-read and compared with the
/// journal and with what the driver saw when it first appeared.
fn check_originals(build: &Path, follower: &Follower, report: &mut Report) {
    report.overwritten = follower.rewritten.clone();
    for (file, (bytes, sha)) in &follower.files {
        if follower.retake_files.contains(file) {
            report.retakes += 1;
        } else {
            report.originals += 1;
        }
        match file_state(&build.join(file)) {
            None => report.lost.push(format!("{file} (no file)")),
            Some((size, modified, now_sha)) => {
                if (size, &now_sha) != (*bytes, sha) {
                    report
                        .lost
                        .push(format!("{file} (differs from its record)"));
                }
                if let Some(first) = follower.seen.get(file) {
                    if *first != (size, modified, now_sha) {
                        report.overwritten.push(file.clone());
                    }
                }
            }
        }
    }
    let raw = build.join(layerwise::build_dir::RAW_DIR);
    for entry in std::fs::read_dir(&raw).into_iter().flatten().flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || name.ends_with(".json") {
            continue;
        }
        let file = format!("{}/{name}", layerwise::build_dir::RAW_DIR);
        if !follower.files.contains_key(&file) {
            report.unjournaled.push(file);
        }
    }
}

/// The samples per window of layers: the first window's first tenth is warm-up.
fn windows(samples: &[Sample], window: u32, layers: u32) -> Vec<Window> {
    let mut out = Vec::new();
    let mut first = 1;
    while first <= layers {
        let last = (first + window - 1).min(layers);
        let from = if first == 1 { 1 + window / 10 } else { first };
        let mut rss: Vec<u64> = samples
            .iter()
            .filter(|s| (from..=last).contains(&s.layer))
            .map(|s| s.rss_kib)
            .collect();
        let runs = samples
            .iter()
            .filter(|s| (first..=last).contains(&s.layer))
            .map(|s| s.run)
            .collect();
        rss.sort_unstable();
        if !rss.is_empty() {
            out.push(Window {
                first,
                last,
                runs,
                samples: rss.len(),
                median_kib: rss[rss.len() / 2],
                max_kib: *rss.last().unwrap(),
            });
        }
        first = last + 1;
    }
    out
}
