//! Time as the library sees it: wall-clock timestamps, a monotonic reading, sleeping and
//! deadlines, all behind [`Clock`], so that tests drive time instead of waiting for it.
//!
//! [`SystemClock`] is the real one. [`ManualClock`] starts at a fixed instant and moves only when
//! told to: [`Clock::sleep`] on it returns at once, having advanced the clock, and
//! [`Clock::after`] fires when the clock passes the deadline. Retry back-offs, settle times and
//! call timeouts therefore cost a unit test no wall time.

use chrono::{DateTime, Utc};
use crossbeam_channel::Receiver;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Milliseconds since `started` on the monotonic clock: for timings that are reported (a
/// frame's steps, a download), never for decisions, which take a [`Clock`].
pub fn ms_since(started: Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}

/// A source of time.
pub trait Clock: Send + Sync {
    /// Wall-clock time (UTC): for records and file contents.
    fn now(&self) -> DateTime<Utc>;
    /// Monotonic time since an arbitrary fixed start: for durations and deadlines.
    fn elapsed(&self) -> Duration;
    /// Waits `duration` (a manual clock advances by it instead).
    fn sleep(&self, duration: Duration);
    /// A channel that receives once, when `duration` has passed.
    fn after(&self, duration: Duration) -> Receiver<Instant>;
    /// Waits `duration` as [`Clock::sleep`] does, unless `interrupt` is ready first (a message,
    /// or its senders gone: a `shutdown::Shutdown::receiver`). Returns whether it was
    /// interrupted.
    fn sleep_unless(&self, duration: Duration, interrupt: &Receiver<()>) -> bool;
}

/// A shared clock.
pub type SharedClock = Arc<dyn Clock>;

/// The real clock.
#[derive(Clone, Debug)]
pub struct SystemClock {
    start: Instant,
}

impl SystemClock {
    pub fn new() -> SystemClock {
        SystemClock {
            start: Instant::now(),
        }
    }

    /// The real clock, shared.
    pub fn shared() -> SharedClock {
        Arc::new(SystemClock::new())
    }
}

impl Default for SystemClock {
    fn default() -> Self {
        SystemClock::new()
    }
}

impl Clock for SystemClock {
    fn now(&self) -> DateTime<Utc> {
        Utc::now()
    }
    fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }
    fn sleep(&self, duration: Duration) {
        if !duration.is_zero() {
            std::thread::sleep(duration);
        }
    }
    fn after(&self, duration: Duration) -> Receiver<Instant> {
        crossbeam_channel::after(duration)
    }
    fn sleep_unless(&self, duration: Duration, interrupt: &Receiver<()>) -> bool {
        crossbeam_channel::select! {
            recv(interrupt) -> _ => true,
            default(duration) => false,
        }
    }
}

/// Exponential back-off: waits `initial`, then twice as long each time, at most `max`.
#[derive(Clone, Debug)]
pub struct Backoff {
    initial: Duration,
    max: Duration,
    current: Duration,
}

impl Backoff {
    pub fn new(initial: Duration, max: Duration) -> Backoff {
        Backoff {
            initial,
            max,
            current: initial,
        }
    }
    /// The next wait.
    pub fn current(&self) -> Duration {
        self.current
    }
    /// Waits the current period on `clock`, then doubles it (up to the maximum).
    pub fn wait(&mut self, clock: &dyn Clock) {
        clock.sleep(self.advance());
    }
    /// The current period, doubling it for next time (for a caller that waits on its own,
    /// e.g. interruptibly).
    pub fn advance(&mut self) -> Duration {
        let current = self.current;
        self.current = (self.current * 2).min(self.max.max(self.initial));
        current
    }
    /// Back to the initial period (after a success).
    pub fn reset(&mut self) {
        self.current = self.initial;
    }
}

#[derive(Debug)]
struct ManualState {
    elapsed: Duration,
    timers: Vec<(Duration, crossbeam_channel::Sender<Instant>)>,
}

/// A clock that moves only when advanced (or slept on): for tests.
#[derive(Clone, Debug)]
pub struct ManualClock {
    start: DateTime<Utc>,
    state: Arc<Mutex<ManualState>>,
}

impl ManualClock {
    /// A clock at `start` that moves only when advanced.
    pub fn starting_at(start: DateTime<Utc>) -> ManualClock {
        ManualClock {
            start,
            state: Arc::new(Mutex::new(ManualState {
                elapsed: Duration::ZERO,
                timers: Vec::new(),
            })),
        }
    }

    /// A clock at 2026-01-01T00:00:00Z.
    pub fn new() -> ManualClock {
        ManualClock::starting_at(
            DateTime::parse_from_rfc3339("2026-01-01T00:00:00Z")
                .map(|t| t.with_timezone(&Utc))
                .unwrap_or_default(),
        )
    }

    /// Moves the clock forward, firing every deadline it passes.
    pub fn advance(&self, by: Duration) {
        let Ok(mut state) = self.state.lock() else {
            return;
        };
        state.elapsed += by;
        let now = state.elapsed;
        state.timers.retain(|(deadline, tx)| {
            if *deadline <= now {
                let _ = tx.try_send(Instant::now());
                false
            } else {
                true
            }
        });
    }

    /// Deadlines not yet passed.
    pub fn pending_timers(&self) -> usize {
        self.state.lock().map(|s| s.timers.len()).unwrap_or(0)
    }
}

impl Default for ManualClock {
    fn default() -> Self {
        ManualClock::new()
    }
}

impl Clock for ManualClock {
    fn now(&self) -> DateTime<Utc> {
        let elapsed = self.elapsed();
        self.start + chrono::Duration::from_std(elapsed).unwrap_or_default()
    }
    fn elapsed(&self) -> Duration {
        self.state.lock().map(|s| s.elapsed).unwrap_or_default()
    }
    fn sleep(&self, duration: Duration) {
        self.advance(duration);
    }
    fn after(&self, duration: Duration) -> Receiver<Instant> {
        let (tx, rx) = crossbeam_channel::bounded(1);
        if let Ok(mut state) = self.state.lock() {
            let deadline = state.elapsed + duration;
            if duration.is_zero() {
                let _ = tx.try_send(Instant::now());
            } else {
                state.timers.push((deadline, tx));
            }
        }
        rx
    }
    /// Interrupted when `interrupt` is ready at the call; else the clock advances by `duration`
    /// at once, as [`Clock::sleep`] does.
    fn sleep_unless(&self, duration: Duration, interrupt: &Receiver<()>) -> bool {
        if !interrupt.is_empty()
            || matches!(
                interrupt.try_recv(),
                Err(crossbeam_channel::TryRecvError::Disconnected)
            )
        {
            return true;
        }
        self.advance(duration);
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_clock_moves_only_when_told() {
        let clock = ManualClock::new();
        let t0 = clock.now();
        assert_eq!(clock.now(), t0);
        clock.sleep(Duration::from_secs(90));
        assert_eq!(clock.elapsed(), Duration::from_secs(90));
        assert_eq!((clock.now() - t0).num_seconds(), 90);
    }

    #[test]
    fn manual_deadlines_fire_when_passed() {
        let clock = ManualClock::new();
        let timer = clock.after(Duration::from_millis(500));
        assert!(timer.try_recv().is_err());
        clock.advance(Duration::from_millis(499));
        assert!(timer.try_recv().is_err());
        clock.advance(Duration::from_millis(1));
        assert!(timer.try_recv().is_ok());
        assert_eq!(clock.pending_timers(), 0);
    }

    #[test]
    fn backoff_doubles_up_to_its_maximum_and_resets() {
        let clock = ManualClock::new();
        let mut backoff = Backoff::new(Duration::from_millis(250), Duration::from_secs(2));
        let mut waits = Vec::new();
        for _ in 0..6 {
            let before = clock.elapsed();
            backoff.wait(&clock);
            waits.push((clock.elapsed() - before).as_millis());
        }
        assert_eq!(waits, [250, 500, 1000, 2000, 2000, 2000]);
        backoff.reset();
        assert_eq!(backoff.current(), Duration::from_millis(250));
    }

    #[test]
    fn an_interruptible_sleep_ends_at_once_when_interrupted() {
        let (stop, interrupt) = crossbeam_channel::bounded::<()>(0);
        let manual = ManualClock::new();
        assert!(!manual.sleep_unless(Duration::from_secs(60), &interrupt));
        assert_eq!(
            manual.elapsed(),
            Duration::from_secs(60),
            "slept on the manual clock"
        );
        drop(stop);
        assert!(manual.sleep_unless(Duration::from_secs(60), &interrupt));
        assert_eq!(
            manual.elapsed(),
            Duration::from_secs(60),
            "interrupted: no time passed"
        );
        let system = SystemClock::new();
        assert!(system.sleep_unless(Duration::from_secs(3600), &interrupt));
    }

    #[test]
    fn system_clock_deadline_fires() {
        let clock = SystemClock::new();
        assert!(clock.after(Duration::ZERO).recv().is_ok());
    }
}
