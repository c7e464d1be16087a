//! Capture-path benchmarks (run with `cargo bench --bench capture_path`):
//! 1. overhead per frame of everything but the camera: lights, the camera thread hop, the
//!    original and sidecar written atomically with fsync, the journal, status, the processing
//!    queue. A prerecorded camera returns a fixed frame instantly, so the time between two frames
//!    of one layer signal is the overhead. Target: median under 5 ms.
//! 2. resident memory through a long mock build (default 10,000 layers; LAYERWISE_BENCH_LAYERS
//!    overrides): it must stay flat.

#[path = "support/prerecorded.rs"]
mod prerecorded;

use layerwise::build_dir::journal::Record;
use layerwise::config::{CameraConfig, Config, TriggerConfig, DEMO_CONFIG};
use prerecorded::{mock_frame, run_prerecorded};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn config(dir: &Path, layers: u32, fsync: bool) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml")).expect("demo config");
    config.build.output_dir = dir.to_path_buf();
    config.storage.fsync = fsync;
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    config
}

fn build(config: &Config, frame: Vec<u8>) {
    run_prerecorded(config, frame);
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn overhead(label: &str, width: u32, height: u32, layers: u32) {
    let dir = tempfile::tempdir().expect("tempdir");
    let frame = mock_frame(width, height);
    let bytes = frame.len();
    build(&config(dir.path(), layers, true), frame);
    // Intervals between consecutive frames of the same layer signal.
    let text = std::fs::read_to_string(dir.path().join("journal.jsonl")).expect("journal");
    let mut last: Option<(u32, layerwise::shot::Phase, chrono::DateTime<chrono::Utc>)> = None;
    let mut gaps = Vec::new();
    for line in text.lines() {
        if let Ok(Record::Frame {
            layer, phase, at, ..
        }) = serde_json::from_str(line)
        {
            if let Some((l, p, t)) = last {
                if (l, p) == (layer, phase) {
                    gaps.push((at - t).num_microseconds().unwrap_or_default() as f64 / 1e3);
                }
            }
            last = Some((layer, phase, at));
        }
    }
    gaps.sort_by(|a, b| a.total_cmp(b));
    println!(
        "capture-path overhead, {label} ({width}x{height} JPEG, {:.2} MB, fsync on): {} frames, median {:.2} ms, p90 {:.2} ms, max {:.2} ms (target: median < 5 ms)",
        bytes as f64 / 1e6,
        gaps.len(),
        percentile(&gaps, 0.5),
        percentile(&gaps, 0.9),
        percentile(&gaps, 1.0)
    );
}

fn rss_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn memory(layers: u32) {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut config = config(dir.path(), layers, false);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = 64;
        mock.height = 43;
    }
    let done = Arc::new(AtomicBool::new(false));
    let flag = done.clone();
    let sampler = std::thread::spawn(move || {
        let mut samples = Vec::new();
        let start = Instant::now();
        while !flag.load(Ordering::SeqCst) {
            samples.push((start.elapsed(), rss_kib()));
            std::thread::sleep(Duration::from_millis(100));
        }
        samples.push((start.elapsed(), rss_kib()));
        samples
    });
    let started = Instant::now();
    build(&config, mock_frame(64, 43));
    done.store(true, Ordering::SeqCst);
    let samples = sampler.join().expect("sampler");
    let total = started.elapsed();
    // "At the start": once the build is running (after the first 5% of its time).
    let start_rss = samples
        .iter()
        .find(|(t, _)| *t >= total / 20)
        .map_or(0, |s| s.1);
    let end_rss = samples.last().map_or(0, |s| s.1);
    let peak = samples.iter().map(|s| s.1).max().unwrap_or(0);
    println!(
        "resident memory through a {layers}-layer mock build ({} frames, {:.0} s): start {:.1} MiB, end {:.1} MiB, peak {:.1} MiB, end/start {:.3}",
        layers * 6,
        total.as_secs_f64(),
        start_rss as f64 / 1024.0,
        end_rss as f64 / 1024.0,
        peak as f64 / 1024.0,
        end_rss as f64 / start_rss.max(1) as f64
    );
}

fn main() {
    // `cargo test --benches` runs bench binaries with --bench absent; do the quick part only then.
    let full = std::env::args().any(|a| a == "--bench");
    let layers: u32 = std::env::var("LAYERWISE_BENCH_LAYERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    overhead(
        "demo-size mock frame",
        1472,
        982,
        if full { 100 } else { 3 },
    );
    if full {
        overhead("D810-size mock frame", 7360, 4912, 20);
        memory(layers);
    }
}
