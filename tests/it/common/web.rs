//! The operator page over HTTP as a client meets it: one request per connection, `layerwise
//! serve` of a build, the daemon's page address from its output.

use super::{calibrated_config, layerwise, run_build, spawn_build, write_config};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::time::Duration;

/// One HTTP/1.1 request on its own connection: (status, body).
pub fn http(addr: SocketAddr, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
    let (status, _, body) = http_with(addr, method, path, "", body);
    (status, body)
}

/// As [`http`], with more `headers` (each line ending in `\r\n`; a `Host` of their own in
/// place of `localhost`); also the answer's head, in lower case.
pub fn http_with(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &str,
    body: &[u8],
) -> (u16, String, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let own_host = headers
        .split("\r\n")
        .any(|line| line.to_ascii_lowercase().starts_with("host:"));
    let host = match own_host {
        true => "",
        false => "Host: localhost\r\n",
    };
    write!(
        s,
        "{method} {path} HTTP/1.1\r\n{host}Connection: close\r\nContent-Type: application/json\r\n{headers}Content-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    // The server may answer (413, 405) before reading a large body and close.
    let _ = s.write_all(body);
    let mut response = Vec::new();
    let _ = s.read_to_end(&mut response);
    let split = response
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .unwrap_or_else(|| {
            panic!(
                "{path}: no HTTP head in {:?}",
                String::from_utf8_lossy(&response)
            )
        });
    let head = String::from_utf8_lossy(&response[..split]).to_ascii_lowercase();
    let status = head[9..12].parse().unwrap();
    let mut body = response[split + 4..].to_vec();
    if head.contains("transfer-encoding: chunked") {
        body = dechunk(&body);
    }
    (status, head, body)
}

fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let line_end = data.windows(2).position(|w| w == b"\r\n").unwrap();
        let size =
            usize::from_str_radix(std::str::from_utf8(&data[..line_end]).unwrap().trim(), 16)
                .unwrap();
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&data[line_end + 2..line_end + 2 + size]);
        data = &data[line_end + 4 + size..];
    }
}

/// A connection that asked for the event stream (read timeout 10 s).
pub fn open_events(addr: SocketAddr) -> TcpStream {
    let mut events = TcpStream::connect(addr).unwrap();
    events
        .set_read_timeout(Some(Duration::from_secs(10)))
        .unwrap();
    write!(
        events,
        "GET /api/events HTTP/1.1\r\nHost: localhost\r\n\r\n"
    )
    .unwrap();
    events
}

pub fn get_json(addr: SocketAddr, path: &str) -> serde_json::Value {
    let (status, body) = http(addr, "GET", path, b"");
    assert_eq!(status, 200, "{path}: {}", String::from_utf8_lossy(&body));
    serde_json::from_slice(&body).unwrap()
}

/// A calibrated mock build of `layers` layers with the vector file of the parts the mock camera
/// photographs (what the demo ships), so the calibration page can register to it.
pub fn web_config(dir: &Path, layers: u32) -> layerwise::config::Config {
    let mut config = calibrated_config(dir, layers, layerwise::dicom::Compression::None);
    let vectors = dir.join("part.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, layers).unwrap();
    config.build.vectors = Some(vectors);
    config
}

/// Reads a child's stream on a thread (so the child never blocks on a full pipe) and returns
/// the first `http://…/` address it prints, and the whole text once the stream ends.
pub fn watch_output(
    stream: impl Read + Send + 'static,
) -> (SocketAddr, std::thread::JoinHandle<String>) {
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stream).lines().map_while(Result::ok) {
            if let Some(at) = line.find("http://") {
                let rest = &line[at + 7..];
                let _ = tx.send(rest[..rest.find('/').unwrap()].to_string());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let addr = rx
        .recv_timeout(Duration::from_secs(60))
        .expect("the page's address is printed")
        .parse()
        .unwrap();
    (addr, reader)
}

/// A finished mock build of `layers` layers in `tmp/build` (see [`web_config`]).
pub fn finished_build(tmp: &Path, layers: u32) -> std::path::PathBuf {
    let dir = tmp.join("build");
    let config_path = tmp.join("layerwise.toml");
    write_config(&web_config(&dir, layers), &config_path);
    run_build(&config_path);
    dir
}

/// A `layerwise serve` that is stopped when dropped, also when a test fails half-way.
pub struct Served(pub std::process::Child);

impl Served {
    pub fn pid(&self) -> u32 {
        self.0.id()
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `layerwise serve` of `dir` on a free port, with `extra` arguments.
pub fn serve(dir: &Path, extra: &[&str]) -> (Served, SocketAddr) {
    let mut child = layerwise()
        .args(["serve", "--listen", "127.0.0.1:0", "--build"])
        .arg(dir)
        .args(extra)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let (addr, _) = watch_output(child.stdout.take().unwrap());
    (Served(child), addr)
}

/// `layerwise run --config FILE` whose configuration serves the page (`web.listen`): the
/// daemon, the page's address from its log, and its whole log once it ended.
pub fn live_page(
    config_path: &Path,
) -> (
    std::process::Child,
    SocketAddr,
    std::thread::JoinHandle<String>,
) {
    let mut daemon = spawn_build(config_path, std::process::Stdio::piped());
    let (addr, log) = watch_output(daemon.stderr.take().unwrap());
    (daemon, addr, log)
}

/// The page process the daemon `daemon` supervises (its child serving on `--listen-fd`).
pub fn page_process(daemon: u32) -> Option<u32> {
    let tasks = std::fs::read_dir(format!("/proc/{daemon}/task")).ok()?;
    tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("children")).ok())
        .flat_map(|c| {
            c.split_whitespace()
                .filter_map(|p| p.parse::<u32>().ok())
                .collect::<Vec<_>>()
        })
        .find(|pid| {
            std::fs::read(format!("/proc/{pid}/cmdline"))
                .is_ok_and(|c| c.split(|&b| b == 0).any(|a| a == b"--listen-fd"))
        })
}

/// Where Debian's chromium-driver put chromedriver (tests/run.sh installs it).
pub fn chromedriver() -> &'static str {
    ["/usr/bin/chromedriver", "/usr/lib/chromium/chromedriver"]
        .into_iter()
        .find(|p| Path::new(p).exists())
        .expect("chromedriver is installed (tests/run.sh installs chromium and chromium-driver)")
}
