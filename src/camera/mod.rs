//! The camera: a trait with the real libgphoto2 backend and the mock, driven through an actor that
//! owns the camera on a dedicated thread (libgphoto2 calls block, and must never stall tokio), with
//! every call bounded by a timeout.

#[cfg(feature = "gphoto")]
pub mod gphoto;
pub mod mock;

use crate::config::CaptureConfig;
use std::collections::BTreeMap;
use std::time::{Duration, Instant};
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

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CameraError {
    /// The body is still busy with the previous frame (PTP 0x2019, Nikon 0xA2xx): try again.
    #[error("camera busy: {0}")]
    Busy(String),
    /// The camera answered too late but the call returned: try again.
    #[error("camera timed out: {0}")]
    Timeout(String),
    /// The USB device dropped: reopen, then try again.
    #[error("camera disconnected: {0}")]
    Disconnected(String),
    #[error("camera failed: {0}")]
    Failed(String),
    /// A call did not return within the bound: the thread is stuck in the driver.
    #[error("camera call did not return within {0:?}; the process must restart")]
    Hung(Duration),
    #[error("camera setting `{key}`: {message}")]
    Setting { key: String, message: String },
}

/// A camera body. Implementations need not be `Send`: the actor creates and keeps them on one thread.
pub trait Camera {
    /// Fires the shutter and downloads the frame, serialised: the next capture starts only after
    /// this frame is downloaded (Nikon bodies answer busy otherwise).
    fn capture(&mut self) -> Result<Frame, CameraError>;
    /// Closes and opens the device again after it dropped off USB.
    fn reopen(&mut self) -> Result<(), CameraError>;
    /// The settings in force, for the frame sidecars.
    fn settings(&self) -> BTreeMap<String, String>;
    /// Model and port, for logs.
    fn describe(&self) -> String;
}

enum Command {
    Capture(crossbeam_channel::Sender<Result<Frame, CameraError>>),
    Reopen(crossbeam_channel::Sender<Result<(), CameraError>>),
}

/// Owns a camera on a dedicated thread; each call waits for its reply at most `timeout`.
pub struct CameraActor {
    commands: crossbeam_channel::Sender<Command>,
    timeout: Duration,
    description: String,
    settings: BTreeMap<String, String>,
}

impl CameraActor {
    /// Opens the camera with `open` on a new thread.
    pub fn spawn<F>(open: F, timeout: Duration) -> Result<CameraActor, CameraError>
    where
        F: FnOnce() -> Result<Box<dyn Camera>, CameraError> + Send + 'static,
    {
        let (commands, inbox) = crossbeam_channel::bounded::<Command>(1);
        let (opened_tx, opened_rx) = crossbeam_channel::bounded(1);
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
                for command in inbox {
                    match command {
                        Command::Capture(reply) => {
                            let _ = reply.send(camera.capture());
                        }
                        Command::Reopen(reply) => {
                            let _ = reply.send(camera.reopen());
                        }
                    }
                }
            })
            .map_err(|e| CameraError::Failed(format!("cannot start the camera thread: {e}")))?;
        let (description, settings) = match opened_rx.recv_timeout(timeout) {
            Ok(result) => result?,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                return Err(CameraError::Hung(timeout))
            }
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => {
                return Err(CameraError::Failed(
                    "the camera thread ended while opening".into(),
                ))
            }
        };
        Ok(CameraActor {
            commands,
            timeout,
            description,
            settings,
        })
    }

    fn call<T>(
        &self,
        make: impl FnOnce(crossbeam_channel::Sender<Result<T, CameraError>>) -> Command,
    ) -> Result<T, CameraError> {
        let (tx, rx) = crossbeam_channel::bounded(1);
        self.commands
            .send_timeout(make(tx), self.timeout)
            .map_err(|_| CameraError::Hung(self.timeout))?;
        match rx.recv_timeout(self.timeout) {
            Ok(result) => result,
            Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                Err(CameraError::Hung(self.timeout))
            }
            Err(crossbeam_channel::RecvTimeoutError::Disconnected) => {
                Err(CameraError::Failed("the camera thread ended".into()))
            }
        }
    }

    pub fn capture(&self) -> Result<Frame, CameraError> {
        self.call(Command::Capture)
    }
    pub fn reopen(&self) -> Result<(), CameraError> {
        self.call(Command::Reopen)
    }
    pub fn describe(&self) -> &str {
        &self.description
    }
    pub fn settings(&self) -> &BTreeMap<String, String> {
        &self.settings
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

/// Why a frame could not be taken even after retries. `Hung` is fatal for the process.
#[derive(Debug, thiserror::Error)]
pub enum CaptureFailure {
    #[error("frame missing after {attempts} attempts: {last}")]
    Missing { attempts: u32, last: CameraError },
    #[error(transparent)]
    Hung(CameraError),
}

/// Captures one frame, retrying busy answers and timeouts with exponential backoff and reopening
/// a camera that dropped off USB. Returns the frame and the number of attempts it took.
pub fn capture_with_retries(
    actor: &CameraActor,
    policy: &RetryPolicy,
) -> Result<(Frame, u32), CaptureFailure> {
    let mut backoff = policy.backoff[0];
    let mut attempts = 0;
    loop {
        attempts += 1;
        let error = match actor.capture() {
            Ok(frame) => return Ok((frame, attempts)),
            Err(e @ CameraError::Hung(_)) => return Err(CaptureFailure::Hung(e)),
            Err(e) => e,
        };
        if attempts > policy.retries {
            return Err(CaptureFailure::Missing {
                attempts,
                last: error,
            });
        }
        warn!(attempt = attempts, error = %error, retry_in_ms = backoff.as_millis() as u64, "camera: capture failed, retrying");
        if let CameraError::Disconnected(_) = error {
            reopen(actor, policy, &mut backoff).map_err(|last| match last {
                e @ CameraError::Hung(_) => CaptureFailure::Hung(e),
                last => CaptureFailure::Missing { attempts, last },
            })?;
        } else {
            std::thread::sleep(backoff);
            backoff = (backoff * 2).min(policy.backoff[1]);
        }
    }
}

fn reopen(
    actor: &CameraActor,
    policy: &RetryPolicy,
    backoff: &mut Duration,
) -> Result<(), CameraError> {
    let mut last = CameraError::Disconnected("not reopened".into());
    for attempt in 1..=policy.reopen_attempts.max(1) {
        std::thread::sleep(*backoff);
        *backoff = (*backoff * 2).min(policy.backoff[1]);
        let started = Instant::now();
        match actor.reopen() {
            Ok(()) => {
                info!(
                    attempt,
                    ms = started.elapsed().as_millis() as u64,
                    camera = actor.describe(),
                    "camera: reopened"
                );
                return Ok(());
            }
            Err(e @ CameraError::Hung(_)) => return Err(e),
            Err(e) => {
                warn!(attempt, error = %e, "camera: reopen failed");
                last = e;
            }
        }
    }
    Err(last)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicU32, Ordering};
    use std::sync::Arc;

    /// A scripted body: answers from a list, then succeeds.
    struct Scripted {
        answers: Vec<Result<(), CameraError>>,
        calls: Arc<AtomicU32>,
        sleep: Duration,
    }

    impl Camera for Scripted {
        fn capture(&mut self) -> Result<Frame, CameraError> {
            self.calls.fetch_add(1, Ordering::SeqCst);
            std::thread::sleep(self.sleep);
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

    fn actor(
        answers: Vec<Result<(), CameraError>>,
        sleep: Duration,
        timeout: Duration,
    ) -> (CameraActor, Arc<AtomicU32>) {
        let calls = Arc::new(AtomicU32::new(0));
        let c = calls.clone();
        let actor = CameraActor::spawn(
            move || {
                Ok(Box::new(Scripted {
                    answers,
                    calls: c,
                    sleep,
                }) as Box<dyn Camera>)
            },
            timeout,
        )
        .unwrap();
        (actor, calls)
    }

    fn policy(retries: u32) -> RetryPolicy {
        RetryPolicy {
            retries,
            backoff: [Duration::from_millis(1), Duration::from_millis(4)],
            reopen_attempts: 2,
        }
    }

    #[test]
    fn busy_is_retried() {
        let busy = || Err(CameraError::Busy("0x2019".into()));
        let (actor, calls) = actor(
            vec![busy(), busy(), busy()],
            Duration::ZERO,
            Duration::from_secs(5),
        );
        let (_, attempts) = capture_with_retries(&actor, &policy(5)).unwrap();
        assert_eq!((attempts, calls.load(Ordering::SeqCst)), (4, 4));
    }

    #[test]
    fn retries_run_out_into_missing() {
        let answers = (0..10)
            .map(|_| Err(CameraError::Failed("x".into())))
            .collect();
        let (actor, _) = actor(answers, Duration::ZERO, Duration::from_secs(5));
        match capture_with_retries(&actor, &policy(2)) {
            Err(CaptureFailure::Missing { attempts: 3, .. }) => {}
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_hanging_call_is_reported_hung() {
        let (actor, _) = actor(
            vec![],
            Duration::from_millis(500),
            Duration::from_millis(50),
        );
        let started = Instant::now();
        match capture_with_retries(&actor, &policy(5)) {
            Err(CaptureFailure::Hung(CameraError::Hung(_))) => {}
            other => panic!("{other:?}"),
        }
        assert!(
            started.elapsed() < Duration::from_millis(400),
            "the caller must not wait for the hung call"
        );
    }

    #[test]
    fn open_failure_is_returned() {
        let result = CameraActor::spawn(
            || Err(CameraError::Disconnected("no camera on usb:".into())),
            Duration::from_secs(1),
        );
        assert!(matches!(result, Err(CameraError::Disconnected(_))));
    }
}
