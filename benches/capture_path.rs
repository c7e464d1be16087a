//! Capture-path benchmarks (run with `cargo bench --bench capture_path`):
//! 1. overhead per frame of everything but the camera: lights, the camera thread hop, the
//!    original and sidecar written atomically with fsync, the journal, status, the processing
//!    queue. A prerecorded camera returns a fixed frame instantly, so the time between two frames
//!    of one layer signal is the overhead. Target: median under 5 ms.
//! 2. the same overhead and the processing worker's time per layer with `[inspection]` off and
//!    on, side by side: a calibrated build with the demo vectors, the same frames, builds
//!    alternated off/on so the machine's load falls on both alike. Inspection must leave the
//!    capture path's overhead unchanged.
//! 3. resident memory through a long mock build (default 10,000 layers; LAYERWISE_BENCH_LAYERS
//!    overrides): it must stay flat.
//! 4. the same overhead with the plant interfaces off and on, side by side: on = `/metrics`
//!    served by the page and scraped every 100 ms, MQTT to a broker that accepts and never
//!    reads (a slow one) or to a closed port (an absent one), the OPC UA server with a client
//!    that sends it garbage every 100 ms, rounds alternating. They must leave the capture path's
//!    overhead unchanged.
//!
//! `LAYERWISE_BENCH_ONLY=inspection cargo bench --bench capture_path` runs only 2,
//! `LAYERWISE_BENCH_ONLY=plant` only 4; `LAYERWISE_BENCH_MODEL=MODEL` adds that defect model to
//! the "on" builds (issue 26: the capture path's overhead must not move with a model on).

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

#[path = "support/builds.rs"]
mod builds;
#[path = "support/prerecorded.rs"]
mod prerecorded;

use builds::{calibrated, config, journal, percentile};
use layerwise::build_dir::inspection::InspectionLog;
use layerwise::build_dir::journal::Record;
use layerwise::config::{CameraConfig, Config};
use prerecorded::{mock_frame, run_prerecorded, run_prerecorded_with};
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

fn build(config: &Config, frame: Vec<u8>) {
    run_prerecorded(config, frame);
}

type At = chrono::DateTime<chrono::Utc>;

fn ms(d: chrono::TimeDelta) -> f64 {
    d.num_microseconds().unwrap_or_default() as f64 / 1e3
}

/// Intervals between consecutive frames of the same layer signal, ms, sorted: the capture
/// path's overhead per frame.
fn frame_gaps(records: &[Record]) -> Vec<f64> {
    let mut last: Option<(u32, layerwise::shot::Phase, At)> = None;
    let mut gaps = Vec::new();
    for record in records {
        if let Record::Frame {
            layer, phase, at, ..
        } = record
        {
            if let Some((l, p, t)) = last {
                if (l, p) == (*layer, *phase) {
                    gaps.push(ms(*at - t));
                }
            }
            last = Some((*layer, *phase, *at));
        }
    }
    gaps.sort_by(|a, b| a.total_cmp(b));
    gaps
}

fn overhead(label: &str, width: u32, height: u32, layers: u32) {
    let dir = tempfile::tempdir().expect("tempdir");
    let frame = mock_frame(width, height);
    let bytes = frame.len();
    build(&config(dir.path(), layers, true), frame);
    let gaps = frame_gaps(&journal(dir.path()));
    println!(
        "capture-path overhead, {label} ({width}x{height} JPEG, {:.2} MB, fsync on): {} frames, median {:.2} ms, p90 {:.2} ms, max {:.2} ms (target: median < 5 ms)",
        bytes as f64 / 1e6,
        gaps.len(),
        percentile(&gaps, 0.5),
        percentile(&gaps, 0.9),
        percentile(&gaps, 1.0)
    );
}

/// The processing worker's time on each layer after its last frame, ms, sorted: from when the
/// layer's last frame is stored (or the previous layer done, if later) to its last view in the
/// series and, with inspection on, the layer's inspection done; the pre-scan views are
/// processed while the printer scans, before that.
fn worker_per_layer(dir: &Path, records: &[Record]) -> Vec<f64> {
    let mut last_frame: BTreeMap<u32, At> = BTreeMap::new();
    let mut done: BTreeMap<u32, At> = BTreeMap::new();
    for record in records {
        match record {
            Record::Frame { layer, at, .. } => {
                last_frame.insert(*layer, *at);
            }
            Record::Processed { layer, at, .. } => {
                let e = done.entry(*layer).or_insert(*at);
                *e = (*e).max(*at);
            }
            _ => {}
        }
    }
    let inspected =
        InspectionLog::read(&dir.join(layerwise::build_dir::INSPECTION)).unwrap_or_default();
    for r in &inspected {
        let end = r.at + chrono::TimeDelta::microseconds((r.ms * 1e3) as i64);
        let e = done.entry(r.layer).or_insert(end);
        *e = (*e).max(end);
    }
    let mut previous: Option<At> = None;
    let mut times = Vec::new();
    for (layer, end) in &done {
        let start = match (last_frame.get(layer), previous) {
            (Some(f), Some(p)) => (*f).max(p),
            (Some(f), None) => *f,
            (None, _) => continue,
        };
        times.push(ms(*end - start).max(0.0));
        previous = Some(*end);
    }
    times.sort_by(|a, b| a.total_cmp(b));
    times
}

/// Inspection off and on side by side: `rounds` pairs of builds of `layers` layers.
fn inspection_side_by_side(width: u32, height: u32, layers: u32, rounds: u32) {
    let frame = mock_frame(width, height);
    // (capture-path gaps, worker per layer, inspection ms) for off and on.
    let mut runs: [(Vec<f64>, Vec<f64>, Vec<f64>); 2] = Default::default();
    for _ in 0..rounds {
        for (k, inspect) in [false, true].into_iter().enumerate() {
            let dir = tempfile::tempdir().expect("tempdir");
            let build_dir = dir.path().join("build");
            build(
                &calibrated(&build_dir, layers, (width, height), None, inspect),
                frame.clone(),
            );
            let records = journal(&build_dir);
            runs[k].0.extend(frame_gaps(&records));
            runs[k].1.extend(worker_per_layer(&build_dir, &records));
            let inspected = InspectionLog::read(&build_dir.join(layerwise::build_dir::INSPECTION))
                .unwrap_or_default();
            if inspect && inspected.len() < layers as usize {
                println!(
                    "  (only {} of {layers} layers inspected before the build ended)",
                    inspected.len()
                );
            }
            runs[k].2.extend(inspected.iter().map(|r| r.ms));
        }
    }
    let sorted = |v: &mut Vec<f64>| v.sort_by(|a, b| a.total_cmp(b));
    for run in &mut runs {
        sorted(&mut run.0);
        sorted(&mut run.1);
        sorted(&mut run.2);
    }
    let [off, on] = &runs;
    let grid = config(Path::new("."), 1, true).rectify;
    println!(
        "inspection off vs on ({width}x{height} JPEG, grid {}x{} at {} mm, demo vectors, {rounds} x {layers} layers each, alternated):",
        grid.columns(),
        grid.rows(),
        grid.pixel_mm
    );
    for (what, a, b) in [
        ("capture-path overhead per frame", &off.0, &on.0),
        ("processing after a layer's last frame", &off.1, &on.1),
    ] {
        println!("  {what}: {}", off_vs_on(a, b));
    }
    println!(
        "  inspecting a layer (its record's ms, after the views' cells): median {:.2} ms, p95 {:.2} ms",
        percentile(&on.2, 0.5),
        percentile(&on.2, 0.95)
    );
}

/// A broker that accepts connections and never reads from them; and a port nobody listens on.
fn broken_brokers() -> (String, String) {
    let blackhole = std::net::TcpListener::bind("127.0.0.1:0").expect("blackhole");
    let slow = format!("mqtt://{}", blackhole.local_addr().expect("address"));
    std::thread::spawn(move || {
        let mut held = Vec::new();
        for stream in blackhole.incoming() {
            held.extend(stream.ok());
        }
    });
    let closed = std::net::TcpListener::bind("127.0.0.1:0").expect("port");
    let absent = format!("mqtt://{}", closed.local_addr().expect("address"));
    drop(closed);
    (slow, absent)
}

/// GETs `/metrics` from `addr` every 100 ms until `done`; how many answers came.
fn scrape(addr: std::net::SocketAddr, done: Arc<AtomicBool>) -> std::thread::JoinHandle<u32> {
    std::thread::spawn(move || {
        use std::io::{Read, Write};
        let mut answers = 0;
        while !done.load(Ordering::SeqCst) {
            if let Ok(mut stream) = std::net::TcpStream::connect(addr) {
                let _ = stream.write_all(
                    b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n",
                );
                let mut answer = Vec::new();
                if stream.read_to_end(&mut answer).is_ok() && answer.starts_with(b"HTTP/1.1 200") {
                    answers += 1;
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        answers
    })
}

/// Connects to the OPC UA server at `addr` every 100 ms and sends it 4 KiB of garbage, until
/// `done`.
fn pester(addr: std::net::SocketAddr, done: Arc<AtomicBool>) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        use std::io::Write;
        let junk: Vec<u8> = (0..4096u32)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect();
        while !done.load(Ordering::SeqCst) {
            if let Ok(mut stream) = std::net::TcpStream::connect(addr) {
                let _ = stream.write_all(&junk);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    })
}

/// The capture path with the plant interfaces off and on: `rounds` pairs of builds.
fn plant_side_by_side(width: u32, height: u32, layers: u32, rounds: u32) {
    use layerwise::shutdown::{Shutdown, StopReason};
    let frame = mock_frame(width, height);
    let (slow, absent) = broken_brokers();
    let mut runs: [Vec<f64>; 2] = Default::default();
    let mut scrapes = 0;
    for round in 0..rounds {
        for (k, on) in [false, true].into_iter().enumerate() {
            let dir = tempfile::tempdir().expect("tempdir");
            let build_dir = dir.path().join("build");
            std::fs::create_dir_all(&build_dir).expect("build dir");
            let mut config = config(&build_dir, layers, true);
            let mut options = layerwise::acquisition::RunOptions::new();
            let stop = Shutdown::new();
            let mut running = None;
            if on {
                config.metrics.enabled = true;
                config.mqtt.url = if round % 2 == 0 {
                    slow.clone()
                } else {
                    absent.clone()
                };
                config.mqtt.queue_dir = dir.path().join("mqtt");
                config.mqtt.retry_backoff_ms = [100, 1000];
                let opcua = std::net::TcpListener::bind("127.0.0.1:0").expect("port");
                let opcua_addr = opcua.local_addr().expect("address");
                drop(opcua);
                config.opcua.listen = format!("opc.tcp://{opcua_addr}");
                config.opcua.pki_dir = dir.path().join("opcua-pki");
                let plant = layerwise::plant::Plant::start(&config, &stop);
                options.plant = plant.sink();
                let addr = "127.0.0.1:0".parse().expect("address");
                let page = layerwise::web::WebServer::start(&build_dir, &config.web, addr, &stop)
                    .expect("page");
                let done = Arc::new(AtomicBool::new(false));
                let scraper = scrape(page.addr, done.clone());
                let pester = pester(opcua_addr, done.clone());
                running = Some((plant, page, done, (scraper, pester)));
            }
            run_prerecorded_with(&config, frame.clone(), options);
            if let Some((plant, page, done, scraper)) = running {
                done.store(true, Ordering::SeqCst);
                scrapes += scraper.0.join().expect("scraper");
                let _ = scraper.1.join();
                stop.request(StopReason::TriggerEnded);
                page.join();
                plant.join();
            }
            runs[k].extend(frame_gaps(&journal(&build_dir)));
        }
    }
    for run in &mut runs {
        run.sort_by(|a, b| a.total_cmp(b));
    }
    let [off, on] = &runs;
    println!(
        "plant interfaces off vs on ({width}x{height} JPEG, {rounds} x {layers} layers each, alternated; on: /metrics scraped every 100 ms ({scrapes} answers), MQTT to a broker that never reads / a closed port, the OPC UA server with a client sending it garbage every 100 ms): capture-path overhead per frame: {}",
        off_vs_on(off, on)
    );
}

/// Two sorted samples side by side: medians, 95th percentiles, sizes and their ratios.
fn off_vs_on(off: &[f64], on: &[f64]) -> String {
    format!(
        "off median {:.2} ms, p95 {:.2} ms ({} samples); on median {:.2} ms, p95 {:.2} ms ({} samples); on/off median {:.3}, p95 {:.3}",
        percentile(off, 0.5),
        percentile(off, 0.95),
        off.len(),
        percentile(on, 0.5),
        percentile(on, 0.95),
        on.len(),
        percentile(on, 0.5) / percentile(off, 0.5),
        percentile(on, 0.95) / percentile(off, 0.95),
    )
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
    // LAYERWISE_BENCH_ONLY=inspection: only the side-by-side of inspection off and on.
    if std::env::var("LAYERWISE_BENCH_ONLY").is_ok_and(|v| v == "inspection") {
        inspection_side_by_side(1472, 982, 8, 2);
        return;
    }
    if std::env::var("LAYERWISE_BENCH_ONLY").is_ok_and(|v| v == "plant") {
        plant_side_by_side(1472, 982, 30, 4);
        return;
    }
    if full {
        inspection_side_by_side(1472, 982, 8, 2);
        plant_side_by_side(1472, 982, 30, 4);
        overhead("D810-size mock frame", 7360, 4912, 20);
        memory(layers);
    } else {
        inspection_side_by_side(1472, 982, 2, 1);
        plant_side_by_side(1472, 982, 2, 1);
    }
}
