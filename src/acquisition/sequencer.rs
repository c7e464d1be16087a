//! The sequencer: for one layer signal, each light in turn (on, settle, capture, off), the
//! original stored and journaled, handed to processing; irregular signals flagged, repeated ones
//! retaken; status.json and systemd's STATUS= kept current.

use super::disk::DiskGuard;
use super::health::{Parts, Processing};
use super::processing::ProcessingQueue;
use super::storage::Storage;
use super::{AcquisitionError, RunSummary};
use crate::build_dir::status::{LastFrame, LiveStatus};
use crate::build_dir::{IrregularSignal, Journal, Progress, Record};
use crate::clock::SharedClock;
use crate::hardware::camera::{capture_with_retries, CameraActor, CaptureFailure, RetryPolicy};
use crate::hardware::lights::LightsGuard;
use crate::hardware::trigger::{LayerEvent, SharedHealth};
use crate::shot::{Light, Phase, Shot, MAX_LAYER};
use chrono::{DateTime, Utc};
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::{error, info, warn};

/// What to do with a layer signal.
enum Signal {
    Capture,
    Retake,
    Ignore,
}

/// The layer currently being captured: which of its lights are done.
pub(super) struct OpenEvent {
    pub(super) layer: u32,
    pub(super) phase: Phase,
    pub(super) at: DateTime<Utc>,
    pub(super) done: BTreeSet<Light>,
}

pub(super) struct Sequencer {
    pub(super) lights_order: Vec<Light>,
    pub(super) settle: Duration,
    pub(super) storage: Storage,
    pub(super) journal: Arc<Mutex<Journal>>,
    pub(super) lights: LightsGuard,
    pub(super) camera: CameraActor,
    pub(super) policy: RetryPolicy,
    /// Where the build stands, compactly (flags per shot, counters): the journal's replay at
    /// start, updated with every record written.
    pub(super) state: Progress,
    /// The previous layer signal (at start, the journal's last one).
    pub(super) prev_signal: Option<(u32, Phase)>,
    /// After a restart, until the first signal that is not history: a trigger that replays
    /// signals already handled (a simulated printer's script) is skipped quietly.
    pub(super) catching_up: bool,
    pub(super) open: Option<OpenEvent>,
    pub(super) queue: Option<ProcessingQueue>,
    pub(super) live: LiveStatus,
    pub(super) summary: RunSummary,
    pub(super) heartbeat: Arc<AtomicU64>,
    pub(super) clock: SharedClock,
    /// Tell systemd (READY, WATCHDOG, STATUS=).
    pub(super) notify: bool,
    /// The trigger's health, updated on its thread.
    pub(super) trigger_health: SharedHealth,
    /// Free space on the build disk: derived data paused when low, capture waits when full.
    pub(super) disk: DiskGuard,
    /// What the camera and the lights did, for status.json.
    pub(super) parts: Parts,
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

    pub(super) fn on_event(&mut self, event: LayerEvent) -> Result<(), AcquisitionError> {
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
        self.check_disk();
        if !self.disk.may_capture() {
            return self.missed_for_space(shot, self.disk.missing_reason());
        }
        let event_at = self
            .open
            .as_ref()
            .map_or_else(|| self.clock.now(), |o| o.at);
        if let Err(e) = self.lights.switch(shot.light, true) {
            self.parts.lights_switched(Err(e.to_string()));
            self.lights.all_off_logged();
            return self.record_missing(
                shot,
                format!("the {} light did not switch on: {e}", shot.light),
            );
        }
        self.clock.sleep(self.settle);
        let result = capture_with_retries(&self.camera, &self.policy, &shot);
        match self.lights.switch(shot.light, false) {
            Ok(()) => self.parts.lights_switched(Ok(())),
            Err(e) => {
                warn!(light = %shot.light, error = %e, "lights: could not switch off; switching all off");
                self.parts.lights_switched(Err(e.to_string()));
                self.lights.all_off_logged();
            }
        }
        self.beat();
        match result {
            Ok((frame, attempts)) => {
                let stored = self.storage.store_frame(
                    &shot,
                    take,
                    &frame,
                    event_at,
                    self.clock.now(),
                    attempts,
                    self.camera.settings(),
                );
                self.parts.captured(self.clock.now(), attempts);
                let sidecar = match stored {
                    Ok(sidecar) => sidecar,
                    Err(e) if crate::fsutil::is_disk_full(&e.source) => {
                        self.disk.filled();
                        self.apply_disk();
                        return self.missed_for_space(
                            shot,
                            format!("captured but not stored: the disk is full ({e})"),
                        );
                    }
                    Err(e) => return Err(e.into()),
                };
                self.disk.stored(sidecar.bytes);
                let retake = take > 1 && self.state.is_stored(&shot);
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
                if let Some(queue) = &self.queue {
                    // A retake replaces the slice only with `[series] take = "last"`.
                    let original = self.storage.root().join(&sidecar.file);
                    let take = if retake { take } else { 1 };
                    queue.submit_take(shot, take, original, self.clock.elapsed());
                    self.live.queue_depth = queue.depth();
                }
                if retake {
                    self.summary.retakes += 1;
                } else {
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
                let reason = format!("camera failed after {attempts} attempts: {last}");
                self.parts.capture_failed(shot, reason.clone());
                self.record_missing(shot, reason)?;
                self.write_live("running");
                Ok(())
            }
            Err(CaptureFailure::Hung(e)) => {
                self.parts.capture_failed(shot, format!("camera hung: {e}"));
                self.lights.all_off_logged();
                self.record_missing(shot, format!("camera hung: {e}"))?;
                Err(AcquisitionError::CameraHung(e))
            }
        }
    }

    /// A frame not captured (or not stored) for want of disk space: journaled as missing,
    /// counted, status.json says so.
    fn missed_for_space(&mut self, shot: Shot, reason: String) -> Result<(), AcquisitionError> {
        self.disk.missed();
        self.record_missing(shot, reason)?;
        self.write_live("running");
        Ok(())
    }

    /// Probes the disk (through its back-off while full): pauses or resumes the derived data and,
    /// once space returns, writes the journal records held meanwhile. Returns whether the disk's
    /// state changed.
    fn check_disk(&mut self) -> bool {
        let changed = self.disk.poll().is_some();
        self.apply_disk();
        changed
    }

    pub(super) fn apply_disk(&mut self) {
        if let Some(queue) = &self.queue {
            queue.set_paused(!self.disk.derived_allowed());
        }
        if self.disk.may_capture() {
            if let Ok(mut journal) = self.journal.lock() {
                if journal.held() > 0 {
                    if let Err(e) = journal.flush_held() {
                        if !e.is_disk_full() {
                            warn!(error = %e, "journal: cannot write the records held while the disk was full");
                        }
                    }
                }
            }
        }
    }

    /// Rewrites status.json when a part's health changed, and while the disk is not ok (called
    /// about once a second while idle).
    pub(super) fn refresh_health(&mut self) {
        let disk_changed = self.check_disk();
        let health = self.trigger_health.get();
        let trigger_changed = self.live.trigger.as_ref() != Some(&health);
        if trigger_changed {
            if let Some(w) = health.warning() {
                warn!("{w}");
            }
        }
        let disk_not_ok = self.disk.state() != crate::build_dir::status::DiskState::Ok;
        let paused = self.queue.as_ref().is_some_and(ProcessingQueue::paused);
        if trigger_changed || disk_changed || disk_not_ok || paused {
            let state = self.live.state.clone();
            self.write_live(&state);
        }
    }

    pub(super) fn write_live(&mut self, state: &str) {
        self.live.state = state.to_string();
        self.live.trigger = Some(self.trigger_health.get());
        self.live.updated_at = Some(self.clock.now());
        if let Some(queue) = &self.queue {
            self.live.queue_depth = queue.depth();
        }
        let mut disk = self.disk.health();
        disk.journal_held = self.journal.lock().map_or(0, |j| j.held());
        let processing = Processing {
            backlog: self.live.queue_depth,
            lag: self
                .queue
                .as_ref()
                .map_or(Duration::ZERO, ProcessingQueue::lag),
            paused: self.queue.as_ref().is_some_and(ProcessingQueue::paused),
        };
        let trigger = self.live.trigger.clone().unwrap_or_default();
        self.live.health = self
            .parts
            .health(self.clock.now(), &trigger, &processing, &disk);
        self.live.disk = Some(disk);
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
                "{state}: {layer}; {} frames, {} missing, {} retakes, {} irregular signals; processing backlog {}; {}",
                self.state.frames(),
                self.state.missing(),
                self.state.retakes(),
                self.state.irregular(),
                self.live.queue_depth,
                crate::build_dir::status::health_line(&self.live.health)
            );
            let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Status(&status)]);
        }
    }

    /// Lights off, processing stopped or drained, the stop journaled.
    pub(super) fn finish(mut self, reason: &str, state: &str, drain: bool) -> RunSummary {
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
        let held = self.journal.lock().map_or(0, |j| j.held());
        if held > 0 {
            error!(
                records = held,
                "the disk is still full: {held} journal records could not be written; originals \
                 they name are adopted again at the next start, frames recorded missing meanwhile \
                 are not (free space before restarting)"
            );
        }
        self.live.queue_depth = 0;
        self.write_live(state);
        self.summary.stop_reason = reason.to_string();
        self.summary
    }
}
