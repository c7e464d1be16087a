//! The acquisition daemon: for every layer signal, for each light in turn: light on, settle,
//! capture and download, light off, store the original, hand it to processing. Resumes from the
//! journal after any stop; never waits for processing.

pub mod check;
pub mod disk;
mod health;
pub mod inspection;
pub mod lifecycle;
pub mod processing;
mod sequencer;
pub mod storage;

use crate::build_dir::status::LiveStatus;
use crate::build_dir::{self, BuildManifest, Journal, JournalError, Progress, Record};
use crate::clock::{SharedClock, SystemClock};
use crate::config::Config;
use crate::fsutil::WriteError;
use crate::hardware::camera::{CameraActor, CameraError, RetryPolicy};
use crate::hardware::lights::{LightsError, LightsGuard};
use crate::hardware::trigger::{LayerEvent, TriggerError};
use crate::hardware::Machine;
use crate::series::{FrameProcessor, KeepOriginals};
use crate::shot::{Light, Phase, Shot};
use processing::ProcessingQueue;
use sequencer::{OpenEvent, Sequencer};
use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use storage::Storage;
use tracing::{error, info, warn};

#[derive(Debug, thiserror::Error)]
pub enum AcquisitionError {
    #[error(transparent)]
    Storage(#[from] WriteError),
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error(transparent)]
    CameraOpen(CameraError),
    #[error("camera hung ({0}); exiting so that systemd restarts the service")]
    CameraHung(CameraError),
    #[error(transparent)]
    Trigger(#[from] TriggerError),
    #[error(transparent)]
    Lights(#[from] LightsError),
    #[error(transparent)]
    Hardware(#[from] crate::hardware::HardwareError),
    #[error(transparent)]
    Calibration(#[from] crate::rectify::CalibrationError),
    #[error(transparent)]
    Series(#[from] crate::series::SeriesError),
    #[error("cannot record the configuration: {0}")]
    Snapshot(#[from] toml::ser::Error),
    #[error("{0}")]
    Runtime(String),
}

/// What a run did.
#[derive(Clone, Debug, Default)]
pub struct RunSummary {
    pub build_dir: PathBuf,
    /// Frames stored (first takes).
    pub stored: u64,
    /// Frames taken again for repeated signals, kept beside the first takes.
    pub retakes: u64,
    pub missing: u64,
    pub skipped: u64,
    pub stop_reason: String,
    /// Stopped by `RunOptions::stop_when` (e.g. the operator ended the build), not by the
    /// trigger or a signal.
    pub stopped_on_request: bool,
}

/// How to run: what to do with frames, and the clock.
pub struct RunOptions {
    /// What to do with stored frames; by default the live DICOM series when a calibration is
    /// configured, else keep the originals only.
    pub processor: Option<Arc<dyn FrameProcessor>>,
    /// Send READY and WATCHDOG to systemd.
    pub notify_systemd: bool,
    /// When the trigger ends (a simulated build), process every frame before returning.
    pub drain_at_end: bool,
    /// Where time comes from.
    pub clock: SharedClock,
    /// Ends the run when it completes, with its reason (e.g. the operator ended the build,
    /// `acquisition::lifecycle`); the frames taken are processed before the run returns.
    pub stop_when: Option<StopWhen>,
    /// Where free space on the build disk is measured (`statvfs`; tests simulate it).
    pub free_space: Arc<dyn crate::fsutil::FreeSpace>,
    /// Called, without blocking, each time a series instance is written (the daemon wakes its
    /// PACS push with it, `pacs::live::PushWaker`).
    pub on_instance: Option<processing::OnWritten>,
}

/// A future that ends a run with its reason.
pub type StopWhen = std::pin::Pin<Box<dyn std::future::Future<Output = String> + Send>>;

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions::new()
    }
}

impl RunOptions {
    pub fn new() -> RunOptions {
        RunOptions {
            processor: None,
            notify_systemd: false,
            drain_at_end: false,
            clock: SystemClock::shared(),
            stop_when: None,
            free_space: Arc::new(crate::fsutil::Statvfs),
            on_instance: None,
        }
    }
}

/// The build directory opened for a run: originals, manifest, journal and what it replayed.
struct OpenedBuild {
    storage: Storage,
    manifest: BuildManifest,
    journal: Journal,
    progress: Progress,
}

/// Opens (or starts) the build directory, adopts originals a crash left unjournaled, and
/// journals the start.
fn open_build(config: &Config, clock: &SharedClock) -> Result<OpenedBuild, AcquisitionError> {
    let dir = config.build.output_dir.clone();
    let storage = Storage::open(&dir, config.storage.fsync)?;
    let views: Vec<String> = config.views.all().iter().map(|v| v.to_string()).collect();
    let manifest = BuildManifest::load_or_create(&dir, || BuildManifest {
        name: config.build.name.clone(),
        id: config.build_id().to_string(),
        created_at: clock.now(),
        layers_expected: config.build.layers,
        views,
        study_instance_uid: crate::dicom::new_uid(),
        frame_of_reference_uid: crate::dicom::new_uid(),
        software_version: env!("CARGO_PKG_VERSION").to_string(),
    })?;
    match snapshot_configuration(config, &storage) {
        // A restart on a full disk still captures when space returns: the snapshot of the last
        // start stays.
        Err(AcquisitionError::Storage(e)) if crate::fsutil::is_disk_full(&e.source) => {
            warn!(error = %e, "disk full: the configuration snapshot is not updated")
        }
        result => result?,
    }
    // The journal folded into compact per-shot flags as it is read: the daemon's memory does not
    // grow with the records of a long build.
    let mut progress = Progress::default();
    let mut journal =
        Journal::open_with(&dir.join(build_dir::JOURNAL), config.storage.fsync, |r| {
            progress.apply(&r)
        })?;
    // Originals that reached the disk but not the journal (a crash in between) are adopted.
    for adopted in storage.recover(|shot| progress.is_stored(shot))? {
        warn!(file = %adopted.file, "recovered a frame stored just before a crash");
        let record = Record::Frame {
            layer: adopted.layer,
            phase: adopted.phase,
            light: adopted.light,
            file: adopted.file.clone(),
            bytes: adopted.bytes,
            sha256: adopted.sha256.clone(),
            at: adopted.captured_at,
        };
        journal.append(&record)?;
        progress.apply(&record);
    }
    journal.append(&Record::Start {
        at: clock.now(),
        pid: std::process::id(),
        version: env!("CARGO_PKG_VERSION").into(),
    })?;
    let last_event = progress
        .last_event
        .map(|(layer, phase)| format!("layer {layer} {phase}"))
        .unwrap_or_else(|| "none".into());
    info!(
        build = %manifest.name,
        dir = %dir.display(),
        frames = progress.frames(),
        missing = progress.missing(),
        restarts = progress.starts,
        last_event = %last_event,
        "build opened"
    );
    Ok(OpenedBuild {
        storage,
        manifest,
        journal,
        progress,
    })
}

/// The event a restart interrupted, with the lights it had already done.
fn interrupted_event(
    config: &Config,
    progress: &Progress,
    clock: &SharedClock,
) -> Option<OpenEvent> {
    let (layer, phase) = progress.last_event?;
    let lights = &config.views.lights;
    let done: BTreeSet<Light> = lights
        .iter()
        .copied()
        .filter(|&light| {
            progress.is_done(&Shot {
                layer,
                phase,
                light,
            })
        })
        .collect();
    (done.len() < lights.len()).then(|| OpenEvent {
        layer,
        phase,
        at: clock.now(),
        done,
    })
}

/// Runs the daemon on `machine` until the trigger ends or SIGTERM/SIGINT arrives.
pub async fn run(
    config: &Config,
    machine: Machine,
    mut options: RunOptions,
) -> Result<RunSummary, AcquisitionError> {
    let clock = options.clock.clone();
    let dir = config.build.output_dir.clone();
    let OpenedBuild {
        storage,
        manifest,
        journal,
        mut progress,
    } = open_build(config, &clock)?;

    let Machine {
        mut trigger,
        lights,
        camera,
        alarm,
        alarm_message,
    } = machine;
    let mut lights = LightsGuard::new(lights);
    lights.all_off_logged();
    let timeout = Duration::from_secs(config.capture.call_timeout_s);
    let camera =
        CameraActor::spawn(camera, timeout, clock.clone()).map_err(AcquisitionError::CameraOpen)?;
    info!(camera = camera.describe(), "camera open");
    trigger.resume_after(progress.last_event);
    let trigger_health = trigger.health();

    let journal = Arc::new(Mutex::new(journal));
    let backlog: Vec<(Shot, u32, PathBuf)> = progress
        .take_backlog(config.series.take)
        .into_iter()
        .map(|(shot, take, file)| (shot, take, dir.join(file)))
        .collect();
    let processor = match options.processor.take() {
        Some(p) => p,
        None => default_processor(config, &manifest, (alarm, alarm_message), &clock)?,
    };
    let queue = ProcessingQueue::start(
        processor,
        config.storage.queue_capacity,
        dir.clone(),
        journal.clone(),
        processing::WorkerPlan {
            backlog,
            take: config.series.take,
            frames_per_signal: config.views.lights.len(),
        },
        clock.clone(),
        options.on_instance.clone(),
    );
    let heartbeat = Arc::new(AtomicU64::new(0));
    let mut sequencer = Sequencer {
        lights_order: config.views.lights.clone(),
        settle: Duration::from_millis(config.capture.settle_ms),
        storage,
        journal,
        lights,
        camera,
        policy: RetryPolicy::from_config(&config.capture),
        open: interrupted_event(config, &progress, &clock),
        queue: Some(queue),
        live: LiveStatus {
            pid: std::process::id(),
            last_frames: BTreeMap::new(),
            ..LiveStatus::default()
        },
        summary: RunSummary {
            build_dir: dir.clone(),
            ..RunSummary::default()
        },
        heartbeat: heartbeat.clone(),
        clock: clock.clone(),
        notify: options.notify_systemd,
        trigger_health: trigger_health.clone(),
        prev_signal: progress.last_event,
        catching_up: progress.last_event.is_some(),
        state: progress,
        disk: disk::DiskGuard::open(
            dir.clone(),
            options.free_space.clone(),
            (config.storage.min_free_gb * 1e9) as u64,
            clock.clone(),
        ),
        parts: Default::default(),
    };
    sequencer.apply_disk();
    sequencer.write_live("running");

    let only_phases: BTreeSet<Phase> = config.views.phases.iter().copied().collect();
    let events = crate::hardware::trigger::spawn(trigger, trigger_health);
    let (sequencer, reason, asked) =
        event_loop(sequencer, events, only_phases, heartbeat, &mut options).await?;
    if options.notify_systemd {
        let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Stopping]);
    }
    let drain = options.drain_at_end && (reason == "the trigger ended" || asked);
    let mut summary =
        tokio::task::spawn_blocking(move || sequencer.finish(&reason, "stopped", drain))
            .await
            .map_err(|e| AcquisitionError::Runtime(format!("shutdown failed: {e}")))?;
    summary.stopped_on_request = asked;
    info!(stored = summary.stored, missing = summary.missing, skipped = summary.skipped, reason = %summary.stop_reason, "acquisition stopped");
    Ok(summary)
}

/// Feeds layer signals to the sequencer (one event at a time, on a blocking thread) until the
/// trigger ends or a signal stops the daemon; pings the systemd watchdog while capture lives.
/// Returns the idle sequencer, why the loop stopped and whether `options.stop_when` stopped it.
async fn event_loop(
    sequencer: Sequencer,
    mut events: tokio::sync::mpsc::Receiver<Result<LayerEvent, TriggerError>>,
    only_phases: BTreeSet<Phase>,
    heartbeat: Arc<AtomicU64>,
    options: &mut RunOptions,
) -> Result<(Sequencer, String, bool), AcquisitionError> {
    let clock = options.clock.clone();
    let watchdog = watchdog_period(options.notify_systemd);
    if options.notify_systemd {
        let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Ready]);
    }
    let mut tick = tokio::time::interval(
        Duration::from_secs(1).min(watchdog.unwrap_or(Duration::from_secs(1))),
    );
    let signal = |kind| {
        tokio::signal::unix::signal(kind)
            .map_err(|e| AcquisitionError::Runtime(format!("cannot watch signal {kind:?}: {e}")))
    };
    let mut sigterm = signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut sigint = signal(tokio::signal::unix::SignalKind::interrupt())?;

    let mut idle = Some(sequencer);
    let mut running: Option<tokio::task::JoinHandle<(Sequencer, Result<(), AcquisitionError>)>> =
        None;
    let mut stop: Option<String> = None;
    let mut stop_when = options.stop_when.take();
    let mut asked = false;
    loop {
        if stop.is_some() && running.is_none() {
            break;
        }
        tokio::select! {
            joined = async { running.as_mut().expect("guarded by the select condition").await }, if running.is_some() => {
                running = None;
                let (sequencer, result) = joined.map_err(|e| AcquisitionError::Runtime(format!("capture task failed: {e}")))?;
                if let Err(e) = result {
                    error!(error = %e, "acquisition stopped by an error");
                    let reason = e.to_string();
                    sequencer.finish(&reason, "failed", false);
                    return Err(e);
                }
                idle = Some(sequencer);
            }
            event = events.recv(), if running.is_none() && stop.is_none() => match event {
                None => stop = Some("the trigger ended".to_string()),
                Some(Err(e)) => {
                    error!(error = %e, "trigger failed");
                    if let Some(sequencer) = idle.take() {
                        sequencer.finish(&e.to_string(), "failed", false);
                    }
                    return Err(e.into());
                }
                Some(Ok(event)) if !only_phases.contains(&event.phase) => {
                    info!(layer = event.layer, phase = %event.phase, "signal for a phase not in views.phases; ignored");
                }
                Some(Ok(event)) => {
                    if let Some(mut sequencer) = idle.take() {
                        running = Some(tokio::task::spawn_blocking(move || {
                            let result = sequencer.on_event(event);
                            (sequencer, result)
                        }));
                    }
                }
            },
            _ = sigterm.recv() => { info!("SIGTERM: finishing the frame in hand, then stopping"); stop = Some("SIGTERM".into()); }
            _ = sigint.recv() => { info!("SIGINT: finishing the frame in hand, then stopping"); stop = Some("SIGINT".into()); }
            reason = async { stop_when.as_mut().expect("guarded by the select condition").await }, if stop_when.is_some() && stop.is_none() => {
                info!(reason = %reason, "finishing the frame in hand, then stopping");
                stop_when = None;
                asked = true;
                stop = Some(reason);
            }
            _ = tick.tick() => {
                if let Some(sequencer) = idle.as_mut() {
                    sequencer.refresh_health();
                }
                if let Some(period) = watchdog {
                    // Ping only while the capture path shows signs of life.
                    let last = Duration::from_millis(heartbeat.load(Ordering::SeqCst));
                    if running.is_none() || clock.elapsed().saturating_sub(last) < period * 2 {
                        let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Watchdog]);
                    }
                }
            }
        }
    }
    let sequencer = idle.ok_or_else(|| AcquisitionError::Runtime("capture task lost".into()))?;
    Ok((sequencer, stop.unwrap_or_default(), asked))
}

/// Leaves the configuration in force (`config.toml`) and a copy of the calibration
/// (`calibration.toml`) in the build directory, so export and locate know how the build was made.
fn snapshot_configuration(config: &Config, storage: &Storage) -> Result<(), AcquisitionError> {
    let dir = storage.root();
    let text = toml::to_string(config)?;
    storage.write_atomic(&dir.join(build_dir::CONFIG_SNAPSHOT), text.as_bytes())?;
    if let Some(calibration) = &config.calibration.file {
        let target = dir.join(build_dir::CALIBRATION_COPY);
        let same = std::fs::canonicalize(calibration).ok() == std::fs::canonicalize(&target).ok();
        if !same {
            let bytes = std::fs::read(calibration).map_err(|source| WriteError {
                path: calibration.clone(),
                source,
            })?;
            storage.write_atomic(&target, &bytes)?;
        }
    }
    Ok(())
}

/// The live DICOM series when a calibration is configured; else the originals are only kept.
fn default_processor(
    config: &Config,
    manifest: &BuildManifest,
    (alarm, message): (
        Box<dyn crate::hardware::lights::Lights>,
        Option<Box<dyn crate::hardware::message::MessageLink>>,
    ),
    clock: &SharedClock,
) -> Result<Arc<dyn FrameProcessor>, AcquisitionError> {
    let Some(path) = &config.calibration.file else {
        warn!("no calibration.file: frames are kept but not rectified; run `layerwise register images` and set it");
        return Ok(Arc::new(KeepOriginals));
    };
    let calibration = crate::rectify::Calibration::load(path)?;
    if let Some(note) = calibration.grid_note(&config.rectify) {
        info!("{}: {note}", path.display());
    }
    let settings = crate::series::SeriesSettings::from_config(config)?;
    let live =
        crate::series::LiveSeries::new(manifest, &config.views.all(), &calibration, settings)?;
    if !config.inspection.enabled {
        return Ok(Arc::new(live));
    }
    let alarm = inspection::Alarm::new(alarm, &config.inspection.alarm)
        .with_message(message, &config.inspection.alarm);
    let dir = &config.build.output_dir;
    Ok(Arc::new(inspection::InspectingSeries::open(
        config,
        dir,
        live,
        alarm,
        clock.clone(),
    )?))
}

fn watchdog_period(enabled: bool) -> Option<Duration> {
    if !enabled {
        return None;
    }
    let mut usec = 0u64;
    sd_notify::watchdog_enabled(false, &mut usec).then(|| Duration::from_micros(usec / 2))
}
