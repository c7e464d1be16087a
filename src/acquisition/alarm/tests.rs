//! The alarm's unit tests: the light, the message and the history over layers, acknowledgements
//! and restarts.

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

/// `alarm` on `dir`'s history, raised by layer 5's critical flag; the history's path.
fn raised_by_layer_5(dir: &Path, mut alarm: Alarm) -> (Alarm, PathBuf) {
    alarm.resume(dir, false).unwrap();
    alarm.after_layer(&record(5, Some(Severity::Critical)), at());
    (alarm, dir.join(crate::build_dir::ALARM))
}

/// The history at `path`, which must say the alarm is raised since `layer`.
fn assert_raised_since(path: &Path, layer: u32) -> Vec<AlarmEvent> {
    let events = AlarmLog::read(path).unwrap();
    assert!(
        matches!(AlarmState::replay(&events), AlarmState::Raised { layer: l, .. } if l == layer),
        "{events:?}"
    );
    events
}

/// Before, the flag of the layer after an acknowledgement that the half-second poll had not
/// read yet found the alarm raised, raised nothing, and the poll then switched it off.
#[test]
fn an_acknowledgement_not_polled_yet_does_not_swallow_the_next_layers_flag() {
    let dir = tempfile::tempdir().unwrap();
    let lights = Arc::new(Mutex::new(Vec::new()));
    let alarm = Alarm::new(Box::new(Recorder(lights.clone())), &AlarmConfig::default());
    let (mut alarm, path) = raised_by_layer_5(dir.path(), alarm);
    acknowledge(&path);
    alarm.after_layer(&record(6, Some(Severity::Critical)), at());
    alarm.poll_acknowledgements(dir.path());
    assert_raised_since(&path, 6);
    // On for layer 5, and on still for layer 6: not switched off and on again between.
    assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);
}

/// Before, an acknowledgement appended between the daemon's read of the history and its
/// decision on a layer found the alarm raised for the layer's new flag, which raised
/// nothing: the acknowledgement of the earlier raise took the new flag with it, unseen.
#[test]
fn an_acknowledgement_that_lands_while_a_layer_is_decided_does_not_take_its_flag() {
    let dir = tempfile::tempdir().unwrap();
    let lights = Arc::new(Mutex::new(Vec::new()));
    let sent = Arc::new(Mutex::new(Vec::new()));
    let config: AlarmConfig =
        toml::from_str(r#"serial = { port = "/dev/null", message = "ALARM {layer}\n" }"#).unwrap();
    let alarm = Alarm::new(Box::new(Recorder(lights.clone())), &config)
        .with_message(Some(Box::new(Printer(sent.clone()))), &config);
    let (mut alarm, path) = raised_by_layer_5(dir.path(), alarm);
    // Layer 6's history read found layer 5's raise open; the acknowledgement lands now.
    alarm.read_acknowledgements(&path, false);
    acknowledge(&path);
    alarm.decide(&record(6, Some(Severity::Critical)), at());
    let events = assert_raised_since(&path, 6);
    assert_eq!(
        String::from_utf8_lossy(&sent.lock().unwrap()),
        "ALARM 5\nALARM 6\n"
    );
    // The poll after it finds nothing new: the light stays on, as it was for layer 5.
    alarm.poll_acknowledgements(dir.path());
    assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);
    // A new flag while the raise is open appends nothing.
    alarm.after_layer(&record(7, Some(Severity::Critical)), at());
    assert_eq!(AlarmLog::read(&path).unwrap().len(), events.len());
}

/// The same, while another process keeps `alarm.jsonl`'s lock past the wait: the check and the
/// raise are made without it, not given up (the flag was lost).
#[test]
fn a_lock_kept_by_another_process_does_not_hold_back_the_raise_after_an_acknowledgement() {
    use std::io::Write;
    use std::os::fd::AsRawFd;
    let dir = tempfile::tempdir().unwrap();
    let lights = Arc::new(Mutex::new(Vec::new()));
    let alarm = Alarm::new(Box::new(Recorder(lights.clone())), &AlarmConfig::default());
    let (mut alarm, path) = raised_by_layer_5(dir.path(), alarm);
    alarm.read_acknowledgements(&path, false);
    let mut other = std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap();
    // SAFETY: flock on a descriptor this test owns.
    assert_eq!(
        unsafe { libc::flock(other.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) },
        0
    );
    let ack = AlarmEvent::Acknowledged {
        at: at(),
        by: "ana".into(),
        note: None,
    };
    writeln!(other, "{}", serde_json::to_string(&ack).unwrap()).unwrap();
    alarm.decide(&record(6, Some(Severity::Critical)), at());
    assert_raised_since(&path, 6);
    alarm.poll_acknowledgements(dir.path());
    assert_eq!(*lights.lock().unwrap(), vec![(Light::Top, true)]);
    drop(other);
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
        toml::from_str(r#"serial = { port = "/dev/null", message = "ALARM {layer}\n" }"#).unwrap();
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
