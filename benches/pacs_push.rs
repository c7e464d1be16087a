//! Our push of one build's series to a real Orthanc over loopback, side by side with the peers:
//! dcmtk's `storescu` for C-STORE and `curl` posting the same files as one multipart STOW-RS
//! request. Each run gets a fresh Orthanc (empty storage), in a private network namespace.
//! Needs root, `orthanc`, `orthanc-dicomweb`, `dcmtk`, `curl`; skipped (said so) without them.
//! Run: `cargo bench --bench pacs_push` (LAYERWISE_BENCH_LAYERS, default 20 layers x 6 views;
//! LAYERWISE_BENCH_ROUNDS, default 3 rounds that alternate who goes first, medians compared).

use layerwise::clock::SystemClock;
use layerwise::dicom::{Compression, Plane, Series, Slice, Study};
use layerwise::pacs::{Destination, Queue};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const HTTP: u16 = 8042;
const DICOM: u16 = 4242;

fn orthanc(dir: &Path) -> Child {
    let _ = std::fs::remove_dir_all(dir);
    std::fs::create_dir_all(dir.join("db")).unwrap();
    let config = serde_json::json!({
        "StorageDirectory": dir.join("db"), "IndexDirectory": dir.join("db"),
        "Plugins": ["/usr/share/orthanc/plugins/libOrthancDicomWeb.so"],
        "HttpPort": HTTP, "DicomPort": DICOM, "DicomAet": "ORTHANC",
        "RemoteAccessAllowed": true, "AuthenticationEnabled": false,
        "DicomWeb": { "Enable": true, "Root": "/dicom-web/" },
    });
    std::fs::write(dir.join("orthanc.json"), config.to_string()).unwrap();
    let child = Command::new("/usr/sbin/Orthanc")
        .arg(dir.join("orthanc.json"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("Orthanc starts");
    let deadline = Instant::now() + Duration::from_secs(30);
    while ureq::get(&format!("http://127.0.0.1:{HTTP}/system"))
        .call()
        .is_err()
        || std::net::TcpStream::connect(("127.0.0.1", DICOM)).is_err()
    {
        assert!(Instant::now() < deadline, "Orthanc did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    child
}

fn stored(expected: usize) -> (u64, u64) {
    let stats: serde_json::Value = serde_json::from_str(
        &ureq::get(&format!("http://127.0.0.1:{HTTP}/statistics"))
            .call()
            .unwrap()
            .into_string()
            .unwrap(),
    )
    .unwrap();
    let count = stats["CountInstances"].as_u64().unwrap();
    assert_eq!(count as usize, expected, "Orthanc holds {count} instances");
    let disk = stats["TotalDiskSize"].as_str().unwrap().parse().unwrap();
    (count, disk)
}

/// One build's series: 6 views x `layers` slices of the demo plate grid (1100 x 1100 at 0.25
/// mm), a textured powder bed so deflate has work to do.
fn write_build(dir: &Path, layers: u32, compression: Compression) -> Vec<PathBuf> {
    let study = Study {
        study_instance_uid: layerwise::dicom::new_uid(),
        frame_of_reference_uid: layerwise::dicom::new_uid(),
        date: "20261201".into(),
        time: "120000".into(),
        patient_name: "bench^".into(),
        patient_id: "BENCH".into(),
        study_id: "1".into(),
        description: "pacs push bench".into(),
    };
    let n = 1100;
    let mut files = Vec::new();
    for (number, view) in [
        "pre_front",
        "pre_side",
        "pre_top",
        "post_front",
        "post_side",
        "post_top",
    ]
    .iter()
    .enumerate()
    {
        let series = Series::named(&study, number as u32 + 1, view);
        for layer in 1..=layers {
            let mut state = 0x9E3779B97F4A7C15u64 ^ u64::from(layer) << 8 ^ number as u64;
            let pixels: Vec<u16> = (0..n * n)
                .map(|i| {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    let (x, y) = (i % n, i / n);
                    let part = if (x / 100 + y / 100) % 3 == 0 {
                        3000
                    } else {
                        1200
                    };
                    part + (state % 200) as u16
                })
                .collect();
            let slice = Slice {
                layer,
                plane: Plane {
                    origin: [-137.5, -137.5, f64::from(layer) * 0.03],
                    pixel_mm: 0.25,
                    rows: n,
                    columns: n,
                    thickness_mm: 0.03,
                },
                pixels: (&pixels).into(),
                acquired: None,
                window: (2000.0, 4000.0),
                derivation: "bench",
            };
            let path = dir.join(view).join(format!("L{layer:05}.dcm"));
            layerwise::dicom::write_slice(&path, &study, &series, &slice, compression).unwrap();
            files.push(path);
        }
    }
    files
}

fn line(name: &str, seconds: f64, instances: usize, bytes: u64) -> f64 {
    let rate = instances as f64 / seconds;
    println!(
        "  {name:<28} {seconds:>7.2} s  {rate:>7.1} instances/s  {:>7.1} MB/s",
        bytes as f64 / 1e6 / seconds
    );
    rate
}

fn main() {
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0
        || !Path::new("/usr/sbin/Orthanc").exists()
        || Command::new("ip")
            .args(["link", "set", "lo", "up"])
            .status()
            .is_err()
    {
        println!("pacs_push: skipped (needs root for a private network namespace, and orthanc)");
        return;
    }
    let layers: u32 = std::env::var("LAYERWISE_BENCH_LAYERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let rounds: usize = std::env::var("LAYERWISE_BENCH_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3)
        .max(1);
    let tmp = tempfile::tempdir().unwrap();
    let clock = SystemClock::new();
    for compression in [Compression::None, Compression::Deflate] {
        let build = tmp.path().join(format!("{compression:?}"));
        let files = write_build(&build, layers, compression);
        let bytes: u64 = files
            .iter()
            .map(|f| std::fs::metadata(f).unwrap().len())
            .sum();
        let count = files.len();
        println!(
            "{count} instances ({compression:?}, {:.1} MB, {:.2} MB each) to Orthanc over loopback, median of {rounds} rounds:",
            bytes as f64 / 1e6,
            bytes as f64 / 1e6 / count as f64
        );
        let orthanc_dir = tmp.path().join("orthanc");
        let ours = |to: &str| {
            let _ = std::fs::remove_dir_all(build.join("pacs"));
            let mut child = orthanc(&orthanc_dir);
            let mut queue = Queue::open(&build, Destination::resolve(to, &[]).unwrap()).unwrap();
            let mut sender = queue.destination.connect();
            let t = Instant::now();
            let count = queue
                .push_pending(sender.as_mut(), false, &clock, None)
                .unwrap();
            let seconds = t.elapsed().as_secs_f64();
            assert!(count.rejected.is_empty(), "{:?}", count.rejected);
            let (_, disk) = stored(files.len());
            let _ = child.kill();
            let _ = child.wait();
            (seconds, disk)
        };
        let peer = |command: &mut Command| {
            let mut child = orthanc(&orthanc_dir);
            let t = Instant::now();
            let status = command.stdout(Stdio::null()).stderr(Stdio::null()).status();
            let seconds = t.elapsed().as_secs_f64();
            assert!(status.is_ok_and(|s| s.success()), "{command:?} failed");
            stored(files.len());
            let _ = child.kill();
            let _ = child.wait();
            seconds
        };
        // curl gets the whole multipart body ready-made in one file (its assembly not timed).
        let boundary = "benchboundary7f3a";
        let mut body = Vec::new();
        for f in &files {
            body.extend_from_slice(
                format!("--{boundary}\r\nContent-Type: application/dicom\r\n\r\n").as_bytes(),
            );
            body.extend_from_slice(&std::fs::read(f).unwrap());
            body.extend_from_slice(b"\r\n");
        }
        body.extend_from_slice(format!("--{boundary}--\r\n").as_bytes());
        let body_path = tmp.path().join("body.multipart");
        std::fs::write(&body_path, &body).unwrap();
        let storescu = || {
            peer(
                Command::new("storescu")
                    .args(["-aec", "ORTHANC", "127.0.0.1", &DICOM.to_string()])
                    .args(&files),
            )
        };
        let curl = || {
            peer(
                Command::new("curl")
                    .args(["-sf", "-X", "POST", "-H"])
                    .arg(format!(
                        "Content-Type: multipart/related; type=\"application/dicom\"; boundary={boundary}"
                    ))
                    .args(["-H", "Accept: application/dicom+json", "--data-binary"])
                    .arg(format!("@{}", body_path.display()))
                    .arg(format!("http://127.0.0.1:{HTTP}/dicom-web/studies")),
            )
        };
        // Rounds alternate who goes first, so that a load that comes and goes on the machine
        // falls on both sides alike; the medians of the rounds are compared.
        let (mut times, mut disk) = ([Vec::new(), Vec::new(), Vec::new(), Vec::new()], 0);
        for round in 0..rounds {
            let ours_first = round % 2 == 0;
            for (ours_i, peer_i, url) in [
                (0, 1, format!("dicom://ORTHANC@127.0.0.1:{DICOM}")),
                (2, 3, format!("http://127.0.0.1:{HTTP}/dicom-web")),
            ] {
                let run_peer = |times: &mut [Vec<f64>; 4]| {
                    let t = if peer_i == 1 { storescu() } else { curl() };
                    times[peer_i].push(t);
                };
                if !ours_first {
                    run_peer(&mut times);
                }
                let (t, d) = ours(&url);
                times[ours_i].push(t);
                disk = d;
                if ours_first {
                    run_peer(&mut times);
                }
            }
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let [cstore, storescu, stow, curl] = times.each_mut().map(median);
        let ours_cstore = line("layerwise push (C-STORE)", cstore, count, bytes);
        let peer_cstore = line("dcmtk storescu", storescu, count, bytes);
        let ours_stow = line("layerwise push (STOW-RS)", stow, count, bytes);
        let peer_stow = line("curl multipart STOW-RS", curl, count, bytes);
        println!(
            "  ratio ours/peer (instances/s): C-STORE {:.2}, STOW-RS {:.2}; Orthanc storage {:.2} MB per instance ({:.2} GB per 1000 layers x 6 views)",
            ours_cstore / peer_cstore,
            ours_stow / peer_stow,
            disk as f64 / 1e6 / count as f64,
            disk as f64 / count as f64 * 6000.0 / 1e9
        );
    }
}
