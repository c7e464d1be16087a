//! The inspection alarm: the stack light (one channel of a relay board or GPIO set) and the
//! printer message, on while a flag is open, on a thread of its own so that neither the light nor
//! the serial line ever holds up the processing worker. Its changes go to `alarm.jsonl`
//! (`build_dir::alarm`); an operator's acknowledgement there (`layerwise alarm ack`) switches it
//! off.

use crate::build_dir::alarm::{AlarmEvent, AlarmLog, AlarmState};
use crate::build_dir::inspection::{InspectionRecord, Severity};
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
                self.journal(AlarmEvent::Raised {
                    at: now,
                    layer: record.layer,
                    kind: flag.kind,
                    severity: flag.severity,
                    message: flag.message.clone(),
                });
            }
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
        let events = match AlarmLog::read(path) {
            Ok(events) => events,
            Err(e) => {
                error!(error = %Chain(&e), "inspection alarm: cannot read its history");
                return;
            }
        };
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
mod tests {
    use super::*;
    use crate::build_dir::inspection::{Flag, FlagKind};
    use crate::hardware::lights::LightsError;
    use crate::hardware::message::MessageError;
    use std::sync::{Arc, Mutex};

    /// Records what it is told.
    struct Recorder(Arc<Mutex<Vec<(Light, bool)>>>);

    impl Lights for Recorder {
        fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
            self.0.lock().unwrap().push((light, on));
            Ok(())
        }
        fn all_off(&mut self) -> Result<(), LightsError> {
            Ok(())
        }
    }

    struct Printer(Arc<Mutex<Vec<u8>>>);

    impl MessageLink for Printer {
        fn send(&mut self, bytes: &[u8]) -> Result<(), MessageError> {
            self.0.lock().unwrap().extend_from_slice(bytes);
            Ok(())
        }
    }

    fn at() -> DateTime<Utc> {
        chrono::DateTime::from_timestamp(0, 0).unwrap()
    }

    /// What `layerwise alarm ack` appends.
    fn acknowledge(path: &Path) {
        AlarmLog::append_only(path)
            .unwrap()
            .append(&AlarmEvent::Acknowledged {
                at: at(),
                by: "ana".into(),
                note: None,
            })
            .unwrap();
    }

    fn record(layer: u32, severity: Option<Severity>) -> InspectionRecord {
        InspectionRecord {
            layer,
            at: at(),
            ms: 0.0,
            views: vec![],
            plate: Default::default(),
            parts: vec![],
            flags: severity
                .map(|severity| Flag {
                    kind: FlagKind::Spatter,
                    class: None,
                    severity,
                    part: None,
                    view: "post_top".into(),
                    bbox_mm: [0.0; 4],
                    bbox_px: [0; 4],
                    score: 2.0,
                    threshold: 1.0,
                    message: "spot".into(),
                    since: None,
                    evidence: vec![],
                })
                .into_iter()
                .collect(),
            axis: None,
            bed: None,
            notes: vec![],
        }
    }

    #[test]
    fn the_alarm_switches_at_its_severity_and_latches_or_not() {
        let log = Arc::new(Mutex::new(Vec::new()));
        let mut config = AlarmConfig {
            channel: Light::Side,
            ..AlarmConfig::default()
        };
        let mut alarm = Alarm::new(Box::new(Recorder(log.clone())), &config);
        alarm.after_layer(&record(1, Some(Severity::Warning)), at());
        assert!(
            log.lock().unwrap().is_empty(),
            "below the default (critical)"
        );
        alarm.after_layer(&record(2, Some(Severity::Critical)), at());
        alarm.after_layer(&record(3, Some(Severity::Critical)), at());
        alarm.after_layer(&record(4, None), at());
        assert_eq!(
            *log.lock().unwrap(),
            vec![(Light::Side, true)],
            "latched, switched once"
        );

        log.lock().unwrap().clear();
        config.latch = false;
        config.severity = AlarmSeverity::Warning;
        let mut alarm = Alarm::new(Box::new(Recorder(log.clone())), &config);
        alarm.after_layer(&record(1, Some(Severity::Warning)), at());
        alarm.after_layer(&record(2, None), at());
        assert_eq!(
            *log.lock().unwrap(),
            vec![(Light::Side, true), (Light::Side, false)]
        );
    }

    #[test]
    fn one_message_per_raise_an_acknowledgement_switches_off_and_a_restart_relights() {
        let dir = tempfile::tempdir().unwrap();
        let lights = Arc::new(Mutex::new(Vec::new()));
        let sent = Arc::new(Mutex::new(Vec::new()));
        let config: AlarmConfig = toml::from_str(
            r#"serial = { port = "/dev/null", message = "ALARM {layer} {kind} {severity} {part}\n" }"#,
        )
        .unwrap();
        let mut alarm = Alarm::new(Box::new(Recorder(lights.clone())), &config)
            .with_message(Some(Box::new(Printer(sent.clone()))), &config);
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(5, Some(Severity::Critical)), at());
        alarm.after_layer(&record(6, Some(Severity::Critical)), at());
        assert_eq!(
            String::from_utf8_lossy(&sent.lock().unwrap()),
            "ALARM 5 spatter critical -\n"
        );
        alarm.poll_acknowledgements(dir.path());
        assert_eq!(
            *lights.lock().unwrap(),
            vec![(Light::Top, true)],
            "no ack yet"
        );

        let path = dir.path().join(crate::build_dir::ALARM);
        acknowledge(&path);
        alarm.poll_acknowledgements(dir.path());
        assert_eq!(
            *lights.lock().unwrap(),
            vec![(Light::Top, true), (Light::Top, false)]
        );
        alarm.after_layer(&record(9, Some(Severity::Critical)), at());
        assert_eq!(
            String::from_utf8_lossy(&sent.lock().unwrap()),
            "ALARM 5 spatter critical -\nALARM 9 spatter critical -\n",
            "raised again after the acknowledgement"
        );
        drop(alarm);

        // Restarted with layer 9's raise open: the light comes back on, no message is resent.
        lights.lock().unwrap().clear();
        let mut alarm = Alarm::new(Box::new(Recorder(lights.clone())), &config);
        alarm.resume(dir.path(), false).unwrap();
        assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);
        alarm.after_layer(&record(10, Some(Severity::Critical)), at());
        assert_eq!(lights.lock().unwrap().len(), 1);
        let events = AlarmLog::read(&path).unwrap();
        assert!(matches!(
            AlarmState::replay(&events),
            AlarmState::Raised { layer: 9, .. }
        ));
    }

    /// Before, the flag of the layer after an acknowledgement that the half-second poll had not
    /// read yet found the alarm raised, raised nothing, and the poll then switched it off.
    #[test]
    fn an_acknowledgement_not_polled_yet_does_not_swallow_the_next_layers_flag() {
        let dir = tempfile::tempdir().unwrap();
        let lights = Arc::new(Mutex::new(Vec::new()));
        let mut alarm = Alarm::new(Box::new(Recorder(lights.clone())), &AlarmConfig::default());
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(5, Some(Severity::Critical)), at());
        let path = dir.path().join(crate::build_dir::ALARM);
        acknowledge(&path);
        alarm.after_layer(&record(6, Some(Severity::Critical)), at());
        alarm.poll_acknowledgements(dir.path());
        let events = AlarmLog::read(&path).unwrap();
        assert!(
            matches!(
                AlarmState::replay(&events),
                AlarmState::Raised { layer: 6, .. }
            ),
            "{events:?}"
        );
        // On for layer 5, and on still for layer 6: not switched off and on again between.
        assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);
    }

    /// Refuses the switches it is told to refuse, in order (`false`: refuse), then obeys.
    struct Flaky {
        log: Arc<Mutex<Vec<(Light, bool)>>>,
        answers: Vec<bool>,
    }

    impl Lights for Flaky {
        fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
            if !self.answers.is_empty() && !self.answers.remove(0) {
                return Err(LightsError::Serial {
                    port: "/dev/ttyUSB1".into(),
                    source: std::io::Error::other("relay board busy"),
                });
            }
            self.log.lock().unwrap().push((light, on));
            Ok(())
        }
        fn all_off(&mut self) -> Result<(), LightsError> {
            Ok(())
        }
    }

    #[test]
    fn a_light_that_refuses_the_acknowledgement_is_retried_and_the_next_flag_raises_again() {
        let dir = tempfile::tempdir().unwrap();
        let lights = Arc::new(Mutex::new(Vec::new()));
        let sent = Arc::new(Mutex::new(Vec::new()));
        let config: AlarmConfig =
            toml::from_str(r#"serial = { port = "/dev/null", message = "ALARM {layer}\n" }"#)
                .unwrap();
        // On: obeyed; off at the acknowledgement: refused once.
        let flaky = Flaky {
            log: lights.clone(),
            answers: vec![true, false],
        };
        let mut alarm = Alarm::new(Box::new(flaky), &config)
            .with_message(Some(Box::new(Printer(sent.clone()))), &config);
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(5, Some(Severity::Critical)), at());
        let path = dir.path().join(crate::build_dir::ALARM);
        acknowledge(&path);
        alarm.poll_acknowledgements(dir.path());
        let fault = alarm.fault.lock().unwrap().clone().expect("a fault");
        assert!(
            fault.contains("cannot switch the stack light (top) off: lights relay /dev/ttyUSB1"),
            "{fault}"
        );
        assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);

        // The next poll switches it off; the next flag raises the alarm again (before, the
        // alarm took itself as still on, so no later flag raised it).
        alarm.poll_acknowledgements(dir.path());
        assert_eq!(alarm.fault.lock().unwrap().clone(), None);
        alarm.after_layer(&record(9, Some(Severity::Critical)), at());
        assert_eq!(
            *lights.lock().unwrap(),
            vec![(Light::Top, true), (Light::Top, false), (Light::Top, true)]
        );
        assert_eq!(
            String::from_utf8_lossy(&sent.lock().unwrap()),
            "ALARM 5\nALARM 9\n"
        );
        let events = AlarmLog::read(&path).unwrap();
        assert!(matches!(
            AlarmState::replay(&events),
            AlarmState::Raised { layer: 9, .. }
        ));
    }

    #[test]
    fn a_light_that_refused_to_go_on_is_no_fault_once_the_alarm_is_acknowledged() {
        let dir = tempfile::tempdir().unwrap();
        let lights = Arc::new(Mutex::new(Vec::new()));
        let flaky = Flaky {
            log: lights.clone(),
            // Refuses the raise, and the poll's retry before the acknowledgement is read.
            answers: vec![false, false],
        };
        let mut alarm = Alarm::new(Box::new(flaky), &AlarmConfig::default());
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(5, Some(Severity::Critical)), at());
        assert!(alarm.fault.lock().unwrap().is_some());
        acknowledge(&dir.path().join(crate::build_dir::ALARM));
        alarm.poll_acknowledgements(dir.path());
        // Off, as the light is: not left at fault until the service restarts.
        assert_eq!(alarm.fault.lock().unwrap().clone(), None);
        assert!(lights.lock().unwrap().is_empty());
    }

    /// Panics at its first switch.
    struct Panics;

    impl Lights for Panics {
        fn switch(&mut self, _: Light, _: bool) -> Result<(), LightsError> {
            panic!("driver bug")
        }
        fn all_off(&mut self) -> Result<(), LightsError> {
            Ok(())
        }
    }

    #[test]
    fn an_alarm_thread_that_panics_says_so_in_its_fault() {
        let dir = tempfile::tempdir().unwrap();
        let clock: SharedClock = Arc::new(crate::clock::ManualClock::new());
        let thread = AlarmThread::spawn(
            Alarm::new(Box::new(Panics), &AlarmConfig::default()),
            dir.path().to_path_buf(),
            clock,
        );
        assert_eq!(thread.fault(), None);
        thread.after_layer(&record(3, Some(Severity::Critical)));
        thread.finish();
        let fault = thread.fault().expect("a fault");
        assert!(
            fault.starts_with("inspection alarm stopped (its thread panicked: driver bug)"),
            "{fault}"
        );
    }

    #[test]
    fn an_alarm_not_latched_raised_before_a_restart_clears_at_the_next_clean_layer() {
        let dir = tempfile::tempdir().unwrap();
        let lights = Arc::new(Mutex::new(Vec::new()));
        let config = AlarmConfig {
            channel: Light::Top,
            latch: false,
            ..AlarmConfig::default()
        };
        let mut alarm = Alarm::new(Box::new(Recorder(lights.clone())), &config);
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(5, Some(Severity::Critical)), at());
        drop(alarm);

        // Restarted with layer 5's raise open: on again, and off at the first clean layer
        // (before, the restarted alarm never knew it was on: raised for good).
        lights.lock().unwrap().clear();
        let mut alarm = Alarm::new(Box::new(Recorder(lights.clone())), &config);
        alarm.resume(dir.path(), false).unwrap();
        alarm.after_layer(&record(6, None), at());
        assert_eq!(
            *lights.lock().unwrap(),
            vec![(Light::Top, true), (Light::Top, false)]
        );
        let events = AlarmLog::read(&dir.path().join(crate::build_dir::ALARM)).unwrap();
        assert!(matches!(AlarmState::replay(&events), AlarmState::Off));
    }
}
