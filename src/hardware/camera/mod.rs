//! The camera: a trait with the real libgphoto2 backend (the simulated one lives in `sim`), driven
//! through an actor that owns the camera on a dedicated thread (libgphoto2 calls block, and must
//! never stall tokio), with every call bounded by a timeout measured on the [`Clock`].

#[cfg(feature = "gphoto")]
pub mod gphoto;

use crate::clock::SharedClock;
use crate::config::CaptureConfig;
use crate::shot::Shot;
use std::collections::BTreeMap;
use std::time::Duration;
use tracing::{info, warn};

/// One frame as downloaded from the camera, untouched.
#[derive(Clone, Debug)]
pub struct Frame {
    pub data: Vec<u8>,
    /// File extension the camera gave the frame ("jpg", "nef", …), lower case.
    pub extension: String,
    pub capture_ms: f64,
    pub download_ms: f64,
}

#[derive(Clone, Debug, thiserror::Error)]
pub enum CameraError {
    /// The body is still busy with the previous frame (PTP 0x2019, Nikon 0xA2xx): try again.
    #[error("camera busy")]
    Busy(#[source] DriverError),
    /// The camera answered too late but the call returned: try again.
    #[error("camera timed out")]
    Timeout(#[source] DriverError),
    /// The USB device dropped: reopen, then try again.
    #[error("camera disconnected")]
    Disconnected(#[source] DriverError),
    #[error("camera failed")]
    Failed(#[source] DriverError),
    /// A call did not return within the bound: the thread is stuck in the driver.
    #[error("camera call did not return within {0:?}; the process must restart")]
    Hung(Duration),
    /// The camera's thread panicked in the driver's code (its message kept), or is gone: the
    /// camera is not called again.
    #[error("the camera's thread ended ({0}); the process must restart")]
    Lost(String),
    #[error("camera setting `{key}`: {message}")]
    Setting { key: String, message: String },
    /// The camera refused a setting.
    #[error("camera setting `{key}`{hint}")]
    SettingRefused {
        key: String,
        /// What to check, when there is something to say.
        hint: &'static str,
        #[source]
        source: DriverError,
    },
}

impl CameraError {
    /// Whether no later call can succeed in this process (hung in the driver, or its thread
    /// gone): the daemon exits for systemd to restart it.
    pub fn is_fatal(&self) -> bool {
        matches!(self, CameraError::Hung(_) | CameraError::Lost(_))
    }

    /// A fatal error in the words of the journal's missing record and the camera's health:
    /// "camera hung: …" or "camera lost: …".
    pub fn fatal_reason(&self) -> String {
        match self {
            CameraError::Lost(_) => format!("camera lost: {self}"),
            _ => format!("camera hung: {self}"),
        }
    }
}

/// What the camera's driver said: libgphoto2's error kept whole, or our own words where we are the
/// one who decides (the simulated camera, the camera thread ending). Cloned with the
/// [`CameraError`] that carries it (the actor's answers cross threads).
#[derive(Clone, Debug)]
pub struct DriverError(std::sync::Arc<dyn std::error::Error + Send + Sync>);

/// Words of ours, as an error.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
struct Said(String);

impl DriverError {
    /// Our own words.
    pub fn said(text: impl Into<String>) -> DriverError {
        DriverError(std::sync::Arc::new(Said(text.into())))
    }

    /// The driver's error, kept with its sources.
    pub fn of(error: impl std::error::Error + Send + Sync + 'static) -> DriverError {
        DriverError(std::sync::Arc::new(error))
    }
}

impl std::fmt::Display for DriverError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.0.fmt(f)
    }
}

impl std::error::Error for DriverError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.0.source()
    }
}

/// A camera body. Implementations need not be `Send`: the actor creates and keeps them on one thread.
pub trait Camera {
    /// Fires the shutter for `shot` and downloads the frame, serialised: the next capture starts
    /// only after this frame is downloaded (Nikon bodies answer busy otherwise).
    fn capture(&mut self, shot: &Shot) -> Result<Frame, CameraError>;
    /// Closes and opens the device again after it dropped off USB.
    fn reopen(&mut self) -> Result<(), CameraError>;
    /// The settings in force, for the frame sidecars.
    fn settings(&self) -> BTreeMap<String, String>;
    /// Model and port, for logs.
    fn describe(&self) -> String;
}

enum Command {
    Capture(Shot, crossbeam_channel::Sender<Result<Frame, CameraError>>),
    Reopen(crossbeam_channel::Sender<Result<(), CameraError>>),
}

impl Command {
    /// Answers the command with `error`, without calling the camera.
    fn fail(self, error: CameraError) {
        // The caller gave up waiting if the reply has nowhere to go.
        match self {
            Command::Capture(_, reply) => drop(reply.send(Err(error))),
            Command::Reopen(reply) => drop(reply.send(Err(error))),
        }
    }
}

/// Owns a camera on a dedicated thread; each call waits for its reply at most `timeout`.
pub struct CameraActor {
    commands: crossbeam_channel::Sender<Command>,
    timeout: Duration,
    clock: SharedClock,
    description: String,
    settings: BTreeMap<String, String>,
}

/// A panic on the camera's thread, said at ERROR: the words of [`CameraError::Lost`].
fn panicked(panic: Box<dyn std::any::Any + Send>) -> String {
    let message = crate::logging::panic_message(&*panic);
    tracing::error!(%message, "camera: its thread panicked in the driver's code");
    format!("panicked: {message}")
}

impl CameraActor {
    /// Opens the camera with `open` on a new thread; every call (opening too) is bounded by
    /// `timeout` on `clock`.
    pub fn spawn<F>(
        open: F,
        timeout: Duration,
        clock: SharedClock,
    ) -> Result<CameraActor, CameraError>
    where
        F: FnOnce() -> Result<Box<dyn Camera>, CameraError> + Send + 'static,
    {
        let (commands, inbox) = crossbeam_channel::bounded::<Command>(1);
        let (opened_tx, opened_rx) = crossbeam_channel::bounded(1);
        let deadline = clock.after(timeout);
        std::thread::Builder::new()
            .name("camera".into())
            .spawn(move || {
                let mut camera = match open() {
                    Ok(camera) => {
                        let _ = opened_tx.send(Ok((camera.describe(), camera.settings())));
                        camera
                    }
                    Err(e) => {
                        let _ = opened_tx.send(Err(e));
                        return;
                    }
                };
                // After a panic the camera is not called again: its caller and every later one
                // are told why (not that the call hung), until the actor is dropped.
                let mut lost: Option<String> = None;
                for command in inbox {
                    if let Some(why) = &lost {
                        command.fail(CameraError::Lost(why.clone()));
                        continue;
                    }
                    let mut call = std::panic::AssertUnwindSafe(&mut camera);
                    let mut lose = |panic| CameraError::Lost(lost.insert(panicked(panic)).clone());
                    match command {
                        Command::Capture(shot, reply) => {
                            let result = std::panic::catch_unwind(move || call.capture(&shot));
                            let _ = reply.send(result.unwrap_or_else(|panic| Err(lose(panic))));
                        }
                        Command::Reopen(reply) => {
                            let result = std::panic::catch_unwind(move || call.reopen());
                            let _ = reply.send(result.unwrap_or_else(|panic| Err(lose(panic))));
                        }
                    }
                }
            })
            .map_err(|e| CameraError::Failed(DriverError::of(CameraThread(e))))?;
        let (description, settings) = match wait(&opened_rx, deadline) {
            Waited::Answer(result) => result?,
            Waited::TimedOut => return Err(CameraError::Hung(timeout)),
            Waited::Gone => {
                return Err(CameraError::Failed(DriverError::said(
                    "the camera thread ended while opening",
                )))
            }
        };
        Ok(CameraActor {
            commands,
            timeout,
            clock,
            description,
            settings,
        })
    }

    fn call<T>(
        &self,
        make: impl FnOnce(crossbeam_channel::Sender<Result<T, CameraError>>) -> Command,
    ) -> Result<T, CameraError> {
        let (tx, rx) = crossbeam_channel::bounded(1);
        // The deadline runs from before the camera thread can see the command.
        let deadline = self.clock.after(self.timeout);
        self.commands
            .send_timeout(make(tx), self.timeout)
            .map_err(|e| match e {
                crossbeam_channel::SendTimeoutError::Timeout(_) => CameraError::Hung(self.timeout),
                crossbeam_channel::SendTimeoutError::Disconnected(_) => {
                    CameraError::Lost("it is gone".into())
                }
            })?;
        match wait(&rx, deadline) {
            Waited::Answer(result) => result,
            Waited::TimedOut => Err(CameraError::Hung(self.timeout)),
            Waited::Gone => Err(CameraError::Lost("it ended without answering".into())),
        }
    }

    pub fn capture(&self, shot: &Shot) -> Result<Frame, CameraError> {
        let shot = *shot;
        tracing::debug!(layer = shot.layer, phase = %shot.phase, light = %shot.light, camera = %self.description, "camera: capture");
        let result = self.call(move |reply| Command::Capture(shot, reply));
        match &result {
            Ok(frame) => tracing::debug!(
                bytes = frame.data.len(),
                capture_ms = frame.capture_ms,
                download_ms = frame.download_ms,
                "camera: frame downloaded"
            ),
            Err(e) => tracing::debug!(error = %e, "camera: capture failed"),
        }
        result
    }
    pub fn reopen(&self) -> Result<(), CameraError> {
        tracing::debug!(camera = %self.description, "camera: reopen");
        self.call(Command::Reopen)
    }
    pub fn describe(&self) -> &str {
        &self.description
    }
    pub fn settings(&self) -> &BTreeMap<String, String> {
        &self.settings
    }
    /// The clock the actor measures its timeouts on.
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }
}

enum Waited<T> {
    Answer(T),
    TimedOut,
    Gone,
}

/// Waits for the camera thread's answer until `deadline` fires.
fn wait<T>(
    rx: &crossbeam_channel::Receiver<T>,
    deadline: crossbeam_channel::Receiver<std::time::Instant>,
) -> Waited<T> {
    crossbeam_channel::select! {
        recv(rx) -> answer => match answer {
            Ok(answer) => Waited::Answer(answer),
            Err(_) => Waited::Gone,
        },
        recv(deadline) -> _ => Waited::TimedOut,
    }
}

/// Retries and reopening around a capture.
#[derive(Clone, Debug)]
pub struct RetryPolicy {
    pub retries: u32,
    pub backoff: [Duration; 2],
    pub reopen_attempts: u32,
}

impl RetryPolicy {
    pub fn from_config(config: &CaptureConfig) -> RetryPolicy {
        RetryPolicy {
            retries: config.retries,
            backoff: [
                Duration::from_millis(config.retry_backoff_ms[0]),
                Duration::from_millis(config.retry_backoff_ms[1]),
            ],
            reopen_attempts: config.reopen_attempts,
        }
    }
}

/// The camera thread could not be started.
#[derive(Debug, thiserror::Error)]
#[error("cannot start the camera thread")]
struct CameraThread(#[source] std::io::Error);

/// Why a frame could not be taken even after retries. `Hung` is fatal for the process.
#[derive(Debug, thiserror::Error)]
pub enum CaptureFailure {
    #[error("frame missing after {attempts} attempts")]
    Missing {
        attempts: u32,
        #[source]
        last: CameraError,
    },
    /// Hung, or its thread lost ([`CameraError::is_fatal`]).
    #[error(transparent)]
    Hung(CameraError),
}

/// Captures one frame, retrying busy answers and timeouts with exponential backoff and reopening
/// a camera that dropped off USB. Returns the frame and the number of attempts it took.
pub fn capture_with_retries(
    actor: &CameraActor,
    policy: &RetryPolicy,
    shot: &Shot,
) -> Result<(Frame, u32), CaptureFailure> {
    let mut backoff = policy.backoff[0];
    let mut attempts = 0;
    loop {
        attempts += 1;
        let error = match actor.capture(shot) {
            Ok(frame) => return Ok((frame, attempts)),
            Err(e) if e.is_fatal() => return Err(CaptureFailure::Hung(e)),
            Err(e) => e,
        };
        if attempts > policy.retries {
            return Err(CaptureFailure::Missing {
                attempts,
                last: error,
            });
        }
        warn!(attempt = attempts, error = %crate::logging::Chain(&error), retry_in_ms = backoff.as_millis() as u64, "camera: capture failed, retrying");
        if let CameraError::Disconnected(_) = error {
            reopen(actor, policy, &mut backoff).map_err(|last| match last {
                e if e.is_fatal() => CaptureFailure::Hung(e),
                last => CaptureFailure::Missing { attempts, last },
            })?;
        } else {
            actor.clock().sleep(backoff);
            backoff = (backoff * 2).min(policy.backoff[1]);
        }
    }
}

fn reopen(
    actor: &CameraActor,
    policy: &RetryPolicy,
    backoff: &mut Duration,
) -> Result<(), CameraError> {
    let mut last = CameraError::Disconnected(DriverError::said("not reopened"));
    for attempt in 1..=policy.reopen_attempts.max(1) {
        actor.clock().sleep(*backoff);
        *backoff = (*backoff * 2).min(policy.backoff[1]);
        let started = actor.clock().elapsed();
        match actor.reopen() {
            Ok(()) => {
                info!(
                    attempt,
                    ms = actor.clock().elapsed().saturating_sub(started).as_millis() as u64,
                    camera = actor.describe(),
                    "camera: reopened"
                );
                return Ok(());
            }
            Err(e) if e.is_fatal() => return Err(e),
            Err(e) => {
                warn!(attempt, error = %crate::logging::Chain(&e), "camera: reopen failed");
                last = e;
            }
        }
    }
    Err(last)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::{Clock, ManualClock};
    use crate::shot::{Light, Phase};
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::sync::Arc;

    /// A scripted body: answers from a list, then succeeds; `hang` makes every capture block
    /// until the body is dropped (a driver stuck in a USB call).
    struct Scripted {
        answers: Vec<Result<(), CameraError>>,
        calls: Arc<AtomicU32>,
        hang: Option<crossbeam_channel::Receiver<()>>,
    }

    impl Camera for Scripted {
        fn capture(&mut self, _shot: &Shot) -> Result<Frame, CameraError> {
            self.calls.fetch_add(1, Ordering::SeqCst);
            if let Some(hang) = &self.hang {
                let _ = hang.recv();
            }
            if !self.answers.is_empty() {
                self.answers.remove(0)?;
            }
            Ok(Frame {
                data: vec![1, 2, 3],
                extension: "jpg".into(),
                capture_ms: 0.0,
                download_ms: 0.0,
            })
        }
        fn reopen(&mut self) -> Result<(), CameraError> {
            Ok(())
        }
        fn settings(&self) -> BTreeMap<String, String> {
            BTreeMap::new()
        }
        fn describe(&self) -> String {
            "scripted".into()
        }
    }

    const SHOT: Shot = Shot {
        layer: 1,
        phase: Phase::Post,
        light: Light::Top,
    };

    fn actor(
        answers: Vec<Result<(), CameraError>>,
        hang: Option<crossbeam_channel::Receiver<()>>,
        timeout: Duration,
        clock: &ManualClock,
    ) -> (CameraActor, Arc<AtomicU32>) {
        let calls = Arc::new(AtomicU32::new(0));
        let c = calls.clone();
        let actor = CameraActor::spawn(
            move || {
                Ok(Box::new(Scripted {
                    answers,
                    calls: c,
                    hang,
                }) as Box<dyn Camera>)
            },
            timeout,
            Arc::new(clock.clone()),
        )
        .unwrap();
        (actor, calls)
    }

    fn policy(retries: u32) -> RetryPolicy {
        RetryPolicy {
            retries,
            backoff: [Duration::from_millis(100), Duration::from_millis(400)],
            reopen_attempts: 2,
        }
    }

    #[test]
    fn busy_is_retried_with_backoff() {
        let clock = ManualClock::new();
        let busy = || Err(CameraError::Busy(DriverError::said("0x2019")));
        let answers = vec![busy(), busy(), busy()];
        let (actor, calls) = actor(answers, None, Duration::from_secs(5), &clock);
        let (_, attempts) = capture_with_retries(&actor, &policy(5), &SHOT).unwrap();
        assert_eq!((attempts, calls.load(Ordering::SeqCst)), (4, 4));
        // 100 + 200 + 400 ms of backoff, on the clock and not on the wall.
        assert_eq!(clock.elapsed(), Duration::from_millis(700));
    }

    #[test]
    fn retries_run_out_into_missing() {
        let clock = ManualClock::new();
        let answers = (0..10)
            .map(|_| Err(CameraError::Failed(DriverError::said("x"))))
            .collect();
        let (actor, _) = actor(answers, None, Duration::from_secs(5), &clock);
        match capture_with_retries(&actor, &policy(2), &SHOT) {
            Err(CaptureFailure::Missing { attempts: 3, .. }) => {}
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_hanging_call_is_reported_hung() {
        let clock = ManualClock::new();
        let (_release, hang) = crossbeam_channel::bounded::<()>(0);
        let timeout = Duration::from_secs(30);
        let (actor, calls) = actor(vec![], Some(hang), timeout, &clock);
        // Once the body is stuck in the call, 30 s go by in an instant.
        let driver = {
            let clock = clock.clone();
            std::thread::spawn(move || {
                while calls.load(Ordering::SeqCst) == 0 {
                    std::thread::yield_now();
                }
                clock.advance(timeout);
            })
        };
        match capture_with_retries(&actor, &policy(5), &SHOT) {
            Err(CaptureFailure::Hung(CameraError::Hung(t))) => assert_eq!(t, timeout),
            other => panic!("{other:?}"),
        }
        driver.join().unwrap();
    }

    /// A body whose driver code panics on capture.
    struct Panics;

    impl Camera for Panics {
        fn capture(&mut self, _shot: &Shot) -> Result<Frame, CameraError> {
            panic!("a driver that panics")
        }
        fn reopen(&mut self) -> Result<(), CameraError> {
            Ok(())
        }
        fn settings(&self) -> BTreeMap<String, String> {
            BTreeMap::new()
        }
        fn describe(&self) -> String {
            "panics".into()
        }
    }

    #[test]
    fn a_camera_thread_that_panics_is_lost_not_hung_and_not_retried() {
        let clock = Arc::new(ManualClock::new());
        let open = || Ok(Box::new(Panics) as Box<dyn Camera>);
        let actor = CameraActor::spawn(open, Duration::from_secs(30), clock.clone()).unwrap();
        // The caller is told the panic's message at once, without retries.
        match capture_with_retries(&actor, &policy(5), &SHOT) {
            Err(CaptureFailure::Hung(e @ CameraError::Lost(_))) => {
                let reason = e.fatal_reason();
                assert!(reason.starts_with("camera lost: "), "{reason}");
                assert!(reason.contains("a driver that panics"), "{reason}");
            }
            other => panic!("{other:?}"),
        }
        // The camera is not called again: the next call says why at once (before, "did not
        // return within 30 s").
        match actor.capture(&SHOT) {
            Err(CameraError::Lost(why)) => assert!(why.contains("a driver that panics"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert_eq!(clock.elapsed(), Duration::ZERO, "no backoff, no timeout");
    }

    #[test]
    fn open_failure_is_returned() {
        let result = CameraActor::spawn(
            || {
                Err(CameraError::Disconnected(DriverError::said(
                    "no camera on usb:",
                )))
            },
            Duration::from_secs(1),
            Arc::new(ManualClock::new()),
        );
        assert!(matches!(result, Err(CameraError::Disconnected(_))));
    }
}
