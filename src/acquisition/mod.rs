//! The acquisition daemon: for every layer signal, for each light in turn: light on, settle,
//! capture and download, light off, store the original, hand it to processing. Resumes from the
//! journal after any stop; never waits for processing.
//!
//! [`run`] is the capture loop on the calling thread: layer signals from the trigger's thread,
//! the health tick on the clock, and the run's [`Shutdown`] in one `select!`. The threads it
//! starts (trigger, camera, processing, alarm, watchdog) each stop on that one request, in order:
//! docs/architecture.md has the table.

pub mod alarm;
pub mod check;
mod commit;
pub mod disk;
mod error;
mod exposure;
mod health;
pub mod inspection;
mod layer_tally;
pub mod lifecycle;
pub mod model;
mod open;
mod preflight;
pub mod processing;
mod recorder;
mod sequencer;
pub mod storage;
mod summary;

use crate::build_dir::BuildManifest;
use crate::clock::{SharedClock, SystemClock};
use crate::config::Config;
use crate::hardware::camera::{CameraActor, RetryPolicy};
use crate::hardware::lights::LightsGuard;
use crate::hardware::Machine;
use crate::logging::Chain;
use crate::series::{FrameProcessor, KeepOriginals};
use crate::shot::Phase;
use crate::shutdown::{Shutdown, StopReason};
pub use error::AcquisitionError;
use exposure::Exposure;
pub use preflight::{preflight, PreflightError};
use processing::ProcessingQueue;
use recorder::{Recorder, StatusSink};
use sequencer::{Heartbeat, Sequencer};
use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;
pub use summary::RunSummary;
use tracing::{error, info, warn};

/// How to run: what to do with frames, the clock, and what stops the run.
pub struct RunOptions {
    /// What to do with stored frames; by default the live DICOM series when a calibration is
    /// configured, else keep the originals only.
    pub processor: Option<Arc<dyn FrameProcessor>>,
    /// Send READY, WATCHDOG, STATUS= and STOPPING to systemd.
    pub notify_systemd: bool,
    /// When the build ends (its trigger ended, or the operator ended it), process every frame
    /// before returning.
    pub drain_at_end: bool,
    /// Where time comes from.
    pub clock: SharedClock,
    /// Ends the run when requested, with its reason (SIGTERM through the process's shutdown, the
    /// operator ending the build through `acquisition::lifecycle::watch_order`); the run also
    /// requests it itself when its trigger ends or it fails, so everything holding it stops.
    pub shutdown: Shutdown,
    /// Where free space on the build disk is measured (`statvfs`; tests simulate it).
    pub free_space: Arc<dyn crate::fsutil::FreeSpace>,
    /// Called, without blocking, each time a series instance is written (the daemon wakes its
    /// PACS push with it, `pacs::live::PushWaker`).
    pub on_instance: Option<processing::OnWritten>,
    /// Where the plant interfaces (metrics, MQTT) are told what happens, without
    /// waiting; off by default.
    pub plant: crate::plant::PlantSink,
}

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
            shutdown: Shutdown::new(),
            free_space: Arc::new(crate::fsutil::Statvfs),
            on_instance: None,
            plant: crate::plant::PlantSink::off(),
        }
    }
}

/// How often status.json follows the parts' health while no signal comes.
const HEALTH_PERIOD: Duration = Duration::from_secs(1);

/// Runs the daemon on `machine` until its trigger ends, `options.shutdown` is requested, or it
/// fails; on the calling thread.
pub fn run(
    config: &Config,
    machine: Machine,
    mut options: RunOptions,
) -> Result<RunSummary, AcquisitionError> {
    let clock = options.clock.clone();
    let shutdown = options.shutdown.clone();
    let dir = config.build.output_dir.clone();
    let open::OpenedBuild {
        storage,
        manifest,
        mut journal,
        mut progress,
    } = open::open_build(config, &clock)?;

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
    let camera = CameraActor::spawn(camera, timeout, clock.clone())
        .map_err(AcquisitionError::CameraOpen)
        .map_err(|e| open::failed_start(&dir, &mut journal, &clock, e))?;
    info!(camera = camera.describe(), "camera open");
    trigger.resume_after(progress.last_event);
    let trigger_health = trigger.health();

    let mut backlog = progress.take_backlog(config.series.take);
    let plant = options.plant.clone();
    plant.emit(|| build_started(config, &clock));
    let processor = match options.processor.take() {
        Some(p) => p,
        None => default_processor(config, &manifest, (alarm, alarm_message), &clock, &plant)
            .map_err(|e| open::failed_start(&dir, &mut journal, &clock, e))?,
    };
    // What the processor wants again (layers a stop left uninspected) goes first, in build
    // order with the backlog, so that layers complete in order.
    // One take per shot: the backlog's, a later take than the slice shows, where both name it.
    backlog.extend(processor.catch_up());
    backlog.sort_by_key(|a| (a.0, std::cmp::Reverse(a.1)));
    backlog.dedup_by(|a, b| a.0 == b.0);
    let journal = Arc::new(Mutex::new(journal));
    let queue = ProcessingQueue::start(
        processor,
        config.storage.queue_capacity,
        dir.clone(),
        journal.clone(),
        processing::WorkerPlan {
            backlog,
            take: config.series.take,
            frames_per_signal: config.views.lights.len(),
            plant: plant.clone(),
        },
        clock.clone(),
        options.on_instance.clone(),
    );
    let open = open::interrupted_event(config, &progress, &clock);
    let disk = disk::DiskGuard::open(
        dir.clone(),
        options.free_space.clone(),
        (config.storage.min_free_gb * 1e9) as u64,
        clock.clone(),
    );
    let sink = StatusSink {
        clock: clock.clone(),
        notify: options.notify_systemd,
        trigger: trigger_health.clone(),
        plant: plant.clone(),
    };
    let recorder = Recorder::new(storage, progress, journal, disk, queue, sink);
    let exposure = Exposure::new(
        lights,
        camera,
        RetryPolicy::from_config(&config.capture),
        Duration::from_millis(config.capture.settle_ms),
        clock.clone(),
    );
    let heartbeat = Heartbeat::default();
    let mut sequencer = Sequencer::new(
        config.views.lights.clone(),
        exposure,
        recorder,
        open,
        heartbeat.clone(),
        clock.clone(),
    );
    sequencer.write_live("running");

    let only_phases: BTreeSet<Phase> = config.views.phases.iter().copied().collect();
    let events = crate::hardware::trigger::spawn(trigger, trigger_health, shutdown.clone());
    let watchdog = options
        .notify_systemd
        .then(|| watchdog(heartbeat, clock.clone(), shutdown.clone()))
        .flatten();
    if options.notify_systemd {
        let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Ready]);
    }
    let stopped = capture_loop(&mut sequencer, &events, &only_phases, &shutdown, &clock);
    let result = match stopped {
        Ok(reason) => {
            if options.notify_systemd {
                let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Stopping]);
            }
            let drain = options.drain_at_end && reason.completes_the_build();
            let summary = sequencer.finish(reason, "stopped", drain);
            info!(
                stored = summary.stored,
                missing = summary.missing,
                skipped = summary.skipped,
                reason = %summary.stop_reason.as_ref().map_or_else(String::new, ToString::to_string),
                "acquisition stopped"
            );
            Ok(summary)
        }
        Err(e) => {
            let reason = StopReason::failure_of(&e);
            shutdown.request(reason.clone());
            sequencer.finish(reason, "failed", false);
            Err(e)
        }
    };
    plant.emit(|| {
        let stop = result.as_ref().ok().and_then(|s| s.stop_reason.as_ref());
        crate::plant::PlantEvent::BuildEnded {
            reason: match (&result, stop) {
                (Err(e), _) => crate::logging::chain(e),
                (Ok(_), stop) => stop.map_or_else(String::new, ToString::to_string),
            },
            completed: stop.is_some_and(StopReason::completes_the_build),
            failed: result.is_err(),
            at: clock.now(),
        }
    });
    // Every path above requested the shutdown: the trigger's and the watchdog's threads end.
    events.join();
    if let Some(watchdog) = watchdog {
        let _ = watchdog.join();
    }
    result
}

/// Feeds layer signals to the sequencer, one event at a time, until the shutdown is requested
/// (the trigger's end requests it); status.json follows the parts' health while idle. Returns
/// why it stopped, or the error that stopped it.
fn capture_loop(
    sequencer: &mut Sequencer,
    events: &crate::hardware::trigger::Events,
    only_phases: &BTreeSet<Phase>,
    shutdown: &Shutdown,
    clock: &SharedClock,
) -> Result<StopReason, AcquisitionError> {
    let mut tick = clock.after(HEALTH_PERIOD);
    loop {
        // A stop comes before any signal still queued: the frame in hand is finished, no other.
        if let Some(reason) = shutdown.reason() {
            return Ok(reason);
        }
        crossbeam_channel::select! {
            recv(events.receiver()) -> event => match event {
                // Hung up: the build's end if the trigger ended, a failure if its thread was
                // lost (a stop requested meanwhile is taken above).
                Err(_) => match events.lost() {
                    Some(e) if shutdown.reason().is_none() => {
                        error!(error = %Chain(&e), "trigger failed");
                        return Err(e.into());
                    }
                    _ => {
                        shutdown.request(StopReason::TriggerEnded);
                    }
                },
                Ok(Err(e)) => {
                    error!(error = %Chain(&e), "trigger failed");
                    return Err(e.into());
                }
                Ok(Ok(event)) if !only_phases.contains(&event.phase) => {
                    info!(layer = event.layer, phase = %event.phase, "signal for a phase not in views.phases; ignored");
                }
                Ok(Ok(event)) => {
                    if let Err(e) = sequencer.on_event(event) {
                        error!(error = %Chain(&e), "acquisition stopped by an error");
                        return Err(e);
                    }
                }
            },
            recv(shutdown.receiver()) -> _ => {}
            recv(tick) -> _ => {
                sequencer.refresh_health();
                tick = clock.after(HEALTH_PERIOD);
            }
        }
    }
}

/// Pings systemd's watchdog every half `WatchdogSec` while the capture path shows signs of life
/// (the sequencer beats at each frame and each health tick), until the shutdown. None when
/// systemd set no watchdog.
fn watchdog(
    heartbeat: Heartbeat,
    clock: SharedClock,
    shutdown: Shutdown,
) -> Option<std::thread::JoinHandle<()>> {
    let mut usec = 0u64;
    if !sd_notify::watchdog_enabled(false, &mut usec) {
        return None;
    }
    let period = Duration::from_micros(usec / 2);
    std::thread::Builder::new()
        .name("watchdog".into())
        .spawn(move || {
            while shutdown.wait(&clock.after(period)).is_none() {
                if clock.elapsed().saturating_sub(heartbeat.last()) < period * 2 {
                    let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Watchdog]);
                }
            }
        })
        .map_err(|e| warn!(error = %e, "systemd watchdog: cannot start its thread"))
        .ok()
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
    plant: &crate::plant::PlantSink,
) -> Result<Arc<dyn FrameProcessor>, AcquisitionError> {
    if let (true, Some(model)) = (config.inspection.enabled, &config.inspection.model) {
        // A bad model file stops the start, calibrated or not.
        crate::learn::Model::load(&model.file).map_err(AcquisitionError::Model)?;
    }
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
    let alarm = alarm::Alarm::new(alarm, &config.inspection.alarm)
        .with_message(message, &config.inspection.alarm)
        .with_plant(plant.clone());
    let dir = &config.build.output_dir;
    Ok(Arc::new(
        inspection::InspectingSeries::open(config, dir, live, alarm, clock.clone())?
            .with_plant(plant.clone()),
    ))
}

/// What the plant interfaces are told when a run of the build starts.
fn build_started(config: &Config, clock: &SharedClock) -> crate::plant::PlantEvent {
    let dir = &config.build.output_dir;
    crate::plant::PlantEvent::BuildStarted(crate::plant::event::BuildInfo {
        name: config.build.name.clone(),
        id: config.build_id().to_string(),
        dir: dir.clone(),
        layers_expected: config.build.layers,
        program: config
            .build
            .vectors
            .as_ref()
            .and_then(|v| v.file_name())
            .map(|n| n.to_string_lossy().into_owned()),
        alarm: crate::build_dir::alarm::state(dir),
        at: clock.now(),
    })
}
