//! Layer signals from the printer: a serial line or GPIO lines (the simulated printer lives in
//! `sim`). Every trigger runs on its own thread (reads block) and yields [`LayerEvent`]s.

use crate::build_dir::status::TriggerHealth;
use crate::clock::{Backoff, SharedClock};
use crate::config::{Edge, GpioMode, GpioTriggerConfig, SerialTriggerConfig};
use crate::shot::Phase;
use crate::shutdown::Shutdown;
use chrono::{DateTime, Utc};
use regex::Regex;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::io::Read;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::{info, warn};

/// The printer says: layer `layer` has reached `phase`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayerEvent {
    pub layer: u32,
    pub phase: Phase,
    pub at: DateTime<Utc>,
}

#[derive(Debug, thiserror::Error)]
pub enum TriggerError {
    #[error("trigger line pattern {pattern}")]
    Pattern {
        pattern: String,
        #[source]
        source: Box<regex::Error>,
    },
    #[error("trigger line pattern {pattern}: no named group `{group}`")]
    PatternGroup {
        pattern: String,
        group: &'static str,
    },
    #[error("{}: cannot read", path.display())]
    ScriptRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: line {line}: expected {expected}, found {found:?}", path.display())]
    Script {
        path: PathBuf,
        line: usize,
        expected: &'static str,
        found: String,
    },
    #[error("GPIO {} (is the chip present, and is the service user in the group that owns it?)", chip.display())]
    Gpio {
        chip: PathBuf,
        #[source]
        source: gpiocdev::Error,
    },
    #[error("trigger: cannot start its thread")]
    Thread {
        #[source]
        source: std::io::Error,
    },
    #[error("trigger: its thread panicked ({message}); the printer's signals are no longer read")]
    Panicked { message: String },
    #[error("trigger: its thread ended without the trigger ending or failing")]
    Lost,
    #[error("trigger: kind = \"mock\" belongs to the simulated machine (`layerwise demo`, tests); configure serial or gpio")]
    Simulated,
}

/// A source of layer signals. `Ok(None)` means the source has ended (a finished mock script) or
/// `shutdown` was requested: real printers never end, their triggers wait for the next signal,
/// looking at `shutdown` at least twice a second.
pub trait Trigger: Send {
    fn next_event(&mut self, shutdown: &Shutdown) -> Result<Option<LayerEvent>, TriggerError>;
    /// Tells the trigger where the build stands (from the journal, at start), so counters resume.
    fn resume_after(&mut self, _last: Option<(u32, Phase)>) {}
    /// The trigger's health, shared with the daemon's status (taken before the trigger moves to
    /// its thread).
    fn health(&self) -> SharedHealth {
        SharedHealth::connected("trigger")
    }
}

/// A trigger's health as it changes on the trigger's thread.
#[derive(Clone, Debug)]
pub struct SharedHealth(Arc<Mutex<TriggerHealth>>);

impl SharedHealth {
    /// A source that is connected from the start (GPIO lines, a script).
    pub fn connected(source: &str) -> SharedHealth {
        SharedHealth(Arc::new(Mutex::new(TriggerHealth {
            source: source.to_string(),
            connected: true,
            ..TriggerHealth::default()
        })))
    }
    /// The health now.
    pub fn get(&self) -> TriggerHealth {
        self.0.lock().map(|h| h.clone()).unwrap_or_default()
    }
    fn update(&self, f: impl FnOnce(&mut TriggerHealth)) {
        if let Ok(mut h) = self.0.lock() {
            f(&mut h);
        }
    }
    /// The source answered.
    pub fn up(&self, at: DateTime<Utc>) {
        self.update(|h| {
            if !h.connected {
                h.since = Some(at);
            }
            h.connected = true;
            h.reopen_attempts = 0;
            h.last_error = None;
        });
    }
    /// The source is gone or cannot be opened.
    pub fn down(&self, at: DateTime<Utc>, error: String, attempt: bool) {
        self.update(|h| {
            if h.connected || h.since.is_none() {
                h.since = Some(at);
            }
            h.connected = false;
            h.reopen_attempts += u64::from(attempt);
            h.last_error = Some(error);
        });
    }
    /// A layer signal arrived.
    pub fn signal(&self, at: DateTime<Utc>) {
        self.update(|h| h.last_signal_at = Some(at));
    }
}

/// What to check when a serial port cannot be opened, by the kind of failure.
pub(crate) fn open_hint(error: &serialport::Error) -> &'static str {
    match error.kind() {
        serialport::ErrorKind::NoDevice => "the port is gone: is the USB adapter plugged in?",
        serialport::ErrorKind::Io(std::io::ErrorKind::NotFound) => {
            "the port is gone: is the USB adapter plugged in?"
        }
        serialport::ErrorKind::Io(std::io::ErrorKind::PermissionDenied) => {
            "permission denied: the service user must be in the dialout group"
        }
        _ => "check the cable and the port name",
    }
}

/// Parses one line of the printer's protocol.
#[derive(Clone, Debug)]
pub struct LineProtocol {
    regex: Regex,
    pre: String,
    post: String,
}

impl LineProtocol {
    pub fn new(pattern: &str, pre: &str, post: &str) -> Result<LineProtocol, TriggerError> {
        let regex = Regex::new(pattern).map_err(|source| TriggerError::Pattern {
            pattern: pattern.to_string(),
            source: Box::new(source),
        })?;
        for group in ["layer", "phase"] {
            if !regex.capture_names().flatten().any(|n| n == group) {
                return Err(TriggerError::PatternGroup {
                    pattern: pattern.to_string(),
                    group,
                });
            }
        }
        Ok(LineProtocol {
            regex,
            pre: pre.to_string(),
            post: post.to_string(),
        })
    }

    pub fn default_protocol() -> LineProtocol {
        // The default pattern is a constant known to compile.
        LineProtocol::new(crate::config::DEFAULT_LINE_PATTERN, "PRE", "POST")
            .unwrap_or_else(|e| unreachable!("default pattern: {e}"))
    }

    /// `Some((layer, phase))` for a signal line, `None` for anything else.
    pub fn parse(&self, line: &str) -> Option<(u32, Phase)> {
        let caps = self.regex.captures(line)?;
        let layer = caps.name("layer")?.as_str().parse().ok()?;
        let token = caps.name("phase")?.as_str();
        let phase = if token.eq_ignore_ascii_case(&self.pre) {
            Phase::Pre
        } else if token.eq_ignore_ascii_case(&self.post) {
            Phase::Post
        } else {
            return None;
        };
        Some((layer, phase))
    }
}

/// Splits a byte stream into lines, bounding what garbage without line breaks can cost.
#[derive(Default)]
struct LineSplitter {
    buffer: Vec<u8>,
    overflowed: bool,
}

const MAX_LINE: usize = 4096;

impl LineSplitter {
    fn push(&mut self, bytes: &[u8], out: &mut VecDeque<String>) {
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                if self.overflowed {
                    warn!(
                        bytes = self.buffer.len(),
                        "trigger: skipped an over-long line"
                    );
                } else if !self.buffer.is_empty() {
                    out.push_back(String::from_utf8_lossy(&self.buffer).into_owned());
                }
                self.buffer.clear();
                self.overflowed = false;
            } else if self.buffer.len() < MAX_LINE {
                self.buffer.push(b);
            } else {
                self.overflowed = true;
            }
        }
    }
}

/// Turns protocol lines into events, warning about lines that are not signals.
fn events_from_lines(
    protocol: &LineProtocol,
    lines: &mut VecDeque<String>,
    source: &str,
    clock: &SharedClock,
) -> Option<LayerEvent> {
    while let Some(line) = lines.pop_front() {
        match protocol.parse(&line) {
            Some((layer, phase)) => {
                return Some(LayerEvent {
                    layer,
                    phase,
                    at: clock.now(),
                })
            }
            None => {
                let shown: String = line.chars().take(120).collect();
                warn!(source, line = %shown.escape_debug(), "trigger: line does not match the protocol, skipped");
            }
        }
    }
    None
}

/// The printer's serial line. A vanished port is reopened with backoff; nothing is fatal.
pub struct SerialTrigger {
    config: SerialTriggerConfig,
    protocol: LineProtocol,
    port: Option<Box<dyn serialport::SerialPort>>,
    splitter: LineSplitter,
    lines: VecDeque<String>,
    backoff: Backoff,
    clock: SharedClock,
    health: SharedHealth,
}

impl SerialTrigger {
    /// The trigger on `config.port`; reopen back-offs and event times come from `clock`.
    pub fn new(
        config: SerialTriggerConfig,
        clock: SharedClock,
    ) -> Result<SerialTrigger, TriggerError> {
        let protocol = LineProtocol::new(&config.pattern, &config.pre, &config.post)?;
        let backoff = Backoff::new(
            Duration::from_millis(config.reopen_backoff_ms[0]),
            Duration::from_millis(config.reopen_backoff_ms[1]),
        );
        let health = SharedHealth(Arc::new(Mutex::new(TriggerHealth {
            source: format!("serial {}", config.port),
            ..TriggerHealth::default()
        })));
        Ok(SerialTrigger {
            config,
            protocol,
            port: None,
            splitter: LineSplitter::default(),
            lines: VecDeque::new(),
            backoff,
            clock,
            health,
        })
    }

    /// Opens the port, retrying with back-off, until it opens or `shutdown` is requested.
    fn ensure_open(&mut self, shutdown: &Shutdown) {
        while self.port.is_none() && !shutdown.is_requested() {
            match serialport::new(&self.config.port, self.config.baud)
                .timeout(Duration::from_millis(500))
                .open()
            {
                Ok(port) => {
                    info!(port = %self.config.port, baud = self.config.baud, "trigger: serial port open");
                    self.port = Some(port);
                    self.backoff.reset();
                    self.health.up(self.clock.now());
                }
                Err(e) => {
                    let hint = open_hint(&e);
                    warn!(port = %self.config.port, error = %e, retry_in_ms = self.backoff.current().as_millis() as u64,
                        "trigger: cannot open the serial port: {hint}");
                    self.health
                        .down(self.clock.now(), format!("{e}: {hint}"), true);
                    self.clock
                        .sleep_unless(self.backoff.advance(), shutdown.receiver());
                }
            }
        }
    }
}

impl Trigger for SerialTrigger {
    fn health(&self) -> SharedHealth {
        self.health.clone()
    }

    fn next_event(&mut self, shutdown: &Shutdown) -> Result<Option<LayerEvent>, TriggerError> {
        let mut chunk = [0u8; 512];
        loop {
            if shutdown.is_requested() {
                return Ok(None);
            }
            if let Some(event) = events_from_lines(
                &self.protocol,
                &mut self.lines,
                &self.config.port,
                &self.clock,
            ) {
                self.health.signal(event.at);
                return Ok(Some(event));
            }
            self.ensure_open(shutdown);
            let Some(port) = self.port.as_mut() else {
                continue;
            };
            match port.read(&mut chunk) {
                Ok(0) => {
                    warn!(port = %self.config.port, "trigger: serial port closed; reopening");
                    self.port = None;
                    self.health
                        .down(self.clock.now(), "the port closed".into(), false);
                }
                Ok(n) => self.splitter.push(&chunk[..n], &mut self.lines),
                Err(e)
                    if e.kind() == std::io::ErrorKind::TimedOut
                        || e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    warn!(port = %self.config.port, error = %e, "trigger: serial port vanished; reopening");
                    self.port = None;
                    self.health
                        .down(self.clock.now(), format!("the port vanished: {e}"), false);
                    self.clock
                        .sleep_unless(self.backoff.current(), shutdown.receiver());
                }
            }
        }
    }
}

/// Layer counting from GPIO pulses, separate from the hardware so it can be tested.
#[derive(Clone, Debug)]
pub struct PulseCounter {
    mode: GpioMode,
    first_layer: u32,
    last: Option<(u32, Phase)>,
}

/// What a pulse was: on the pre line, the post line, or the single alternating line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pulse {
    PreLine,
    PostLine,
    Line,
}

impl PulseCounter {
    pub fn new(mode: GpioMode, first_layer: u32) -> PulseCounter {
        PulseCounter {
            mode,
            first_layer,
            last: None,
        }
    }
    pub fn resume_after(&mut self, last: Option<(u32, Phase)>) {
        self.last = last;
    }
    pub fn on_pulse(&mut self, pulse: Pulse) -> Option<(u32, Phase)> {
        let next_layer = self.last.map_or(self.first_layer, |(layer, _)| layer + 1);
        let current_layer = self.last.map_or(self.first_layer, |(layer, _)| layer);
        let event = match (self.mode, pulse) {
            (GpioMode::PerPhase, Pulse::PreLine) => (next_layer, Phase::Pre),
            (GpioMode::PerPhase, Pulse::PostLine) => match self.last {
                // Post of the layer whose pre we saw; a post with no pre starts a new layer.
                Some((layer, Phase::Pre)) => (layer, Phase::Post),
                _ => (next_layer, Phase::Post),
            },
            (GpioMode::Alternating, Pulse::Line) => match self.last {
                Some((layer, Phase::Pre)) => (layer, Phase::Post),
                Some(_) => (next_layer, Phase::Pre),
                None => (current_layer, Phase::Pre),
            },
            _ => return None,
        };
        self.last = Some(event);
        Some(event)
    }
}

/// GPIO lines through the Linux character device.
pub struct GpioTrigger {
    config: GpioTriggerConfig,
    request: gpiocdev::Request,
    counter: PulseCounter,
    clock: SharedClock,
}

impl GpioTrigger {
    /// Requests the configured lines; event times come from `clock`.
    pub fn open(
        config: GpioTriggerConfig,
        clock: SharedClock,
    ) -> Result<GpioTrigger, TriggerError> {
        let offsets: Vec<u32> = match config.mode {
            GpioMode::PerPhase => config
                .pre_line
                .into_iter()
                .chain(config.post_line)
                .collect(),
            GpioMode::Alternating => config.line.into_iter().collect(),
        };
        let edge = match config.edge {
            Edge::Rising => gpiocdev::line::EdgeDetection::RisingEdge,
            Edge::Falling => gpiocdev::line::EdgeDetection::FallingEdge,
            Edge::Both => gpiocdev::line::EdgeDetection::BothEdges,
        };
        let mut builder = gpiocdev::Request::builder();
        builder
            .on_chip(&config.chip)
            .with_consumer("layerwise-trigger")
            .with_lines(&offsets)
            .as_input()
            .with_edge_detection(edge)
            .with_debounce_period(Duration::from_millis(config.debounce_ms));
        if config.active_low {
            builder.as_active_low();
        }
        let request = builder.request().map_err(|source| TriggerError::Gpio {
            chip: config.chip.clone(),
            source,
        })?;
        let counter = PulseCounter::new(config.mode, config.first_layer);
        Ok(GpioTrigger {
            config,
            request,
            counter,
            clock,
        })
    }
}

impl Trigger for GpioTrigger {
    fn health(&self) -> SharedHealth {
        SharedHealth::connected(&format!("gpio {}", self.config.chip.display()))
    }

    fn next_event(&mut self, shutdown: &Shutdown) -> Result<Option<LayerEvent>, TriggerError> {
        let gpio = |source| TriggerError::Gpio {
            chip: self.config.chip.clone(),
            source,
        };
        loop {
            // An edge, or another look at the shutdown twice a second.
            while !self.request.wait_edge_event(SHUTDOWN_LOOK).map_err(gpio)? {
                if shutdown.is_requested() {
                    return Ok(None);
                }
            }
            let edge = self.request.read_edge_event().map_err(gpio)?;
            let pulse = match self.config.mode {
                GpioMode::Alternating => Pulse::Line,
                GpioMode::PerPhase if Some(edge.offset) == self.config.pre_line => Pulse::PreLine,
                GpioMode::PerPhase => Pulse::PostLine,
            };
            if let Some((layer, phase)) = self.counter.on_pulse(pulse) {
                return Ok(Some(LayerEvent {
                    layer,
                    phase,
                    at: self.clock.now(),
                }));
            }
        }
    }

    fn resume_after(&mut self, last: Option<(u32, Phase)>) {
        self.counter.resume_after(last);
    }
}

/// How often a trigger waiting for a signal looks at the shutdown.
pub const SHUTDOWN_LOOK: Duration = Duration::from_millis(500);

/// The trigger's thread and its events.
pub struct Events {
    receiver: crossbeam_channel::Receiver<Result<LayerEvent, TriggerError>>,
    /// Set by the thread when its trigger says it has ended (`Ok(None)`).
    ended: Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Events {
    /// The events, in order; disconnected once the trigger has ended (or failed, after its
    /// error).
    pub fn receiver(&self) -> &crossbeam_channel::Receiver<Result<LayerEvent, TriggerError>> {
        &self.receiver
    }

    /// Why the events stopped, once [`Events::receiver`] is disconnected: none if the trigger
    /// said it ended (its script is done, or it saw the shutdown), else the thread was lost
    /// without saying why (its error, a panic's included, comes through the channel first), or
    /// it quit waiting to send because the shutdown was requested: callers look at the shutdown
    /// first.
    pub fn lost(&self) -> Option<TriggerError> {
        (!self.ended.load(std::sync::atomic::Ordering::SeqCst)).then_some(TriggerError::Lost)
    }

    /// Waits for the trigger's thread to end (it does once the shutdown is requested).
    pub fn join(mut self) {
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Runs a trigger on its own thread, forwarding events into a channel (64 deep: a waiting
/// trigger blocks, the printer's signals wait in its own buffer). The thread ends when the
/// trigger ends, fails, panics (an error: [`TriggerError::Panicked`]), or `shutdown` is
/// requested; a thread that cannot start is an error too ([`TriggerError::Thread`]): neither is
/// the build's end. Every event's time goes into `health` (the one `Trigger::health` gave the
/// daemon's status: its "last signal"), whatever the backend.
pub fn spawn(mut trigger: Box<dyn Trigger>, health: SharedHealth, shutdown: Shutdown) -> Events {
    let (tx, rx) = crossbeam_channel::bounded(64);
    let ended = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let told = tx.clone();
    let thread_ended = ended.clone();
    let spawned = std::thread::Builder::new()
        .name("trigger".into())
        .spawn(move || {
            // Each message waits for room (or the shutdown): an error is never dropped.
            let send = |message: Result<LayerEvent, TriggerError>| {
                crossbeam_channel::select! {
                    send(tx, message) -> sent => sent.is_ok(),
                    recv(shutdown.receiver()) -> _ => false,
                }
            };
            let read = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| loop {
                match trigger.next_event(&shutdown) {
                    Ok(Some(event)) => {
                        health.signal(event.at);
                        if !send(Ok(event)) {
                            return;
                        }
                    }
                    Ok(None) => {
                        thread_ended.store(true, std::sync::atomic::Ordering::SeqCst);
                        return;
                    }
                    Err(e) => {
                        send(Err(e));
                        return;
                    }
                }
            }));
            if let Err(panic) = read {
                let message = crate::logging::panic_message(&*panic);
                send(Err(TriggerError::Panicked { message }));
            }
        });
    let thread = match spawned {
        Ok(thread) => Some(thread),
        Err(source) => {
            // The channel is empty: the error is its one message.
            let _ = told.try_send(Err(TriggerError::Thread { source }));
            None
        }
    };
    Events {
        receiver: rx,
        ended,
        thread,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_protocol_parses_signals_and_rejects_garbage() {
        let p = LineProtocol::default_protocol();
        assert_eq!(p.parse("LAYER 42 PRE"), Some((42, Phase::Pre)));
        assert_eq!(p.parse("  LAYER 7 POST "), Some((7, Phase::Post)));
        assert_eq!(p.parse("LAYER x PRE"), None);
        assert_eq!(p.parse("LAYER 99999999999999 PRE"), None);
        assert_eq!(p.parse("\u{fffd}\u{fffd}LAYER"), None);
    }

    #[test]
    fn custom_protocol_tokens() {
        let p =
            LineProtocol::new(r"^L(?P<layer>\d+):(?P<phase>\w+)$", "recoated", "exposed").unwrap();
        assert_eq!(p.parse("L3:recoated"), Some((3, Phase::Pre)));
        assert_eq!(p.parse("L3:EXPOSED"), Some((3, Phase::Post)));
        assert_eq!(p.parse("L3:other"), None);
        assert!(LineProtocol::new(r"(?P<layer>\d+)", "a", "b").is_err());
    }

    #[test]
    fn splitter_bounds_garbage() {
        let mut s = LineSplitter::default();
        let mut out = VecDeque::new();
        s.push(&vec![b'x'; 10_000], &mut out);
        s.push(b"\nLAYER 1 PRE\r\n", &mut out);
        assert_eq!(out, VecDeque::from(vec!["LAYER 1 PRE".to_string()]));
    }

    #[test]
    fn per_phase_counter_resumes() {
        let mut c = PulseCounter::new(GpioMode::PerPhase, 1);
        assert_eq!(c.on_pulse(Pulse::PreLine), Some((1, Phase::Pre)));
        assert_eq!(c.on_pulse(Pulse::PostLine), Some((1, Phase::Post)));
        assert_eq!(c.on_pulse(Pulse::PreLine), Some((2, Phase::Pre)));
        let mut resumed = PulseCounter::new(GpioMode::PerPhase, 1);
        resumed.resume_after(Some((2, Phase::Pre)));
        assert_eq!(resumed.on_pulse(Pulse::PostLine), Some((2, Phase::Post)));
        assert_eq!(resumed.on_pulse(Pulse::PreLine), Some((3, Phase::Pre)));
    }

    #[test]
    fn alternating_counter_resumes() {
        let mut c = PulseCounter::new(GpioMode::Alternating, 5);
        assert_eq!(c.on_pulse(Pulse::Line), Some((5, Phase::Pre)));
        assert_eq!(c.on_pulse(Pulse::Line), Some((5, Phase::Post)));
        assert_eq!(c.on_pulse(Pulse::Line), Some((6, Phase::Pre)));
        let mut resumed = PulseCounter::new(GpioMode::Alternating, 1);
        resumed.resume_after(Some((6, Phase::Post)));
        assert_eq!(resumed.on_pulse(Pulse::Line), Some((7, Phase::Pre)));
    }

    /// Gives `signals` layer signals, then ends as told.
    struct Scripted {
        signals: u32,
        then: fn() -> Result<Option<LayerEvent>, TriggerError>,
    }

    impl Trigger for Scripted {
        fn next_event(&mut self, _: &Shutdown) -> Result<Option<LayerEvent>, TriggerError> {
            if self.signals == 0 {
                return (self.then)();
            }
            self.signals -= 1;
            Ok(Some(LayerEvent {
                layer: 1,
                phase: Phase::Pre,
                at: DateTime::<Utc>::UNIX_EPOCH,
            }))
        }
    }

    /// What the thread of a trigger giving `signals` signals, then `then`, sends: the count of
    /// events, the error after them, and whether the trigger was lost.
    fn spawned(
        signals: u32,
        then: fn() -> Result<Option<LayerEvent>, TriggerError>,
    ) -> (usize, Option<String>, bool) {
        let trigger = Box::new(Scripted { signals, then });
        let events = spawn(trigger, SharedHealth::connected("test"), Shutdown::new());
        // Read once the thread has queued what it can (64 at most) and then ended, or, with the
        // queue full, waited 200 ms for room (the thread before dropped an error it could not
        // queue at once, and ended).
        let queued = 64.min(signals as usize + 1);
        let finished = |events: &Events| events.thread.as_ref().is_none_or(|t| t.is_finished());
        let wait = |until: std::time::Instant, done: &dyn Fn() -> bool| {
            while !done() && std::time::Instant::now() < until {
                std::thread::sleep(Duration::from_millis(1));
            }
        };
        let now = std::time::Instant::now();
        wait(now + Duration::from_secs(5), &|| {
            events.receiver().len() >= queued || finished(&events)
        });
        wait(
            std::time::Instant::now() + Duration::from_millis(200),
            &|| finished(&events),
        );
        let (mut count, mut error) = (0, None);
        for message in events.receiver().iter() {
            match message {
                Ok(_) => count += 1,
                Err(e) => error = Some(crate::logging::chain(&e)),
            }
        }
        let lost = events.lost().is_some();
        events.join();
        (count, error, lost)
    }

    #[test]
    fn a_trigger_that_ends_ends_its_events() {
        assert_eq!(spawned(3, || Ok(None)), (3, None, false));
    }

    #[test]
    fn a_trigger_that_panics_is_an_error_not_the_end_of_its_signals() {
        let (count, error, lost) = spawned(2, || panic!("a trigger that panics"));
        assert_eq!(count, 2);
        let error = error.expect("the panic is told");
        assert!(
            error.contains("panicked (a trigger that panics)"),
            "{error}"
        );
        // Before, the thread's end hung up the channel as a trigger's end does.
        assert!(lost);
    }

    #[test]
    fn a_trigger_error_behind_a_full_queue_is_not_dropped() {
        // 64 signals fill the channel before the error comes (before, it was tried once and
        // dropped: the hang-up then read as the build's end).
        let fails = || {
            Err(TriggerError::Script {
                path: "printer.txt".into(),
                line: 65,
                expected: "a signal",
                found: "x".into(),
            })
        };
        let (count, error, _) = spawned(64, fails);
        assert_eq!(count, 64);
        assert!(error.is_some_and(|e| e.contains("line 65")));
    }
}
