//! The push to a PACS against a real Orthanc (Debian's `orthanc` and `orthanc-dicomweb`), each
//! test in a private network namespace of its own (Orthanc listens on every interface): the
//! test thread enters a new namespace, brings loopback up, and everything it starts (Orthanc,
//! layerwise) and every request it makes stays inside.

use crate::common;
use crate::common::{
    calibrated_config, layerwise, mock_printer, private_network, wait_until, write_config, Run,
};
use layerwise::config::pacs::PacsDestination;
use layerwise::dicom::Compression;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

const ORTHANC: &str = "/usr/sbin/Orthanc";
const DICOMWEB_PLUGIN: &str = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";

/// One Orthanc with its own storage, HTTP port and DICOM port, the DICOMweb plugin loaded.
struct Orthanc {
    dir: PathBuf,
    http: u16,
    dicom: u16,
    /// The Authorization header of the test's own requests, when authentication is on.
    authorization: Option<String>,
    child: Option<Child>,
}

impl Orthanc {
    /// Writes the configuration; `users` turns HTTP authentication on.
    fn new(dir: &Path, http: u16, dicom: u16, users: &[(&str, &str)]) -> Orthanc {
        let dir = dir.join(format!("orthanc-{http}"));
        std::fs::create_dir_all(dir.join("db")).unwrap();
        let registered: serde_json::Map<String, serde_json::Value> = users
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
            "AuthenticationEnabled": !registered.is_empty(),
            "RegisteredUsers": registered,
            "DicomWeb": { "Enable": true, "Root": "/dicom-web/" },
            "ConcurrentJobs": 1,
            "StorageCompression": false,
        });
        std::fs::write(
            dir.join("orthanc.json"),
            serde_json::to_vec_pretty(&config).unwrap(),
        )
        .unwrap();
        // The test's own requests: `curl -u` would send the same header.
        let authorization = users.first().map(|(u, p)| {
            let out = Command::new("base64")
                .arg("-w0")
                .stdin(std::process::Stdio::piped())
                .stdout(std::process::Stdio::piped())
                .spawn()
                .and_then(|mut child| {
                    use std::io::Write;
                    child
                        .stdin
                        .take()
                        .unwrap()
                        .write_all(format!("{u}:{p}").as_bytes())?;
                    child.wait_with_output()
                })
                .unwrap();
            format!("Basic {}", String::from_utf8(out.stdout).unwrap())
        });
        let mut orthanc = Orthanc {
            dir,
            http,
            dicom,
            authorization,
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

    fn request(&self, method: &str, path: &str) -> ureq::Request {
        let request = ureq::request(method, &self.url(path));
        match &self.authorization {
            Some(a) => request.set("Authorization", a),
            None => request,
        }
    }

    fn get(&self, path: &str) -> ureq::Response {
        self.request("GET", path)
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
        let found = self
            .request("POST", "/tools/lookup")
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
        deadline_s: 60,
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

/// A build whose layer signals come every `interval_ms`, pushing to `destinations`.
fn slow_build(
    tmp: &Path,
    layers: u32,
    interval_ms: u64,
    destinations: Vec<PacsDestination>,
) -> (PathBuf, PathBuf) {
    let build = tmp.join("build");
    let mut config = calibrated_config(&build, layers, Compression::None);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = interval_ms;
    }
    config.pacs = destinations;
    let config_path = tmp.join("layerwise.toml");
    write_config(&config, &config_path);
    (build, config_path)
}

/// Every series file is logged stored exactly once.
fn assert_logged_once(build: &Path, name: &str, layers: usize) {
    let (stored, rejected, _) = log_counts(build, name);
    assert_eq!(rejected, 0);
    assert_eq!(stored.len(), 6 * layers, "{stored:?}");
    assert!(stored.values().all(|&n| n == 1), "{stored:?}");
    let files: Vec<_> = series_files(build).into_keys().collect();
    assert_eq!(stored.into_keys().collect::<Vec<_>>(), files);
}

#[test]
fn an_archive_down_in_mid_build_gets_everything_once_when_it_returns() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let mut web = Orthanc::new(tmp.path(), 8042, 4242, &[]);
    let layers = 8;
    let (build, config_path) = slow_build(tmp.path(), layers, 300, vec![stow("web", &web)]);
    let daemon = common::spawn_build(&config_path, std::process::Stdio::null());
    wait_until("the first pushes", Duration::from_secs(60), || {
        !log_counts(&build, "web").0.is_empty()
    });
    web.stop();
    let frames_at_stop = common::originals(&build).len();
    // Capture goes on while the archive is away; the queue grows and the error shows.
    wait_until(
        "frames and an error while the archive is down",
        Duration::from_secs(60),
        || common::originals(&build).len() >= frames_at_stop + 6 && log_counts(&build, "web").2 > 0,
    );
    let status = status_json(&build);
    let pacs = &status["pacs"][0];
    assert!(pacs["pending"].as_u64().unwrap() > 0, "{pacs}");
    let error = pacs["last_error"].as_str().unwrap();
    assert!(
        error.contains("/dicom-web/studies") && error.to_lowercase().contains("connect"),
        "{error}"
    );
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .succeeds();
    assert!(
        stdout(&text).contains("pacs       web:"),
        "{}",
        stdout(&text)
    );
    web.start();
    let out = daemon.wait_with_output().unwrap();
    assert!(out.status.success(), "{}", stderr(&out));
    assert_holds_the_build(&web, &build, layers as usize);
    assert_eq!(web.instance_count(), 6 * layers as u64);
    assert_logged_once(&build, "web", layers as usize);
    assert_eq!(status_json(&build)["pacs"][0]["pending"], 0);
}

#[test]
fn a_daemon_killed_while_pushing_completes_the_push_on_restart() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let dimse = Orthanc::new(tmp.path(), 8043, 4243, &[]);
    let layers = 8;
    let (build, config_path) = slow_build(
        tmp.path(),
        layers,
        300,
        vec![cstore("dimse", &dimse, "ORTHANC")],
    );
    let mut daemon = common::spawn_build(&config_path, std::process::Stdio::null());
    wait_until("the first pushes", Duration::from_secs(60), || {
        log_counts(&build, "dimse").0.len() >= 3
    });
    daemon.kill().unwrap();
    daemon.wait().unwrap();
    assert!(
        series_files(&build).len() < 6 * layers as usize,
        "killed too late to test anything"
    );
    common::run_build(&config_path);
    assert_holds_the_build(&dimse, &build, layers as usize);
    assert_eq!(dimse.instance_count(), 6 * layers as u64);
    assert_logged_once(&build, "dimse", layers as usize);
}

#[test]
fn rejections_and_unreachable_archives_are_reported_with_their_reason() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let secured = Orthanc::new(tmp.path(), 8042, 4242, &[("printer07", "s3cret")]);
    // An export-like folder: one good instance, one without its StudyInstanceUID.
    let build = tmp.path().join("build");
    let mut config = calibrated_config(&build, 1, Compression::None);
    let config_path = tmp.path().join("build.toml");
    write_config(&config, &config_path);
    common::run_build(&config_path);
    let folder = tmp.path().join("export");
    std::fs::create_dir_all(folder.join("series")).unwrap();
    let files: Vec<String> = series_files(&build).into_keys().collect();
    std::fs::copy(build.join(&files[0]), folder.join("series/good.dcm")).unwrap();
    let mut bad = dicom_object::open_file(build.join(&files[1])).unwrap();
    bad.remove_element(dicom_dictionary_std::tags::STUDY_INSTANCE_UID);
    bad.write_to_file(folder.join("series/bad.dcm")).unwrap();

    // 401 without credentials, said plainly; nothing recorded as pushed.
    let url = secured.dicom_web();
    let unauthorized = push(&folder, &["--to", &url]);
    assert!(!unauthorized.status.success());
    assert!(
        stderr(&unauthorized).contains("HTTP 401 Unauthorized"),
        "{}",
        stderr(&unauthorized)
    );
    // With the secret from a file: the good one stored, the bad one rejected with the reason.
    let secret = tmp.path().join("pacs.secret");
    std::fs::write(&secret, "s3cret\n").unwrap();
    let mut web = stow("archive", &secured);
    web.auth = Some(layerwise::config::pacs::PacsAuth::Basic);
    web.user = Some("printer07".into());
    web.secret_file = Some(secret);
    config.pacs = vec![web];
    write_config(&config, &config_path);
    let rejected = push(
        &folder,
        &["--config", config_path.to_str().unwrap(), "--to", "archive"],
    );
    assert_eq!(rejected.status.code(), Some(1), "{}", stderr(&rejected));
    assert!(
        stdout(&rejected).contains("1 pushed"),
        "{}",
        stdout(&rejected)
    );
    assert!(
        stdout(&rejected).contains("rejected series/bad.dcm: STOW-RS FailureReason"),
        "{}",
        stdout(&rejected)
    );
    // Not retried on the next push: it is recorded as failed.
    let again = push(&folder, &["--config", config_path.to_str().unwrap()]);
    assert!(
        stdout(&again).contains("0 pushed"),
        "{}{}",
        stdout(&again),
        stderr(&again)
    );
    assert_eq!(log_counts(&folder, "archive").1, 1);
    // C-STORE: the same refusal with its status, and a wrong AE title refused at association.
    let dimse = format!("dicom://ORTHANC@127.0.0.1:{}", secured.dicom);
    let refused = push(&folder, &["--to", &dimse]);
    assert!(
        stdout(&refused).contains("rejected series/bad.dcm: C-STORE status"),
        "{}",
        stdout(&refused)
    );
    let wrong_ae = push(
        &folder,
        &[
            "--to",
            &format!("dicom://WRONG@127.0.0.1:{}", secured.dicom),
        ],
    );
    assert!(
        stderr(&wrong_ae).contains("called AE title not recognized"),
        "{}",
        stderr(&wrong_ae)
    );
    // Nothing listening: connection refused, for both protocols, in the log for status.
    for to in [
        "http://127.0.0.1:9/dicom-web",
        "dicom://ORTHANC@127.0.0.1:9",
    ] {
        let down = push(&folder, &["--to", to]);
        assert!(!down.status.success());
        assert!(stderr(&down).contains("refused"), "{to}: {}", stderr(&down));
    }
    // status of a build shows the destination's failures and last error.
    let on_build = push(
        &build,
        &[
            "--to",
            &format!("dicom://WRONG@127.0.0.1:{}", secured.dicom),
        ],
    );
    assert!(!on_build.status.success());
    let status = status_json(&build);
    let entry = &status["pacs"][0];
    assert_eq!(entry["pending"], 6, "{entry}");
    assert!(
        entry["last_error"]
            .as_str()
            .unwrap()
            .contains("called AE title not recognized"),
        "{entry}"
    );
    assert_eq!(secured.instance_count(), 1);
}

#[test]
fn a_slice_replaced_by_a_retake_is_pushed_as_a_new_instance() {
    private_network();
    let tmp = tempfile::tempdir().unwrap();
    let web = Orthanc::new(tmp.path(), 8042, 4242, &[]);
    let build = tmp.path().join("build");
    let mut config = calibrated_config(&build, 2, Compression::Deflate);
    config.rectify.pixel_mm = 2.0;
    config.series.take = layerwise::config::series::SeriesTake::Last;
    config.pacs = vec![stow("web", &web)];
    let set_script = |config: &mut layerwise::config::Config, text: &str| {
        mock_printer(config, tmp.path(), text);
        let config_path = tmp.path().join("layerwise.toml");
        write_config(config, &config_path);
        config_path
    };
    // Layer 1, pushed in full.
    common::run_build(&set_script(&mut config, "LAYER 1 PRE\nLAYER 1 POST\n"));
    let before = series_files(&build);
    assert_eq!(before.len(), 6);
    assert_eq!(web.instance_count(), 6);
    // After a restart, layer 2, then layer 1's post signal twice (going backwards, then
    // repeated): its three slices are replaced by the retakes, each a new instance to push.
    common::run_build(&set_script(
        &mut config,
        "LAYER 2 PRE\nLAYER 1 POST\nLAYER 1 POST\n",
    ));
    assert!(build.join("raw/L00001_post_top.r2.jpg").is_file());
    let after = series_files(&build);
    assert_eq!(after.len(), 9);
    for (file, uid) in &after {
        let replaced = file.contains("post_") && file.ends_with("L00001.dcm");
        assert_eq!(
            before.get(file).is_some_and(|old| old != uid),
            replaced,
            "{file}"
        );
        let local = std::fs::read(build.join(file)).unwrap();
        assert_eq!(pixel_data(&web.file_of(uid)), pixel_data(&local), "{file}");
    }
    // The archive keeps the first takes it had, and has the retakes beside them.
    assert_eq!(web.instance_count(), 6 + 3 + 3);
    let (stored, rejected, _) = log_counts(&build, "web");
    assert_eq!(rejected, 0);
    for (file, n) in &stored {
        let replaced = file.contains("post_") && file.ends_with("L00001.dcm");
        assert_eq!(*n, if replaced { 2 } else { 1 }, "{file}: {stored:?}");
    }
    // Nothing is pending, and pushing again sends nothing.
    let again = push(&build, &[]);
    assert!(stdout(&again).contains(": 0 pushed"), "{}", stdout(&again));
    assert_eq!(web.instance_count(), 12);
}
