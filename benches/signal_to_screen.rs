//! The whole path, signal to screen (issue 29), run with
//! `cargo bench --bench signal_to_screen --all-features`: the daemon in this process on a mock
//! trigger, a camera serving six prerecorded D810-size views (7360 x 4912 JPEG, rendered once by
//! the mock camera) each after the D810's download time, every frame rectified onto the 4400 x
//! 4400 plate grid and written deflated (`storage.dicom = "deflate"`), every layer inspected
//! against the demo vectors; the page served on loopback with one client reading its event
//! stream over HTTP. Per step, median and 95th percentile over the layers (default 50):
//! - download: the camera's download time per frame (the frame's sidecar);
//! - read, decode, rectify, encode, write, commit, cells: each frame's steps in the processing
//!   worker (its `frame processed` line at DEBUG; the commit, the slice's fsync and rename, runs
//!   on the worker's commit thread while the lanes go on);
//! - inspection: inspecting a layer once its views' cells are in (its record's `ms`);
//! - processing per layer: the worker's time on the layer, its six frames' steps on the lanes
//!   (the commit left out) and its inspection summed (the worker runs two frames at a time on two cores);
//! - the daemon's part: from the layer's post-scan signal to its inspection record written (the
//!   post-scan views downloaded, stored, processed, the layer inspected);
//! - page event: from the layer's inspection record written to the first event at the page
//!   whose status counts it;
//! - signal to screen: from the layer's post-scan signal to that event at the page.
//!
//! And the peak resident memory of this process (daemon, page and client) through the run.
//!
//! LAYERWISE_BENCH_LAYERS sets the layers (default 50), LAYERWISE_BENCH_INTERVAL_MS the time
//! between signals (default 3000). Without `--bench` (`cargo test --benches`): a quick check
//! with frames a tenth the size, 2 layers.

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

#[path = "support/views.rs"]
mod bench_views;
#[path = "support/builds.rs"]
mod builds;
#[path = "support/memory.rs"]
mod memory;
#[path = "support/prerecorded.rs"]
mod prerecorded;

use builds::{calibrated, journal, percentile};
use chrono::{DateTime, Utc};
use layerwise::build_dir::journal::Record;
use layerwise::config::TriggerConfig;
use layerwise::shot::{Light, Phase, View};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::Layer;

/// The D810's frames come over USB 2.0 (PTP bulk transfers): about 30-35 MB/s in practice,
/// 32 MB/s taken here (a 10 MB JPEG in about 0.3 s).
const DOWNLOAD_MB_PER_S: f64 = 32.0;

/// A frame's steps in its `frame processed` line.
const STEP_FIELDS: [&str; 7] = [
    "read_ms",
    "decode_ms",
    "rectify_ms",
    "encode_ms",
    "write_ms",
    "commit_ms",
    "cells_ms",
];

/// One log event's fields, as text.
type Fields = BTreeMap<String, String>;

/// Keeps the daemon's `frame processed` lines.
struct Steps(Arc<Mutex<Vec<Fields>>>);

struct Visit<'a>(&'a mut Fields);

impl tracing::field::Visit for Visit<'_> {
    fn record_f64(&mut self, field: &tracing::field::Field, value: f64) {
        self.0.insert(field.name().into(), value.to_string());
    }
    fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
        self.0.insert(field.name().into(), format!("{value:?}"));
    }
}

impl<S: tracing::Subscriber> tracing_subscriber::Layer<S> for Steps {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        let mut fields = Fields::new();
        event.record(&mut Visit(&mut fields));
        let message = fields.get("message").map(String::as_str);
        if message == Some("frame processed") {
            if let Ok(mut kept) = self.0.lock() {
                kept.push(fields);
            }
        }
    }
}

/// An event at the page and when it came.
type PageEvent = (DateTime<Utc>, serde_json::Value);

/// The page's client: reads the event stream of the page at `addr` and sends each event's data,
/// with when it came, until `stop`.
fn watch_page(
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    events: crossbeam_channel::Sender<PageEvent>,
) -> std::thread::JoinHandle<()> {
    let mut stream = TcpStream::connect(addr).expect("page");
    stream
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    write!(
        stream,
        "GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    )
    .expect("request");
    std::thread::spawn(move || {
        let mut reader = BufReader::new(stream);
        let mut line = String::new();
        while !stop.load(Ordering::SeqCst) {
            // A timed-out read keeps what it read so far in `line`.
            match reader.read_line(&mut line) {
                Ok(0) => return,
                Ok(_) => {
                    if let Some(data) = line.trim_end().strip_prefix("data: ") {
                        let value = serde_json::from_str(data).unwrap_or_default();
                        let _ = events.send((Utc::now(), value));
                    }
                    line.clear();
                }
                Err(_) => {}
            }
        }
    })
}

/// How many bytes of `inspection.jsonl` the status in a page event counts.
fn inspection_bytes(event: &serde_json::Value) -> u64 {
    event["status"]["bytes_by_kind"]["inspection"]
        .as_u64()
        .unwrap_or(0)
}

fn load_average() -> String {
    let text = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    text.split_whitespace()
        .take(3)
        .collect::<Vec<_>>()
        .join(" ")
}

fn ms(d: chrono::TimeDelta) -> f64 {
    d.num_microseconds().unwrap_or_default() as f64 / 1e3
}

/// What the run left: the daemon's records, its log lines, the page's events.
struct Run {
    records: Vec<Record>,
    steps: Vec<Fields>,
    events: Vec<PageEvent>,
}

/// The per-step samples of a run, ms, each sorted, in the table's order.
fn samples(dir: &Path, run: &Run) -> Vec<(&'static str, Vec<f64>)> {
    let mut rows: Vec<(&'static str, Vec<f64>)> = Vec::new();
    // Download, per frame, from the sidecars.
    let download = std::fs::read_dir(dir.join("raw"))
        .expect("raw")
        .filter_map(|e| e.ok())
        .filter(|e| e.path().extension().is_some_and(|x| x == "json"))
        .filter_map(|e| std::fs::read_to_string(e.path()).ok())
        .filter_map(|t| serde_json::from_str::<layerwise::build_dir::Sidecar>(&t).ok())
        .map(|s| s.download_ms)
        .collect();
    rows.push(("download (per frame)", download));
    let field = |f: &Fields, name: &str| f.get(name).and_then(|v| v.parse::<f64>().ok());
    let frames = &run.steps;
    for (name, key) in [
        "read the original (per frame)",
        "decode (per frame)",
        "rectify (per frame)",
        "encode, deflate (per frame)",
        "write (per frame)",
        "commit: fsync, rename (per frame, on the commit thread)",
        "inspection's cells (per frame)",
    ]
    .into_iter()
    .zip(STEP_FIELDS)
    {
        rows.push((name, frames.iter().filter_map(|f| field(f, key)).collect()));
    }
    let inspected = layerwise::build_dir::inspection::InspectionLog::read(
        &dir.join(layerwise::build_dir::INSPECTION),
    )
    .unwrap_or_default();
    rows.push((
        "inspection (per layer)",
        inspected.iter().map(|r| r.ms).collect(),
    ));
    // The worker's time on a layer: its six frames' steps and its inspection.
    let mut per_layer: BTreeMap<u32, f64> = inspected.iter().map(|r| (r.layer, r.ms)).collect();
    for f in frames {
        let layer = f.get("layer").and_then(|l| l.parse().ok());
        let took: f64 = STEP_FIELDS
            .iter()
            .filter(|k| **k != "commit_ms")
            .filter_map(|k| field(f, k))
            .sum();
        if let Some(sum) = layer.and_then(|l: u32| per_layer.get_mut(&l)) {
            *sum += took;
        }
    }
    rows.push((
        "processing, six views: their steps + inspection, summed (per layer)",
        per_layer.into_values().collect(),
    ));
    // Each layer's record: where it ends in inspection.jsonl, when it was written.
    let text =
        std::fs::read_to_string(dir.join(layerwise::build_dir::INSPECTION)).unwrap_or_default();
    let mut end = 0u64;
    let mut written = BTreeMap::new();
    for (line, record) in text.lines().zip(&inspected) {
        end += line.len() as u64 + 1;
        let at = record.at + chrono::TimeDelta::microseconds((record.ms * 1e3) as i64);
        written.insert(record.layer, (end, at));
    }
    let signals: BTreeMap<u32, DateTime<Utc>> = run
        .records
        .iter()
        .filter_map(|r| match r {
            Record::Event {
                layer,
                phase: Phase::Post,
                at,
            } => Some((*layer, *at)),
            _ => None,
        })
        .collect();
    let (mut daemon, mut page, mut total) = (Vec::new(), Vec::new(), Vec::new());
    for (layer, (end, at)) in &written {
        if let Some(signal) = signals.get(layer) {
            daemon.push(ms(*at - *signal));
        }
        let Some(seen) = run
            .events
            .iter()
            .find(|(_, e)| inspection_bytes(e) >= *end)
            .map(|(t, _)| *t)
        else {
            continue;
        };
        page.push(ms(seen - *at));
        if let Some(signal) = signals.get(layer) {
            total.push(ms(seen - *signal));
        }
    }
    rows.push(("post-scan signal → the layer's record written", daemon));
    rows.push(("page event: record written → event at the page", page));
    rows.push((
        "**signal to screen**: post-scan signal → event at the page",
        total,
    ));
    for (_, v) in &mut rows {
        v.sort_by(f64::total_cmp);
    }
    rows
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let env = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let layers = env("LAYERWISE_BENCH_LAYERS", if full { 50 } else { 2 }) as u32;
    let interval_ms = env("LAYERWISE_BENCH_INTERVAL_MS", if full { 3000 } else { 300 });
    let (w, h, grid) = bench_views::bench_scale(full);
    let load_before = load_average();
    // The six views, rendered once.
    let parts = mock_camera::demo_parts(1);
    let renderer = mock_camera::Renderer::new(w, h, mock_camera::Homography::oblique_view(w, h));
    let views: Vec<View> = Phase::ALL
        .iter()
        .flat_map(|&phase| Light::ALL.iter().map(move |&light| View { phase, light }))
        .collect();
    let frames: BTreeMap<View, Vec<u8>> = views
        .par_iter()
        .map(|view| {
            (
                *view,
                renderer.render_jpeg(&bench_views::scene(&parts, view), 95),
            )
        })
        .collect();
    let mean_bytes = frames.values().map(Vec::len).sum::<usize>() as f64 / frames.len() as f64;
    let download = Duration::from_secs_f64(mean_bytes / (DOWNLOAD_MB_PER_S * 1e6));
    let camera = prerecorded::Prerecorded {
        frames: Arc::new(frames),
        fallback: Vec::new(),
        download,
    };
    drop(renderer);

    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("build");
    let mut config = calibrated(&dir, layers, (w, h), Some(grid), true);
    config.storage.dicom = layerwise::dicom::Compression::Deflate;
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = interval_ms;
    }
    // The daemon's per-frame steps at DEBUG; its warnings and errors to stderr.
    let kept = Arc::new(Mutex::new(Vec::new()));
    let subscriber = tracing_subscriber::registry()
        .with(
            Steps(kept.clone()).with_filter(
                tracing_subscriber::filter::Targets::new()
                    .with_target("layerwise", tracing::Level::DEBUG),
            ),
        )
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_filter(tracing::level_filters::LevelFilter::WARN),
        );
    tracing::subscriber::set_global_default(subscriber).expect("subscriber");

    let stop = layerwise::shutdown::Shutdown::new();
    let page = layerwise::web::WebServer::start(
        &dir,
        &config.web,
        "127.0.0.1:0".parse().expect("address"),
        &stop,
    )
    .expect("page");
    let (tx, rx) = crossbeam_channel::unbounded();
    let done = Arc::new(AtomicBool::new(false));
    let client = watch_page(page.addr, done.clone(), tx);
    // The page's first event says it is open.
    let mut events = vec![rx
        .recv_timeout(Duration::from_secs(30))
        .expect("first event")];
    // The peak from here on: the daemon's run, not the frames' rendering.
    memory::reset_peak();
    let started = std::time::Instant::now();
    // Every frame processed and every layer inspected before the run returns.
    let mut options = layerwise::acquisition::RunOptions::new();
    options.drain_at_end = true;
    prerecorded::run_camera(&config, camera, options);
    let took = started.elapsed();
    // The page tells the last layer's record within a few watch periods.
    let inspected =
        std::fs::metadata(dir.join(layerwise::build_dir::INSPECTION)).map_or(0, |m| m.len());
    while let Ok(event) = rx.recv_timeout(Duration::from_secs(10)) {
        let told = inspection_bytes(&event.1) >= inspected;
        events.push(event);
        if told {
            break;
        }
    }
    let peak_kib = memory::peak_rss_kib();
    done.store(true, Ordering::SeqCst);
    let _ = client.join();
    stop.request(layerwise::shutdown::StopReason::TriggerEnded);
    page.join();
    events.extend(rx.try_iter());
    let run = Run {
        records: journal(&dir),
        steps: std::mem::take(&mut *kept.lock().expect("steps")),
        events,
    };
    let rows = samples(&dir, &run);

    println!(
        "signal to screen: {layers} layers of six {w}x{h} JPEG views ({:.1} MB each, download {:.0} ms at {DOWNLOAD_MB_PER_S} MB/s), signals {interval_ms} ms apart, grid {}x{} at {} mm, storage.dicom = deflate, inspection on (demo vectors), one page client; {:.0} s; load average {load_before} before, {} after",
        mean_bytes / 1e6,
        download.as_secs_f64() * 1e3,
        grid.columns(),
        grid.rows(),
        grid.pixel_mm,
        took.as_secs_f64(),
        load_average()
    );
    println!(
        "peak resident memory of the process (daemon, page, client; VmHWM from the first signal): {:.0} MiB",
        peak_kib as f64 / 1024.0
    );
    println!();
    println!("| step | median | p95 | samples |");
    println!("| --- | --- | --- | --- |");
    for (name, v) in &rows {
        if v.is_empty() {
            println!("| {name} | - | - | 0 |");
            continue;
        }
        println!(
            "| {name} | {:.0} ms | {:.0} ms | {} |",
            percentile(v, 0.5),
            percentile(v, 0.95),
            v.len()
        );
    }
}
