//! The acquisition daemon driven in-process with the mock trigger, lights and camera.

use crate::common::*;
use layerwise::acquisition::{AcquisitionError, RunOptions};
use layerwise::series::{FrameProcessor, ProcessError};
use layerwise::shot::{Light, Phase, Shot};
use layerwise::sim::{LightSwitch, MockLightsLog};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn options_with_log() -> (RunOptions, Arc<Mutex<Option<MockLightsLog>>>) {
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    let slot = Arc::new(Mutex::new(None));
    (options, slot)
}

/// Runs the simulated build, keeping the mock lights' log in `slot`.
fn run_logged(
    config: &layerwise::config::Config,
    options: RunOptions,
    slot: &Arc<Mutex<Option<MockLightsLog>>>,
) -> Result<layerwise::acquisition::RunSummary, AcquisitionError> {
    run_daemon_with(config, options, |_, sim| {
        *slot.lock().unwrap() = sim.lights_log.clone();
    })
}

fn log_of(slot: &Arc<Mutex<Option<MockLightsLog>>>) -> MockLightsLog {
    slot.lock()
        .unwrap()
        .clone()
        .expect("mock lights were opened")
}

fn mean_brightness(path: &Path) -> f64 {
    let img = image::open(path).expect("decodes").to_luma8();
    img.pixels().map(|p| p.0[0] as f64).sum::<f64>() / (img.width() * img.height()) as f64
}

#[test]
fn a_clean_build_stores_every_view_lit_and_turns_lights_off() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 3);
    let (options, slot) = options_with_log();
    let summary = run_logged(&config, options, &slot).unwrap();
    assert_eq!((summary.stored, summary.missing), (18, 0));
    assert_eq!(originals(dir.path()), expected_originals(3));
    assert!(frame_records(dir.path()).values().all(|&n| n == 1));
    assert_sidecars_match(dir.path());
    // Each frame was taken with exactly its light on: never dark, never two lamps.
    let log = log_of(&slot);
    assert!(log.lit().is_empty(), "lights left on: {:?}", log.lit());
    let switches: Vec<LightSwitch> = log
        .history()
        .into_iter()
        .filter(|s| s.light.is_some())
        .collect();
    assert_eq!(switches.len(), 36, "on and off for each of 18 frames");
    for pair in switches.chunks(2) {
        assert_eq!(
            (pair[0].on, pair[1].on, pair[0].light),
            (true, false, pair[1].light)
        );
    }
    for file in originals(dir.path()) {
        assert!(
            mean_brightness(&dir.path().join(&file)) > 40.0,
            "{file} looks unlit"
        );
    }
    let replay = replay(dir.path());
    assert_eq!(replay.processed.len(), 18, "every frame processed");
}

#[test]
fn busy_disconnect_and_a_dead_frame_are_survived() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 4);
    add_fault(&mut config, "busy", 2, "post", "top", 3, 0);
    add_fault(&mut config, "disconnect", 3, "pre", "front", 0, 0);
    add_fault(&mut config, "fail", 3, "post", "side", 0, 0);
    let (options, slot) = options_with_log();
    let summary = run_logged(&config, options, &slot).unwrap();
    assert_eq!((summary.stored, summary.missing), (23, 1));

    let sidecar = |stem: &str| read_json(&dir.path().join(format!("raw/{stem}.json")));
    assert_eq!(
        sidecar("L00002_post_top")["attempts"],
        4,
        "three busy answers, then the frame"
    );
    assert_eq!(
        sidecar("L00003_pre_front")["attempts"],
        2,
        "disconnected, reopened, then the frame"
    );
    let replay = replay(dir.path());
    let dead = Shot {
        layer: 3,
        phase: Phase::Post,
        light: Light::Side,
    };
    assert!(
        replay
            .missing
            .get(&dead)
            .is_some_and(|r| r.contains("attempts")),
        "{:?}",
        replay.missing
    );
    // The build went on after the dead frame.
    assert!(replay.frames.contains_key(&Shot {
        layer: 3,
        phase: Phase::Post,
        light: Light::Top
    }));
    assert!(replay.frames.contains_key(&Shot {
        layer: 4,
        phase: Phase::Post,
        light: Light::Top
    }));
    assert!(!dir.path().join("raw/L00003_post_side.jpg").exists());
    assert!(log_of(&slot).lit().is_empty());
    assert_eq!(
        read_json(&dir.path().join("status.json"))["state"],
        "stopped"
    );
}

#[test]
fn a_hung_camera_stops_the_daemon_with_lights_off() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 3);
    // A timeout that no sound call reaches while the rest of the suite loads both cores (at
    // 1 s, the mock camera's render of a frame missed it once on a 2-core Zen 1 host, and the
    // daemon stopped at layer 1), and a hang far past it.
    config.capture.call_timeout_s = 4;
    add_fault(&mut config, "hang", 2, "pre", "side", 0, 15_000);
    let (options, slot) = options_with_log();
    let started = Instant::now();
    let result = run_logged(&config, options, &slot);
    assert!(
        matches!(result, Err(AcquisitionError::CameraHung(_))),
        "{result:?}"
    );
    assert!(
        started.elapsed() < Duration::from_secs(15),
        "the daemon must not wait for the hung call"
    );
    let log = log_of(&slot);
    assert!(log.lit().is_empty(), "lights left on after the hang");
    assert_eq!(
        log.history().last(),
        Some(&LightSwitch {
            light: None,
            on: false
        })
    );
    let replay = replay(dir.path());
    assert_eq!(
        replay.frames.len(),
        7,
        "layer 1 and layer 2 pre front were stored"
    );
    assert!(replay.missing.values().any(|r| r.contains("hung")));
    assert_eq!(
        read_json(&dir.path().join("status.json"))["state"],
        "failed"
    );
}

/// Layer 1's two signals, then a panic on the trigger's thread.
struct PanicsAfterLayerOne(Vec<Phase>);

impl layerwise::hardware::trigger::Trigger for PanicsAfterLayerOne {
    fn next_event(
        &mut self,
        _: &layerwise::shutdown::Shutdown,
    ) -> Result<
        Option<layerwise::hardware::trigger::LayerEvent>,
        layerwise::hardware::trigger::TriggerError,
    > {
        let phase = self.0.pop().expect("a trigger that panics");
        Ok(Some(layerwise::hardware::trigger::LayerEvent {
            layer: 1,
            phase,
            at: chrono::Utc::now(),
        }))
    }
}

#[test]
fn a_trigger_thread_that_panics_fails_the_run_instead_of_ending_the_build() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 3);
    let (options, _) = options_with_log();
    let result = run_daemon_with(&config, options, |machine, _| {
        machine.trigger = Box::new(PanicsAfterLayerOne(vec![Phase::Post, Phase::Pre]));
    });
    // Before, the thread's end read as the trigger's: the run ended as a completed build.
    let Err(AcquisitionError::Trigger(error)) = &result else {
        panic!("{result:?}")
    };
    assert!(
        error
            .to_string()
            .contains("panicked (a trigger that panics)"),
        "{error}"
    );
    assert_eq!(replay(dir.path()).frames.len(), 6, "layer 1 was stored");
    let stop = records(dir.path())
        .into_iter()
        .rev()
        .find_map(|record| match record {
            layerwise::build_dir::journal::Record::Stop { reason, .. } => Some(reason),
            _ => None,
        })
        .expect("the journal says why the run stopped");
    assert!(stop.contains("panicked"), "{stop}");
    assert_eq!(
        read_json(&dir.path().join("status.json"))["state"],
        "failed"
    );
}

#[test]
fn status_shows_the_backlog_emptied_while_the_printer_is_idle() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 3);
    let (signals, events) = crossbeam_channel::unbounded();
    let (options, _) = options_with_log();
    let run = std::thread::spawn(move || {
        run_daemon_with(&config, options, |machine, _| {
            machine.trigger = Box::new(layerwise::sim::MockTrigger::from_channel(events));
        })
    });
    for phase in [Phase::Pre, Phase::Post] {
        let at = chrono::Utc::now();
        let event = layerwise::hardware::trigger::LayerEvent {
            layer: 1,
            phase,
            at,
        };
        signals.send(event).unwrap();
    }
    let journal = dir.path().join(layerwise::build_dir::JOURNAL);
    wait_until("layer 1 processed", Duration::from_secs(60), || {
        journal.exists() && replay(dir.path()).processed.len() == 6
    });
    // The printer is idle; within a few of the daemon's once-a-second looks, status.json shows
    // the backlog empty (before, it kept the count written with layer 1's last frame: 1 or more,
    // to the next layer).
    let status = dir.path().join("status.json");
    wait_until(
        "status.json shows no backlog",
        Duration::from_secs(5),
        || read_json(&status)["queue_depth"] == 0,
    );
    assert_eq!(read_json(&status)["state"], "running");
    drop(signals);
    run.join().unwrap().unwrap();
}

/// A camera whose driver code panics on its first capture.
struct PanickingCamera;

impl layerwise::hardware::camera::Camera for PanickingCamera {
    fn capture(
        &mut self,
        _: &Shot,
    ) -> Result<layerwise::hardware::camera::Frame, layerwise::hardware::camera::CameraError> {
        panic!("a driver that panics")
    }
    fn reopen(&mut self) -> Result<(), layerwise::hardware::camera::CameraError> {
        Ok(())
    }
    fn settings(&self) -> std::collections::BTreeMap<String, String> {
        Default::default()
    }
    fn describe(&self) -> String {
        "panicking camera".into()
    }
}

#[test]
fn a_camera_thread_that_panics_stops_the_daemon_as_lost_not_hung() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 3);
    let (options, _) = options_with_log();
    let result = run_daemon_with(&config, options, |machine, _| {
        machine.camera = Box::new(|| Ok(Box::new(PanickingCamera) as Box<_>));
    });
    assert!(
        matches!(result, Err(AcquisitionError::CameraLost(_))),
        "{result:?}"
    );
    // The first frame is missing for the right reason (before: "camera hung: camera call did
    // not return within 60s", when nothing had hung), and nothing was retried.
    let replay = replay(dir.path());
    let reasons: Vec<&String> = replay.missing.values().collect();
    assert_eq!(reasons.len(), 1, "{reasons:?}");
    assert!(
        reasons[0].starts_with("camera lost: ") && reasons[0].contains("a driver that panics"),
        "{reasons:?}"
    );
    assert_eq!(
        read_json(&dir.path().join("status.json"))["state"],
        "failed"
    );
}

#[test]
fn a_start_whose_camera_cannot_be_opened_says_failed_not_the_run_before() {
    let dir = tempfile::tempdir().unwrap();
    let config = demo_config(dir.path(), 1);
    let (options, _) = options_with_log();
    run_daemon_with(&config, options, |_, _| {}).unwrap();
    let status = dir.path().join("status.json");
    assert_ne!(read_json(&status)["state"], "failed");
    // The restart cannot open the camera.
    let (options, _) = options_with_log();
    let result = run_daemon_with(&config, options, |machine, _| {
        machine.camera = Box::new(|| {
            Err(layerwise::hardware::camera::CameraError::Disconnected(
                layerwise::hardware::camera::DriverError::said("no camera on usb:"),
            ))
        });
    });
    assert!(
        matches!(result, Err(AcquisitionError::CameraOpen(_))),
        "{result:?}"
    );
    // status.json and the journal say so (before: the run before's state, and no stop).
    assert_eq!(read_json(&status)["state"], "failed");
    let last = records(dir.path()).pop().unwrap();
    let layerwise::build_dir::journal::Record::Stop { reason, .. } = last else {
        panic!("{last:?}")
    };
    assert!(reason.contains("no camera on usb:"), "{reason}");
}

#[test]
fn a_restart_resumes_without_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    let first = demo_config(dir.path(), 2);
    run_daemon(&first, RunOptions::new()).unwrap();
    // The same build, restarted: the trigger replays layers 1-2 (already stored) then goes on.
    let second = demo_config(dir.path(), 4);
    let summary = run_daemon(&second, RunOptions::new()).unwrap();
    assert_eq!((summary.stored, summary.skipped), (12, 12));
    assert_eq!(originals(dir.path()), expected_originals(4));
    assert!(frame_records(dir.path()).values().all(|&n| n == 1));
}

/// Blocks every frame until released: stands in for rectification that cannot keep up.
struct GatedProcessor {
    open: Arc<(Mutex<bool>, std::sync::Condvar)>,
    processed: AtomicUsize,
}

impl FrameProcessor for GatedProcessor {
    fn process(&self, _dir: &Path, _shot: Shot, original: &Path) -> Result<(), ProcessError> {
        let (lock, cvar) = &*self.open;
        let mut open = lock.lock().map_err(|e| e.to_string())?;
        while !*open {
            open = cvar.wait(open).map_err(|e| e.to_string())?;
        }
        std::fs::metadata(original)?;
        self.processed.fetch_add(1, Ordering::SeqCst);
        Ok(())
    }
}

#[test]
fn capture_never_waits_for_processing() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 4);
    config.storage.queue_capacity = 2;
    let gate = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
    let processor = Arc::new(GatedProcessor {
        open: gate.clone(),
        processed: AtomicUsize::new(0),
    });
    let mut options = RunOptions::new();
    options.processor = Some(processor.clone());
    options.drain_at_end = true;
    let build = dir.path().to_path_buf();
    let daemon = std::thread::spawn(move || run_daemon(&config, options));
    // All 24 frames reach the disk while processing is stuck on the first one (a timeout here:
    // capture was blocked by processing).
    wait_for_originals(&build, 24, Duration::from_secs(60));
    assert_eq!(processor.processed.load(Ordering::SeqCst), 0);
    {
        let (lock, cvar) = &*gate;
        *lock.lock().unwrap() = true;
        cvar.notify_all();
    }
    let summary = daemon.join().unwrap().unwrap();
    assert_eq!(summary.stored, 24);
    assert_eq!(
        processor.processed.load(Ordering::SeqCst),
        24,
        "every frame processed exactly once"
    );
    let processed_records = records(&build)
        .into_iter()
        .filter(|r| matches!(r, layerwise::build_dir::journal::Record::Processed { .. }))
        .count();
    assert_eq!(processed_records, 24);
}

#[test]
fn bad_trigger_script_fails_with_its_line() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 1);
    mock_printer(&mut config, dir.path(), "LAYER 1 PRE\nLAYER one POST\n");
    let (options, slot) = options_with_log();
    let err = run_logged(&config, options, &slot).unwrap_err().to_string();
    assert!(
        err.contains("printer.txt") && err.contains("line 2"),
        "{err}"
    );
    // Nothing was left lit by the failed start.
    let log = slot.lock().unwrap().clone();
    if let Some(log) = log {
        assert!(log.lit().is_empty());
    }
}

#[test]
fn irregular_signals_are_journaled_and_no_original_is_overwritten() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = demo_config(dir.path(), 1);
    // A repeated signal, a skipped layer, one going backwards and one no printer sends.
    mock_printer(
        &mut config,
        dir.path(),
        "LAYER 1 PRE\nLAYER 1 POST\nLAYER 1 POST\nLAYER 3 PRE\nLAYER 2 PRE\nLAYER 0 POST\n",
    );
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    let summary = run_daemon(&config, options).unwrap();
    assert_eq!((summary.stored, summary.retakes), (12, 3));
    let raw = dir.path().join("raw");
    let first: std::collections::BTreeMap<String, String> = records(dir.path())
        .into_iter()
        .filter_map(|r| match r {
            layerwise::build_dir::Record::Frame { file, sha256, .. } => Some((file, sha256)),
            _ => None,
        })
        .collect();
    assert_eq!(first.len(), 12);
    // The first takes are still the files the journal recorded: nothing was overwritten.
    for (file, sha) in &first {
        let bytes = std::fs::read(dir.path().join(file)).unwrap();
        assert_eq!(&layerwise::fsutil::sha256_hex(&bytes), sha, "{file}");
    }
    for light in ["front", "side", "top"] {
        assert!(raw.join(format!("L00001_post_{light}.r2.jpg")).exists());
        assert!(raw.join(format!("L00001_post_{light}.r2.json")).exists());
    }
    assert!(
        !raw.join("L00000_post_top.jpg").exists(),
        "layer 0 is not captured"
    );
    let status = |dir: &Path| {
        let out = layerwise()
            .args(["status", "--json", "--build"])
            .arg(dir)
            .json_ok();
        (
            out["retakes"].clone(),
            out["irregular"].clone(),
            out["frames"].clone(),
        )
    };
    let (retakes, irregular, frames) = status(dir.path());
    assert_eq!(
        (retakes, frames),
        (serde_json::json!(3), serde_json::json!(12))
    );
    let lines: Vec<String> = irregular
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    assert_eq!(lines.len(), 4, "{lines:?}");
    for (line, expected) in lines.iter().zip([
        "L00001 post: repeated signal",
        "L00003 pre: skipped layers: layers 2 to 2",
        "L00002 pre: signal going backwards: after layer 3 pre",
        "L00000 post: layer out of range",
    ]) {
        assert!(line.starts_with(expected), "{line} vs {expected}");
    }
    // A restart that replays the same signals changes nothing: no new take, no new flag.
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    let again = run_daemon(&config, options).unwrap();
    assert_eq!((again.stored, again.retakes), (0, 0));
    assert_eq!(
        status(dir.path()),
        (serde_json::json!(3), irregular, serde_json::json!(12))
    );
}

/// The header fields of a series slice that say which original it shows.
struct SliceOrigin {
    sop_instance_uid: String,
    series_instance_uid: String,
    comments: String,
    acquisition_time: String,
    pixels: Vec<u16>,
}

fn slice_origin(path: &Path) -> SliceOrigin {
    use dicom_dictionary_std::tags;
    let obj = dicom_object::open_file(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let text = |tag| {
        obj.element(tag)
            .map(|e| {
                e.to_str()
                    .unwrap()
                    .trim_end_matches('\0')
                    .trim()
                    .to_string()
            })
            .unwrap_or_default()
    };
    let pixels = obj
        .element(tags::PIXEL_DATA)
        .unwrap()
        .to_bytes()
        .unwrap()
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    SliceOrigin {
        sop_instance_uid: text(tags::SOP_INSTANCE_UID),
        series_instance_uid: text(tags::SERIES_INSTANCE_UID),
        comments: text(tags::IMAGE_COMMENTS),
        acquisition_time: text(tags::ACQUISITION_TIME),
        pixels,
    }
}

/// The AcquisitionTime a slice made from `original` carries: its sidecar's capture time.
fn captured_time(original: &Path) -> String {
    let sidecar: serde_json::Value = read_json(&original.with_extension("json"));
    let at: chrono::DateTime<chrono::Utc> =
        sidecar["captured_at"].as_str().unwrap().parse().unwrap();
    at.format("%H%M%S%.6f").to_string()
}

/// `layerwise status --json`'s count of frames waiting for processing.
fn waiting_for_processing(build: &Path) -> u64 {
    let status = layerwise()
        .args(["status", "--json", "--build"])
        .arg(build)
        .json_ok();
    status["waiting_for_processing"].as_u64().unwrap()
}

/// A build through the binary whose layer-1 post signal comes twice, with `[series] take`.
fn retaken_build(dir: &Path, take: &str) -> std::path::PathBuf {
    let build = dir.join("build");
    let mut config = calibrated_config(&build, 1, layerwise::dicom::Compression::Deflate);
    config.rectify.pixel_mm = 2.0;
    config.series.take = serde_json::from_value(serde_json::json!(take)).unwrap();
    mock_printer(
        &mut config,
        dir,
        "LAYER 1 PRE\nLAYER 1 POST\nLAYER 1 POST\n",
    );
    let config_path = dir.join("layerwise.toml");
    write_config(&config, &config_path);
    let text = std::fs::read_to_string(&config_path).unwrap();
    assert!(
        text.contains(&format!("take = \"{take}\"")),
        "the key as an operator writes it:\n{text}"
    );
    run_build(&config_path);
    build
}

#[test]
fn series_take_last_shows_the_retake_with_its_own_uid_and_first_keeps_the_old_uid() {
    let post_front = Shot {
        layer: 1,
        phase: Phase::Post,
        light: Light::Front,
    };
    // take = "last": the slice of layer 1 post/front is the retake's.
    let last = tempfile::tempdir().unwrap();
    let build = retaken_build(last.path(), "last");
    let raw = build.join("raw");
    let (first_take, retake) = (
        raw.join("L00001_post_front.jpg"),
        raw.join("L00001_post_front.r2.jpg"),
    );
    assert!(first_take.is_file() && retake.is_file());
    let slice_path = layerwise::series::series_dir(&build, post_front.view()).join("L00001.dcm");
    let slice = slice_origin(&slice_path);
    assert_eq!(
        slice.comments,
        "take 2 of the layer's frame: raw/L00001_post_front.r2.jpg"
    );
    assert_eq!(slice.acquisition_time, captured_time(&retake));
    assert_ne!(captured_time(&retake), captured_time(&first_take));
    let series = layerwise::dicom::Series {
        series_instance_uid: slice.series_instance_uid.clone(),
        number: 0,
        description: String::new(),
    };
    let take1_uid = layerwise::dicom::instance_uid(&series, 1);
    assert_ne!(slice.sop_instance_uid, take1_uid);
    assert_eq!(
        slice.sop_instance_uid,
        layerwise::dicom::instance_uid_of_take(&series, 1, 2)
    );
    // A view that was not retaken (pre) keeps its take-1 slice and UID.
    let pre = slice_origin(
        &layerwise::series::series_dir(
            &build,
            Shot {
                phase: Phase::Pre,
                ..post_front
            }
            .view(),
        )
        .join("L00001.dcm"),
    );
    assert!(pre
        .comments
        .starts_with("take 1 of the layer's frame: raw/L00001_pre_front.jpg"));
    // Journaled: the restart that replays the same signals shows the same take.
    let journal = records(&build);
    assert_eq!(
        journal
            .iter()
            .filter(|r| matches!(r, layerwise::build_dir::Record::SliceTake { take: 2, .. }))
            .count(),
        3
    );
    // As after a kill -9 between storing the retakes and writing their slices: the slices and
    // their records are gone; the restart writes them from the retakes again.
    let journal_path = build.join(layerwise::build_dir::JOURNAL);
    let kept: String = std::fs::read_to_string(&journal_path)
        .unwrap()
        .lines()
        .filter(|l| !l.contains("\"slice_take\""))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(&journal_path, kept).unwrap();
    std::fs::write(&slice_path, b"").unwrap();
    // `status` counts the three retakes whose slices are not written as waiting for processing
    // (under take = "last" only: under "first" their slices show what they should).
    assert_eq!(waiting_for_processing(&build), 3);
    let snapshot = build.join(layerwise::build_dir::CONFIG_SNAPSHOT);
    let last_text = std::fs::read_to_string(&snapshot).unwrap();
    let first_text = last_text.replace("take = \"last\"", "take = \"first\"");
    assert_ne!(first_text, last_text, "the snapshot names the take");
    std::fs::write(&snapshot, first_text).unwrap();
    assert_eq!(waiting_for_processing(&build), 0);
    std::fs::write(&snapshot, last_text).unwrap();
    run_build(&last.path().join("layerwise.toml"));
    assert_eq!(waiting_for_processing(&build), 0);
    let again = slice_origin(&slice_path);
    assert_eq!(again.sop_instance_uid, slice.sop_instance_uid);
    assert_eq!(again.comments, slice.comments);
    assert_eq!(again.pixels, slice.pixels);
    // The export follows the key too; a later take on disk (here made dark) replaces the slice.
    // Its sidecar describes it (name, size, SHA-256) as the daemon's would: an original is only
    // used with a sidecar it matches.
    let dark = image::RgbImage::new(320, 214);
    let r3 = raw.join("L00001_post_front.r3.jpg");
    dark.save(&r3).unwrap();
    let bytes = std::fs::read(&r3).unwrap();
    let mut sidecar = crate::common::read_json(&raw.join("L00001_post_front.r2.json"));
    sidecar["file"] = "raw/L00001_post_front.r3.jpg".into();
    sidecar["bytes"] = bytes.len().into();
    sidecar["sha256"] = layerwise::fsutil::sha256_hex(&bytes).into();
    std::fs::write(raw.join("L00001_post_front.r3.json"), sidecar.to_string()).unwrap();
    let out = last.path().join("export");
    layerwise()
        .args(["export", "--build"])
        .arg(&build)
        .arg("--out")
        .arg(&out)
        .succeeds();
    let exported = slice_origin(&out.join("post_front_export/L00001.dcm"));
    assert_eq!(
        exported.comments,
        "take 3 of the layer's frame: raw/L00001_post_front.r3.jpg"
    );
    assert!(
        exported.pixels.iter().all(|&p| p < 8),
        "the dark take's pixels"
    );
    assert!(
        slice.pixels.iter().any(|&p| p > 50),
        "the lit take's pixels"
    );

    // take = "first" (the default): the first take, with the UID builds always had.
    let first = tempfile::tempdir().unwrap();
    let build = retaken_build(first.path(), "first");
    assert!(build.join("raw/L00001_post_front.r2.jpg").is_file());
    let slice =
        slice_origin(&layerwise::series::series_dir(&build, post_front.view()).join("L00001.dcm"));
    let series = layerwise::dicom::Series {
        series_instance_uid: slice.series_instance_uid.clone(),
        number: 0,
        description: String::new(),
    };
    assert_eq!(
        slice.sop_instance_uid,
        layerwise::dicom::instance_uid(&series, 1)
    );
    assert_eq!(
        slice.comments,
        "take 1 of the layer's frame: raw/L00001_post_front.jpg"
    );
    assert_eq!(
        slice.acquisition_time,
        captured_time(&build.join("raw/L00001_post_front.jpg"))
    );
}
