//! The sequencer: for one layer signal, each light in turn exposed ([`Exposure`]) and recorded
//! ([`Recorder`]); irregular signals flagged, repeated ones retaken, a layer a restart
//! interrupted finished or given up.

use super::exposure::{Exposed, Exposure};
use super::recorder::{self, Recorder};
use super::{AcquisitionError, RunSummary};
use crate::build_dir::IrregularSignal;
use crate::clock::SharedClock;
use crate::hardware::camera::CameraError;
use crate::hardware::trigger::LayerEvent;
use crate::shot::{Light, Phase, Shot, MAX_LAYER};
use crate::shutdown::StopReason;
use chrono::{DateTime, Utc};
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use tracing::info;

/// What to do with a layer signal.
enum Handling {
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

/// When the capture path last showed signs of life (the clock's monotonic milliseconds), for the
/// systemd watchdog.
#[derive(Clone, Default)]
pub(super) struct Heartbeat(Arc<AtomicU64>);

impl Heartbeat {
    pub(super) fn beat(&self, clock: &SharedClock) {
        self.0
            .store(clock.elapsed().as_millis() as u64, Ordering::SeqCst);
    }

    pub(super) fn last(&self) -> std::time::Duration {
        std::time::Duration::from_millis(self.0.load(Ordering::SeqCst))
    }
}

pub(super) struct Sequencer {
    lights: Vec<Light>,
    exposure: Exposure,
    recorder: Recorder,
    open: Option<OpenEvent>,
    /// The previous layer signal (at start, the journal's last one).
    prev_signal: Option<(u32, Phase)>,
    /// After a restart, until the first signal that is not history: a trigger that replays
    /// signals already handled (a simulated printer's script) is skipped quietly.
    catching_up: bool,
    heartbeat: Heartbeat,
    clock: SharedClock,
}

impl Sequencer {
    /// `open`: the layer a restart interrupted, if any.
    pub(super) fn new(
        lights: Vec<Light>,
        exposure: Exposure,
        recorder: Recorder,
        open: Option<OpenEvent>,
        heartbeat: Heartbeat,
        clock: SharedClock,
    ) -> Sequencer {
        let prev_signal = recorder.progress().last_event;
        Sequencer {
            lights,
            exposure,
            recorder,
            open,
            prev_signal,
            catching_up: prev_signal.is_some(),
            heartbeat,
            clock,
        }
    }

    fn beat(&self) {
        self.heartbeat.beat(&self.clock);
    }

    fn is_done(&self, shot: &Shot) -> bool {
        self.recorder.progress().is_done(shot)
            || self.open.as_ref().is_some_and(|o| {
                o.layer == shot.layer && o.phase == shot.phase && o.done.contains(&shot.light)
            })
    }

    fn mark_done(&mut self, light: Light) {
        if let Some(open) = self.open.as_mut() {
            open.done.insert(light);
        }
    }

    fn missing(&mut self, shot: Shot, reason: String) -> Result<(), AcquisitionError> {
        self.recorder.missing(shot, reason)?;
        self.mark_done(shot.light);
        Ok(())
    }

    /// Gives up on the views of an event that a newer signal overtook (e.g. across a restart).
    fn close_open_event(&mut self, reason: &str) -> Result<(), AcquisitionError> {
        let Some(open) = self.open.take() else {
            return Ok(());
        };
        for light in self.lights.clone() {
            let shot = Shot {
                layer: open.layer,
                phase: open.phase,
                light,
            };
            if !open.done.contains(&light) && !self.recorder.progress().is_done(&shot) {
                self.recorder.missing(shot, reason.to_string())?;
            }
        }
        Ok(())
    }

    /// Checks a signal against the previous one: out of range (not captured), repeated (its
    /// frames are retaken), skipping layers or going backwards (flagged, then handled as usual).
    fn classify(
        &mut self,
        event: &LayerEvent,
        shots: &[Shot],
    ) -> Result<Handling, AcquisitionError> {
        let key = (event.layer, event.phase);
        if event.layer == 0 || event.layer > MAX_LAYER {
            if !self.catching_up {
                self.recorder.irregular(
                    event,
                    IrregularSignal::OutOfRange,
                    format!("printers count layers 1 to {MAX_LAYER}; not captured"),
                )?;
            }
            return Ok(Handling::Ignore);
        }
        let prev = self.prev_signal.replace(key);
        let all_done = shots.iter().all(|s| self.is_done(s));
        if self.catching_up {
            // After a restart, signals for frames already stored are the printer (or a script)
            // replaying what was handled: skipped quietly until the first new signal.
            if all_done {
                return Ok(Handling::Capture);
            }
            self.catching_up = false;
        }
        let Some(prev) = prev else {
            return Ok(Handling::Capture);
        };
        if prev == key && all_done {
            let progress = self.recorder.progress();
            let takes = shots.iter().map(|s| progress.takes(s)).max().unwrap_or(0);
            self.recorder.irregular(
                event,
                IrregularSignal::Repeated,
                format!(
                    "the same signal again: take {} kept beside the first, nothing overwritten",
                    takes + 1
                ),
            )?;
            return Ok(Handling::Retake);
        }
        if key < prev {
            self.recorder.irregular(
                event,
                IrregularSignal::Backwards,
                format!("after layer {} {}", prev.0, prev.1),
            )?;
        } else if event.layer > prev.0.saturating_add(1) {
            self.recorder.irregular(
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
        Ok(Handling::Capture)
    }

    pub(super) fn on_event(&mut self, event: LayerEvent) -> Result<(), AcquisitionError> {
        self.beat();
        info!(layer = event.layer, phase = %event.phase, "layer signal");
        self.recorder.journal(&crate::build_dir::Record::Event {
            layer: event.layer,
            phase: event.phase,
            at: event.at,
        })?;
        let key = (event.layer, event.phase);
        let shots: Vec<Shot> = self
            .lights
            .iter()
            .map(|&light| Shot {
                layer: event.layer,
                phase: event.phase,
                light,
            })
            .collect();
        match self.classify(&event, &shots)? {
            Handling::Ignore => return Ok(()),
            Handling::Retake => return self.retake(&event, shots),
            Handling::Capture => {}
        }
        if self.open.as_ref().is_some_and(|o| key > (o.layer, o.phase)) {
            self.close_open_event("not captured: the printer moved on (daemon stopped or busy)")?;
        }
        if shots.iter().all(|s| self.is_done(s)) {
            info!(layer = event.layer, phase = %event.phase, "layer signal for frames already stored; skipped");
            self.recorder.skipped(shots.len());
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
        self.recorder.at_layer(event.layer, event.phase);
        let started = self.clock.elapsed();
        let (stored, missing) = self.recorder.counts();
        for shot in shots {
            if self.is_done(&shot) {
                self.recorder.skipped(1);
                continue;
            }
            self.take(shot, 1)?;
        }
        self.open = None;
        self.recorder.phase_done(event.layer, event.phase, event.at);
        let (stored_now, missing_now) = self.recorder.counts();
        info!(
            layer = event.layer,
            phase = %event.phase,
            frames = stored_now - stored,
            missing = missing_now - missing,
            capture_ms = self.clock.elapsed().saturating_sub(started).as_millis() as u64,
            backlog = self.recorder.backlog(),
            "layer done"
        );
        Ok(())
    }

    /// Takes every light of a repeated signal again, each as its next take.
    fn retake(&mut self, event: &LayerEvent, shots: Vec<Shot>) -> Result<(), AcquisitionError> {
        self.recorder.at_layer(event.layer, event.phase);
        for shot in shots {
            let take = self.recorder.progress().takes(&shot) + 1;
            self.take(shot, take)?;
        }
        self.recorder.phase_done(event.layer, event.phase, event.at);
        Ok(())
    }

    /// Exposes take `take` of `shot` (1: the frame; more: a retake kept beside it) and records it.
    fn take(&mut self, shot: Shot, take: u32) -> Result<(), AcquisitionError> {
        self.beat();
        if let Some(reason) = self.recorder.no_room() {
            self.recorder
                .missed_for_space(shot, reason, self.exposure.parts())?;
            self.mark_done(shot.light);
            return Ok(());
        }
        let event_at = self
            .open
            .as_ref()
            .map_or_else(|| self.clock.now(), |o| o.at);
        let exposed = self.exposure.expose(shot);
        self.beat();
        match exposed {
            Exposed::Frame { frame, attempts } => {
                let exposed = recorder::Exposed {
                    shot,
                    take,
                    frame: &frame,
                    event_at,
                    attempts,
                    camera: self.exposure.camera_settings(),
                };
                self.recorder.store(exposed, self.exposure.parts())?;
                self.mark_done(shot.light);
                Ok(())
            }
            Exposed::Missing(reason) => {
                self.missing(shot, reason)?;
                self.recorder.write_live("running", self.exposure.parts());
                Ok(())
            }
            Exposed::Hung(e) => {
                self.missing(shot, e.fatal_reason())?;
                Err(match e {
                    CameraError::Lost(_) => AcquisitionError::CameraLost(e),
                    e => AcquisitionError::CameraHung(e),
                })
            }
        }
    }

    /// Called about once a second while idle: status.json follows the parts' health.
    pub(super) fn refresh_health(&mut self) {
        self.beat();
        self.recorder.refresh_health(self.exposure.parts());
    }

    pub(super) fn write_live(&mut self, state: &str) {
        self.recorder.write_live(state, self.exposure.parts());
    }

    /// Lights off, processing stopped or drained, the stop journaled.
    pub(super) fn finish(mut self, reason: StopReason, state: &str, drain: bool) -> RunSummary {
        self.exposure.all_off();
        let Sequencer {
            exposure, recorder, ..
        } = self;
        recorder.finish(reason, state, drain, exposure.parts())
    }
}
