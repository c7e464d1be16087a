//! The build disk running low and full under the daemon: `storage.min_free_gb` pauses the derived
//! data (DICOM series) while originals are still captured; a full disk (ENOSPC on an original)
//! never stops the daemon: the frames it cannot store are journaled as missing, status says it
//! waits for space, and capture and the series resume when space returns. The real test runs the
//! binary on a small tmpfs in a private mount namespace (needs root, as CI runs it); another
//! drives the disk guard through the simulated probe (`sim::disk`).

// The soak driver (benches/support/soak.rs, the `soak` module here) includes its own copy: the
// bench needs it without this crate. 50 lines twice, private to each.
#[allow(clippy::duplicate_mod)]
#[path = "../../benches/support/tmpfs.rs"]
mod tmpfs;

use crate::common::*;
use layerwise::acquisition::RunOptions;
use layerwise::build_dir::journal::Record;
use layerwise::fsutil::FreeSpace;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A calibrated mock build with a coarse rectified grid (2 mm: 138 x 138 slices), deflated.
fn small_calibrated(dir: &Path, layers: u32) -> layerwise::config::Config {
    let mut config = calibrated_config(dir, layers, layerwise::dicom::Compression::Deflate);
    config.rectify.pixel_mm = 2.0;
    // The demo's limit (the tests' common configuration sets none).
    config.storage.min_free_gb = 1.0;
    config
}

/// Moves this test's thread (and every process it starts) into a private mount namespace and
/// mounts a tmpfs of `mb` MB at `at`; the host never sees it.
fn small_disk(at: &Path, mb: u32) {
    tmpfs::mount(at, u64::from(mb)).unwrap_or_else(|e| {
        panic!("a tmpfs in a private mount namespace: {e} (the disk-full test needs root, as CI runs it)")
    });
}

fn unmount(at: &Path) {
    tmpfs::unmount(at);
}

/// Writes `path` until the disk holding it has at most `leave` bytes free (0: until ENOSPC).
fn ballast(path: &Path, leave: u64) {
    let mut file = std::fs::File::create(path).unwrap();
    let chunk = vec![0x5Au8; 64 * 1024];
    loop {
        let free = layerwise::fsutil::Statvfs.free_bytes(path).unwrap();
        if leave > 0 && free <= leave + chunk.len() as u64 {
            break;
        }
        match file.write_all(&chunk).and_then(|()| file.sync_data()) {
            Ok(()) => {}
            Err(e) if layerwise::fsutil::is_disk_full(&e) => break,
            Err(e) => panic!("ballast: {e}"),
        }
    }
}

/// Waits for `what` to hold, failing with `message` and the daemon's log after `secs` s.
fn wait_until(secs: u64, log: &Path, message: &str, mut what: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !what() {
        assert!(
            Instant::now() < deadline,
            "{message}\n--- daemon log (last lines)\n{}",
            tail(log)
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The daemon's disk lines and its last lines.
fn tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    let disk: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.contains("disk") && !l.contains("frame missing"))
        .take(40)
        .collect();
    format!(
        "{}\n…\n{}",
        disk.join("\n"),
        lines[lines.len().saturating_sub(10)..].join("\n")
    )
}

/// Kills the daemon if the test fails half way (a build of thousands of layers).
struct Daemon(Option<std::process::Child>);

impl Drop for Daemon {
    fn drop(&mut self) {
        if let Some(mut child) = self.0.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

fn status_json(build: &Path) -> serde_json::Value {
    layerwise()
        .args(["status", "--json", "--build"])
        .arg(build)
        .json_ok()
}

/// status.json's disk state ("ok", "low", "full"), if written yet.
fn disk_state(build: &Path) -> String {
    std::fs::read(build.join("status.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| v["disk"]["state"].as_str().map(str::to_string))
        .unwrap_or_default()
}

/// (frames stored, processed, missing for want of space) from the journal as it stands.
fn counts(build: &Path) -> (usize, usize, usize) {
    let Ok(replay) = layerwise::build_dir::Journal::read(&build.join("journal.jsonl")) else {
        return (0, 0, 0);
    };
    let full = replay
        .missing
        .values()
        .filter(|r| r.contains("disk is full"))
        .count();
    (replay.frames.len(), replay.processed.len(), full)
}

#[test]
fn disk_full_waits_records_missing_frames_and_resumes_with_the_series_caught_up() {
    let dir = tempfile::tempdir().unwrap();
    let disk = dir.path().join("disk");
    small_disk(&disk, 64);
    let build = disk.join("build");
    let mut config = small_calibrated(&build, 5000);
    // Below 6 MB free: derived data waits, originals go on.
    config.storage.min_free_gb = 0.006;
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 100;
    }
    let config_path = dir.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let log_path = dir.path().join("daemon.log");
    let mut daemon = Daemon(Some(spawn_build(
        &config_path,
        Stdio::from(std::fs::File::create(&log_path).unwrap()),
    )));
    let log = log_path.as_path();
    let mut alive = || {
        let child = daemon.0.as_mut().unwrap();
        assert!(
            child.try_wait().unwrap().is_none(),
            "the daemon exited\n{}",
            tail(log)
        )
    };

    wait_until(60, log, "no frames stored", || counts(&build).0 >= 12);
    let before: Vec<String> = originals(&build);

    // Low: below storage.min_free_gb the series wait while the originals keep coming.
    ballast(&disk.join("ballast-1"), 3_000_000);
    wait_until(30, log, "status never said the disk is low", || {
        disk_state(&build) == "low"
    });
    let low = status_json(&build);
    assert_eq!(low["health"]["processing"]["state"], "warning", "{low:#}");
    assert!(
        low["warning"]
            .as_str()
            .unwrap_or_default()
            .contains("disk low"),
        "{low:#}"
    );
    wait_until(
        30,
        log,
        "the originals stopped or the series went on",
        || {
            let (frames, processed, _) = counts(&build);
            frames >= processed + 9
        },
    );
    alive();

    // Full: frames are journaled as missing, status says the daemon waits for space.
    ballast(&disk.join("ballast-2"), 0);
    wait_until(30, log, "the daemon never noticed the full disk", || {
        counts(&build).2 >= 6
    });
    alive();
    assert_eq!(disk_state(&build), "full");
    let full = status_json(&build);
    let warning = full["warning"].as_str().unwrap_or_default().to_string();
    assert!(
        warning.contains("waiting for disk space: ") && warning.contains(" MB free, need "),
        "{full:#}"
    );
    assert_eq!(full["health"]["disk"]["state"], "error", "{full:#}");
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("waiting for disk space"), "{text}");

    // Space returns: capture resumes, the series catch up everything skipped.
    std::fs::remove_file(disk.join("ballast-1")).unwrap();
    std::fs::remove_file(disk.join("ballast-2")).unwrap();
    let (stored_when_freed, _, missed) = counts(&build);
    let free = layerwise::fsutil::Statvfs.free_bytes(&build).unwrap();
    let message = format!("capture never resumed ({free} bytes free)");
    wait_until(60, log, &message, || {
        counts(&build).0 >= stored_when_freed + 12
    });
    // Every frame stored so far (before, during and after the low period) gets its slice.
    let resumed = replay(&build);
    let message = format!(
        "the series never caught up: {}",
        status_json(&build)["bytes_by_kind"]
    );
    wait_until(60, log, &message, || {
        let now = replay(&build);
        resumed
            .frames
            .keys()
            .all(|shot| now.processed.contains(shot))
    });
    assert_eq!(disk_state(&build), "ok");
    let out = terminate(daemon.0.take().unwrap());
    assert_success(&out);

    // Nothing written was lost or torn; every original is journaled once, every frame of the
    // full period is recorded missing and has no file.
    let replay = replay(&build);
    let after = originals(&build);
    for file in &before {
        assert!(after.contains(file), "{file} lost");
    }
    assert!(frame_records(&build).values().all(|&n| n == 1));
    assert_sidecars_match(&build);
    assert!(temporaries(&build).is_empty(), "{:?}", temporaries(&build));
    let missing: Vec<_> = replay
        .missing
        .iter()
        .filter(|(_, r)| r.contains("disk is full"))
        .collect();
    assert!(missing.len() >= missed && missed >= 6);
    for (shot, _) in &missing {
        assert!(!replay.frames.contains_key(shot));
        assert!(!build.join(format!("raw/{}.jpg", shot.stem())).exists());
    }
    let last_missing = missing.iter().map(|(s, _)| s.layer).max().unwrap();
    assert!(
        replay
            .frames
            .keys()
            .filter(|s| s.layer > last_missing)
            .count()
            >= 6,
        "capture resumed after the full period"
    );
    // The series hold a slice for every frame stored up to the resumption (the later ones are
    // caught up by the next start, as the daemon stopped on SIGTERM).
    for shot in resumed.frames.keys() {
        let slice = layerwise::build_dir::series_dir(&build, shot.view())
            .join(format!("L{:05}.dcm", shot.layer));
        assert!(slice.is_file(), "{} has no slice", shot.stem());
    }
    unmount(&disk);
}

/// The simulated probe: a build that runs low keeps every original and leaves the series for
/// later; the next start, with room again, catches them up.
#[test]
fn disk_low_keeps_originals_and_the_next_start_catches_up_the_series() {
    let dir = tempfile::tempdir().unwrap();
    let build: PathBuf = dir.path().join("build");
    let config = small_calibrated(&build, 3);
    let disk = layerwise::sim::disk::SimulatedDisk::with_free(1_000_000);
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    options.free_space = Arc::new(disk.clone());
    let summary = run_daemon(&config, options).unwrap();
    assert_eq!((summary.stored, summary.missing), (18, 0));
    assert_eq!(originals(&build), expected_originals(3));
    let low = replay(&build);
    assert_eq!(low.processed.len(), 0, "the series waited");
    let status = read_json(&build.join("status.json"));
    assert_eq!(status["disk"]["state"], "low");
    assert_eq!(status["disk"]["derived_paused"], true);
    assert_eq!(status["health"]["disk"]["state"], "warning");

    disk.set_free(100_000_000_000);
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    options.free_space = Arc::new(disk);
    run_daemon(&config, options).unwrap();
    let caught_up = replay(&build);
    assert_eq!(caught_up.processed.len(), 18, "the series caught up");
    assert!(records(&build)
        .iter()
        .all(|r| !matches!(r, Record::ProcessingFailed { .. })));
    let status = read_json(&build.join("status.json"));
    assert_eq!(status["disk"]["state"], "ok");
}

/// Stands in for a slice that does not fit: the first frame's processing finds the disk full
/// (ENOSPC) while `full` holds; every try counted.
struct SliceDoesNotFit {
    first: layerwise::shot::Shot,
    full: std::sync::atomic::AtomicBool,
    tries: std::sync::atomic::AtomicUsize,
}

impl layerwise::series::FrameProcessor for SliceDoesNotFit {
    fn process(
        &self,
        _: &Path,
        shot: layerwise::shot::Shot,
        _: &Path,
    ) -> Result<(), layerwise::series::ProcessError> {
        use std::sync::atomic::Ordering::SeqCst;
        if shot != self.first {
            return Ok(());
        }
        self.tries.fetch_add(1, SeqCst);
        match self.full.load(SeqCst) {
            true => Err(Box::new(std::io::Error::from_raw_os_error(28))),
            false => Ok(()),
        }
    }
}

/// A slice that finds the disk full while the free space the guard measures stays above
/// `storage.min_free_gb` (a quota, a slice larger than the room left): the series and the
/// inspection wait until the free space grows, and status says why, rather than the slice being
/// tried again at every probe of the disk (each second) for as long as the disk stays so.
#[test]
fn a_slice_that_finds_the_disk_full_waits_for_the_free_space_to_grow() {
    use std::sync::atomic::Ordering::SeqCst;
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    // 24 signals 400 ms apart: the build goes on well after the free space grows.
    let mut config = small_calibrated(&build, 12);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 400;
    }
    let disk = layerwise::sim::disk::SimulatedDisk::with_free(100_000_000_000);
    let processor = Arc::new(SliceDoesNotFit {
        first: layerwise::shot::Shot::new(
            1,
            layerwise::shot::Phase::Pre,
            layerwise::shot::Light::Front,
        ),
        full: true.into(),
        tries: 0.into(),
    });
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    options.free_space = Arc::new(disk.clone());
    options.processor = Some(processor.clone());
    let daemon = {
        let config = config.clone();
        std::thread::spawn(move || run_daemon(&config, options))
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while processor.tries.load(SeqCst) == 0 {
        assert!(Instant::now() < deadline, "the first frame never processed");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Three probes of the disk later, the slice is still not tried again (before: once each).
    std::thread::sleep(Duration::from_millis(3200));
    assert_eq!(
        processor.tries.load(SeqCst),
        1,
        "tried again on a full disk"
    );
    let status = read_json(&build.join("status.json"));
    assert_eq!(status["disk"]["state"], "ok", "{status:#}");
    assert_eq!(status["disk"]["derived_paused"], true, "{status:#}");
    assert_eq!(status["health"]["disk"]["state"], "warning", "{status:#}");
    let warning = status["health"]["disk"]["warning"]
        .as_str()
        .unwrap_or_default();
    assert!(
        warning.contains("a slice found the disk full"),
        "{status:#}"
    );

    // Room made: the derived data is caught up, the slice tried once more.
    processor.full.store(false, SeqCst);
    disk.set_free(100_100_000_000);
    let summary = daemon.join().unwrap().unwrap();
    assert_eq!(processor.tries.load(SeqCst), 2);
    let caught_up = replay(&build);
    assert_eq!(caught_up.processed.len() as u64, summary.stored);
    assert_eq!(summary.stored, 72);
    let status = read_json(&build.join("status.json"));
    assert_eq!(status["disk"]["derived_paused"], false, "{status:#}");
}
