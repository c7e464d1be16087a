//! The page stays inside its build (issue 30, "The page leaves its build"): links planted in
//! `raw/` (to /etc/passwd, ../../etc/hostname, another build's frame) are not followed, a FIFO
//! blocks no request, `/dev/zero` is not read; a crop smaller than a pixel is a bad request; a
//! frame that cannot be decoded is refused (422) and the page goes on ("One request stops a
//! build").

use crate::common::*;
use std::os::unix::fs::symlink;
use std::path::Path;
use std::time::{Duration, Instant};

/// A FIFO at `path`.
fn mkfifo(path: &Path) {
    let name = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(name.as_ptr(), 0o600) }, 0, "mkfifo");
}

/// `/dev/zero`'s own device node at `path` when this test may make one (root), else a link.
fn dev_zero(path: &Path) -> &'static str {
    let name = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path; makedev(1, 5) is /dev/zero.
    let made = unsafe { libc::mknod(name.as_ptr(), libc::S_IFCHR | 0o600, libc::makedev(1, 5)) };
    if made == 0 {
        "device"
    } else {
        symlink("/dev/zero", path).unwrap();
        "link"
    }
}

/// The peak resident memory of a process, in MB.
fn peak_rss_mb(pid: u32) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    kb / 1024.0
}

/// `path` answered 403 within 10 s, saying why, with none of `secrets` (the files a link
/// points at) in the answer; `zero`: how `/dev/zero` was planted.
fn refused_at_once(addr: std::net::SocketAddr, path: &str, zero: &str, secrets: &[Vec<u8>]) {
    let started = Instant::now();
    let (status, body) = http(addr, "GET", path, b"");
    let text = String::from_utf8_lossy(&body);
    assert_eq!(status, 403, "{path} ({zero}): {text:.300}");
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "{path}: {:?}",
        started.elapsed()
    );
    assert!(
        text.contains("symbolic link") || text.contains("not a regular file"),
        "{path}: {text}"
    );
    for secret in secrets {
        assert!(
            secret.is_empty() || !body.windows(secret.len()).any(|w| w == secret),
            "{path} served another file"
        );
    }
}

#[test]
fn planted_links_fifos_and_devices_in_raw_are_refused_and_block_nobody() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 2);
    let other_tmp = tmp.path().join("other");
    std::fs::create_dir(&other_tmp).unwrap();
    let other = finished_build(&other_tmp, 1);
    let raw = dir.join("raw");
    let replace = |name: &str| {
        std::fs::remove_file(raw.join(name)).unwrap();
        raw.join(name)
    };
    symlink("/etc/passwd", replace("L00001_post_top.jpg")).unwrap();
    symlink("../../etc/hostname", replace("L00001_post_front.jpg")).unwrap();
    let others = other.join("raw/L00001_post_side.jpg");
    symlink(&others, replace("L00001_post_side.jpg")).unwrap();
    mkfifo(&replace("L00002_post_top.jpg"));
    let zero = dev_zero(&replace("L00002_post_front.jpg"));
    symlink("/dev/zero", replace("L00002_post_side.jpg")).unwrap();
    let secrets = [
        std::fs::read("/etc/passwd").unwrap_or_default(),
        std::fs::read(&others).unwrap(),
    ];

    let (served, addr) = serve(&dir, &[]);
    for layer in [1, 2] {
        for view in ["post_top", "post_front", "post_side"] {
            for what in [
                "original",
                "picture.jpg?kind=raw",
                "picture.jpg?kind=rectified",
            ] {
                let path = format!("/api/layers/{layer}/{view}/{what}");
                refused_at_once(addr, &path, zero, &secrets);
            }
        }
    }
    // raw/ itself a link to another build's frames: nothing of it is served.
    std::fs::rename(&raw, dir.join("raw-moved")).unwrap();
    symlink(other.join("raw"), &raw).unwrap();
    let (status, body) = http(addr, "GET", "/api/layers/1/pre_top/original", b"");
    assert_eq!(status, 403, "{}", String::from_utf8_lossy(&body));
    std::fs::remove_file(&raw).unwrap();
    std::fs::rename(dir.join("raw-moved"), &raw).unwrap();
    // The frames that are what they should be are served as before, to everyone.
    let (status, body) = http(addr, "GET", "/api/layers/1/pre_top/original", b"");
    assert_eq!(status, 200);
    assert_eq!(body, std::fs::read(raw.join("L00001_pre_top.jpg")).unwrap());
    let (status, _) = http(addr, "GET", "/api/layers/2/pre_top/picture.jpg", b"");
    assert_eq!(status, 200);
    // /dev/zero was never read: the server is as small as a page server is.
    let peak = peak_rss_mb(served.pid());
    assert!(peak < 400.0, "peak resident memory {peak:.0} MB");
    drop(served);
}

/// The model's heat maps go through the same opener: before, the route read them with
/// `std::fs::read`, following a link to any file the service could read, waiting on a FIFO (four
/// of them took every blocking thread) and reading `/dev/zero` until the page was killed.
#[test]
fn planted_heat_maps_are_refused_and_a_real_one_is_served() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 2);
    let maps = dir.join(layerwise::learn::live::HEATMAP_DIR);
    for view in ["post_top", "post_front", "post_side"] {
        std::fs::create_dir_all(maps.join(view)).unwrap();
    }
    let png = {
        let mut bytes = Vec::new();
        image::GrayImage::from_pixel(4, 3, image::Luma([200u8]))
            .write_to(
                &mut std::io::Cursor::new(&mut bytes),
                image::ImageFormat::Png,
            )
            .unwrap();
        bytes
    };
    std::fs::write(maps.join("post_top/L00002.png"), &png).unwrap();
    symlink("/etc/passwd", maps.join("post_top/L00001.png")).unwrap();
    mkfifo(&maps.join("post_front/L00001.png"));
    let zero = dev_zero(&maps.join("post_side/L00001.png"));
    symlink("/dev/zero", maps.join("post_front/L00002.png")).unwrap();
    let passwd = std::fs::read("/etc/passwd").unwrap_or_default();

    let (served, addr) = serve(&dir, &[]);
    let planted = [
        (1, "post_top"),
        (1, "post_front"),
        (1, "post_side"),
        (2, "post_front"),
    ];
    for (layer, view) in planted {
        let path = format!("/api/layers/{layer}/{view}/heatmap.png");
        refused_at_once(addr, &path, zero, std::slice::from_ref(&passwd));
    }
    let (status, body) = http(addr, "GET", "/api/layers/2/post_top/heatmap.png", b"");
    assert_eq!((status, body), (200, png));
    let (status, _) = http(addr, "GET", "/api/layers/2/post_side/heatmap.png", b"");
    assert_eq!(status, 404, "none written");
    let peak = peak_rss_mb(served.pid());
    assert!(peak < 400.0, "peak resident memory {peak:.0} MB");
    drop(served);
}

/// Moves the first number of the build's calibration copy by a millionth of itself.
fn nudge_calibration(build: &Path) {
    fn nudge(value: &mut toml::Value) -> bool {
        match value {
            toml::Value::Float(f) => {
                *f += f.abs().max(1.0) * 1e-6;
                true
            }
            toml::Value::Array(items) => items.iter_mut().any(nudge),
            toml::Value::Table(table) => table.iter_mut().any(|(_, v)| nudge(v)),
            _ => false,
        }
    }
    let path = build.join(layerwise::build_dir::CALIBRATION_COPY);
    let mut calibration: toml::Value =
        toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert!(nudge(&mut calibration), "a number in {}", path.display());
    std::fs::write(&path, toml::to_string(&calibration).unwrap()).unwrap();
}

/// A picture carries its original's identity (ETag) and is to be asked for again (`no-cache`):
/// another build served at the same address has other pictures for the same layer and view,
/// and a browser that kept build A's layer 1 sees build B's; a calibration changed since is
/// another picture too. Before, pictures were sent
/// `max-age=600` by layer and view alone: a page kept showing the build before's pictures for up
/// to ten minutes, reloads included.
#[test]
fn a_picture_is_asked_for_again_and_another_builds_is_not_taken_for_it() {
    let tmp = tempfile::tempdir().unwrap();
    let builds = ["a", "b"].map(|name| {
        let at = tmp.path().join(name);
        std::fs::create_dir(&at).unwrap();
        finished_build(&at, 1)
    });
    let path = "/api/layers/1/post_top/picture.jpg";
    let tag_of = |head: &str| -> String {
        let line = head.lines().find_map(|l| l.strip_prefix("etag: "));
        line.unwrap_or_else(|| panic!("no etag: {head}"))
            .to_string()
    };
    let (served, addr) = serve(&builds[0], &[]);
    let (status, head, body) = http_with(addr, "GET", path, "", b"");
    assert_eq!(status, 200, "{head}");
    assert!(head.contains("cache-control: private, no-cache"), "{head}");
    assert!(!body.is_empty());
    let tag = tag_of(&head);
    let asked = format!("If-None-Match: {tag}\r\n");
    let (status, head, body) = http_with(addr, "GET", path, &asked, b"");
    assert_eq!((status, body.len()), (304, 0), "{head}");
    assert_eq!(tag_of(&head), tag);
    // Another kind of picture of the same frame is another picture.
    let raw = format!("{path}?kind=raw");
    assert_eq!(http_with(addr, "GET", &raw, &asked, b"").0, 200);
    drop(served);
    // Build A served again with its calibration changed (a restart with a new one): the
    // rectified picture is another, though its original is the same file.
    nudge_calibration(&builds[0]);
    let (served, addr) = serve(&builds[0], &[]);
    let (status, head, _) = http_with(addr, "GET", path, &asked, b"");
    assert_eq!(status, 200, "{head}");
    assert_ne!(tag_of(&head), tag);
    drop(served);
    // Build B at an address a page knew build A at: its layer 1 is sent whole.
    let (served, addr) = serve(&builds[1], &[]);
    let (status, head, body) = http_with(addr, "GET", path, &asked, b"");
    assert_eq!(status, 200, "{head}");
    assert!(!body.is_empty());
    assert_ne!(tag_of(&head), tag);
    // The status names the build, so a page open at this address reloads for build B.
    let uid = |at: &std::path::Path| {
        read_json(&at.join(layerwise::build_dir::MANIFEST))["study_instance_uid"].clone()
    };
    let (_, status) = http(addr, "GET", "/api/status", b"");
    let status: serde_json::Value = serde_json::from_slice(&status).unwrap();
    assert_eq!(status["build_uid"], uid(&builds[1]));
    assert_ne!(uid(&builds[0]), uid(&builds[1]));
    drop(served);
}

/// The page reads the build's settings again when their files change: a new build writes its
/// configuration first and its calibration after it, and a page that looked in between showed
/// raw frames only, for the page's whole life (the settings were read once).
#[test]
fn a_calibration_that_comes_after_the_page_started_is_used() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let copy = dir.join(layerwise::build_dir::CALIBRATION_COPY);
    let aside = tmp.path().join("calibration.toml");
    std::fs::rename(&copy, &aside).unwrap();
    let (served, addr) = serve(&dir, &[]);
    let rectified = || get_json(addr, "/api/layers")["rectified"].clone();
    let picture = "/api/layers/1/post_top/picture.jpg?kind=rectified";
    assert_eq!(rectified(), false);
    assert_eq!(http(addr, "GET", picture, b"").0, 404);
    std::fs::rename(&aside, &copy).unwrap();
    assert_eq!(rectified(), true);
    let (status, body) = http(addr, "GET", picture, b"");
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
    drop(served);
}

#[test]
fn a_crop_smaller_than_a_pixel_is_a_bad_request_not_a_server_error() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let (served, addr) = serve(&dir, &[]);
    for kind in ["rectified", "raw"] {
        let path =
            format!("/api/layers/1/post_top/picture.jpg?kind={kind}&x=0.5&y=0.5&w=0.0001&h=0.0001");
        let (status, body) = http(addr, "GET", &path, b"");
        let text = String::from_utf8_lossy(&body);
        assert_eq!(status, 400, "{path}: {text}");
        assert!(text.contains("smaller than a pixel"), "{text}");
        // One pixel is a crop.
        let path =
            format!("/api/layers/1/post_top/picture.jpg?kind={kind}&x=0.5&y=0.5&w=0.01&h=0.01");
        assert_eq!(http(addr, "GET", &path, b"").0, 200, "{path}");
    }
    drop(served);
}

#[test]
fn the_calibration_page_writes_nothing_through_a_link_planted_as_its_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 1);
    let elsewhere = tmp.path().join("elsewhere");
    std::fs::create_dir(&elsewhere).unwrap();
    symlink(&elsewhere, dir.join("calibration")).unwrap();
    let (served, addr) = serve(&dir, &["--calibration-page"]);
    let points: Vec<_> = [(0.2, 0.2), (0.8, 0.2), (0.8, 0.8), (0.2, 0.8)]
        .iter()
        .map(|&(fx, fy)| serde_json::json!({"fx": fx, "fy": fy, "x": 0.0, "y": 0.0}))
        .collect();
    let body = serde_json::json!({"layer": 1, "view": "post_top", "points": points});
    let (status, answer) = http(
        addr,
        "POST",
        "/api/calibration",
        body.to_string().as_bytes(),
    );
    let text = String::from_utf8_lossy(&answer);
    assert_eq!(status, 400, "{text}");
    assert!(text.contains("not a folder of the build"), "{text}");
    assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0);
    drop(served);
}

/// A 30-byte little-endian TIFF whose one directory names itself as the next (the probe's
/// input: decoders that follow the chain never end, or reserve gigabytes on the way).
fn self_pointing_tiff() -> Vec<u8> {
    let mut tiff = b"II*\0".to_vec();
    tiff.extend_from_slice(&8u32.to_le_bytes()); // the first directory, at 8
    tiff.extend_from_slice(&1u16.to_le_bytes()); // one entry:
    tiff.extend_from_slice(&[0x00, 0x01, 3, 0, 1, 0, 0, 0, 1, 0, 0, 0]); // ImageWidth 1
    tiff.extend_from_slice(&8u32.to_le_bytes()); // the next directory: this one again
    tiff.resize(30, 0);
    tiff
}

/// The finding: a 30-byte TIFF whose directory points to itself, stored as a frame and asked
/// for through the daemon's page (`…/picture.jpg?kind=raw`), aborted the daemon mid-build.
/// Every picture of it (raw, rectified, crops) is refused 422 naming the frame, at once, and
/// the page goes on: the other frames are served, by the same process, no bigger for it.
#[test]
fn a_self_pointing_tiff_as_a_frame_is_refused_and_the_page_goes_on() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 2);
    std::fs::write(dir.join("raw/L00001_post_top.jpg"), self_pointing_tiff()).unwrap();
    let (mut served, addr) = serve(&dir, &[]);
    let crop = "x=0.25&y=0.25&w=0.5&h=0.5";
    for query in [
        "kind=raw".to_string(),
        "kind=rectified".to_string(),
        format!("kind=raw&{crop}"),
        format!("kind=rectified&{crop}"),
    ] {
        let path = format!("/api/layers/1/post_top/picture.jpg?{query}");
        let started = Instant::now();
        let (status, body) = http(addr, "GET", &path, b"");
        let text = String::from_utf8_lossy(&body);
        assert_eq!(status, 422, "{path}: {text}");
        assert!(
            text.contains("raw/L00001_post_top.jpg") && text.contains("cannot be decoded"),
            "{path}: {text}"
        );
        assert!(started.elapsed() < Duration::from_secs(10), "{path}");
        // The page goes on, for every other picture.
        for other in ["1/post_front", "2/post_top"] {
            let path = format!("/api/layers/{other}/picture.jpg?{query}");
            assert_eq!(http(addr, "GET", &path, b"").0, 200, "{path}");
        }
    }
    assert_eq!(http(addr, "GET", "/api/status", b"").0, 200);
    assert!(served.0.try_wait().unwrap().is_none(), "the page ended");
    let peak = peak_rss_mb(served.pid());
    assert!(peak < 400.0, "peak resident memory {peak:.0} MB");
}

/// The page reads the journal and the inspection log as the daemon writes them: regular files,
/// never through a link. Before, a FIFO planted as the journal while the page served held every
/// request that shows the layers for good: the watch's read waited on the FIFO with the
/// timeline locked.
#[test]
fn a_fifo_planted_as_the_journal_holds_up_no_request() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = finished_build(tmp.path(), 2);
    let journal = dir.join(layerwise::build_dir::JOURNAL);
    let inspection = dir.join(layerwise::build_dir::INSPECTION);
    let (served, addr) = serve(&dir, &[]);
    let count = || {
        let layers = get_json(addr, "/api/layers");
        layers["layers"].as_array().map(Vec::len)
    };
    assert_eq!(count(), Some(2));

    let aside = tmp.path().join("journal.jsonl");
    std::fs::rename(&journal, &aside).unwrap();
    mkfifo(&journal);
    let _ = std::fs::remove_file(&inspection);
    let zero = dev_zero(&inspection);
    // The watch looks every 250 ms and when the directory changes.
    std::thread::sleep(Duration::from_secs(1));
    for _ in 0..3 {
        let started = Instant::now();
        assert_eq!(count(), Some(2), "{zero}");
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "{:?}",
            started.elapsed()
        );
        std::thread::sleep(Duration::from_millis(300));
    }
    // The journal back as a file, with a layer more: the page reads on.
    std::fs::remove_file(&journal).unwrap();
    std::fs::rename(&aside, &journal).unwrap();
    let more = layerwise::build_dir::Record::Event {
        layer: 3,
        phase: layerwise::shot::Phase::Pre,
        at: chrono::Utc::now(),
    };
    let mut file = std::fs::OpenOptions::new()
        .append(true)
        .open(&journal)
        .unwrap();
    std::io::Write::write_all(
        &mut file,
        (serde_json::to_string(&more).unwrap() + "\n").as_bytes(),
    )
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    while count() != Some(3) {
        assert!(Instant::now() < deadline, "layer 3 never shown");
        std::thread::sleep(Duration::from_millis(100));
    }
    let peak = peak_rss_mb(served.pid());
    assert!(peak < 400.0, "peak resident memory {peak:.0} MB");
    drop(served);
}
