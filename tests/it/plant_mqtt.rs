//! MQTT against the real Mosquitto (Debian's `mosquitto` and `mosquitto-clients`), each test in
//! a private network namespace: every layer message of a build arrives in order, a broker
//! restarted in the middle of the build loses none, the last will marks a killed daemon
//! offline; and a broker that answers garbage, never answers or sends a huge topic neither stops
//! capture nor grows memory, while the messages wait on disk for a broker that works.

use crate::common::*;
use std::collections::BTreeSet;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const PORT: u16 = 18830;
const PREFIX: &str = "layerwise/demo-build";

/// A Mosquitto with its own configuration and persistence.
struct Mosquitto {
    dir: PathBuf,
    child: Option<Child>,
}

impl Mosquitto {
    fn start(dir: &Path) -> Mosquitto {
        let dir = dir.join("mosquitto");
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("mosquitto.conf"),
            format!(
                "listener {PORT} 127.0.0.1\nallow_anonymous true\npersistence true\n\
                 persistence_location {}/\nautosave_interval 1\nmax_queued_messages 100000\n\
                 log_dest file {}/mosquitto.log\n",
                dir.display(),
                dir.display()
            ),
        )
        .unwrap();
        let mut broker = Mosquitto { dir, child: None };
        broker.run();
        broker
    }

    fn run(&mut self) {
        let child = Command::new("mosquitto")
            .arg("-c")
            .arg(self.dir.join("mosquitto.conf"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto (Debian's package) starts");
        self.child = Some(child);
        wait_until("mosquitto listening", Duration::from_secs(20), || {
            TcpStream::connect(("127.0.0.1", PORT)).is_ok()
        });
    }

    /// SIGTERM (Mosquitto saves its persistence database), then wait.
    fn stop(&mut self) {
        if let Some(child) = self.child.take() {
            let _ = terminate(child);
        }
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        self.stop();
    }
}

/// `mosquitto_sub` with a persistent session (`-c -i`), QoS 1, restarted whenever it exits (a
/// broker restart), collecting `topic payload` lines.
struct Subscriber {
    lines: Arc<Mutex<Vec<String>>>,
    stop: Arc<AtomicBool>,
    pid: Arc<AtomicUsize>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Subscriber {
    fn start(id: &str, topics: &[&str]) -> Subscriber {
        let lines = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let pid = Arc::new(AtomicUsize::new(0));
        let mut args: Vec<String> = [
            "-h",
            "127.0.0.1",
            "-V",
            "mqttv311",
            "-c",
            "-i",
            id,
            "-q",
            "1",
            "-v",
            "-t",
            "test/probe",
        ]
        .map(String::from)
        .to_vec();
        args.extend(
            topics
                .iter()
                .flat_map(|t| ["-t".to_string(), t.to_string()]),
        );
        args.extend(["-p".into(), PORT.to_string()]);
        let (l, s, p) = (lines.clone(), stop.clone(), pid.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Ordering::SeqCst) {
                let Ok(mut child) = Command::new("mosquitto_sub")
                    .args(&args)
                    .stdout(Stdio::piped())
                    .stderr(Stdio::null())
                    .spawn()
                else {
                    return;
                };
                p.store(child.id() as usize, Ordering::SeqCst);
                for line in BufReader::new(child.stdout.take().unwrap()).lines() {
                    match line {
                        Ok(line) => l.lock().unwrap().push(line),
                        Err(_) => break,
                    }
                }
                let _ = child.wait();
                std::thread::sleep(Duration::from_millis(200));
            }
        });
        let subscriber = Subscriber {
            lines,
            stop,
            pid,
            thread: Some(thread),
        };
        // Its session exists once it gets a message.
        wait_until("mosquitto_sub subscribed", Duration::from_secs(20), || {
            publish("test/probe", "probe");
            std::thread::sleep(Duration::from_millis(100));
            subscriber
                .lines()
                .iter()
                .any(|l| l.starts_with("test/probe"))
        });
        subscriber
    }

    fn lines(&self) -> Vec<String> {
        self.lines.lock().unwrap().clone()
    }

    /// The payloads of `kind` messages (`{PREFIX}/{kind}`), as JSON, in arrival order.
    fn messages(&self, kind: &str) -> Vec<serde_json::Value> {
        let topic = format!("{PREFIX}/{kind} ");
        self.lines()
            .iter()
            .filter_map(|l| l.strip_prefix(&topic))
            .map(|p| serde_json::from_str(p).expect("a JSON payload"))
            .collect()
    }
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        let pid = self.pid.load(Ordering::SeqCst);
        if pid != 0 {
            let _ = nix::sys::signal::kill(
                nix::unistd::Pid::from_raw(pid as i32),
                nix::sys::signal::Signal::SIGTERM,
            );
        }
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn publish(topic: &str, payload: &str) {
    let _ = Command::new("mosquitto_pub")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &PORT.to_string(),
            "-q",
            "1",
            "-t",
            topic,
            "-m",
            payload,
        ])
        .status();
}

/// The retained message of `topic` (None when there is none within 2 s).
fn retained(topic: &str) -> Option<serde_json::Value> {
    let out = Command::new("mosquitto_sub")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &PORT.to_string(),
            "-t",
            topic,
            "-C",
            "1",
            "-W",
            "2",
        ])
        .output()
        .ok()?;
    serde_json::from_slice(&out.stdout).ok()
}

/// A 12-layer build publishing to the broker, its queue in `tmp`.
fn config(tmp: &Path, layers: u32, pause_ms: u64, hold_ms: u64) -> PathBuf {
    let mut config = demo_config(&tmp.join("build"), layers);
    config.web.listen = String::new();
    config.mqtt.url = format!("mqtt://127.0.0.1:{PORT}");
    config.mqtt.queue_dir = tmp.join("mqtt-queue");
    config.mqtt.retry_backoff_ms = [200, 1000];
    config.mqtt.keep_alive_s = 5;
    printer_script(&mut config, tmp, layers, pause_ms, hold_ms);
    let path = tmp.join("layerwise.toml");
    write_config(&config, &path);
    path
}

/// Each layer message once, in the order sent: duplicates (at-least-once) dropped by `seq`,
/// and what is left numbered in increasing order with every (layer, phase) of the build.
fn assert_every_layer_in_order(messages: &[serde_json::Value], layers: u32) {
    let mut seen = BTreeSet::new();
    let mut order = Vec::new();
    for m in messages {
        let seq = m["seq"].as_u64().expect("seq");
        if seen.insert(seq) {
            order.push((
                seq,
                m["layer"].as_u64().unwrap(),
                m["phase"].as_str().unwrap().to_string(),
            ));
        }
    }
    assert!(
        order.windows(2).all(|w| w[0].0 < w[1].0),
        "in order: {order:?}"
    );
    let got: Vec<(u64, String)> = order.iter().map(|(_, l, p)| (*l, p.clone())).collect();
    let want: Vec<(u64, String)> = (1..=u64::from(layers))
        .flat_map(|l| [(l, "pre".to_string()), (l, "post".to_string())])
        .collect();
    assert_eq!(got, want);
}

/// Every layer message of a build reaches a persistent subscriber in order, the broker
/// restarted (SIGTERM, start again) in the middle; the retained status says online while it
/// runs and "stopped" after a clean stop, after the build's `ended` message.
#[test]
fn every_layer_message_arrives_in_order_through_a_broker_restart() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let layers = 12;
    let mut broker = Mosquitto::start(tmp.path());
    let layer_topic = format!("{PREFIX}/layer");
    let build_topic = format!("{PREFIX}/build");
    let counter = Subscriber::start("lw-count", &[&layer_topic, &build_topic]);
    let daemon = spawn_build(&config(tmp.path(), layers, 250, 600_000), Stdio::null());
    wait_until("six layer messages", Duration::from_secs(60), || {
        counter.messages("layer").len() >= 6
    });
    let status = retained(&format!("{PREFIX}/status")).expect("a retained status");
    assert_eq!(status["online"], true, "{status}");
    broker.stop();
    std::thread::sleep(Duration::from_millis(1500));
    broker.run();
    wait_until("every layer message", Duration::from_secs(90), || {
        let seqs: BTreeSet<u64> = counter
            .messages("layer")
            .iter()
            .filter_map(|m| m["seq"].as_u64())
            .collect();
        seqs.len() >= 2 * layers as usize
    });
    assert_success(&terminate(daemon));
    wait_until("the build's end", Duration::from_secs(30), || {
        counter
            .messages("build")
            .iter()
            .any(|m| m["event"] == "ended")
    });
    assert_every_layer_in_order(&counter.messages("layer"), layers);
    let builds = counter.messages("build");
    assert_eq!(builds[0]["event"], "started");
    assert_eq!(builds[0]["layers_expected"], layers);
    let status = retained(&format!("{PREFIX}/status")).expect("a retained status");
    assert_eq!(status["online"], false, "{status}");
    assert_eq!(status["reason"], "stopped", "{status}");
}

/// kill -9: the broker publishes the last will, the retained status says offline, "lost".
#[test]
fn the_last_will_marks_a_killed_daemon_offline() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let _broker = Mosquitto::start(tmp.path());
    let mut daemon = spawn_build(&config(tmp.path(), 2, 100, 600_000), Stdio::null());
    let topic = format!("{PREFIX}/status");
    wait_until("the status online", Duration::from_secs(30), || {
        retained(&topic).is_some_and(|s| s["online"] == true)
    });
    daemon.kill().unwrap();
    let _ = daemon.wait();
    wait_until("the last will", Duration::from_secs(10), || {
        retained(&topic).is_some_and(|s| s["online"] == false && s["reason"] == "lost")
    });
}

/// What a fake broker does with each connection, in turn.
#[derive(Clone, Copy, Debug)]
enum Bad {
    /// Reads and never answers.
    Silent,
    /// CONNACK, then a megabyte of random bytes.
    Garbage,
    /// CONNACK, then a PUBLISH with a 64 KiB topic and a megabyte of payload.
    HugeTopic,
}

fn bad_broker(listener: TcpListener, connections: Arc<AtomicUsize>, stop: Arc<AtomicBool>) {
    listener.set_nonblocking(true).unwrap();
    let modes = [Bad::Silent, Bad::Garbage, Bad::HugeTopic];
    let mut rng = Rng(0x5eed);
    while !stop.load(Ordering::SeqCst) {
        let Ok((mut stream, _)) = listener.accept() else {
            std::thread::sleep(Duration::from_millis(20));
            continue;
        };
        let mode = modes[connections.fetch_add(1, Ordering::SeqCst) % modes.len()];
        let _ = stream.set_nonblocking(false);
        let _ = stream.set_read_timeout(Some(Duration::from_millis(300)));
        let mut connect = [0u8; 256];
        let _ = stream.read(&mut connect);
        let mut bytes = Vec::new();
        match mode {
            Bad::Silent => {
                std::thread::sleep(Duration::from_secs(6));
                continue;
            }
            Bad::Garbage => {
                bytes.extend([0x20, 0x02, 0x00, 0x00]);
                bytes.extend((0..1 << 20).map(|_| rng.next() as u8));
            }
            Bad::HugeTopic => {
                bytes.extend([0x20, 0x02, 0x00, 0x00]);
                let remaining: u32 = 2 + 0xFFFF + (1 << 20);
                bytes.push(0x30);
                let mut x = remaining;
                loop {
                    let mut byte = (x % 128) as u8;
                    x /= 128;
                    if x > 0 {
                        byte |= 0x80;
                    }
                    bytes.push(byte);
                    if x == 0 {
                        break;
                    }
                }
                bytes.extend([0xFF, 0xFF]);
                bytes.extend(std::iter::repeat_n(b'a', 0xFFFF + (1 << 20)));
            }
        }
        let _ = stream.write_all(&bytes);
    }
}

/// A broker that never answers, answers garbage or sends a huge topic: capture goes on to the
/// last frame, memory stays bounded, reconnects follow the back-off, and every message waits in
/// the queue on disk; a working broker on the same port then gets them all, in order, from the
/// daemon started again.
#[test]
fn a_broken_broker_never_stops_capture_and_the_queue_waits_for_a_good_one() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let layers = 10;
    let listener = TcpListener::bind(("127.0.0.1", PORT)).unwrap();
    let connections = Arc::new(AtomicUsize::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let fake = {
        let (c, s) = (connections.clone(), stop.clone());
        std::thread::spawn(move || bad_broker(listener, c, s))
    };
    let config_path = config(tmp.path(), layers, 300, 5_000);
    let started = std::time::Instant::now();
    let daemon = spawn_build(&config_path, Stdio::null());
    let pid = daemon.id();
    let mut peak = 0;
    wait_until("a few bad connections", Duration::from_secs(60), || {
        peak = peak.max(peak_memory(pid));
        connections.load(Ordering::SeqCst) >= 3
    });
    wait_until("every frame", Duration::from_secs(120), || {
        peak = peak.max(peak_memory(pid));
        originals(&tmp.path().join("build")).len() == expected_originals(layers).len()
    });
    let seconds = started.elapsed().as_secs_f64();
    assert_success(&terminate(daemon));
    stop.store(true, Ordering::SeqCst);
    fake.join().unwrap();
    assert_eq!(
        originals(&tmp.path().join("build")),
        expected_originals(layers)
    );
    let tried = connections.load(Ordering::SeqCst);
    // The back-off of [200, 1000] ms with a 5 s connect timeout: never more than one attempt
    // per 200 ms.
    assert!(
        (tried as f64) < seconds / 0.2 + 2.0,
        "{tried} connections in {seconds:.1} s"
    );
    assert!(peak < 400 << 20, "peak memory {} MB", peak >> 20);

    // A working broker on the same port: the daemon started again sends the queue, in order.
    let _broker = Mosquitto::start(tmp.path());
    let counter = Subscriber::start("lw-late", &[&format!("{PREFIX}/layer")]);
    let mut again = demo_config(&tmp.path().join("build"), layers);
    again.web.listen = String::new();
    again.mqtt.url = format!("mqtt://127.0.0.1:{PORT}");
    again.mqtt.queue_dir = tmp.path().join("mqtt-queue");
    printer_script(&mut again, tmp.path(), 0, 0, 600_000);
    write_config(&again, &config_path);
    let daemon = spawn_build(&config_path, Stdio::null());
    wait_until("the queued layer messages", Duration::from_secs(60), || {
        counter.messages("layer").len() >= 2 * layers as usize
    });
    assert_success(&terminate(daemon));
    assert_every_layer_in_order(&counter.messages("layer"), layers);
}
