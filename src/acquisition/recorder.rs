//! What records a frame: the original and its sidecar on disk, the journal, where the build stands
//! ([`Progress`]), the disk's room, the hand-over to processing, status.json and systemd's
//! STATUS=. It exposes nothing: the [`super::exposure::Exposure`] does that.

use super::disk::DiskGuard;
use super::health::{Parts, Processing};
use super::processing::ProcessingQueue;
use super::storage::Storage;
use super::{AcquisitionError, RunSummary};
use crate::build_dir::status::{DiskState, LastFrame, LiveStatus};
use crate::build_dir::{IrregularSignal, Journal, Progress, Record};
use crate::clock::SharedClock;
use crate::hardware::camera::Frame;
use crate::hardware::trigger::{LayerEvent, SharedHealth};
use crate::logging::Chain;
use crate::shot::{Phase, Shot};
use crate::shutdown::StopReason;
use chrono::{DateTime, Utc};
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::{error, info, warn};

/// Where status.json and systemd's STATUS= go.
pub(super) struct StatusSink {
    pub(super) clock: SharedClock,
    /// Tell systemd (STATUS=).
    pub(super) notify: bool,
    /// The trigger's health, updated on its thread.
    pub(super) trigger: SharedHealth,
    /// The plant interfaces.
    pub(super) plant: crate::plant::PlantSink,
}

/// A frame handed to the recorder.
pub(super) struct Exposed<'a> {
    pub(super) shot: Shot,
    /// 1: the frame; more: a retake kept beside it.
    pub(super) take: u32,
    pub(super) frame: &'a Frame,
    /// When its layer was signalled.
    pub(super) event_at: DateTime<Utc>,
    pub(super) attempts: u32,
    pub(super) camera: &'a BTreeMap<String, String>,
}

pub(super) struct Recorder {
    storage: Storage,
    journal: Arc<Mutex<Journal>>,
    /// Where the build stands, compactly (flags per shot, counters): the journal's replay at
    /// start, updated with every record written.
    progress: Progress,
    /// Free space on the build disk: derived data paused when low, capture waits when full.
    disk: DiskGuard,
    queue: Option<ProcessingQueue>,
    live: LiveStatus,
    /// The processing lag status.json last showed (its backlog is `live.queue_depth`): rewritten
    /// when either changes.
    shown_lag: Duration,
    /// The processor's fault status.json last showed ([`ProcessingQueue::fault`]); after the
    /// queue has ended, the one it ended with.
    shown_fault: Option<String>,
    summary: RunSummary,
    sink: StatusSink,
}

impl Recorder {
    pub(super) fn new(
        storage: Storage,
        progress: Progress,
        journal: Arc<Mutex<Journal>>,
        disk: DiskGuard,
        queue: ProcessingQueue,
        sink: StatusSink,
    ) -> Recorder {
        let build_dir = storage.root().to_path_buf();
        // After a restart, the layer the build had reached, not "waiting for the first layer".
        let (layer, phase) = progress.last_event.unzip();
        let mut recorder = Recorder {
            storage,
            journal,
            progress,
            disk,
            queue: Some(queue),
            live: LiveStatus {
                pid: std::process::id(),
                last_frames: BTreeMap::new(),
                layer,
                phase,
                ..LiveStatus::default()
            },
            shown_lag: Duration::ZERO,
            shown_fault: None,
            summary: RunSummary::new(build_dir),
            sink,
        };
        recorder.apply_disk();
        recorder
    }

    /// Every light of a layer signal is done: the plant interfaces are told.
    pub(super) fn phase_done(&self, layer: u32, phase: Phase, signal_at: DateTime<Utc>) {
        let at = self.sink.clock.now();
        self.sink
            .plant
            .emit(|| crate::plant::PlantEvent::PhaseDone {
                layer,
                phase,
                signal_at,
                at,
            });
    }

    /// Where the build stands.
    pub(super) fn progress(&self) -> &Progress {
        &self.progress
    }

    pub(super) fn journal(&mut self, record: &Record) -> Result<(), AcquisitionError> {
        let mut journal = self
            .journal
            .lock()
            .map_err(|_| AcquisitionError::Poisoned)?;
        journal.append(record)?;
        drop(journal);
        self.progress.apply(record);
        Ok(())
    }

    /// A frame not taken: journaled, counted, logged. A retake not taken of a shot already
    /// stored (or already missing) is journaled and logged, but neither counted again nor told
    /// the plant as missing, as `status` reads the journal: the shot has its frame.
    pub(super) fn missing(&mut self, shot: Shot, reason: String) -> Result<(), AcquisitionError> {
        error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, %reason, "frame missing");
        let at = self.sink.clock.now();
        let counted = self.progress.is_done(&shot);
        if !counted {
            self.sink
                .plant
                .emit(|| crate::plant::PlantEvent::FrameMissing {
                    shot,
                    reason: reason.clone(),
                    at,
                });
        }
        self.journal(&Record::Missing {
            layer: shot.layer,
            phase: shot.phase,
            light: shot.light,
            reason,
            at,
        })?;
        if !counted {
            self.summary.missing += 1;
        }
        Ok(())
    }

    /// Journals and logs a signal out of the expected order.
    pub(super) fn irregular(
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
            at: self.sink.clock.now(),
        })
    }

    /// Frames of a signal already stored.
    pub(super) fn skipped(&mut self, frames: usize) {
        self.summary.skipped += frames as u64;
    }

    /// The layer being captured, for status.json.
    pub(super) fn at_layer(&mut self, layer: u32, phase: Phase) {
        self.live.layer = Some(layer);
        self.live.phase = Some(phase);
    }

    /// Before a capture: probes the disk; the reason a frame cannot be captured (the disk is
    /// full), if it cannot.
    pub(super) fn no_room(&mut self) -> Option<String> {
        self.check_disk();
        (!self.disk.may_capture()).then(|| self.disk.missing_reason())
    }

    /// A frame not captured (or not stored) for want of disk space: journaled as missing,
    /// counted, status.json says so.
    pub(super) fn missed_for_space(
        &mut self,
        shot: Shot,
        reason: String,
        parts: &Parts,
    ) -> Result<(), AcquisitionError> {
        self.disk.missed();
        self.missing(shot, reason)?;
        self.write_live("running", parts);
        Ok(())
    }

    /// Stores the original and its sidecar, journals it, hands it to processing. Returns whether
    /// it was stored: false when the disk was full (then journaled as missing).
    pub(super) fn store(
        &mut self,
        exposed: Exposed<'_>,
        parts: &Parts,
    ) -> Result<bool, AcquisitionError> {
        let Exposed {
            shot,
            take,
            frame,
            event_at,
            attempts,
            camera,
        } = exposed;
        let now = self.sink.clock.now();
        let sidecar = match self
            .storage
            .store_frame(&shot, take, frame, event_at, now, attempts, camera)
        {
            Ok(sidecar) => sidecar,
            Err(e) if crate::fsutil::is_disk_full(&e.source) => {
                self.disk.filled();
                self.apply_disk();
                let reason = format!("captured but not stored: the disk is full ({})", Chain(&e));
                self.missed_for_space(shot, reason, parts)?;
                return Ok(false);
            }
            Err(e) => return Err(e.into()),
        };
        self.disk.stored(sidecar.bytes);
        let retake = take > 1 && self.progress.is_stored(&shot);
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
        if let Some(queue) = &self.queue {
            // A retake replaces the slice only with `[series] take = "last"`.
            let original = self.storage.root().join(&sidecar.file);
            let take = if retake { take } else { 1 };
            queue.submit_take(shot, take, original, self.sink.clock.elapsed());
            self.live.queue_depth = queue.depth();
        }
        if retake {
            self.summary.retakes += 1;
        } else {
            self.summary.stored += 1;
        }
        self.sink.plant.emit(|| {
            crate::plant::PlantEvent::FrameStored(crate::plant::event::FrameInfo {
                shot,
                take,
                file: sidecar.file.clone(),
                bytes: sidecar.bytes,
                capture_ms: frame.capture_ms,
                download_ms: frame.download_ms,
                attempts,
                at: sidecar.captured_at,
            })
        });
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
        self.write_live("running", parts);
        Ok(true)
    }

    /// Frames stored and missing so far this run.
    pub(super) fn counts(&self) -> (u64, u64) {
        (self.summary.stored, self.summary.missing)
    }

    /// Frames stored but not processed yet.
    pub(super) fn backlog(&self) -> usize {
        self.queue.as_ref().map_or(0, ProcessingQueue::depth)
    }

    /// Probes the disk (through its back-off while full): pauses or resumes the derived data and,
    /// once space returns, writes the journal records held meanwhile. Returns whether the disk's
    /// state changed.
    fn check_disk(&mut self) -> bool {
        let changed = self.disk.poll().is_some();
        self.apply_disk();
        changed
    }

    fn apply_disk(&mut self) {
        // The records held first: a catch-up the end of a pause starts reads the journal.
        if self.disk.may_capture() {
            if let Ok(mut journal) = self.journal.lock() {
                if journal.held() > 0 {
                    if let Err(e) = journal.flush_held() {
                        if !e.is_disk_full() {
                            warn!(error = %Chain(&e), "journal: cannot write the records held while the disk was full");
                        }
                    }
                }
            }
        }
        if let Some(queue) = &self.queue {
            // A slice that found the disk full holds the pause until the free space grows: the
            // guard alone, seeing room above storage.min_free_gb, would lift it at once, and
            // the worker would try the same slice again every second.
            if queue.slice_found_disk_full() {
                self.disk.derived_filled();
            }
            queue.set_paused(!self.disk.derived_allowed());
        }
    }

    /// Rewrites status.json when a part's health or the processing backlog or lag changed, and
    /// while the disk is not ok (called about once a second while idle).
    pub(super) fn refresh_health(&mut self, parts: &Parts) {
        let disk_changed = self.check_disk();
        let health = self.sink.trigger.get();
        let trigger_changed = self.live.trigger.as_ref() != Some(&health);
        if trigger_changed {
            if let Some(w) = health.warning() {
                warn!("{w}");
            }
        }
        let disk_not_ok = self.disk.state() != DiskState::Ok;
        let paused = self.queue.as_ref().is_some_and(ProcessingQueue::paused);
        // The backlog goes on emptying after a layer's last frame: shown as it changes, not
        // left at that frame's count while the printer is idle.
        let processing_changed = self.queue.as_ref().is_some_and(|queue| {
            (queue.depth(), queue.lag()) != (self.live.queue_depth, self.shown_lag)
                || queue.fault() != self.shown_fault
        });
        if trigger_changed || disk_changed || disk_not_ok || paused || processing_changed {
            let state = self.live.state.clone();
            self.write_live(&state, parts);
        }
    }

    pub(super) fn write_live(&mut self, state: &str, parts: &Parts) {
        let clock = &self.sink.clock;
        self.live.state = state.to_string();
        self.live.trigger = Some(self.sink.trigger.get());
        self.live.updated_at = Some(clock.now());
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
            fault: match &self.queue {
                Some(queue) => queue.fault(),
                None => self.shown_fault.clone(),
            },
        };
        self.shown_lag = processing.lag;
        self.shown_fault = processing.fault.clone();
        let trigger = self.live.trigger.clone().unwrap_or_default();
        self.live.health = parts.health(clock.now(), &trigger, &processing, &disk);
        self.live.camera = Some(parts.camera_report());
        self.live.disk = Some(disk);
        self.sink.plant.status(|| crate::plant::PlantStatus {
            layer: self.live.layer,
            phase: self.live.phase,
            state: self.live.state.clone(),
            health: self.live.health.clone(),
            updated_at: self.live.updated_at,
        });
        if let Err(e) = self.live.write(self.storage.root()) {
            warn!(error = %Chain(&e), "status: cannot write status.json");
        }
        if self.sink.notify {
            // What `systemctl status layerwise` shows.
            let layer = match (self.live.layer, self.live.phase) {
                (Some(l), Some(p)) => format!("layer {l} {p}"),
                _ => "waiting for the first layer".into(),
            };
            let status = format!(
                "{state}: {layer}; {} frames, {} missing, {} retakes, {} irregular signals; processing backlog {}; {}",
                self.progress.frames(),
                self.progress.missing(),
                self.progress.retakes(),
                self.progress.irregular(),
                self.live.queue_depth,
                crate::build_dir::status::health_line(&self.live.health)
            );
            let _ = sd_notify::notify(false, &[sd_notify::NotifyState::Status(&status)]);
        }
    }

    /// Processing stopped (after the frame in hand, with `reason`) or drained, the stop
    /// journaled, status.json's last word.
    pub(super) fn finish(
        mut self,
        reason: StopReason,
        state: &str,
        drain: bool,
        parts: &Parts,
    ) -> RunSummary {
        if let Some(queue) = self.queue.take() {
            let processor = queue.processor();
            if drain {
                info!(frames = queue.depth(), "processing the remaining frames");
                queue.drain();
            } else {
                queue.stop(reason.clone());
            }
            // Its light may be left stuck on: the last status says so.
            self.shown_fault = processor.fault();
        }
        if let Err(e) = self.journal(&Record::Stop {
            reason: reason.to_string(),
            at: self.sink.clock.now(),
        }) {
            error!(error = %Chain(&e), "cannot journal the stop");
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
        self.write_live(state, parts);
        self.summary.stop_reason = Some(reason);
        self.summary
    }
}
