//! The inspection alarm: the stack light (one channel of a relay board or GPIO set) and the
//! printer message, on while a flag is open, on a thread of its own so that neither the light nor
//! the serial line ever holds up the processing worker. Its changes go to `alarm.jsonl`
//! (`build_dir::alarm`); an operator's acknowledgement there (`layerwise alarm ack`) switches it
//! off.

use crate::build_dir::alarm::{AlarmEvent, AlarmLog, AlarmState};
use crate::build_dir::inspection::{InspectionRecord, Severity};
use crate::build_dir::lines::AppendIfError;
use crate::build_dir::JournalError;
use crate::clock::SharedClock;
use crate::config::inspection::{AlarmConfig, AlarmSerialConfig, AlarmSeverity};
use crate::hardware::lights::Lights;
use crate::hardware::message::MessageLink;
use crate::logging::Chain;
use crate::shot::Light;
use chrono::{DateTime, Utc};
use crossbeam_channel::Sender;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::{error, info, warn};

/// How often the alarm looks for an operator's acknowledgement in `alarm.jsonl`.
pub const ACKNOWLEDGEMENT_POLL: Duration = Duration::from_millis(500);

/// The stack light and the printer message, on while a flag is open.
pub struct Alarm {
    output: Box<dyn Lights>,
    channel: Light,
    level: Severity,
    latch: bool,
    /// Raised: a flag at the alarm's level is open (what `alarm.jsonl` says).
    raised: bool,
    /// What the light was last switched to (taken as off at the start).
    light: bool,
    /// Why the light refused its last switch, until it answers again: logged once, tried
    /// again at each poll, and shown in the lights' health ([`AlarmThread::fault`]).
    fault: Arc<Mutex<Option<String>>>,
    message: Option<(Box<dyn MessageLink>, AlarmSerialConfig)>,
    history: Option<AlarmLog>,
    /// Events of the history already looked at.
    seen: usize,
    /// Told every change (raised, acknowledged, cleared).
    plant: crate::plant::PlantSink,
}

impl Alarm {
    pub fn new(output: Box<dyn Lights>, config: &AlarmConfig) -> Alarm {
        Alarm {
            output,
            channel: config.channel,
            level: match config.severity {
                AlarmSeverity::Warning => Severity::Warning,
                AlarmSeverity::Critical => Severity::Critical,
            },
            latch: config.latch,
            raised: false,
            light: false,
            fault: Arc::default(),
            message: None,
            history: None,
            seen: 0,
            plant: crate::plant::PlantSink::off(),
        }
    }

    /// Also tells the plant interfaces each change.
    pub fn with_plant(mut self, plant: crate::plant::PlantSink) -> Alarm {
        self.plant = plant;
        self
    }

    /// Also sends `config.serial`'s message through `link` whenever the alarm is raised.
    pub fn with_message(
        mut self,
        link: Option<Box<dyn MessageLink>>,
        config: &AlarmConfig,
    ) -> Alarm {
        self.message = link.zip(config.serial.clone());
        self
    }

    /// Journals to `alarm.jsonl` in `build_dir`; an alarm the history leaves raised (the daemon
    /// stopped before anyone acknowledged it, or before a clean layer cleared it) is switched on
    /// again, and goes off as it would have: acknowledged, or, unless latched, at a clean layer.
    pub fn resume(&mut self, build_dir: &Path, fsync: bool) -> Result<(), JournalError> {
        let (log, events) = AlarmLog::open(&build_dir.join(crate::build_dir::ALARM), fsync)?;
        self.history = Some(log);
        self.seen = events.len();
        if let AlarmState::Raised { layer, kind, .. } = AlarmState::replay(&events) {
            if self.latch {
                warn!(layer, kind = %kind, "inspection alarm still raised from before the restart (acknowledge with `layerwise alarm ack`)");
            } else {
                warn!(layer, kind = %kind, "inspection alarm still raised from before the restart (off at the next clean layer, or with `layerwise alarm ack`)");
            }
            self.raised = true;
            self.drive_light();
        }
        Ok(())
    }

    /// Switches the light to what the alarm is (raised or not) unless it already is. A light
    /// that refuses is logged once and tried again at the next poll and layer: the alarm's
    /// state (the history, the plant, the next raise) does not wait on the relay.
    fn drive_light(&mut self) {
        let on = self.raised;
        // A light already where it should be (one that refused to go on, then acknowledged) is
        // not switched, and nothing is at fault.
        let switched = if self.light == on {
            Ok(())
        } else {
            self.output.switch(self.channel, on)
        };
        match switched {
            Ok(()) => {
                self.light = on;
                if set_fault(&self.fault, None).is_some() {
                    info!(
                        on,
                        "inspection alarm: the stack light is as the alarm is again"
                    );
                }
            }
            Err(e) => {
                let fault = format!(
                    "inspection alarm: cannot switch the stack light ({}) {}: {}; check the relay \
                     board or GPIO line (tried again every {} ms)",
                    self.channel,
                    if on { "on" } else { "off" },
                    Chain(&e),
                    ACKNOWLEDGEMENT_POLL.as_millis()
                );
                if set_fault(&self.fault, Some(fault.clone())).is_none() {
                    error!("{fault}");
                }
            }
        }
    }

    fn journal(&mut self, event: AlarmEvent) {
        self.plant
            .emit(|| crate::plant::PlantEvent::Alarm(event.clone()));
        if let Some(log) = self.history.as_mut() {
            match log.append(&event) {
                Ok(()) => self.seen += 1,
                Err(e) => error!(error = %Chain(&e), "inspection alarm: cannot write its history"),
            }
        }
    }

    /// Switches on for a record with a new flag at the alarm's severity (and sends the message);
    /// off after a clean layer unless latched. A flag that persists from an earlier layer
    /// (`since`) keeps the alarm from clearing but does not raise it again once acknowledged.
    pub fn after_layer(&mut self, record: &InspectionRecord, now: DateTime<Utc>) {
        // An acknowledgement appended since the last poll counts first: the flag it left behind
        // raises the alarm again, rather than finding it raised and being switched off with it.
        if let Some(path) = self.history.as_ref().map(|h| h.path().to_path_buf()) {
            // The light is switched once, below, as the layer leaves the alarm (not off, then on
            // again for a new flag).
            self.read_acknowledgements(&path, false);
        }
        self.decide(record, now);
    }

    /// [`Alarm::after_layer`] once the acknowledgements so far are taken in.
    fn decide(&mut self, record: &InspectionRecord, now: DateTime<Utc>) {
        let at_level = |f: &&crate::build_dir::inspection::Flag| f.severity >= self.level;
        let raised = record
            .flags
            .iter()
            .filter(at_level)
            .find(|f| f.since.is_none());
        let persisting = record
            .flags
            .iter()
            .filter(at_level)
            .any(|f| f.since.is_some());
        match raised {
            Some(flag) if !self.raised => {
                self.announce(record, flag);
                self.journal(raise_event(record, flag, now));
            }
            Some(flag) => self.raise_unless_raised(record, flag, now),
            None if self.raised && !self.latch && !persisting => {
                self.raised = false;
                self.drive_light();
                info!(
                    layer = record.layer,
                    "inspection alarm off: layer {} is clean", record.layer
                );
                self.journal(AlarmEvent::Cleared {
                    at: now,
                    layer: record.layer,
                });
            }
            _ => self.drive_light(),
        }
    }

    /// A new flag while the alarm is raised raises nothing, unless an acknowledgement landed
    /// since the history was read: that is checked, and the raise appended, under
    /// `alarm.jsonl`'s lock, so an acknowledgement can never land between the two and take
    /// this flag with the raise it acknowledged. A lock another process keeps past its wait is
    /// not waited for (the check and the raise are made without it: a raise is never held
    /// back); a raise that cannot be written still switches the alarm on.
    fn raise_unless_raised(
        &mut self,
        record: &InspectionRecord,
        flag: &crate::build_dir::inspection::Flag,
        now: DateTime<Utc>,
    ) {
        let Some(log) = self.history.as_mut() else {
            return self.drive_light();
        };
        let path = log.path().to_path_buf();
        let event = raise_event(record, flag, now);
        let mut passed = None;
        let appended = log.append_if(&event, |events| {
            if AlarmState::replay(events).is_raised() {
                return Err(());
            }
            passed = Some(events.to_vec());
            Ok(())
        });
        match (appended, passed) {
            (Ok(Ok(before)), _) => {
                self.take_acknowledgements(&before, false);
                // The raise just appended.
                self.seen += 1;
                self.raise_again(record, flag, event);
            }
            (Err(AppendIfError::Log(e)), Some(before)) => {
                error!(error = %Chain(&e), "inspection alarm: cannot write its history");
                self.take_acknowledgements(&before, false);
                self.raise_again(record, flag, event);
            }
            (Err(AppendIfError::Busy { .. }), _) => {
                warn!(file = %path.display(), "inspection alarm: another process keeps the history's lock; checking for an acknowledgement without it");
                match AlarmLog::read(&path) {
                    Ok(events) if !AlarmState::replay(&events).is_raised() => {
                        self.take_acknowledgements(&events, false);
                        self.announce(record, flag);
                        self.journal(event);
                    }
                    Ok(_) => self.drive_light(),
                    Err(e) => {
                        error!(error = %Chain(&e), "inspection alarm: cannot read its history");
                        self.drive_light();
                    }
                }
            }
            // Still raised.
            (Ok(Err(())), _) => self.drive_light(),
            (Err(e), _) => {
                error!(error = %Chain(&e), "inspection alarm: cannot check its history for an acknowledgement");
                self.drive_light();
            }
        }
    }

    /// Tells the plant of `event`, the raise of `flag` after an acknowledgement, and switches on.
    fn raise_again(
        &mut self,
        record: &InspectionRecord,
        flag: &crate::build_dir::inspection::Flag,
        event: AlarmEvent,
    ) {
        self.plant.emit(|| crate::plant::PlantEvent::Alarm(event));
        self.announce(record, flag);
    }

    /// Switches on for `flag` and sends the printer its message.
    fn announce(&mut self, record: &InspectionRecord, flag: &crate::build_dir::inspection::Flag) {
        self.raised = true;
        self.drive_light();
        warn!(layer = record.layer, kind = %flag.kind, channel = %self.channel, "inspection alarm ON: layer {}: {}", record.layer, flag.message);
        if let Some((link, config)) = self.message.as_mut() {
            let text = config.render(
                record.layer,
                flag.kind.name(),
                &flag.severity.to_string(),
                flag.part,
            );
            match link.send(text.as_bytes()) {
                Ok(()) => {
                    info!(layer = record.layer, port = %config.port, "inspection alarm: message sent to the printer")
                }
                Err(e) => {
                    error!(error = %Chain(&e), "inspection alarm: the printer did not get the message")
                }
            }
        }
    }

    /// Looks for acknowledgements appended to the history since the last look (by `layerwise
    /// alarm ack`) and switches off for one; a light that refused its last switch is tried again.
    pub fn poll_acknowledgements(&mut self, build_dir: &Path) {
        self.drive_light();
        if self.history.is_none() {
            return;
        }
        self.read_acknowledgements(&build_dir.join(crate::build_dir::ALARM), true);
    }

    /// Takes in the acknowledgements appended to the history at `path` since the last look, and
    /// switches the light off for one when `drive`.
    fn read_acknowledgements(&mut self, path: &Path, drive: bool) {
        match AlarmLog::read(path) {
            Ok(events) => self.take_acknowledgements(&events, drive),
            Err(e) => error!(error = %Chain(&e), "inspection alarm: cannot read its history"),
        }
    }

    /// Takes in the acknowledgements among `events` (the whole history) past those seen, and
    /// switches the light off for one when `drive`.
    fn take_acknowledgements(&mut self, events: &[AlarmEvent], drive: bool) {
        let new = events.get(self.seen..).unwrap_or_default();
        self.seen = events.len();
        for event in new {
            if let AlarmEvent::Acknowledged { by, .. } = event {
                if !self.raised {
                    continue;
                }
                self.plant
                    .emit(|| crate::plant::PlantEvent::Alarm(event.clone()));
                self.raised = false;
                if drive {
                    self.drive_light();
                }
                info!(by = %by, "inspection alarm off: acknowledged by {by}");
            }
        }
    }
}

/// The history's record of `flag` raising the alarm.
fn raise_event(
    record: &InspectionRecord,
    flag: &crate::build_dir::inspection::Flag,
    now: DateTime<Utc>,
) -> AlarmEvent {
    AlarmEvent::Raised {
        at: now,
        layer: record.layer,
        kind: flag.kind,
        severity: flag.severity,
        message: flag.message.clone(),
    }
}

/// Sets the alarm's fault, returning the one before.
fn set_fault(fault: &Mutex<Option<String>>, now: Option<String>) -> Option<String> {
    std::mem::replace(&mut *fault.lock().unwrap_or_else(|e| e.into_inner()), now)
}

/// The alarm on its own thread: layers' records come in over a channel, acknowledgements are
/// looked for every [`ACKNOWLEDGEMENT_POLL`] on the clock. It ends when its input hangs up
/// ([`AlarmThread::finish`], when the processing worker ends), after the records it was sent.
/// A thread that ends on a panic (a light's driver) or cannot start says why in its fault: the
/// records sent to it after are lost, and the lights' health shows it until the service restarts.
pub struct AlarmThread {
    records: Mutex<Option<Sender<InspectionRecord>>>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
    fault: Arc<Mutex<Option<String>>>,
}

impl AlarmThread {
    pub fn spawn(mut alarm: Alarm, build_dir: PathBuf, clock: SharedClock) -> AlarmThread {
        let (records, inbox) = crossbeam_channel::unbounded::<InspectionRecord>();
        let fault = alarm.fault.clone();
        let thread_fault = fault.clone();
        let run = move || {
            let mut poll = clock.after(ACKNOWLEDGEMENT_POLL);
            loop {
                crossbeam_channel::select! {
                    recv(inbox) -> record => match record {
                        Ok(record) => alarm.after_layer(&record, clock.now()),
                        Err(_) => {
                            alarm.poll_acknowledgements(&build_dir);
                            return;
                        }
                    },
                    recv(poll) -> _ => poll = clock.after(ACKNOWLEDGEMENT_POLL),
                }
                alarm.poll_acknowledgements(&build_dir);
            }
        };
        let thread = std::thread::Builder::new()
            .name("alarm".into())
            .spawn(move || {
                if let Err(panic) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(run)) {
                    let why = crate::logging::panic_message(&*panic);
                    stopped(&thread_fault, &format!("its thread panicked: {why}"));
                }
            });
        let thread = match thread {
            Ok(thread) => Some(thread),
            Err(e) => {
                stopped(&fault, &format!("cannot start its thread: {e}"));
                None
            }
        };
        AlarmThread {
            records: Mutex::new(Some(records)),
            thread: Mutex::new(thread),
            fault,
        }
    }

    /// Hands a layer's record to the alarm (never waits).
    pub fn after_layer(&self, record: &InspectionRecord) {
        let records = self.records.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(records) = records.as_ref() {
            if records.send(record.clone()).is_err() {
                error!(
                    layer = record.layer,
                    "inspection alarm stopped: layer {}'s flags reach neither the stack light nor \
                     the printer (restart the service)",
                    record.layer
                );
            }
        }
    }

    /// What keeps the alarm from working now (its light refuses, or it stopped), if anything.
    pub fn fault(&self) -> Option<String> {
        self.fault.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Hangs up and waits for the thread to handle what it was sent.
    pub fn finish(&self) {
        drop(
            self.records
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take(),
        );
        let thread = self.thread.lock().unwrap_or_else(|e| e.into_inner()).take();
        if let Some(thread) = thread {
            let _ = thread.join();
        }
    }
}

/// The alarm has stopped for good: logged, and kept as its fault.
fn stopped(fault: &Mutex<Option<String>>, why: &str) {
    let fault_text = format!(
        "inspection alarm stopped ({why}): flags no longer switch the stack light or send the \
         printer message; restart the service"
    );
    error!("{fault_text}");
    set_fault(fault, Some(fault_text));
}

impl Drop for AlarmThread {
    /// A processing worker that never ran still lets the alarm's thread end.
    fn drop(&mut self) {
        self.finish();
    }
}

#[cfg(test)]
mod tests;
