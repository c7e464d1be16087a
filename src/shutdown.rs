//! One way to stop. A [`Shutdown`] is requested once, with a [`StopReason`]; every thread of the
//! daemon holds a clone and sees the request the way its code waits:
//!
//! - blocking code selects on [`Shutdown::receiver`] beside its own channels (it is ready, with
//!   `Err(Disconnected)`, from the request on), or waits with [`Shutdown::wait`] on a timer of
//!   the clock (`clock.after(d)`), so a test's manual clock drives every timed wait;
//! - async code awaits [`Shutdown::requested`];
//! - anything checks [`Shutdown::reason`] between steps.
//!
//! A [`Shutdown::child`] stops when its parent does, with the parent's reason, and can also stop
//! alone: the process's shutdown (SIGTERM, SIGINT: [`watch_signals`]) is the parent of each build's
//! run, which also ends when its trigger ends or the operator ends the build. The model is
//! moonfire-nvr's `base/shutdown.rs`, with the reason carried and the clock's timers.

use crossbeam_channel::{Receiver, Sender};
use std::fmt;
use std::sync::{Arc, Mutex, Weak};
use std::time::Instant;

/// Why a run (or the process) stops.
#[derive(Clone, Debug)]
pub enum StopReason {
    /// The trigger has no more signals (a simulated printer's script ended).
    TriggerEnded,
    /// A Unix signal: systemd's stop (SIGTERM) or Ctrl-C (SIGINT).
    Terminated(TermSignal),
    /// The operator ended the build (`layerwise build stop`), or started the next one (its name).
    BuildStopped { next: Option<String> },
    /// An error that capture cannot go on after (its text, sources included, as the journal and
    /// the log show it).
    Failed(Arc<dyn std::error::Error + Send + Sync>),
}

/// The Unix signals that stop the daemon.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TermSignal {
    Term,
    Int,
}

impl StopReason {
    /// A failure, keeping the error and its sources.
    pub fn failed(error: impl std::error::Error + Send + Sync + 'static) -> StopReason {
        StopReason::Failed(Arc::new(error))
    }

    /// A failure, from an error that stays with its owner: its text and its sources' are kept,
    /// each on its own level of the chain.
    pub fn failure_of(error: &(dyn std::error::Error + 'static)) -> StopReason {
        StopReason::Failed(Arc::new(Captured::of(error)))
    }

    /// Whether the frames already taken are still to be processed before the run returns: the
    /// build ended normally (its trigger ended, or the operator moved on); not after a signal
    /// (systemd wants the process gone) or a failure.
    pub fn completes_the_build(&self) -> bool {
        matches!(
            self,
            StopReason::TriggerEnded | StopReason::BuildStopped { .. }
        )
    }
}

/// An error's message and its sources', copied.
#[derive(Debug)]
struct Captured {
    message: String,
    source: Option<Box<Captured>>,
}

impl Captured {
    fn of(error: &(dyn std::error::Error + 'static)) -> Captured {
        Captured {
            message: error.to_string(),
            source: error.source().map(|s| Box::new(Captured::of(s))),
        }
    }
}

impl fmt::Display for Captured {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for Captured {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        self.source
            .as_deref()
            .map(|s| s as &(dyn std::error::Error + 'static))
    }
}

/// The words the journal's stop record, the log and `status` show.
impl fmt::Display for StopReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StopReason::TriggerEnded => f.write_str("the trigger ended"),
            StopReason::Terminated(TermSignal::Term) => f.write_str("SIGTERM"),
            StopReason::Terminated(TermSignal::Int) => f.write_str("SIGINT"),
            StopReason::BuildStopped { next: None } => {
                f.write_str("the build was ended (layerwise build stop)")
            }
            StopReason::BuildStopped { next: Some(name) } => {
                write!(f, "the next build was started ({name})")
            }
            // The error with its sources, as `logging::Chain` writes them.
            StopReason::Failed(error) => {
                write!(f, "{error}")?;
                let mut source = error.source();
                while let Some(cause) = source {
                    write!(f, ": {cause}")?;
                    source = cause.source();
                }
                Ok(())
            }
        }
    }
}

struct Inner {
    reason: Mutex<Option<StopReason>>,
    /// Dropped on the request: every [`Shutdown::receiver`] becomes ready. Nothing is ever sent.
    hang_up: Mutex<Option<Sender<()>>>,
    receiver: Receiver<()>,
    /// Wakes the async waiters.
    notify: tokio::sync::Notify,
    children: Mutex<Vec<Weak<Inner>>>,
}

impl Inner {
    fn new() -> Inner {
        let (hang_up, receiver) = crossbeam_channel::bounded(0);
        Inner {
            reason: Mutex::new(None),
            hang_up: Mutex::new(Some(hang_up)),
            receiver,
            notify: tokio::sync::Notify::new(),
            children: Mutex::new(Vec::new()),
        }
    }

    fn request(&self, reason: StopReason) -> bool {
        {
            let mut slot = self.reason.lock().unwrap_or_else(|e| e.into_inner());
            if slot.is_some() {
                return false;
            }
            *slot = Some(reason.clone());
        }
        // The reason first, then the wakes: a waiter woken always finds it.
        drop(
            self.hang_up
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take(),
        );
        self.notify.notify_waiters();
        let children =
            std::mem::take(&mut *self.children.lock().unwrap_or_else(|e| e.into_inner()));
        for child in children.iter().filter_map(Weak::upgrade) {
            child.request(reason.clone());
        }
        true
    }

    fn reason(&self) -> Option<StopReason> {
        self.reason
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }
}

/// A request to stop, shared by every thread that must stop on it. Clones share one request.
#[derive(Clone)]
pub struct Shutdown {
    inner: Arc<Inner>,
}

impl fmt::Debug for Shutdown {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Shutdown")
            .field("reason", &self.reason())
            .finish()
    }
}

impl Default for Shutdown {
    fn default() -> Self {
        Shutdown::new()
    }
}

impl Shutdown {
    /// Not requested yet.
    pub fn new() -> Shutdown {
        Shutdown {
            inner: Arc::new(Inner::new()),
        }
    }

    /// A shutdown that is requested with this one's reason when this one is (at once, if it
    /// already was), and can be requested alone.
    pub fn child(&self) -> Shutdown {
        let child = Shutdown::new();
        {
            let mut children = self
                .inner
                .children
                .lock()
                .unwrap_or_else(|e| e.into_inner());
            children.retain(|c| c.strong_count() > 0);
            children.push(Arc::downgrade(&child.inner));
        }
        // Requested before the child was registered: the child stops too.
        if let Some(reason) = self.reason() {
            child.request(reason);
        }
        child
    }

    /// Asks every holder to stop; the first reason stands. Returns whether this was the first.
    pub fn request(&self, reason: StopReason) -> bool {
        self.inner.request(reason)
    }

    /// The reason, once requested.
    pub fn reason(&self) -> Option<StopReason> {
        self.inner.reason()
    }

    pub fn is_requested(&self) -> bool {
        self.reason().is_some()
    }

    /// For `crossbeam_channel::select!` beside a thread's own channels, and for
    /// `Clock::sleep_unless`: ready (with `Err(RecvError)`) from the request on; it never carries
    /// a message.
    pub fn receiver(&self) -> &Receiver<()> {
        &self.inner.receiver
    }

    /// Waits until `timer` fires (a clock's `after`: a manual clock's advance ends it); the
    /// reason when the stop was requested meanwhile (or before), None when the time ran out.
    pub fn wait(&self, timer: &Receiver<Instant>) -> Option<StopReason> {
        if let Some(reason) = self.reason() {
            return Some(reason);
        }
        crossbeam_channel::select! {
            recv(self.inner.receiver) -> _ => self.reason(),
            recv(timer) -> _ => self.reason(),
        }
    }

    /// Completes with the reason once the stop is requested.
    pub async fn requested(&self) -> StopReason {
        loop {
            let notified = self.inner.notify.notified();
            tokio::pin!(notified);
            // Registered before the check, so a request in between still wakes it.
            notified.as_mut().enable();
            if let Some(reason) = self.reason() {
                return reason;
            }
            notified.await;
        }
    }
}

/// SIGTERM and SIGINT request `shutdown` (`StopReason::Terminated`) from a thread of their own,
/// as long as the returned watch lives.
pub fn watch_signals(shutdown: &Shutdown) -> std::io::Result<SignalWatch> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGTERM, SIGINT])?;
    let handle = signals.handle();
    let shutdown = shutdown.clone();
    let thread = std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for signal in signals.forever() {
                let which = if signal == SIGINT {
                    TermSignal::Int
                } else {
                    TermSignal::Term
                };
                if shutdown.request(StopReason::Terminated(which)) {
                    tracing::info!(
                        "{}: finishing the frame in hand, then stopping",
                        StopReason::Terminated(which)
                    );
                }
            }
            // Its end of the wake-up pipe goes back to the watch, which drops it after `close`
            // wrote to the other end: a watch dropped before this thread ran must not write to
            // a closed pipe (SIGPIPE, whose default the binary keeps, would end the process).
            signals
        })?;
    Ok(SignalWatch {
        handle,
        thread: Some(thread),
    })
}

/// Watches SIGTERM and SIGINT until dropped. signal-hook keeps its handler after that (the
/// signals are then ignored), so a command keeps its watch until it ends.
pub struct SignalWatch {
    handle: signal_hook::iterator::Handle,
    thread: Option<std::thread::JoinHandle<signal_hook::iterator::Signals>>,
}

impl Drop for SignalWatch {
    fn drop(&mut self) {
        self.handle.close();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Set in the copy of this test binary that `a_watch_dropped_at_once_never_dies_of_sigpipe`
    /// runs.
    const SIGPIPE_CHILD: &str = "LAYERWISE_TEST_SIGPIPE_CHILD";

    /// The binary keeps SIGPIPE's default disposition (main.rs), and a command that fails right
    /// after `watch_signals` (`demo --listen` on a busy port) drops the watch before its thread
    /// ran: the wake-up written on close must not find the thread's end closed (the process would
    /// die of SIGPIPE without its error). Run in a copy of this test binary with SIGPIPE at its
    /// default, many times over, since the race is one of timing.
    #[test]
    fn a_watch_dropped_at_once_never_dies_of_sigpipe() {
        const NAME: &str = "shutdown::tests::a_watch_dropped_at_once_never_dies_of_sigpipe";
        if std::env::var_os(SIGPIPE_CHILD).is_some() {
            // SAFETY: restoring the default disposition of SIGPIPE, as main.rs does.
            unsafe {
                libc::signal(libc::SIGPIPE, libc::SIG_DFL);
            }
            // Dropped at different times after the thread was started, to meet it as it starts.
            for i in 0..2000u32 {
                let watch = watch_signals(&Shutdown::new()).unwrap();
                let started = Instant::now();
                while started.elapsed() < std::time::Duration::from_nanos(u64::from(i % 100) * 500)
                {
                    std::hint::spin_loop();
                }
                drop(watch);
            }
            return;
        }
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args(["--exact", NAME, "--test-threads", "1"])
            .env(SIGPIPE_CHILD, "1")
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "the copy ended with {:?} (signal {:?})",
            out.status.code(),
            std::os::unix::process::ExitStatusExt::signal(&out.status)
        );
        assert!(
            String::from_utf8_lossy(&out.stdout).contains("1 passed"),
            "the copy ran the test"
        );
    }

    #[test]
    fn the_first_reason_stands_and_every_clone_sees_it() {
        let shutdown = Shutdown::new();
        let other = shutdown.clone();
        assert!(shutdown.reason().is_none());
        assert!(other.receiver().try_recv().is_err());
        assert!(shutdown.request(StopReason::TriggerEnded));
        assert!(!other.request(StopReason::Terminated(TermSignal::Term)));
        assert_eq!(other.reason().unwrap().to_string(), "the trigger ended");
        // Ready from the request on, for select!.
        assert!(matches!(
            other.receiver().try_recv(),
            Err(crossbeam_channel::TryRecvError::Disconnected)
        ));
    }

    #[test]
    fn a_child_stops_with_its_parent_but_not_the_other_way() {
        let process = Shutdown::new();
        let run = process.child();
        let other_run = process.child();
        run.request(StopReason::BuildStopped { next: None });
        assert!(!process.is_requested());
        assert!(!other_run.is_requested());
        process.request(StopReason::Terminated(TermSignal::Int));
        assert_eq!(other_run.reason().unwrap().to_string(), "SIGINT");
        assert_eq!(
            run.reason().unwrap().to_string(),
            "the build was ended (layerwise build stop)",
            "its own reason stands"
        );
        // A child made after the request is stopped at once.
        assert_eq!(process.child().reason().unwrap().to_string(), "SIGINT");
    }

    #[test]
    fn a_blocking_wait_ends_on_its_timer_or_on_the_request() {
        let shutdown = Shutdown::new();
        let (waiter, requester) = (shutdown.clone(), shutdown.clone());
        // A timer as a clock makes it (`Clock::after`), fired by hand: nothing sleeps.
        let (fire, timer) = crossbeam_channel::bounded(1);
        let thread = std::thread::spawn(move || waiter.wait(&timer));
        fire.send(Instant::now()).unwrap();
        assert!(thread.join().unwrap().is_none(), "the timer fired first");

        let waiter = shutdown.clone();
        let (_never_fired, timer) = crossbeam_channel::bounded::<Instant>(1);
        let thread = std::thread::spawn(move || waiter.wait(&timer));
        requester.request(StopReason::failed(std::io::Error::other("disk gone")));
        assert_eq!(thread.join().unwrap().unwrap().to_string(), "disk gone");
    }

    #[test]
    fn an_async_wait_ends_on_the_request() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let shutdown = Shutdown::new();
        let requester = shutdown.clone();
        let reason = runtime.block_on(async move {
            let waiting = tokio::spawn(async move { shutdown.requested().await });
            tokio::task::yield_now().await;
            requester.request(StopReason::BuildStopped {
                next: Some("part B".into()),
            });
            waiting.await.unwrap()
        });
        assert_eq!(reason.to_string(), "the next build was started (part B)");
        assert!(reason.completes_the_build());
    }

    #[test]
    fn a_failure_keeps_its_sources_and_stops_without_completing() {
        #[derive(Debug, thiserror::Error)]
        #[error("cannot store the frame")]
        struct Outer(#[source] std::io::Error);
        let reason = StopReason::failed(Outer(std::io::Error::other("no space")));
        assert_eq!(reason.to_string(), "cannot store the frame: no space");
        let kept = Outer(std::io::Error::other("no space"));
        let copied = StopReason::failure_of(&kept);
        assert_eq!(copied.to_string(), "cannot store the frame: no space");
        let StopReason::Failed(error) = copied else {
            unreachable!()
        };
        assert_eq!(
            error.to_string(),
            "cannot store the frame",
            "one level each"
        );
        assert!(!reason.completes_the_build());
        assert!(!StopReason::Terminated(TermSignal::Term).completes_the_build());
    }
}
