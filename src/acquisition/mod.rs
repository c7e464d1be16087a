//! The acquisition daemon: for every layer signal, for each light in turn: light on, settle,
//! capture and download, light off, store the original, hand it to processing. Resumes from the
//! journal after any stop; never waits for processing.

pub mod processing;
pub mod storage;

use crate::build_dir::status::{LastFrame, LiveStatus};
use crate::build_dir::{
    self, BuildManifest, IrregularSignal, Journal, JournalError, Record, Replay,
};
use crate::clock::{SharedClock, SystemClock};
use crate::config::Config;
use crate::fsutil::WriteError;
use crate::hardware::camera::{
    capture_with_retries, CameraActor, CameraError, CaptureFailure, RetryPolicy,
};
use crate::hardware::lights::{LightsError, LightsGuard};
use crate::hardware::trigger::{LayerEvent, SharedHealth, TriggerError};
use crate::hardware::Machine;
use crate::series::{FrameProcessor, KeepOriginals};
use crate::shot::MAX_LAYER;
use crate::shot::{Light, Phase, Shot};
use chrono::{DateTime, Utc};
use processing::ProcessingQueue;
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
        }
    }
}

/// What to do with a layer signal.
enum Signal {
    Capture,
    Retake,
    Ignore,
}

/// The layer currently being captured: which of its lights are done.
struct OpenEvent {
    layer: u32,
    phase: Phase,
    at: DateTime<Utc>,
    done: BTreeSet<Light>,
}

struct Sequencer {
    lights_order: Vec<Light>,
    settle: Duration,
    storage: Storage,
    journal: Arc<Mutex<Journal>>,
    lights: LightsGuard,
    camera: CameraActor,
    policy: RetryPolicy,
    /// Where the build stands: the journal's replay at start, grown with every record written.
    state: Replay,
    /// The previous layer signal (at start, the journal's last one).
    prev_signal: Option<(u32, Phase)>,
    /// After a restart, until the first signal that is not history: a trigger that replays
    /// signals already handled (a simulated printer's script) is skipped quietly.
    catching_up: bool,
    open: Option<OpenEvent>,
    queue: Option<ProcessingQueue>,
    live: LiveStatus,
    summary: RunSummary,
    heartbeat: Arc<AtomicU64>,
    clock: SharedClock,
    /// Tell systemd (READY, WATCHDOG, STATUS=).
    notify: bool,
    /// The trigger's health, updated on its thread.
    trigger_health: SharedHealth,
}

impl Sequencer {
    fn beat(&self) {
        self.heartbeat
            .store(self.clock.elapsed().as_millis() as u64, Ordering::SeqCst);
    }

    fn journal(&mut self, record: &Record) -> Result<(), AcquisitionError> {
        let mut journal = self
            .journal
            .lock()
            .map_err(|_| AcquisitionError::Runtime("journal lock poisoned".into()))?;
        journal.append(record)?;
        drop(journal);
        self.state.apply(record);
        Ok(())
    }

    fn is_done(&self, shot: &Shot) -> bool {
        self.state.is_done(shot)
            || self.open.as_ref().is_some_and(|o| {
                o.layer == shot.layer && o.phase == shot.phase && o.done.contains(&shot.light)
            })
    }

    fn record_missing(&mut self, shot: Shot, reason: String) -> Result<(), AcquisitionError> {
        error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, %reason, "frame missing");
        self.journal(&Record::Missing {
            layer: shot.layer,
            phase: shot.phase,
            light: shot.light,
            reason,
            at: self.clock.now(),
        })?;
        self.summary.missing += 1;
        if let Some(open) = self.open.as_mut() {
            open.done.insert(shot.light);
        }
        Ok(())
    }

    /// Gives up on the views of an event that a newer signal overtook (e.g. across a restart).
    fn close_open_event(&mut self, reason: &str) -> Result<(), AcquisitionError> {
        let Some(open) = self.open.take() else {
            return Ok(());
        };
        for light in self.lights_order.clone() {
            let shot = Shot {
                layer: open.layer,
                phase: open.phase,
                light,
            };
            if !open.done.contains(&light) && !self.state.is_done(&shot) {
                self.open = Some(OpenEvent {
                    done: open.done.clone(),
                    ..open
                });
                self.record_missing(shot, reason.to_string())?;
                self.open = None;
            }
        }
        Ok(())
    }

    /// Journals and logs a signal out of the expected order.
    fn irregular(
        &mut self,
        event: &LayerEvent,
        signal: IrregularSignal,
        detail: String,
    ) -> Result<(), AcquisitionError> {
        warn!(layer = event.layer, phase = %event.phase, signal = %signal, "layer {} {}: {signal}: {detail}", event.layer, event.phase);
        self.journal(&Record::Irregular {
            layer: event.layer,
            phase: event.phase,
            signal,
            detail,
            at: self.clock.now(),
        })
    }

    /// Checks a signal against the previous one: out of range (not captured), repeated (its
    /// frames are retaken), skipping layers or going backwards (flagged, then handled as usual).
    /// Returns whether the signal is to be captured, and whether as a retake.
    fn classify(&mut self, event: &LayerEvent, shots: &[Shot]) -> Result<Signal, AcquisitionError> {
        let key = (event.layer, event.phase);
        if event.layer == 0 || event.layer > MAX_LAYER {
            if self.catching_up {
                return Ok(Signal::Ignore);
            }
            self.irregular(
                event,
                IrregularSignal::OutOfRange,
                format!("printers count layers 1 to {MAX_LAYER}; not captured"),
            )?;
            return Ok(Signal::Ignore);
        }
        let prev = self.prev_signal.replace(key);
        let all_done = shots.iter().all(|s| self.is_done(s));
        if self.catching_up {
            // After a restart, signals for frames already stored are the printer (or a script)
            // replaying what was handled: skipped quietly until the first new signal.
            if all_done {
                return Ok(Signal::Capture);
            }
            self.catching_up = false;
        }
        let Some(prev) = prev else {
            return Ok(Signal::Capture);
        };
        if prev == key && all_done {
            let takes = shots.iter().map(|s| self.state.takes(s)).max().unwrap_or(0);
            self.irregular(
                event,
                IrregularSignal::Repeated,
                format!(
                    "the same signal again: take {} kept beside the first, nothing overwritten",
                    takes + 1
                ),
            )?;
            return Ok(Signal::Retake);
        }
        if key < prev {
            self.irregular(
                event,
                IrregularSignal::Backwards,
                format!("after layer {} {}", prev.0, prev.1),
            )?;
        } else if event.layer > prev.0.saturating_add(1) {
            self.irregular(
                event,
                IrregularSignal::Skipped,
                format!(
                    "layers {} to {} never signalled (after layer {} {})",
                    prev.0 + 1,
                    event.layer - 1,
                    prev.0,
                    prev.1
                ),
            )?;
        }
        Ok(Signal::Capture)
    }

    fn on_event(&mut self, event: LayerEvent) -> Result<(), AcquisitionError> {
        self.beat();
        info!(layer = event.layer, phase = %event.phase, "layer signal");
        self.journal(&Record::Event {
            layer: event.layer,
            phase: event.phase,
            at: event.at,
        })?;
        let key = (event.layer, event.phase);
        let all_lights: Vec<Shot> = self
            .lights_order
            .iter()
            .map(|&light| Shot {
                layer: event.layer,
                phase: event.phase,
                light,
            })
            .collect();
        match self.classify(&event, &all_lights)? {
            Signal::Ignore => return Ok(()),
            Signal::Retake => return self.retake(&event, all_lights),
            Signal::Capture => {}
        }
        if let Some(open) = &self.open {
            if key > (open.layer, open.phase) {
                self.close_open_event(
                    "not captured: the printer moved on (daemon stopped or busy)",
                )?;
            }
        }
        let shots = all_lights;
        if shots.iter().all(|s| self.is_done(s)) {
            info!(layer = event.layer, phase = %event.phase, "layer signal for frames already stored; skipped");
            self.summary.skipped += shots.len() as u64;
            return Ok(());
        }
        if self.open.as_ref().map(|o| (o.layer, o.phase)) != Some(key) {
            self.open = Some(OpenEvent {
                layer: event.layer,
                phase: event.phase,
                at: event.at,
                done: BTreeSet::new(),
            });
        }
        self.live.layer = Some(event.layer);
        self.live.phase = Some(event.phase);
        let started = self.clock.elapsed();
        let (stored, missing) = (self.summary.stored, self.summary.missing);
        for shot in shots {
            if self.is_done(&shot) {
                self.summary.skipped += 1;
                continue;
            }
            self.take(shot, 1)?;
        }
        self.open = None;
        let backlog = self.queue.as_ref().map_or(0, ProcessingQueue::depth);
        info!(
            layer = event.layer,
            phase = %event.phase,
            frames = self.summary.stored - stored,
            missing = self.summary.missing - missing,
            capture_ms = self.clock.elapsed().saturating_sub(started).as_millis() as u64,
            backlog,
            "layer done"
        );
        Ok(())
    }

    /// Takes every light of a repeated signal again, each as its next take.
    fn retake(&mut self, event: &LayerEvent, shots: Vec<Shot>) -> Result<(), AcquisitionError> {
        self.live.layer = Some(event.layer);
        self.live.phase = Some(event.phase);
        for shot in shots {
            let take = self.state.takes(&shot) + 1;
            self.take(shot, take)?;
        }
        Ok(())
    }

    /// Captures take `take` of `shot` (1: the frame; more: a retake kept beside it).
    fn take(&mut self, shot: Shot, take: u32) -> Result<(), AcquisitionError> {
        self.beat();
        let event_at = self
            .open
            .as_ref()
            .map_or_else(|| self.clock.now(), |o| o.at);
        if let Err(e) = self.lights.switch(shot.light, true) {
            self.lights.all_off_logged();
            return self.record_missing(
                shot,
                format!("the {} light did not switch on: {e}", shot.light),
            );
        }
        self.clock.sleep(self.settle);
        let result = capture_with_retries(&self.camera, &self.policy, &shot);
        if let Err(e) = self.lights.switch(shot.light, false) {
            warn!(light = %shot.light, error = %e, "lights: could not switch off; switching all off");
            self.lights.all_off_logged();
        }
        self.beat();
        match result {
            Ok((frame, attempts)) => {
                let sidecar = self.storage.store_frame(
                    &shot,
                    take,
                    &frame,
                    event_at,
                    self.clock.now(),
                    attempts,
                    self.camera.settings(),
                )?;
                let retake = take > 1 && self.state.frames.contains_key(&shot);
                let record = if retake {
                    Record::Retake {
                        layer: shot.layer,
                        phase: shot.phase,
                        light: shot.light,
                        take,
                        file: sidecar.file.clone(),
                        bytes: sidecar.bytes,
                        sha256: sidecar.sha256.clone(),
                        at: sidecar.captured_at,
                    }
                } else {
                    Record::Frame {
                        layer: shot.layer,
                        phase: shot.phase,
                        light: shot.light,
                        file: sidecar.file.clone(),
                        bytes: sidecar.bytes,
                        sha256: sidecar.sha256.clone(),
                        at: sidecar.captured_at,
                    }
                };
                self.journal(&record)?;
                if let Some(open) = self.open.as_mut() {
                    open.done.insert(shot.light);
                }
                if retake {
                    // The series keep showing the first take.
                    self.summary.retakes += 1;
                } else {
                    if let Some(queue) = &self.queue {
                        queue.submit(shot, self.storage.root().join(&sidecar.file));
                        self.live.queue_depth = queue.depth();
                    }
                    self.summary.stored += 1;
                }
                info!(
                    layer = shot.layer,
                    phase = %shot.phase,
                    light = %shot.light,
                    capture_ms = format!("{:.1}", frame.capture_ms),
                    download_ms = format!("{:.1}", frame.download_ms),
                    bytes = sidecar.bytes,
                    attempts,
                    "frame stored"
                );
                self.live.last_frames.insert(
                    shot.view().to_string(),
                    LastFrame {
                        layer: shot.layer,
                        file: sidecar.file,
                        at: sidecar.captured_at,
                    },
                );
                self.write_live("running");
                Ok(())
            }
            Err(CaptureFailure::Missing { attempts, last }) => {
                self.record_missing(
                    shot,
                    format!("camera failed after {attempts} attempts: {last}"),
                )?;
                self.write_live("running");
                Ok(())
            }
            Err(CaptureFailure::Hung(e)) => {
                self.lights.all_off_logged();
                self.record_missing(shot, format!("camera hung: {e}"))?;
                Err(AcquisitionError::CameraHung(e))
            }
        }
    }

    /// Rewrites status.json when the trigger's health changed (called while idle).
    fn refresh_health(&mut self) {
        let health = self.trigger_health.get();
        if self.live.trigger.as_ref() != Some(&health) {
            if let Some(w) = health.warning() {
                warn!("{w}");
            }
            let state = self.live.state.clone();
            self.write_live(&state);
        }
    }

    fn write_live(&mut self, state: &str) {
        self.live.state = state.to_string();
        self.live.trigger = Some(self.trigger_health.get());
        self.live.updated_at = Some(self.clock.now());
        if let Some(queue) = &self.queue {
            self.live.queue_depth = queue.depth();
        }
        if let Err(e) = self.live.write(self.storage.root()) {
            warn!(error = %e, "status: cannot write status.json");
        }
        if self.notify {
            // What `systemctl status layerwise` shows.
            let layer = match (self.live.layer, self.live.phase) {
                (Some(l), Some(p)) => format!("layer {l} {p}"),
                _ => "waiting for the first layer".into(),
            };
            let status = format!(
                "{state}: {layer}; {} frames, {} missing, {} retakes, {} irregular signals; processing backlog {}",
                self.state.frames.len(),
                self.state.missing.len(),
                self.state.retakes.values().map(Vec::len).sum::<usize>(),
                self.state.irregular.len(),
                self.live.queue_depth
            );
            let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Status(&status)]);
        }
    }

    /// Lights off, processing stopped or drained, the stop journaled.
    fn finish(mut self, reason: &str, state: &str, drain: bool) -> RunSummary {
        self.lights.all_off_logged();
        if let Some(queue) = self.queue.take() {
            if drain {
                info!(frames = queue.depth(), "processing the remaining frames");
                queue.drain();
            } else {
                queue.stop();
            }
        }
        if let Err(e) = self.journal(&Record::Stop {
            reason: reason.to_string(),
            at: self.clock.now(),
        }) {
            error!(error = %e, "cannot journal the stop");
        }
        self.live.queue_depth = 0;
        self.write_live(state);
        self.summary.stop_reason = reason.to_string();
        self.summary
    }
}

/// The build directory opened for a run: originals, manifest, journal and what it replayed.
struct OpenedBuild {
    storage: Storage,
    manifest: BuildManifest,
    journal: Journal,
    replay: Replay,
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
    snapshot_configuration(config, &storage)?;
    let (mut journal, mut replay) =
        Journal::open(&dir.join(build_dir::JOURNAL), config.storage.fsync)?;
    // Originals that reached the disk but not the journal (a crash in between) are adopted.
    for adopted in storage.recover(|shot| replay.frames.contains_key(shot))? {
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
        replay.apply(&record);
    }
    journal.append(&Record::Start {
        at: clock.now(),
        pid: std::process::id(),
        version: env!("CARGO_PKG_VERSION").into(),
    })?;
    let last_event = replay
        .last_event
        .map(|(layer, phase)| format!("layer {layer} {phase}"))
        .unwrap_or_else(|| "none".into());
    info!(
        build = %manifest.name,
        dir = %dir.display(),
        frames = replay.frames.len(),
        missing = replay.missing.len(),
        restarts = replay.starts,
        last_event = %last_event,
        "build opened"
    );
    Ok(OpenedBuild {
        storage,
        manifest,
        journal,
        replay,
    })
}

/// The event a restart interrupted, with the lights it had already done.
fn interrupted_event(config: &Config, replay: &Replay, clock: &SharedClock) -> Option<OpenEvent> {
    let (layer, phase) = replay.last_event?;
    let lights = &config.views.lights;
    let done: BTreeSet<Light> = lights
        .iter()
        .copied()
        .filter(|&light| {
            replay.is_done(&Shot {
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
        replay,
    } = open_build(config, &clock)?;

    let Machine {
        mut trigger,
        lights,
        camera,
    } = machine;
    let mut lights = LightsGuard::new(lights);
    lights.all_off_logged();
    let timeout = Duration::from_secs(config.capture.call_timeout_s);
    let camera =
        CameraActor::spawn(camera, timeout, clock.clone()).map_err(AcquisitionError::CameraOpen)?;
    info!(camera = camera.describe(), "camera open");
    trigger.resume_after(replay.last_event);
    let trigger_health = trigger.health();

    let journal = Arc::new(Mutex::new(journal));
    let backlog: Vec<(Shot, PathBuf)> = replay
        .unprocessed()
        .into_iter()
        .filter_map(|shot| replay.frames.get(&shot).map(|f| (shot, dir.join(&f.file))))
        .collect();
    let processor = match options.processor.take() {
        Some(p) => p,
        None => default_processor(config, &manifest)?,
    };
    let queue = ProcessingQueue::start(
        processor,
        config.storage.queue_capacity,
        dir.clone(),
        journal.clone(),
        backlog,
        clock.clone(),
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
        open: interrupted_event(config, &replay, &clock),
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
        trigger_health,
        prev_signal: replay.last_event,
        catching_up: replay.last_event.is_some(),
        state: replay,
    };
    sequencer.write_live("running");

    let only_phases: BTreeSet<Phase> = config.views.phases.iter().copied().collect();
    let events = crate::hardware::trigger::spawn(trigger);
    let (sequencer, reason) =
        event_loop(sequencer, events, only_phases, heartbeat, &options).await?;
    if options.notify_systemd {
        let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Stopping]);
    }
    let drain = options.drain_at_end && reason == "the trigger ended";
    let summary = tokio::task::spawn_blocking(move || sequencer.finish(&reason, "stopped", drain))
        .await
        .map_err(|e| AcquisitionError::Runtime(format!("shutdown failed: {e}")))?;
    info!(stored = summary.stored, missing = summary.missing, skipped = summary.skipped, reason = %summary.stop_reason, "acquisition stopped");
    Ok(summary)
}

/// Feeds layer signals to the sequencer (one event at a time, on a blocking thread) until the
/// trigger ends or a signal stops the daemon; pings the systemd watchdog while capture lives.
/// Returns the idle sequencer and why the loop stopped.
async fn event_loop(
    sequencer: Sequencer,
    mut events: tokio::sync::mpsc::Receiver<Result<LayerEvent, TriggerError>>,
    only_phases: BTreeSet<Phase>,
    heartbeat: Arc<AtomicU64>,
    options: &RunOptions,
) -> Result<(Sequencer, String), AcquisitionError> {
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
    Ok((sequencer, stop.unwrap_or_default()))
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
) -> Result<Arc<dyn FrameProcessor>, AcquisitionError> {
    let Some(path) = &config.calibration.file else {
        warn!("no calibration.file: frames are kept but not rectified; run `layerwise register images` and set it");
        return Ok(Arc::new(KeepOriginals));
    };
    let calibration = crate::rectify::Calibration::load(path)?;
    let settings = crate::series::SeriesSettings::from_config(config)?;
    let live =
        crate::series::LiveSeries::new(manifest, &config.views.all(), &calibration, settings)?;
    Ok(Arc::new(live))
}

fn watchdog_period(enabled: bool) -> Option<Duration> {
    if !enabled {
        return None;
    }
    let mut usec = 0u64;
    sd_notify::watchdog_enabled(false, &mut usec).then(|| Duration::from_micros(usec / 2))
}
