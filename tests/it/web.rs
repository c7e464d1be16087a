//! The operator page over HTTP: `layerwise serve` on a finished build (JSON, pictures, crops,
//! originals, vectors, events; requests that try to leave the build directory), and the daemon
//! serving its page while it captures, with many connections open.

use crate::common::*;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::time::{Duration, Instant};

fn get_jpeg(addr: SocketAddr, path: &str) -> image::DynamicImage {
    let (status, body) = http(addr, "GET", path, b"");
    assert_eq!(status, 200, "{path}: {}", String::from_utf8_lossy(&body));
    image::load_from_memory_with_format(&body, image::ImageFormat::Jpeg).unwrap()
}

/// Where the mock camera's part 3 (the 20 x 12 mm box) is, build mm `[x0, y0, x1, y1]`.
const PART3_MM: [f64; 4] = [40.0, 44.0, 60.0, 56.0];

/// [`web_config`] with the mock camera at 640 x 427 (the inspection's smallest tested frames)
/// rendering `inject` (`demo --inject` syntax).
pub(crate) fn injected_config(
    dir: &Path,
    layers: u32,
    inject: &[&str],
) -> layerwise::config::Config {
    let mut config = web_config(dir, layers);
    let (w, h) = (640, 427);
    if let layerwise::config::CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = w;
        mock.height = h;
        mock.inject = inject.iter().map(|i| i.parse().unwrap()).collect();
    }
    config.calibration.file = Some(write_true_calibration(
        dir,
        &mock_camera::Homography::oblique_view(w, h),
    ));
    config
}

/// A build-mm box as fractions `[x, y, w, h]` of the rectified picture of `grid` (the JSON of
/// `/api/layers`), rows from the far (+y) edge.
fn picture_fractions(grid: &serde_json::Value, mm: [f64; 4]) -> [f64; 4] {
    let g = |k: &str| grid[k].as_f64().unwrap();
    let (width, height) = (g("x_max") - g("x_min"), g("y_max") - g("y_min"));
    [
        (mm[0] - g("x_min")) / width,
        (g("y_max") - mm[3]) / height,
        (mm[2] - mm[0]) / width,
        (mm[3] - mm[1]) / height,
    ]
}

#[test]
fn serve_answers_the_page_json_pictures_and_events_and_nothing_outside_the_build() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 3);
    let (child, addr) = serve(&dir, &[]);

    let (status, page) = http(addr, "GET", "/", b"");
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&page).contains("id=\"layer-number\""));
    assert_eq!(http(addr, "GET", "/app.js", b"").0, 200);

    let report = get_json(addr, "/api/status");
    assert_eq!(report["layer"], 3);
    assert_eq!(report["frames"], 18);
    let layers = get_json(addr, "/api/layers");
    assert_eq!(layers["newest"], 3);
    assert_eq!(layers["views"].as_array().unwrap().len(), 6);
    assert_eq!(
        (layers["rectified"].as_bool(), layers["vectors"].as_bool()),
        (Some(true), Some(true))
    );
    let timeline = layers["layers"].as_array().unwrap();
    assert_eq!(timeline.len(), 3);
    for l in timeline {
        assert_eq!(
            (
                l["stored"].as_u64(),
                l["processed"].as_u64(),
                l["missing"].as_u64()
            ),
            (Some(6), Some(6), Some(0)),
            "{l}"
        );
        assert!(l["lag_ms"].as_i64().unwrap() >= 0);
    }
    let layer = get_json(addr, "/api/layers/2");
    assert_eq!(layer["views"]["post_top"]["state"], "processed");
    assert_eq!(
        layer["views"]["post_top"]["file"],
        "raw/L00002_post_top.jpg"
    );

    // Previews: rectified on the 550 x 550 grid, the oblique frame at its 320 x 214; a crop of a
    // tenth of the plate at full resolution.
    let rectified = get_jpeg(
        addr,
        layer["pictures"]["post_top"]["rectified"].as_str().unwrap(),
    );
    assert_eq!((rectified.width(), rectified.height()), (550, 550));
    let raw = get_jpeg(addr, layer["pictures"]["post_top"]["raw"].as_str().unwrap());
    assert_eq!((raw.width(), raw.height()), (320, 214));
    let crop = get_jpeg(
        addr,
        "/api/layers/2/post_top/picture.jpg?kind=rectified&x=0.45&y=0.45&w=0.1&h=0.1",
    );
    assert_eq!((crop.width(), crop.height()), (55, 55));
    // The preview shows the frame: the middle of the plate is not the fill of pixels off the frame.
    assert!(rectified.to_luma8().get_pixel(275, 275)[0] > 0);
    let (status, original) = http(addr, "GET", "/api/layers/2/post_top/original", b"");
    assert_eq!(status, 200);
    assert_eq!(
        original,
        std::fs::read(dir.join("raw/L00002_post_top.jpg")).unwrap()
    );
    let (status, svg) = http(addr, "GET", "/api/layers/2/vectors.svg", b"");
    let svg = String::from_utf8(svg).unwrap();
    assert_eq!(status, 200);
    assert!(
        svg.contains("viewBox=\"0 0 550 550\"") && svg.contains("class=\"contour\" d=\"M"),
        "{svg:.300}"
    );

    // The event stream tells a page where the build stands as soon as it connects.
    let mut events = open_events(addr);
    let mut seen = String::new();
    let mut buf = [0u8; 4096];
    while !seen.contains("\"newest\":3") {
        let n = events.read(&mut buf).expect("an update event arrives");
        assert!(n > 0, "stream closed: {seen}");
        seen.push_str(&String::from_utf8_lossy(&buf[..n]));
    }
    assert!(
        seen.contains("text/event-stream") && seen.contains("event: update"),
        "{seen}"
    );

    // Only layer numbers and view names reach the disk.
    let journal = std::fs::read_to_string(dir.join("journal.jsonl")).unwrap();
    for path in [
        "/api/layers/..",
        "/api/layers/0",
        "/api/layers/100000",
        "/api/layers/4294967297",
        "/api/layers/99999999999999999999999",
        "/api/layers/-1",
        "/api/layers/+2",
        "/api/layers/2.0",
        "/api/layers/%2e%2e",
        "/api/layers/..%2F..%2Fjournal.jsonl",
        "/api/layers/2/..%2F..%2Fjournal.jsonl/original",
        "/api/layers/2/post_top%2F..%2F..%2Fjournal.jsonl/original",
        "/api/layers/2/%2Fetc%2Fpasswd/original",
        "/api/layers/2/..%5C..%5Cjournal.jsonl/original",
        "/api/layers/2/POST_TOP/original",
        "/api/layers/2/post_top/../../../journal.jsonl",
        "/api/layers/2/post_top/picture.jpg?kind=..%2F..%2Fjournal.jsonl",
        "/api/layers/2/post_top/picture.jpg?x=0.9&y=0&w=0.5&h=0.1",
        "/api/layers/2/post_top/picture.jpg?x=NaN&y=0&w=0.1&h=0.1",
        "/api/layers/2/post_top/picture.jpg?x=0&y=0&w=1e-300&h=0.1",
        "/api/layers/2/post_top/picture.jpg?x=0",
        "/api/layers/99/post_top/original",
        "/api/layers/99/vectors.svg",
        "/journal.jsonl",
        "/raw/L00002_post_top.jpg",
        "//etc/passwd",
        "/../journal.jsonl",
    ] {
        let (status, body) = http(addr, "GET", path, b"");
        let text = String::from_utf8_lossy(&body);
        assert!(matches!(status, 400 | 404), "{path}: {status} {text:.200}");
        assert!(
            !text.contains("\"kind\":\"frame\"") && !text.contains("root:"),
            "{path}: {text:.200}"
        );
        assert!(!journal.is_empty());
    }
    // Read-only, with bounded request bodies.
    let (status, _) = http(addr, "POST", "/api/layers", &vec![b'x'; 1 << 20]);
    assert!(matches!(status, 405 | 413), "{status}");
    let (status, _) = http(addr, "PUT", "/api/layers/2/post_top/original", b"x");
    assert_eq!(status, 405);
    // Still serving after all that.
    assert_eq!(get_json(addr, "/api/layers/3")["layer"], 3);
    drop(child);
}

/// The layer detail of an injected layer carries each inspection flag with its box as fractions
/// of the rectified picture: the flag's grid pixels over the grid's size (the contract of
/// vectors.svg and the previews), on the anomaly; a plate-wide flag is drawn over every view of
/// its phase, a part's over its own view; the timeline marks the layer, a clean layer has none.
#[test]
fn the_layer_detail_outlines_inspection_flags_in_picture_fractions() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    // The first three layers are the bed's reference: a streak is judged from layer 4 on.
    let config = injected_config(&dir, 6, &["streak@4/y=-60/w=3/c=30", "no-fusion@5/part=3"]);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    run_build(&config_path);
    let (child, addr) = serve(&dir, &[]);
    let layers = get_json(addr, "/api/layers");
    let grid = &layers["grid"];
    let (cols, rows) = (550.0, 550.0);
    assert_eq!(grid["pixel_mm"], 0.5, "{grid}");
    let worst: Vec<_> = layers["layers"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l["worst"].as_str().unwrap_or("").to_string())
        .collect();
    assert_eq!(worst[0], "", "{worst:?}");
    assert!(!worst[3].is_empty() && !worst[4].is_empty(), "{worst:?}");

    let clean = get_json(addr, "/api/layers/1");
    assert_eq!(clean["inspection"], serde_json::json!([]), "{clean}");

    let check_box = |flag: &serde_json::Value, mm: [f64; 4], tolerance_mm: f64| {
        let b = &flag["box"];
        let px: Vec<f64> = flag["bbox_px"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let fraction = ["x", "y", "w", "h"].map(|k| b[k].as_f64().unwrap());
        let contract = [
            px[0] / cols,
            px[1] / rows,
            (px[2] + 1.0 - px[0]) / cols,
            (px[3] + 1.0 - px[1]) / rows,
        ];
        for (got, want) in fraction.iter().zip(contract) {
            assert!(
                (got - want).abs() < 1e-9,
                "{flag}: {fraction:?} vs {contract:?}"
            );
        }
        let truth = picture_fractions(grid, mm);
        let tolerance = tolerance_mm / 275.0;
        for (got, want) in fraction.iter().zip(truth) {
            assert!(
                (got - want).abs() < tolerance,
                "{flag}: {fraction:?} vs {truth:?}"
            );
        }
    };

    let streaky = get_json(addr, "/api/layers/4");
    let streak = streaky["inspection"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["kind"] == "streak")
        .unwrap_or_else(|| panic!("{streaky}"))
        .clone();
    // Along x over the injected span (found per 40 mm segment), 3 mm wide at y = -60.
    check_box(&streak, [-40.0, -61.5, 95.0, -58.5], 25.0);
    let b = &streak["box"];
    let y_mid = b["y"].as_f64().unwrap() + b["h"].as_f64().unwrap() / 2.0;
    assert!(
        (y_mid - (137.5 + 60.0) / 275.0).abs() < 2.0 / 275.0,
        "{streak}"
    );
    assert_eq!(
        streak["draw_on"],
        serde_json::json!(["pre_front", "pre_side", "pre_top"])
    );

    let unfused = get_json(addr, "/api/layers/5");
    let flag = unfused["inspection"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["kind"] == "under_fusion")
        .unwrap_or_else(|| panic!("{unfused}"))
        .clone();
    assert_eq!(flag["part"], 3);
    check_box(&flag, PART3_MM, 1.5);
    assert_eq!(flag["draw_on"], serde_json::json!(["post_top"]));
    assert!(
        unfused["summary"]["flags"].as_u64().unwrap() >= 1,
        "{unfused}"
    );
    drop(child);
}

#[test]
fn the_daemon_serves_its_page_while_capturing_and_many_idle_connections_do_not_slow_capture() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let mut config = web_config(&dir, 8);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 150;
    }
    config.web.listen = "127.0.0.1:0".into();
    config.web.max_connections = 8;
    config.web.max_event_streams = 4;
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let started = Instant::now();
    let (mut child, addr, stderr) = live_page(&config_path);
    // Four open pages, then two hundred connections that never send a request: far beyond
    // web.max_connections. They give way to one another; capture does not notice.
    let mut streams = Vec::new();
    for _ in 0..4 {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET /api/events HTTP/1.1\r\nHost: localhost\r\n\r\n").unwrap();
        streams.push(s);
    }
    let idle: Vec<TcpStream> = (0..200)
        .filter_map(|_| TcpStream::connect(addr).ok())
        .collect();
    assert!(idle.len() >= 100, "only {} connections", idle.len());
    let status = child.wait().unwrap();
    let log = stderr.join().unwrap();
    assert!(status.success(), "{log}");
    let elapsed = started.elapsed();
    let replay = replay(&dir);
    assert_eq!(
        (replay.frames.len(), replay.missing.len()),
        (48, 0),
        "{log}"
    );
    // A guard against a hang, not a speed target (bench web_clients measures the capture
    // path's overhead with pages open): 16 signals 150 ms apart end long before this.
    assert!(elapsed < Duration::from_secs(120), "{elapsed:?}\n{log}");
    // Every signal's three frames carry their sidecar (the per-frame capture times are
    // there for the operator; their bound is the benchmark's business).
    let mut layers = std::collections::BTreeMap::<u64, usize>::new();
    for entry in std::fs::read_dir(dir.join("raw")).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "json") {
            let sidecar = read_json(&path);
            assert!(
                sidecar["capture_ms"].as_f64().is_some(),
                "{}",
                path.display()
            );
            *layers
                .entry(sidecar["layer"].as_u64().unwrap())
                .or_default() += 1;
        }
    }
    assert_eq!(layers.len(), 8, "{layers:?}");
    assert!(layers.values().all(|&n| n == 6), "{layers:?}");
    drop(idle);
    drop(streams);
}

/// Idle clients cannot hold the page: with every connection of `max_connections` (64) taken by
/// clients that send nothing or half a request, a page's request is answered at once (the idle
/// connection waiting longest makes room), and `--idle-timeout-s 1` closes the others; an open
/// event stream outlives the timeout (its keep-alive).
#[test]
fn idle_connections_give_way_to_a_request_and_are_closed_after_the_idle_timeout() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let (child, addr) = serve(&dir, &["--idle-timeout-s", "1", "--max-connections", "64"]);
    let mut events = open_events(addr);
    let mut buf = [0u8; 4096];
    assert!(events.read(&mut buf).unwrap() > 0, "the stream answers");
    let mut idle: Vec<TcpStream> = (0..63)
        .map(|k| {
            let mut s = TcpStream::connect(addr).unwrap();
            if k % 2 == 0 {
                write!(s, "GET /api/status HTTP/1.1\r\nHost: loc").unwrap();
            }
            s
        })
        .collect();
    // Every place is taken: an idle connection makes room for this request.
    let started = Instant::now();
    let (status, body) = http(addr, "GET", "/api/layers", b"");
    let waited = started.elapsed();
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    assert!(waited < Duration::from_secs(2), "answered after {waited:?}");
    // The idle ones were closed by the server.
    for s in &mut idle {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut rest = Vec::new();
        let _ = s.read_to_end(&mut rest);
        assert!(
            rest.is_empty() || String::from_utf8_lossy(&rest).starts_with("HTTP/1.1 408"),
            "{}",
            String::from_utf8_lossy(&rest)
        );
    }
    // The open page's stream is still there: keep-alives keep coming.
    let mut seen = 0;
    let until = Instant::now() + Duration::from_millis(1500);
    while Instant::now() < until {
        let n = events.read(&mut buf).expect("the event stream stays open");
        assert!(n > 0, "the event stream was closed");
        seen += n;
    }
    assert!(seen > 0);
    drop(child);
}

/// The daemon's page is a process of its own (issue 30, "One request stops a build": a request
/// once ended the daemon mid-build). Killed with SIGKILL mid-build, the page takes nothing of
/// capture with it: every frame of 30 layers x 6 views is stored with its sidecar, none missing;
/// the daemon's supervisor starts the page again on the same address, and it serves the layers
/// captured since before the build ends.
#[test]
fn killing_the_page_process_mid_build_leaves_capture_whole_and_the_page_restarts() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let layers = 30;
    let mut config = web_config(&dir, layers);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 200;
    }
    config.web.listen = "127.0.0.1:0".into();
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let (mut daemon, addr, log) = live_page(&config_path);
    let stored = |layer: u32| dir.join(format!("raw/L{layer:05}_post_top.json")).exists();
    wait_until("layer 4 captured", Duration::from_secs(60), || stored(4));
    let first = page_process(daemon.id()).expect("the daemon's page process");
    assert_eq!(http(addr, "GET", "/api/status", b"").0, 200);
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(first as i32),
        nix::sys::signal::Signal::SIGKILL,
    )
    .unwrap();
    // Started again (after the supervisor's 1 s back-off), while the daemon goes on capturing.
    let mut second = None;
    wait_until(
        "the page process started again",
        Duration::from_secs(20),
        || {
            second = page_process(daemon.id()).filter(|&p| p != first);
            second.is_some()
        },
    );
    let (status, body) = http(addr, "GET", "/api/layers", b"");
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    let newest = get_json(addr, "/api/status");
    assert!(
        daemon.try_wait().unwrap().is_none() && !stored(layers),
        "the page came back only after the build: {newest}"
    );
    // A layer captured after the kill is served by the new process.
    wait_until("a layer after the kill", Duration::from_secs(30), || {
        stored(8)
    });
    // (once the new process's journal watch has seen it: it may answer 404 for a moment)
    wait_until(
        "layer 8's picture from the new page",
        Duration::from_secs(20),
        || http(addr, "GET", "/api/layers/8/post_top/picture.jpg", b"").0 == 200,
    );
    let ended = daemon.wait().unwrap();
    let log = log.join().unwrap();
    assert!(ended.success(), "{log}");
    let replay = replay(&dir);
    assert_eq!(
        (replay.frames.len(), replay.missing.len()),
        (layers as usize * 6, 0),
        "{log}"
    );
    assert_sidecars_match(&dir);
    // The supervisor said what happened, once.
    let restarts = log.matches("the operator page process ended").count();
    assert_eq!(restarts, 1, "{log}");
    assert!(
        log.contains("SIGKILL") || log.contains("signal: 9"),
        "{log}"
    );
}

/// Headless Chromium drives the page of a running build (tests/web_browser.py): the layer
/// advances without a reload, the newest layer's picture loads, a click on an earlier layer of
/// the timeline shows it; on the layer where part 3 did not fuse (injected) the flag is outlined
/// on the part's place over the post-scan top view, in the large view and a crop, F toggles it,
/// a clean layer shows none; the powder bed, settled by then, is outlined over the pre-scan views
/// of that layer and not before it settled. Screenshots are kept in target/test-artifacts: live-page.png,
/// flagged-layer.png and flagged-layer-zoom.png.
#[test]
fn a_browser_follows_the_build_live_and_jumps_to_an_earlier_layer() {
    let chromedriver = chromedriver();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let (flagged, clean) = (5, 3);
    let mut config = injected_config(&dir, 100, &[&format!("no-fusion@{flagged}/part=3")]);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 400;
    }
    config.web.listen = "127.0.0.1:0".into();
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let (child, addr, stderr) = live_page(&config_path);
    let artifacts = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/test-artifacts");
    std::fs::create_dir_all(&artifacts).unwrap();
    let screenshot = artifacts.join("live-page.png");
    let flag_shot = artifacts.join("flagged-layer.png");
    for png in [&screenshot, &flag_shot] {
        let _ = std::fs::remove_file(png);
    }
    let grid = serde_json::to_value(plate_grid()).unwrap();
    let expected = picture_fractions(&grid, PART3_MM).map(|v| format!("{v:.5}"));
    let out = std::process::Command::new("python3")
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/web_browser.py"))
        .arg(format!("http://{addr}/"))
        .arg(chromedriver)
        .arg(&screenshot)
        .arg(flagged.to_string())
        .arg("post_top")
        .args(&expected)
        .arg(clean.to_string())
        .arg(&flag_shot)
        .output()
        .unwrap();
    let daemon = terminate(child);
    let log = stderr.join().unwrap();
    assert!(out.status.success(), "{}\n--- daemon\n{log}", report(&out));
    assert!(daemon.status.success(), "{log}");
    for png in [&screenshot, &flag_shot] {
        let png = image::open(png).unwrap();
        assert!(
            png.width() >= 1000 && png.height() >= 600,
            "{}x{}",
            png.width(),
            png.height()
        );
    }
    println!("{}", String::from_utf8_lossy(&out.stdout));
}

/// POST /api/calibration as the calibration page sends it.
fn post_pairs(addr: SocketAddr, layer: u32, pairs: &[[f64; 4]]) -> (u16, serde_json::Value) {
    let points: Vec<_> = pairs
        .iter()
        .map(|p| serde_json::json!({"fx": p[0], "fy": p[1], "x": p[2], "y": p[3]}))
        .collect();
    let body = serde_json::json!({"layer": layer, "view": "post_top", "points": points});
    let (status, answer) = http(
        addr,
        "POST",
        "/api/calibration",
        body.to_string().as_bytes(),
    );
    (status, serde_json::from_slice(&answer).unwrap_or_default())
}

#[test]
fn the_calibration_page_saves_new_points_files_and_registers_only_when_enabled() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 2);
    // The clicks of an operator who hit the true points: build corners seen through the mock
    // camera's homography, as fractions of the 320 x 214 frame.
    let truth = mock_camera::Homography::oblique_view(320, 214);
    let image_from_build = truth.inverse().unwrap();
    let pairs: Vec<[f64; 4]> = [
        (-60.0, -50.0),
        (60.0, -50.0),
        (60.0, 50.0),
        (-60.0, 50.0),
        (0.0, 0.0),
    ]
    .iter()
    .map(|&(x, y)| {
        let (u, v) = image_from_build.apply(x, y).unwrap();
        [u / 320.0, v / 214.0, x, y]
    })
    .collect();
    assert!(pairs
        .iter()
        .all(|p| (0.0..=1.0).contains(&p[0]) && (0.0..=1.0).contains(&p[1])));

    let (off, addr) = serve(&dir, &[]);
    let (status, body) = post_pairs(addr, 1, &pairs);
    assert_eq!(status, 403, "{body}");
    assert!(!dir.join("calibration").exists());
    drop(off);

    let (on, addr) = serve(&dir, &["--calibration-page"]);
    let (status, page) = http(addr, "GET", "/calibrate", b"");
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&page).contains("Save &amp; register"));
    assert_eq!(post_pairs(addr, 1, &pairs[..3]).0, 400);
    assert_eq!(post_pairs(addr, 99, &pairs).0, 404);
    let (status, first) = post_pairs(addr, 1, &pairs);
    assert_eq!(status, 200, "{first}");
    let points_file = dir.join(first["points_file"].as_str().unwrap());
    assert!(first["points_file"]
        .as_str()
        .unwrap()
        .starts_with("calibration/points-L00001-post_top-"));
    let saved = std::fs::read_to_string(&points_file).unwrap();
    let read = layerwise::calibrate::parse_points(&saved, &points_file).unwrap();
    assert_eq!(read.len(), 5);
    for (c, p) in read.iter().zip(&pairs) {
        assert!((c.image.u - p[0] * 320.0).abs() < 0.01 && (c.image.v - p[1] * 214.0).abs() < 0.01);
        assert!((c.build.x - p[2]).abs() < 1e-3 && (c.build.y - p[3]).abs() < 1e-3);
    }
    // The registration ran to the vectors of the parts in view: a new calibration with its
    // overlay, a better correlation than the clicks gave, and one residual per pair, a few
    // pixels at most on this 320 x 214 frame (about 1 mm a pixel) since the clicks were true.
    let calibration = first["calibration_file"]
        .as_str()
        .unwrap_or_else(|| panic!("{first}"));
    assert!(dir.join(calibration).is_file());
    let residuals = first["click_residuals_px"].as_array().unwrap();
    assert_eq!(residuals.len(), 5);
    assert!(
        residuals.iter().all(|r| r.as_f64().unwrap() < 5.0),
        "{first}"
    );
    let correlation = first["correlation"].as_array().unwrap();
    let (start, end) = (
        correlation[0].as_f64().unwrap(),
        correlation[1].as_f64().unwrap(),
    );
    assert!(end > start && end > 0.9, "{first}");
    let (status, png) = http(addr, "GET", first["overlay"].as_str().unwrap(), b"");
    assert_eq!(status, 200);
    assert!(png.starts_with(b"\x89PNG"));
    // Saving again writes another file; the first stays as it was.
    let (_, second) = post_pairs(addr, 1, &pairs);
    assert_ne!(second["points_file"], first["points_file"]);
    assert_eq!(std::fs::read_to_string(&points_file).unwrap(), saved);
    assert_eq!(
        http(
            addr,
            "GET",
            "/api/calibration/..%2F..%2Fjournal/overlay.png",
            b""
        )
        .0,
        400
    );
    drop(on);
}

/// Confirm / false alarm on the model's flags through the page: recorded with who and when in
/// verdicts.jsonl (only for a flag the layer has), listed back, behind the token when one is
/// set; the model's heat map is served per layer and view.
#[test]
fn operators_confirm_or_dismiss_flags_and_the_page_serves_the_heat_map() {
    let tmp = tempfile::tempdir().unwrap();
    let (dir, _) = model_build(tmp.path());
    let token = "0123456789abcdef0123";
    let token_file = tmp.path().join("token");
    std::fs::write(&token_file, token).unwrap();
    let (_child, addr) = serve(&dir, &["--token-file", token_file.to_str().unwrap()]);
    let auth = format!("token={token}");
    let (layer, flag) = (1..=3)
        .find_map(|n| {
            let (status, body) = http(addr, "GET", &format!("/api/layers/{n}?{auth}"), b"");
            assert_eq!(status, 200);
            let detail: serde_json::Value = serde_json::from_slice(&body).unwrap();
            let flags = detail["inspection"].as_array().unwrap().clone();
            flags
                .into_iter()
                .find(|f| f["kind"] == "model")
                .map(|f| (n, f))
        })
        .expect("a model flag");
    let body = serde_json::json!({
        "view": flag["view"], "verdict": "confirm", "who": "anna",
        "flag": {"kind": "model", "class": flag["class"], "bbox_mm": flag["bbox_mm"]},
    })
    .to_string();
    let path = format!("/api/layers/{layer}/verdicts");
    let (status, _) = http(addr, "POST", &path, body.as_bytes());
    assert_eq!(status, 401, "no token, no verdict");
    let (status, answer) = http(addr, "POST", &format!("{path}?{auth}"), body.as_bytes());
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&answer));
    let wrong = body
        .replace("\"confirm\"", "\"false_alarm\"")
        .replace("\"model\"", "\"streak\"");
    let (status, answer) = http(addr, "POST", &format!("{path}?{auth}"), wrong.as_bytes());
    assert_eq!(status, 404, "{}", String::from_utf8_lossy(&answer));
    let (status, _) = http(
        addr,
        "POST",
        &format!("{path}?{auth}"),
        b"{\"view\":\"pre_top\"}",
    );
    assert!(status == 400 || status == 422, "{status}");
    let lines = std::fs::read_to_string(dir.join("verdicts.jsonl")).unwrap();
    assert_eq!(lines.lines().count(), 1, "{lines}");
    let v: serde_json::Value = serde_json::from_str(lines.trim()).unwrap();
    assert_eq!(
        (v["who"].as_str(), v["verdict"].as_str()),
        (Some("anna"), Some("confirm"))
    );
    assert_eq!(v["layer"], layer);
    assert!(v["at"].as_str().unwrap().contains('T'), "{v}");
    let (status, listed) = http(addr, "GET", &format!("{path}?{auth}"), b"");
    assert_eq!(status, 200);
    let listed: serde_json::Value = serde_json::from_slice(&listed).unwrap();
    assert_eq!(listed["verdicts"].as_array().unwrap().len(), 1, "{listed}");
    let view = flag["view"].as_str().unwrap();
    let (status, png) = http(
        addr,
        "GET",
        &format!("/api/layers/{layer}/{view}/heatmap.png?{auth}"),
        b"",
    );
    assert_eq!(status, 200);
    assert_eq!(image::load_from_memory(&png).unwrap().width(), 137);

    // Training on the build's verdicts needs 10 or more of each class; it says so.
    let said = layerwise()
        .args(["learn", "train", "--out"])
        .arg(tmp.path().join("v.safetensors"))
        .arg("--data")
        .arg(&dir)
        .fails();
    assert!(said.contains("a model needs 10 or more of each"), "{said}");
}

/// The powder bed the inspection judged (found over the first `reference_layers` layers, then
/// kept) joins the layer detail once it settled: null on the layers before, and from the layer
/// it settled on its outline in fractions of the rectified picture spans the box inspection.jsonl
/// recorded (within half a pixel of the picture), with the same box and area, on every later
/// layer too.
#[test]
fn the_layer_detail_outlines_the_powder_bed_the_inspection_judged() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let layers = 7;
    let config = injected_config(&dir, layers, &[]);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    run_build(&config_path);
    let records = std::fs::read_to_string(dir.join(layerwise::build_dir::INSPECTION)).unwrap();
    let (settled, bed) = records
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|r| r["bed"]["outline_mm"].is_array())
        .map(|r| (r["layer"].as_u64().unwrap() as u32, r["bed"].clone()))
        .unwrap_or_else(|| panic!("no settled bed in inspection.jsonl:\n{records}"));
    assert_eq!(
        settled as usize, config.inspection.reference_layers,
        "{records}"
    );
    let (child, addr) = serve(&dir, &[]);
    let grid = get_json(addr, "/api/layers")["grid"].clone();
    let (cols, rows) = (550.0, 550.0);
    assert_eq!(grid["pixel_mm"], 0.5, "{grid}");
    let mm: Vec<f64> = bed["bbox_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let [x, y, w, h] = picture_fractions(&grid, [mm[0], mm[1], mm[2], mm[3]]);
    assert!(w > 0.3 && h > 0.3, "the bed is most of the plate: {bed}");
    for n in 1..settled {
        let detail = get_json(addr, &format!("/api/layers/{n}"));
        assert!(detail["bed"].is_null(), "layer {n}: {}", detail["bed"]);
    }
    for n in settled..=layers {
        let shown = get_json(addr, &format!("/api/layers/{n}"))["bed"].clone();
        assert_eq!(shown["layer"], settled, "layer {n}: {shown}");
        assert_eq!(shown["bbox_mm"], bed["bbox_mm"], "layer {n}");
        assert_eq!(shown["area_mm2"], bed["area_mm2"], "layer {n}");
        let outline: Vec<[f64; 2]> = serde_json::from_value(shown["outline"].clone()).unwrap();
        assert!(outline.len() >= 16, "layer {n}: {shown}");
        let extent = |k: usize| {
            let v = outline.iter().map(|p| p[k]);
            (
                v.clone().fold(f64::INFINITY, f64::min),
                v.fold(f64::NEG_INFINITY, f64::max),
            )
        };
        let ((x0, x1), (y0, y1)) = (extent(0), extent(1));
        let (px, py) = (0.5 / cols, 0.5 / rows);
        for (got, want, half) in [(x0, x, px), (x1, x + w, px), (y0, y, py), (y1, y + h, py)] {
            assert!(
                (got - want).abs() <= half,
                "layer {n}: outline spans x {x0}..{x1}, y {y0}..{y1}; the bed {bed} is at {:?}",
                [x, y, w, h]
            );
        }
    }
    drop(child);
}
