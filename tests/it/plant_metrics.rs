//! `/metrics` against the real Prometheus (Debian's `prometheus` and `promtool`), in a private
//! network namespace: Prometheus scrapes the page of a running build every second, and its
//! query API returns the layers captured; promtool checks what the page serves.

use crate::common::*;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const PAGE: &str = "127.0.0.1:18040";
const PROMETHEUS: &str = "127.0.0.1:19090";

/// One HTTP/1.1 GET; the status and the body.
fn get(addr: &str, path: &str) -> (u16, String) {
    let Ok(mut stream) = TcpStream::connect(addr) else {
        return (0, String::new());
    };
    let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
    let _ = write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    );
    let mut response = String::new();
    let _ = stream.read_to_string(&mut response);
    let status = response
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    let (head, body) = response.split_once("\r\n\r\n").unwrap_or_default();
    // The page may answer in chunks; a query API answer is one JSON document.
    let chunked = head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked");
    (
        status,
        if chunked {
            dechunked(body)
        } else {
            body.to_string()
        },
    )
}

fn dechunked(body: &str) -> String {
    let mut out = String::new();
    let mut rest = body;
    while let Some((size, after)) = rest.split_once("\r\n") {
        let Ok(size) = usize::from_str_radix(size.trim(), 16) else {
            return body.to_string();
        };
        if size == 0 || after.len() < size {
            break;
        }
        out.push_str(&after[..size]);
        rest = after[size..].trim_start_matches("\r\n");
    }
    out
}

fn start_prometheus(dir: &Path) -> Child {
    let config = dir.join("prometheus.yml");
    std::fs::write(
        &config,
        format!(
            "global: {{scrape_interval: 1s, scrape_timeout: 1s, evaluation_interval: 1s}}\n\
             scrape_configs:\n  - job_name: layerwise\n    static_configs: [{{targets: [\"{PAGE}\"]}}]\n"
        ),
    )
    .unwrap();
    Command::new("prometheus")
        .arg(format!("--config.file={}", config.display()))
        .arg(format!(
            "--storage.tsdb.path={}",
            dir.join("tsdb").display()
        ))
        .arg(format!("--web.listen-address={PROMETHEUS}"))
        .arg("--log.level=warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("prometheus (Debian's package) starts")
}

/// The first value Prometheus has for `query` now.
fn query(query: &str) -> Option<String> {
    let (status, body) = get(
        PROMETHEUS,
        &format!("/api/v1/query?query={}", query.replace(' ', "%20")),
    );
    if status != 200 {
        return None;
    }
    let answer: serde_json::Value = serde_json::from_str(&body).ok()?;
    answer["data"]["result"][0]["value"][1]
        .as_str()
        .map(str::to_string)
}

/// The demo's 12 layers with metrics on, scraped by Prometheus while they are captured; its
/// query API gives the layer count and the page's health, and `promtool check metrics` finds
/// nothing to say about the text.
#[test]
fn prometheus_scrapes_a_build_and_promtool_accepts_the_metrics() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let layers = 12;
    let mut config = demo_config(&tmp.path().join("build"), layers);
    config.metrics.enabled = true;
    config.web.listen = PAGE.into();
    printer_script(&mut config, tmp.path(), layers, 250, 600_000);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let mut prometheus = start_prometheus(tmp.path());
    wait_until("Prometheus ready", Duration::from_secs(30), || {
        get(PROMETHEUS, "/-/ready").0 == 200
    });
    let daemon = spawn_build(&config_path, Stdio::null());
    // A layer counts once its first frame is stored; its last view follows a phase later.
    wait_until(
        "Prometheus has the 12 layers and their last frames",
        Duration::from_secs(120),
        || {
            query("layerwise_layers_captured_total").as_deref() == Some("12")
                && query("layerwise_frames_stored_total{view=\"post_top\"}").as_deref()
                    == Some("12")
        },
    );
    assert_eq!(query("up{job=\"layerwise\"}").as_deref(), Some("1"));
    assert_eq!(
        query("layerwise_health_state{part=\"camera\",state=\"ok\"}").as_deref(),
        Some("1")
    );
    assert!(
        query("layerwise_capture_duration_seconds_count{view=\"pre_top\"}")
            .is_some_and(|n| n.parse::<u64>().unwrap_or(0) >= 12),
        "the capture histogram is scraped"
    );

    let (status, body) = get(PAGE, "/metrics");
    assert_eq!(status, 200, "{body}");
    let mut promtool = Command::new("promtool")
        .args(["check", "metrics"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("promtool runs");
    promtool
        .stdin
        .take()
        .unwrap()
        .write_all(body.as_bytes())
        .unwrap();
    let checked = promtool.wait_with_output().unwrap();
    assert!(
        checked.status.success() && checked.stdout.is_empty() && checked.stderr.is_empty(),
        "promtool check metrics: {}\n{body}",
        report(&checked)
    );
    assert_success(&terminate(daemon));
    let _ = prometheus.kill();
    let _ = prometheus.wait();
}

/// `serve` of a finished build: no `/metrics` unless asked (404 says what to set), with
/// `--metrics` the build's state from its files (no live metrics: no daemon in this process).
#[test]
fn serve_has_metrics_only_when_asked() {
    let tmp = tempfile::tempdir().unwrap();
    let build = tmp.path().join("build");
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&demo_config(&build, 2), &config_path);
    run_build(&config_path);
    for metrics in [false, true] {
        let mut command = layerwise();
        command
            .args(["serve", "--listen", "127.0.0.1:0", "--build"])
            .arg(&build);
        if metrics {
            command.arg("--metrics");
        }
        let mut serve = command.stdout(Stdio::piped()).spawn().unwrap();
        let mut line = String::new();
        let mut out = std::io::BufReader::new(serve.stdout.take().unwrap());
        std::io::BufRead::read_line(&mut out, &mut line).unwrap();
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|r| r.split('/').next())
            .unwrap()
            .to_string();
        if metrics {
            let mut body = String::new();
            wait_until(
                "the build's state in /metrics",
                Duration::from_secs(20),
                || {
                    body = get(&addr, "/metrics").1;
                    body.contains("layerwise_layers_captured_total 2")
                },
            );
            assert!(body.contains("layerwise_daemon_running 0"), "{body}");
            assert!(
                !body.contains("layerwise_capture_duration_seconds"),
                "{body}"
            );
        } else {
            let (status, body) = get(&addr, "/metrics");
            assert_eq!(status, 404);
            assert!(body.contains("[metrics] enabled = true"), "{body}");
        }
        assert_success(&terminate(serve));
    }
}
