//! The push to a PACS against a real Orthanc (Debian's `orthanc` and `orthanc-dicomweb`), each
//! test in a private network namespace of its own (Orthanc listens on every interface): the
//! test thread enters a new namespace, brings loopback up, and everything it starts (Orthanc,
//! layerwise) and every request it makes stays inside.

mod common;

use common::{calibrated_config, layerwise, write_config, Run};
use layerwise::config::pacs::PacsDestination;
use layerwise::dicom::Compression;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

const ORTHANC: &str = "/usr/sbin/Orthanc";
const DICOMWEB_PLUGIN: &str = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";

/// Moves this test's thread (and so every process it starts) into a new network namespace
/// with loopback up. Needs root (CI runs as root).
fn private_network() {
    // SAFETY: unshare only changes the calling thread's namespaces.
    let rc = unsafe { libc::unshare(libc::CLONE_NEWNET) };
    assert_eq!(
        rc,
        0,
        "unshare(CLONE_NEWNET) failed ({}): the PACS tests need root, as CI runs them, to keep \
         Orthanc reachable from this machine alone",
        std::io::Error::last_os_error()
    );
    let up = Command::new("ip")
        .args(["link", "set", "lo", "up"])
        .status()
        .expect("ip (iproute2) runs");
    assert!(up.success(), "ip link set lo up failed");
}

/// One Orthanc with its own storage, HTTP port and DICOM port, the DICOMweb plugin loaded.
struct Orthanc {
    dir: PathBuf,
    http: u16,
    dicom: u16,
    child: Option<Child>,
}

impl Orthanc {
    /// Writes the configuration; `users` turns HTTP authentication on.
    fn new(dir: &Path, http: u16, dicom: u16, users: &[(&str, &str)]) -> Orthanc {
        let dir = dir.join(format!("orthanc-{http}"));
        std::fs::create_dir_all(dir.join("db")).unwrap();
        let users: serde_json::Map<String, serde_json::Value> = users
            .iter()
            .map(|(u, p)| (u.to_string(), serde_json::Value::from(*p)))
            .collect();
        let config = serde_json::json!({
            "Name": format!("test-{http}"),
            "StorageDirectory": dir.join("db"),
            "IndexDirectory": dir.join("db"),
            "Plugins": [DICOMWEB_PLUGIN],
            "HttpPort": http,
            "DicomPort": dicom,
            "DicomAet": "ORTHANC",
            "DicomCheckCalledAet": true,
            "RemoteAccessAllowed": true,
            "AuthenticationEnabled": !users.is_empty(),
            "RegisteredUsers": users,
            "DicomWeb": { "Enable": true, "Root": "/dicom-web/" },
            "ConcurrentJobs": 1,
            "StorageCompression": false,
        });
        std::fs::write(
            dir.join("orthanc.json"),
            serde_json::to_vec_pretty(&config).unwrap(),
        )
        .unwrap();
        let mut orthanc = Orthanc {
            dir,
            http,
            dicom,
            child: None,
        };
        orthanc.start();
        orthanc
    }

    fn start(&mut self) {
        assert!(self.child.is_none());
        let log = std::fs::File::options()
            .create(true)
            .append(true)
            .open(self.dir.join("orthanc.log"))
            .unwrap();
        let child = Command::new(ORTHANC)
            .arg(self.dir.join("orthanc.json"))
            .stdout(log.try_clone().unwrap())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("{ORTHANC} starts (apt-get install orthanc): {e}"));
        self.child = Some(child);
        let deadline = Instant::now() + Duration::from_secs(30);
        // Any HTTP answer (401 included) means it listens; the DICOM port opens with it.
        while !matches!(
            ureq::get(&self.url("/system")).call(),
            Ok(_) | Err(ureq::Error::Status(..))
        ) || std::net::TcpStream::connect(("127.0.0.1", self.dicom)).is_err()
        {
            assert!(
                Instant::now() < deadline,
                "Orthanc did not start: {}",
                std::fs::read_to_string(self.dir.join("orthanc.log")).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn stop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }

    fn url(&self, path: &str) -> String {
        format!("http://127.0.0.1:{}{path}", self.http)
    }

    fn dicom_web(&self) -> String {
        self.url("/dicom-web")
    }

    fn get(&self, path: &str) -> ureq::Response {
        ureq::get(&self.url(path))
            .call()
            .unwrap_or_else(|e| panic!("GET {path}: {e}"))
    }

    fn json(&self, path: &str) -> serde_json::Value {
        serde_json::from_str(&self.get(path).into_string().unwrap()).unwrap()
    }

    /// Series description → instances in it, and the number of studies.
    fn contents(&self) -> (usize, BTreeMap<String, usize>) {
        let studies = self.json("/studies").as_array().unwrap().len();
        let mut series = BTreeMap::new();
        for id in self.json("/series").as_array().unwrap() {
            let s = self.json(&format!("/series/{}", id.as_str().unwrap()));
            let name = s["MainDicomTags"]["SeriesDescription"]
                .as_str()
                .unwrap_or("?")
                .to_string();
            series.insert(name, s["Instances"].as_array().unwrap().len());
        }
        (studies, series)
    }

    fn instance_count(&self) -> u64 {
        self.json("/statistics")["CountInstances"].as_u64().unwrap()
    }

    /// The stored file of the instance with this SOP Instance UID.
    fn file_of(&self, sop_instance_uid: &str) -> Vec<u8> {
        let found = ureq::post(&self.url("/tools/lookup"))
            .send_string(sop_instance_uid)
            .unwrap()
            .into_string()
            .unwrap();
        let found: serde_json::Value = serde_json::from_str(&found).unwrap();
        let id = found[0]["ID"].as_str().expect("instance in Orthanc");
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(
            &mut self.get(&format!("/instances/{id}/file")).into_reader(),
            &mut bytes,
        )
        .unwrap();
        bytes
    }
}

impl Drop for Orthanc {
    fn drop(&mut self) {
        self.stop();
    }
}

fn stow(name: &str, orthanc: &Orthanc) -> PacsDestination {
    destination(name, Some(orthanc.dicom_web()), None)
}

fn cstore(name: &str, orthanc: &Orthanc, called_ae: &str) -> PacsDestination {
    destination(name, None, Some((orthanc.dicom, called_ae)))
}

fn destination(name: &str, url: Option<String>, dimse: Option<(u16, &str)>) -> PacsDestination {
    PacsDestination {
        name: name.into(),
        url,
        auth: None,
        user: None,
        secret_file: None,
        host: dimse.map(|_| "127.0.0.1".into()),
        port: dimse.map(|(p, _)| p),
        called_ae: dimse.map(|(_, ae)| ae.into()),
        calling_ae: "PROX320_TEST".into(),
        timeout_s: 10,
        retry_backoff_ms: [100, 400],
    }
}

/// The DICOM files of a build's series: path relative to the build → SOP Instance UID.
fn series_files(build: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for view in std::fs::read_dir(build.join("dicom")).unwrap().flatten() {
        for file in std::fs::read_dir(view.path()).unwrap().flatten() {
            let path = file.path();
            if path.extension().is_some_and(|e| e == "dcm") {
                let object = dicom_object::open_file(&path).unwrap();
                let relative = path
                    .strip_prefix(build)
                    .unwrap()
                    .to_string_lossy()
                    .into_owned();
                out.insert(
                    relative,
                    object.meta().media_storage_sop_instance_uid().to_string(),
                );
            }
        }
    }
    out
}

fn pixel_data(bytes: &[u8]) -> Vec<u8> {
    let object = dicom_object::OpenFileOptions::new()
        .from_reader(&bytes[128..])
        .unwrap();
    object
        .element(dicom_dictionary_std::tags::PIXEL_DATA)
        .unwrap()
        .to_bytes()
        .unwrap()
        .into_owned()
}

/// Orthanc holds one study of six series of `layers` instances, each with the pixel data of
/// the file on disk.
fn assert_holds_the_build(orthanc: &Orthanc, build: &Path, layers: usize) {
    let (studies, series) = orthanc.contents();
    assert_eq!(studies, 1, "{series:?}");
    assert_eq!(series.len(), 6, "{series:?}");
    assert!(series.values().all(|&n| n == layers), "{series:?}");
    let files = series_files(build);
    assert_eq!(files.len(), 6 * layers);
    for (file, uid) in &files {
        let local = std::fs::read(build.join(file)).unwrap();
        let stored = orthanc.file_of(uid);
        assert_eq!(
            pixel_data(&stored),
            pixel_data(&local),
            "{file}: pixel data in Orthanc differ"
        );
    }
}

/// Records of each kind per file in a push log.
fn log_counts(build: &Path, name: &str) -> (BTreeMap<String, usize>, usize, usize) {
    let text = std::fs::read_to_string(build.join("pacs").join(format!("{name}.jsonl")))
        .unwrap_or_default();
    let mut stored = BTreeMap::new();
    let (mut rejected, mut errors) = (0, 0);
    for line in text.lines() {
        let record: serde_json::Value = serde_json::from_str(line).unwrap();
        match record["kind"].as_str().unwrap() {
            "stored" => {
                *stored
                    .entry(record["file"].as_str().unwrap().to_string())
                    .or_insert(0) += 1
            }
            "rejected" => rejected += 1,
            _ => errors += 1,
        }
    }
    (stored, rejected, errors)
}

fn status_json(build: &Path) -> serde_json::Value {
    let out = layerwise()
        .args(["status", "--json", "--build"])
        .arg(build)
        .succeeds();
    serde_json::from_slice(&out.stdout).unwrap()
}

fn push(build: &Path, args: &[&str]) -> std::process::Output {
    layerwise()
        .args(["push", "--build"])
        .arg(build)
        .args(args)
        .output()
        .unwrap()
}

fn stdout(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn stderr(out: &std::process::Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn a_build_is_pushed_live_by_stow_rs_and_c_store_and_push_again_sends_nothing() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let web = Orthanc::new(tmp.path(), 8042, 4242, &[]);
    let dimse = Orthanc::new(tmp.path(), 8043, 4243, &[]);
    let build = tmp.path().join("build");
    let layers = 3;
    let mut config = calibrated_config(&build, layers, Compression::Deflate);
    config.pacs = vec![stow("web", &web), cstore("dimse", &dimse, "ORTHANC")];
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    common::run_build(&config_path);

    for orthanc in [&web, &dimse] {
        assert_holds_the_build(orthanc, &build, layers as usize);
    }
    let status = status_json(&build);
    let pacs = status["pacs"].as_array().unwrap();
    assert_eq!(pacs.len(), 2, "{status}");
    for destination in pacs {
        assert_eq!(destination["pushed"], 18, "{destination}");
        assert_eq!(destination["pending"], 0, "{destination}");
        assert_eq!(destination["failed"], 0, "{destination}");
        let (stored, _, _) = log_counts(&build, destination["destination"].as_str().unwrap());
        assert!(stored.values().all(|&n| n == 1), "{stored:?}");
    }
    // A second push sends nothing: everything is in the logs.
    let again = push(&build, &[]);
    assert!(again.status.success(), "{}", stderr(&again));
    assert_eq!(
        stdout(&again).matches(": 0 pushed").count(),
        2,
        "{}",
        stdout(&again)
    );
    assert_eq!(web.instance_count(), 18);
    // An archive given by URL on the command line (a new log) gets everything, once.
    let by_url = format!("dicom://ORTHANC@127.0.0.1:{}", web.dicom);
    let first = push(&build, &["--to", &by_url]);
    assert!(
        stdout(&first).contains("18 pushed"),
        "{}{}",
        stdout(&first),
        stderr(&first)
    );
    let second = push(&build, &["--to", &by_url]);
    assert!(stdout(&second).contains("0 pushed"), "{}", stdout(&second));
    assert_eq!(web.instance_count(), 18);
}
