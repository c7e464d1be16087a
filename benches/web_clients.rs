//! The operator page's cost to the daemon (`cargo bench --bench web_clients`): the same mock
//! build (demo-size frames from a prerecorded camera, rectified onto the demo grid and written
//! as DICOM, layer signals every 250 ms) with the page served and 0, then 5 clients open. Each
//! client does what the page does: an event stream, and on every update the layer list and the
//! six pictures of the newest complete layer. Side by side:
//! - capture-path overhead: the time between consecutive frames of one layer signal;
//! - processing per frame: from the frame stored to its slice written (the queue is empty at
//!   this rate, so this is the processing time).
//!
//! LAYERWISE_BENCH_LAYERS sets the layers per run (default 20), LAYERWISE_BENCH_ROUNDS the
//! alternating rounds of 0 and 5 clients (default 3).

#[path = "support/prerecorded.rs"]
mod prerecorded;

use layerwise::build_dir::journal::Record;
use layerwise::config::{Config, TriggerConfig, DEMO_CONFIG};
use prerecorded::{mock_frame, run_prerecorded};
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

const WIDTH: u32 = 1472;
const HEIGHT: u32 = 982;

fn config(dir: &Path, layers: u32) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml")).expect("demo config");
    config.build.output_dir = dir.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
        mock.interval_ms = 250;
    }
    let truth = mock_camera::Homography::oblique_view(WIDTH, HEIGHT);
    let calibration = layerwise::rectify::Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(config.rectify),
        fit: None,
    };
    std::fs::create_dir_all(dir).expect("build dir");
    let path = dir.join("calibration.toml");
    std::fs::write(&path, calibration.to_toml()).expect("calibration");
    config.calibration.file = Some(path);
    config.web.listen = "127.0.0.1:0".into();
    config
}

fn get(addr: SocketAddr, path: &str) -> Vec<u8> {
    let Ok(mut s) = TcpStream::connect(addr) else {
        return Vec::new();
    };
    let _ = s.set_read_timeout(Some(Duration::from_secs(30)));
    let _ = write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n"
    );
    let mut out = Vec::new();
    let _ = s.read_to_end(&mut out);
    let start = out
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .map_or(0, |p| p + 4);
    out.split_off(start)
}

/// A client doing what the page does; counts the pictures it loaded.
fn client(addr: SocketAddr, stop: Arc<AtomicBool>, pictures: Arc<AtomicU64>) {
    let Ok(mut events) = TcpStream::connect(addr) else {
        return;
    };
    let _ = events.set_read_timeout(Some(Duration::from_millis(200)));
    let _ = write!(
        events,
        "GET /api/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    );
    let mut reader = BufReader::new(events);
    let mut line = String::new();
    while !stop.load(Ordering::SeqCst) {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) => return,
            Ok(_) if line.starts_with("event: update") => {
                let layers: serde_json::Value =
                    serde_json::from_slice(&get(addr, "/api/layers")).unwrap_or_default();
                let Some(n) = layers["complete"].as_u64() else {
                    continue;
                };
                for view in layers["views"].as_array().into_iter().flatten() {
                    let view = view.as_str().unwrap_or_default();
                    let jpeg = get(addr, &format!("/api/layers/{n}/{view}/picture.jpg"));
                    if jpeg.starts_with(&[0xFF, 0xD8]) {
                        pictures.fetch_add(1, Ordering::SeqCst);
                    }
                }
            }
            _ => {}
        }
    }
}

#[derive(Default)]
struct Measured {
    gaps_ms: Vec<f64>,
    processing_ms: Vec<f64>,
    pictures: u64,
}

impl Measured {
    fn pool(&mut self, other: Measured) {
        self.gaps_ms.extend(other.gaps_ms);
        self.processing_ms.extend(other.processing_ms);
        self.gaps_ms.sort_by(f64::total_cmp);
        self.processing_ms.sort_by(f64::total_cmp);
        self.pictures += other.pictures;
    }
}

fn build(layers: u32, clients: usize) -> Measured {
    let dir = tempfile::tempdir().expect("tempdir");
    let config = config(dir.path(), layers);
    let addr = config.web.address().expect("address").expect("listen");
    let page = layerwise::web::WebServer::start(
        dir.path(),
        &config.web,
        addr,
        &layerwise::shutdown::Shutdown::new(),
    )
    .expect("page server");
    let stop = Arc::new(AtomicBool::new(false));
    let pictures = Arc::new(AtomicU64::new(0));
    let threads: Vec<_> = (0..clients)
        .map(|_| {
            let (stop, pictures, addr) = (stop.clone(), pictures.clone(), page.addr);
            std::thread::spawn(move || client(addr, stop, pictures))
        })
        .collect();
    run_prerecorded(&config, mock_frame(WIDTH, HEIGHT));
    stop.store(true, Ordering::SeqCst);
    for t in threads {
        let _ = t.join();
    }
    drop(page);
    let text = std::fs::read_to_string(dir.path().join("journal.jsonl")).expect("journal");
    let mut last = None;
    let mut stored = BTreeMap::new();
    let (mut gaps_ms, mut processing_ms) = (Vec::new(), Vec::new());
    let ms = |d: chrono::TimeDelta| d.num_microseconds().unwrap_or_default() as f64 / 1e3;
    for record in text
        .lines()
        .filter_map(|l| serde_json::from_str::<Record>(l).ok())
    {
        match (&record, record.shot()) {
            (Record::Frame { at, .. }, Some(shot)) => {
                if let Some((l, p, t)) = last {
                    if (l, p) == (shot.layer, shot.phase) {
                        gaps_ms.push(ms(*at - t));
                    }
                }
                last = Some((shot.layer, shot.phase, *at));
                stored.insert(shot, *at);
            }
            (Record::Processed { at, .. }, Some(shot)) => {
                if let Some(t) = stored.get(&shot) {
                    processing_ms.push(ms(*at - *t));
                }
            }
            _ => {}
        }
    }
    gaps_ms.sort_by(f64::total_cmp);
    processing_ms.sort_by(f64::total_cmp);
    Measured {
        gaps_ms,
        processing_ms,
        pictures: pictures.load(Ordering::SeqCst),
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let layers: u32 = std::env::var("LAYERWISE_BENCH_LAYERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(if full { 20 } else { 2 });
    // Rounds alternate 0 and 5 clients and pool their frames, so that a load that comes and goes
    // on the machine falls on both sides alike.
    let rounds: usize = std::env::var("LAYERWISE_BENCH_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(if full { 3 } else { 1 });
    let (mut idle, mut busy) = (Measured::default(), Measured::default());
    for _ in 0..rounds {
        idle.pool(build(layers, 0));
        busy.pool(build(layers, 5));
    }
    println!(
        "operator page, {rounds} x {layers} layers of {WIDTH}x{HEIGHT} frames per side, signals 250 ms apart ({} and {} pictures loaded by the clients)",
        idle.pictures, busy.pictures
    );
    println!(
        "{:<44} {:>12} {:>12} {:>8}",
        "", "0 clients", "5 clients", "ratio"
    );
    for (name, a, b) in [
        (
            "capture-path overhead per frame, median ms",
            &idle.gaps_ms,
            &busy.gaps_ms,
            0.5,
        ),
        (
            "capture-path overhead per frame, p90 ms",
            &idle.gaps_ms,
            &busy.gaps_ms,
            0.9,
        ),
        (
            "processing per frame, median ms",
            &idle.processing_ms,
            &busy.processing_ms,
            0.5,
        ),
        (
            "processing per frame, p90 ms",
            &idle.processing_ms,
            &busy.processing_ms,
            0.9,
        ),
    ]
    .map(|(n, a, b, p)| (n, percentile(a, p), percentile(b, p)))
    {
        println!("{name:<44} {a:>12.2} {b:>12.2} {:>8.2}", b / a);
    }
}
