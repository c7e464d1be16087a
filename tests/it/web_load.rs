//! The daemon's page under a bounded attack on loopback while it captures (issue 30, "Header and
//! body deadlines, limits per client, and the operator served under load"): tests/web_stress.py,
//! a process of its own, keeps 2,000 idle connections, 64 slow `POST /api/calibration` bodies
//! and event streams that never read open against `layerwise run`'s page, without and with a
//! token, from 127.0.0.2 (the operator is 127.0.0.1: the limits per address keep it in; from
//! the flood's own address a new connection can sit silent for its TCP retransmission, longer
//! than the flood leaves it). Meanwhile an operator's requests are answered within 2 s, the page process's memory
//! stays within `web.memory_mb` and it is never restarted, and capture stores every frame with
//! its usual per-frame times (before and under the attack, printed).
//!
//! Then each promise on its own, against `layerwise serve`: headers and bodies that trickle are
//! cut at their deadlines and a body declared too large is refused at once; 64 slow bodies
//! holding every connection, and 2,000 idle connections from the operator's own address, keep
//! no one out for 2 s, without and with a token.

use crate::common::*;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::time::{Duration, Instant};

/// What tests/web_stress.py keeps open.
const IDLE: usize = 2000;
const SLOW: usize = 64;
const STREAMS: usize = 64;
/// Layers of the build and the layer after which the attack starts (the frames before it are
/// capture's usual times).
const LAYERS: u32 = 60;
const CALM_LAYERS: u64 = 8;
const TOKEN: &str = "stress-test-token-0123456789";

/// One request of the operator on its own connection, with the token when there is one:
/// (status, how long until the whole answer was read); on no answer, what happened instead.
fn operator_get(addr: SocketAddr, path: &str, token: bool) -> (Result<u16, String>, Duration) {
    let started = Instant::now();
    let status = (|| {
        let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(10))
            .map_err(|e| format!("connect: {e}"))?;
        s.set_read_timeout(Some(Duration::from_secs(10)))
            .map_err(|e| e.to_string())?;
        let auth = if token {
            format!("Authorization: Bearer {TOKEN}\r\n")
        } else {
            String::new()
        };
        // In one write, as a browser sends it (`write!` would send each piece on its own).
        let request =
            format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n{auth}Connection: close\r\n\r\n");
        s.write_all(request.as_bytes())
            .map_err(|e| format!("send: {e}"))?;
        let mut answer = Vec::new();
        s.read_to_end(&mut answer)
            .map_err(|e| format!("read: {e}"))?;
        let code = answer.get(9..12).and_then(|c| std::str::from_utf8(c).ok());
        code.and_then(|c| c.parse().ok())
            .ok_or_else(|| format!("answered {:?}", String::from_utf8_lossy(&answer)))
    })();
    (status, started.elapsed())
}

/// A `/proc/PID/status` field in kB (VmHWM: the most memory the process has held).
fn status_kb(pid: u32, field: &str) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Per-frame capture times (ms) from the sidecars in raw/: (before the attack, under it).
fn capture_times(dir: &Path, attack_from: u64) -> (Vec<f64>, Vec<f64>) {
    let (mut calm, mut loaded) = (Vec::new(), Vec::new());
    for entry in std::fs::read_dir(dir.join("raw")).unwrap().flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "json") {
            let sidecar = read_json(&path);
            let ms = sidecar["capture_ms"].as_f64().unwrap();
            if sidecar["layer"].as_u64().unwrap() < attack_from {
                calm.push(ms);
            } else {
                loaded.push(ms);
            }
        }
    }
    (calm, loaded)
}

/// (median, 95th percentile, maximum) of `v`.
fn spread(v: &mut [f64]) -> (f64, f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.95), at(1.0))
}

/// What one attack measured.
struct Attacked {
    answered: Vec<Duration>,
    page_hwm_kb: u64,
    stress: String,
}

fn attack(token: bool) -> Attacked {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("build");
    let mut config = web_config(&dir, LAYERS);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 150;
    }
    config.web.listen = "127.0.0.1:0".into();
    if token {
        let path = tmp.path().join("web.token");
        std::fs::write(&path, TOKEN).unwrap();
        config.web.token_file = Some(path);
    }
    let memory_mb = config.web.memory_mb;
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let (mut daemon, addr, log) = live_page(&config_path);

    // Capture's usual times first (until the last frame of layer CALM_LAYERS), then the attack.
    let calm_until = Instant::now() + Duration::from_secs(60);
    let calm_done = dir.join(format!("raw/L{CALM_LAYERS:05}_post_top.json"));
    while !calm_done.exists() {
        assert!(
            Instant::now() < calm_until,
            "the build never reached layer {CALM_LAYERS}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let attack_from = CALM_LAYERS + 1;
    let python = std::env::var("LAYERWISE_TEST_PYTHON").unwrap_or_else(|_| "python3".into());
    let mut stress = std::process::Command::new(python)
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/web_stress.py"))
        .args([addr.ip().to_string(), addr.port().to_string()])
        .args([IDLE, SLOW, STREAMS].map(|n| n.to_string()))
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("python3 runs tests/web_stress.py");
    let stress_out = stress.stdout.take().unwrap();
    let stress_lines = std::thread::spawn(move || {
        BufReader::new(stress_out)
            .lines()
            .map_while(Result::ok)
            .collect::<Vec<_>>()
    });

    // The operator, every 200 ms: the status, every fourth time a picture.
    let page = page_process(daemon.id()).expect("the daemon's page process");
    let attack_started = Instant::now();
    let (mut answered, mut failed, mut k) = (Vec::new(), Vec::new(), 0u32);
    let mut hwm_kb = 0;
    // Until the last layer's first signal: the page stops with the build (a request then is
    // cut off by the stop, not by the attack).
    let last = dir.join(format!("raw/L{LAYERS:05}_pre_top.json"));
    let ended = loop {
        if last.exists() {
            break daemon.wait().unwrap();
        }
        if let Some(status) = daemon.try_wait().unwrap() {
            break status;
        }
        k += 1;
        let path = if k % 4 == 0 {
            "/api/layers/1/post_top/picture.jpg".to_string()
        } else {
            "/api/status".to_string()
        };
        match operator_get(addr, &path, token) {
            (Ok(200), took) => answered.push(took),
            (other, took) => failed.push(format!(
                "request {k} ({:?} into the attack), {path} after {took:?}: {other:?}",
                attack_started.elapsed()
            )),
        }
        hwm_kb = hwm_kb.max(status_kb(page, "VmHWM").unwrap_or(0));
        std::thread::sleep(Duration::from_millis(200));
    };
    drop(stress.stdin.take());
    let _ = stress.wait();
    let stress_lines = stress_lines.join().unwrap();
    let log = log.join().unwrap();
    assert!(ended.success(), "{log}");
    assert!(
        failed.is_empty(),
        "the operator was not answered under attack (token: {token}): {failed:?}\n{log}\n{stress_lines:?}"
    );
    assert!(
        !log.contains("the operator page process ended"),
        "the page process was restarted under the attack:\n{log}"
    );
    let replay = replay(&dir);
    assert_eq!(
        (replay.frames.len(), replay.missing.len()),
        (LAYERS as usize * 6, 0),
        "{log}"
    );
    let (mut calm, mut loaded) = capture_times(&dir, attack_from);
    let (calm, loaded) = (spread(&mut calm), spread(&mut loaded));
    let stress = stress_lines.last().cloned().unwrap_or_default();
    eprintln!(
        "web_load (token: {token}): operator answered {} times, slowest {:?}; page process peak \
         RSS {} MB (bound {memory_mb} MB); capture ms median/p95/max before the attack \
         {calm:.1?}, under it {loaded:.1?}; stress: {stress}",
        answered.len(),
        answered.iter().max(),
        hwm_kb / 1000
    );
    // The attack was there: thousands of connections opened and the slow bodies cut off.
    let report: serde_json::Value = serde_json::from_str(&stress).unwrap_or_default();
    assert!(
        report["reopened"]["idle"].as_u64().unwrap_or(0) > 0,
        "the page never closed an idle connection: {stress_lines:?}"
    );
    // Capture did not wait for the page: under the attack frames still took less than the time
    // between two signals (150 ms), the 95th percentile of them; a single slow frame is the
    // machine's (CI runs the other tests beside this one on 2 cores: one frame of 262 ms among
    // hundreds of 8 ms, p95 28 ms, once), and a page that held capture up would hold up many.
    // No frame may take a second, whatever the machine.
    assert!(
        loaded.1 < 150.0 && loaded.2 < 1000.0,
        "capture under attack {loaded:?}, before {calm:?}"
    );
    Attacked {
        answered,
        page_hwm_kb: hwm_kb,
        stress,
    }
}

#[test]
fn under_2000_idle_connections_slow_bodies_and_unread_streams_the_operator_is_answered_and_capture_goes_on(
) {
    for token in [false, true] {
        let attacked = attack(token);
        let slowest = *attacked.answered.iter().max().unwrap();
        assert!(
            attacked.answered.len() >= 10,
            "{} answers",
            attacked.answered.len()
        );
        assert!(
            slowest < Duration::from_secs(2),
            "token {token}: the operator waited {slowest:?} ({})",
            attacked.stress
        );
        // Bounded: far below web.memory_mb (2,048 MB), whatever the attack holds.
        assert!(
            attacked.page_hwm_kb < 256_000,
            "the page process took {} kB",
            attacked.page_hwm_kb
        );
    }
}

/// Raises this process's open-file limit to its hard limit (the floods below hold thousands).
fn raise_open_files() {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: prlimit reading, then setting, this process's own limit.
    unsafe {
        assert_eq!(
            libc::prlimit(0, libc::RLIMIT_NOFILE, std::ptr::null(), &mut limit),
            0
        );
        limit.rlim_cur = limit.rlim_max;
        libc::prlimit(0, libc::RLIMIT_NOFILE, &limit, std::ptr::null_mut());
    }
}

/// A client that sends `head`, then one byte of `drip` (cycled) every 250 ms: what the server
/// answered (its status line, or "" when it just closed) and when, from the connection's start.
fn trickle(addr: SocketAddr, head: &str, drip: &[u8]) -> (String, Duration) {
    let started = Instant::now();
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(head.as_bytes()).unwrap();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (mut writer, stopped, drip) = (s.try_clone().unwrap(), stop.clone(), drip.to_vec());
    let dripping = std::thread::spawn(move || {
        for b in drip.iter().cycle() {
            std::thread::sleep(Duration::from_millis(250));
            if stopped.load(std::sync::atomic::Ordering::SeqCst) || writer.write_all(&[*b]).is_err()
            {
                return;
            }
        }
    });
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    let mut first = [0u8; 4096];
    let n = s.read(&mut first).unwrap_or(0);
    let when = started.elapsed();
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
    dripping.join().unwrap();
    let answer = String::from_utf8_lossy(&first[..n]);
    (answer.lines().next().unwrap_or("").to_string(), when)
}

/// A request head for `POST /api/calibration` with these framing headers.
fn post_head(framing: &str, token: Option<&str>) -> String {
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    format!(
        "POST /api/calibration HTTP/1.1\r\nHost: localhost\r\n{auth}\
         Content-Type: application/json\r\n{framing}\r\n\r\n"
    )
}

/// The finding: headers and bodies were read for as long as each byte came within the idle
/// timeout (a slow body held its place 69 s). Headers that trickle are cut at
/// `--header-timeout-s`, a body that trickles (declared or chunked) is answered 408 at
/// `--body-timeout-s`, and a body declared larger than the page takes (1e9 bytes) is answered
/// 413 at once.
#[test]
fn trickled_headers_and_bodies_are_cut_at_their_deadlines_and_an_oversized_body_at_once() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let (_served, addr) = serve(&dir, &["--header-timeout-s", "2", "--body-timeout-s", "3"]);
    let within = |what: &str, took: Duration, from: f64, to: f64| {
        assert!(
            (from..to).contains(&took.as_secs_f64()),
            "{what}: after {took:?}, expected {from} to {to} s"
        );
    };
    let (answer, took) = trickle(
        addr,
        "GET /api/status HTTP/1.1\r\nHost: localhost\r\n",
        b"X-Slow: a\r\n",
    );
    assert!(answer.is_empty() || answer.contains(" 408 "), "{answer}");
    within("trickled headers", took, 1.8, 5.0);
    for framing in ["Content-Length: 60000", "Transfer-Encoding: chunked"] {
        let drip: &[u8] = if framing.contains("chunked") {
            b"1\r\n{\r\n"
        } else {
            b"{"
        };
        let (answer, took) = trickle(addr, &post_head(framing, None), drip);
        assert!(answer.contains(" 408 "), "{framing}: {answer}");
        within(framing, took, 2.8, 6.0);
    }
    let (answer, took) = trickle(addr, &post_head("Content-Length: 1000000000", None), b"{");
    assert!(answer.contains(" 413 "), "{answer}");
    within("1e9 declared", took, 0.0, 1.0);
    // Those clients took nothing from the next.
    let (status, took) = operator_get(addr, "/api/status", false);
    assert_eq!(status, Ok(200));
    within("the next request", took, 0.0, 2.0);
}

/// 64 clients declaring 1e9-byte bodies and 64 trickling bodies that fit (every one of
/// `--max-connections 64` being received): the operator is answered within 2 s each time,
/// without and with a token (the slow bodies carry it too: the worst case), each 1e9 one is
/// refused 413 at once, and every trickling one is ended by `--body-timeout-s`.
#[test]
fn while_64_slow_bodies_hold_every_connection_the_operator_is_answered_within_2_s() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let token_file = tmp.path().join("web.token");
    std::fs::write(&token_file, TOKEN).unwrap();
    for token in [None, Some(TOKEN)] {
        let mut args = vec!["--max-connections", "64", "--body-timeout-s", "4"];
        if token.is_some() {
            args.extend(["--token-file", token_file.to_str().unwrap()]);
        }
        let (_served, addr) = serve(&dir, &args);
        let huge = post_head("Content-Length: 1000000000", token);
        for k in 0..64 {
            let started = Instant::now();
            let mut s = TcpStream::connect(addr).unwrap();
            s.write_all(huge.as_bytes()).unwrap();
            s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
            let mut answer = [0u8; 12];
            s.read_exact(&mut answer).unwrap();
            assert_eq!(&answer[9..], b"413", "1e9 body {k}");
            assert!(started.elapsed() < Duration::from_secs(1), "1e9 body {k}");
        }
        let opened = Instant::now();
        let mut slow: Vec<TcpStream> = (0..64)
            .map(|_| {
                let mut s = TcpStream::connect(addr).unwrap();
                s.write_all(post_head("Content-Length: 60000", token).as_bytes())
                    .unwrap();
                s
            })
            .collect();
        let mut writers: Vec<TcpStream> = slow.iter().map(|s| s.try_clone().unwrap()).collect();
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let stopped = stop.clone();
        let dripping = std::thread::spawn(move || {
            while !stopped.load(std::sync::atomic::Ordering::SeqCst) {
                for w in &mut writers {
                    let _ = w.write_all(b" ");
                }
                std::thread::sleep(Duration::from_millis(250));
            }
        });
        for k in 0..6 {
            let (status, took) = operator_get(addr, "/api/status", token.is_some());
            assert_eq!(status, Ok(200), "token {token:?}, request {k}");
            assert!(
                took < Duration::from_secs(2),
                "token {token:?}, request {k}: answered after {took:?}"
            );
        }
        // Every slow body was ended within the body deadline (408, or closed for the operator).
        for (k, s) in slow.iter_mut().enumerate() {
            s.set_read_timeout(Some(Duration::from_secs(15))).unwrap();
            let mut answer = Vec::new();
            let _ = s.read_to_end(&mut answer);
            let answer = String::from_utf8_lossy(&answer);
            assert!(
                answer.is_empty() || answer.starts_with("HTTP/1.1 408"),
                "slow body {k}: {answer:.200}"
            );
        }
        let took = opened.elapsed();
        assert!(
            took < Duration::from_secs(8),
            "slow bodies ended after {took:?}"
        );
        stop.store(true, std::sync::atomic::Ordering::SeqCst);
        dripping.join().unwrap();
    }
}

/// The finding: 2,000 idle connections kept a legitimate client out for 25 s, and with a token
/// 300 kept a token holder out for 42 s. From the operator's own address (127.0.0.1: the
/// per-client limit does not set it apart from the flood), 2,000 connections that send nothing
/// and stay open; a request after them is answered within 2 s, without and with a token.
#[test]
fn a_flood_of_idle_connections_from_the_operators_own_address_does_not_lock_it_out() {
    raise_open_files();
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let token_file = tmp.path().join("web.token");
    std::fs::write(&token_file, TOKEN).unwrap();
    for token in [false, true] {
        let mut args = vec![];
        if token {
            args.extend(["--token-file", token_file.to_str().unwrap()]);
        }
        let (_served, addr) = serve(&dir, &args);
        let flood: Vec<TcpStream> = (0..IDLE)
            .filter_map(|_| TcpStream::connect_timeout(&addr, Duration::from_secs(10)).ok())
            .collect();
        assert!(
            flood.len() >= IDLE * 9 / 10,
            "only {} connected",
            flood.len()
        );
        for k in 0..5 {
            let (status, took) = operator_get(addr, "/api/status", token);
            assert_eq!(status, Ok(200), "token {token}, request {k}");
            assert!(
                took < Duration::from_secs(2),
                "token {token}, request {k}: answered after {took:?}"
            );
        }
        drop(flood);
    }
}
