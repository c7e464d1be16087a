//! How the processing worker's takes end: each slice committed (fsync, rename), then the take
//! journaled, counted for its layer's line and told (the PACS wake), on a commit thread beside
//! the lanes, in the order the lanes handed them over; and what the queue and its worker share.

use super::layer_tally::{log_layers, LayerTally};
use crate::build_dir::{Journal, Record};
use crate::clock::SharedClock;
use crate::logging::Chain;
use crate::series::Then;
use crate::shot::Shot;
use crossbeam_channel::Sender;
use std::collections::BTreeSet;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::error;

/// What the queue and its worker share.
pub(super) struct QueueState {
    /// The takes stored and not processed yet: the queue's depth.
    pub(super) waiting: Waiting,
    /// The takes whose processing failed this run: a catch-up from the journal does not try
    /// them again (the same file fails the same way; the next start tries them), nor logs their
    /// layer's line a second time.
    pub(super) failed: Mutex<BTreeSet<(Shot, u32)>>,
    /// The takes the full disk left unwritten this run: the next catch-up processes them, with
    /// what the journal says is not processed.
    pub(super) again: Mutex<BTreeSet<(Shot, u32)>>,
    pub(super) overflowed: AtomicBool,
    /// Derived data waits (the disk is low).
    pub(super) paused: AtomicBool,
    /// A slice found the disk full (the worker paused itself): for the disk guard, which then
    /// holds the pause until the free space grows ([`super::disk::DiskGuard::derived_filled`]).
    pub(super) slice_found_disk_full: AtomicBool,
    /// Told each change of `paused` (a channel of one: changes coalesce).
    pub(super) pause_changed: Sender<()>,
    /// From submission to the end of processing, for the last frame processed.
    pub(super) lag_ms: AtomicU64,
    /// Told each time a slice is written.
    pub(super) written: Option<OnWritten>,
    /// Set by [`super::processing::ProcessingQueue::drain`]: the build ended, nothing more will
    /// be handed over.
    pub(super) build_over: AtomicBool,
}

impl QueueState {
    /// Nothing failed, paused or overflowed yet; `waiting`: the takes the worker starts with.
    pub(super) fn new(
        waiting: Waiting,
        pause_changed: Sender<()>,
        written: Option<OnWritten>,
    ) -> QueueState {
        QueueState {
            waiting,
            failed: Mutex::default(),
            again: Mutex::default(),
            overflowed: AtomicBool::new(false),
            paused: AtomicBool::new(false),
            slice_found_disk_full: AtomicBool::new(false),
            pause_changed,
            lag_ms: AtomicU64::new(0),
            written,
            build_over: AtomicBool::new(false),
        }
    }

    pub(super) fn set_paused(&self, paused: bool) -> bool {
        let was = self.paused.swap(paused, Ordering::SeqCst);
        if was != paused {
            let _ = self.pause_changed.try_send(());
        }
        was
    }

    pub(super) fn paused(&self) -> bool {
        self.paused.load(Ordering::SeqCst)
    }
}

/// The takes stored and not processed yet (queued, or waiting on disk for a catch-up), by shot
/// and take: a set, not a count, so that what the worker does more than once (a frame that
/// failed is tried again by each catch-up from the journal) or never (a first take a catch-up
/// skips for the shot's retake) leaves no phantom backlog, nor hides one.
#[derive(Default)]
pub(super) struct Waiting(Mutex<BTreeSet<(Shot, u32)>>);

impl Waiting {
    pub(super) fn new(takes: impl IntoIterator<Item = (Shot, u32)>) -> Waiting {
        Waiting(Mutex::new(takes.into_iter().collect()))
    }

    /// A take stored, to be processed.
    pub(super) fn add(&self, shot: Shot, take: u32) {
        if let Ok(mut waiting) = self.0.lock() {
            waiting.insert((shot, take));
        }
    }

    /// A take whose processing ended (its slice written, or failed; a retry of it later is not
    /// waited for), or that the worker let go of (processed already): it, and the shot's
    /// earlier takes its slice replaces, wait no more.
    pub(super) fn done(&self, shot: Shot, take: u32) {
        if let Ok(mut waiting) = self.0.lock() {
            let ended: Vec<_> = waiting.range((shot, 0)..=(shot, take)).copied().collect();
            for key in ended {
                waiting.remove(&key);
            }
        }
    }

    /// Lets go of every take the journal shows processed: a take handed over just after a
    /// catch-up processed it from its record would otherwise be counted again, and for good.
    pub(super) fn settle_with(&self, replay: &crate::build_dir::journal::Replay) {
        if let Ok(mut waiting) = self.0.lock() {
            waiting.retain(|(shot, take)| replay.slice_take(shot) < *take);
        }
    }

    pub(super) fn len(&self) -> usize {
        self.0.lock().map_or(0, |waiting| waiting.len())
    }

    /// Whether take `take` of `shot` still waits (not journaled yet).
    pub(super) fn holds(&self, shot: Shot, take: u32) -> bool {
        self.0
            .lock()
            .is_ok_and(|waiting| waiting.contains(&(shot, take)))
    }
}

/// Called, without blocking, each time a frame's slice is written (e.g. wakes the PACS push).
pub type OnWritten = Arc<dyn Fn() + Send + Sync>;

/// Whether an error (or one of its sources) is a write that found the disk full.
pub(super) fn disk_full(error: &crate::series::ProcessError) -> bool {
    let mut current: Option<&(dyn std::error::Error + 'static)> = Some(&**error);
    while let Some(e) = current {
        if e.downcast_ref::<std::io::Error>()
            .is_some_and(crate::fsutil::is_disk_full)
        {
            return true;
        }
        current = e.source();
    }
    false
}

/// The layers still open when the worker ends (stopped, drained, paused to the end) are told
/// then, whichever way it returns.
pub(super) struct TallyGuard<'a> {
    pub(super) tally: Mutex<LayerTally>,
    pub(super) state: &'a QueueState,
}

impl TallyGuard<'_> {
    /// A frame that will not be counted: the layer lines it held back.
    fn forget(&self, shot: &Shot) {
        if let Ok(mut open) = self.tally.lock() {
            log_layers(open.forget(shot), self.state.waiting.len());
        }
    }
}

impl Drop for TallyGuard<'_> {
    fn drop(&mut self) {
        if let Ok(mut open) = self.tally.lock() {
            log_layers(open.flush(), self.state.waiting.len());
        }
    }
}

/// A take whose slice's commit panicked: journaled as its failure.
#[derive(Debug, thiserror::Error)]
#[error("committing its slice panicked: {0}")]
struct CommitPanicked(String);

/// A take processed up to its slice's commit: the rest, or why it failed.
pub(super) struct Ended<'a> {
    pub(super) shot: Shot,
    pub(super) take: u32,
    /// When its processing began (the clock's monotonic time).
    pub(super) start: Duration,
    pub(super) outcome: Result<Then<'a>, crate::series::ProcessError>,
    pub(super) submitted: Option<Duration>,
}

/// What the commit thread is handed.
pub(super) enum Commit<'a> {
    Take(Ended<'a>),
    /// Told once everything handed over before it has ended.
    Settled(Sender<()>),
}

/// How takes end: their slices committed, the result journaled and counted for the layer's
/// line. On the worker's commit thread: the fsync waits for the disk there while the lanes
/// decode the next frames.
pub(super) struct Ends<'a> {
    pub(super) state: &'a QueueState,
    pub(super) journal: &'a Mutex<Journal>,
    pub(super) clock: &'a SharedClock,
    pub(super) tally: TallyGuard<'a>,
    pub(super) plant: &'a crate::plant::PlantSink,
}

/// Takes handed to the commit thread and not yet taken up, per lane, before a lane waits.
const COMMITS_PER_LANE: usize = 2;

impl<'a> Ends<'a> {
    /// Starts the commit thread in `scope`; its queue, or none if it cannot start.
    pub(super) fn start_committing<'scope>(
        &'a self,
        scope: &'scope std::thread::Scope<'scope, '_>,
    ) -> Option<Sender<Commit<'a>>>
    where
        'a: 'scope,
    {
        let lanes = rayon::current_num_threads().max(1);
        let (commits, queue) = crossbeam_channel::bounded(COMMITS_PER_LANE * lanes);
        let started = std::thread::Builder::new()
            .name("commit".into())
            .spawn_scoped(scope, move || {
                for commit in queue {
                    match commit {
                        Commit::Take(ended) => {
                            let (shot, take) = (ended.shot, ended.take);
                            let concluded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(
                                || self.commit(ended),
                            ));
                            if concluded.is_err() {
                                // Only concluding the take is left to panic here (a panic in
                                // its slice's commit is its failure, journaled). The thread goes
                                // on with the takes behind it; a take not journaled yet waits
                                // on disk for the next start (not a catch-up now, which could
                                // panic the same way, again and again), and its layer's line
                                // no longer waits for it.
                                error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, take, "processing: concluding the frame panicked");
                                if self.state.waiting.holds(shot, take) {
                                    self.tally.forget(&shot);
                                }
                            }
                        }
                        Commit::Settled(done) => {
                            let _ = done.send(());
                        }
                    }
                }
            });
        match started {
            Ok(_) => Some(commits),
            Err(e) => {
                error!(error = %e, "processing: cannot start the commit thread; each frame's slice is committed on its lane");
                None
            }
        }
    }

    /// Commits a take's slice (the rest of its processing), then concludes it. A panic in the
    /// commit is the take's failure, journaled with its message (the next start tries it again),
    /// as a panic before it is ([`super::processing`]).
    pub(super) fn commit(&self, ended: Ended<'_>) {
        let result = ended.outcome.and_then(|then| {
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(then)).unwrap_or_else(|panic| {
                let message = crate::logging::panic_message(&*panic);
                Err(Box::new(CommitPanicked(message)))
            })
        });
        self.conclude(ended.shot, ended.take, ended.start, result, ended.submitted);
    }

    /// Journals what processing one take gave, counts it for its layer's line.
    fn conclude(
        &self,
        shot: Shot,
        take: u32,
        start: Duration,
        result: Result<(), crate::series::ProcessError>,
        submitted: Option<Duration>,
    ) {
        let (state, clock) = (self.state, self.clock);
        let record = match result {
            Err(reason) if disk_full(&reason) => {
                // Not a failure of the frame: it waits (paused) and is caught up from the
                // journal once the disk has room again.
                error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, error = %Chain(&*reason), "processing: the disk is full; derived data paused, the frame waits");
                // The worker said so at once if the slice's write found it (not its commit).
                if !state.paused() {
                    state.slice_found_disk_full.store(true, Ordering::SeqCst);
                }
                state.set_paused(true);
                state.overflowed.store(true, Ordering::SeqCst);
                // The catch-up takes it again, even where the journal counts it processed (a
                // take processed again for the inspection a stop left undone).
                if let Ok(mut again) = state.again.lock() {
                    again.insert((shot, take));
                }
                // Its layer's line (and every later one) no longer waits for it.
                self.tally.forget(&shot);
                return;
            }
            Ok(()) if take > 1 => Record::SliceTake {
                layer: shot.layer,
                phase: shot.phase,
                light: shot.light,
                take,
                at: clock.now(),
            },
            Ok(()) => Record::Processed {
                layer: shot.layer,
                phase: shot.phase,
                light: shot.light,
                at: clock.now(),
            },
            Err(reason) => {
                let reason = crate::logging::chain(&*reason);
                error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, %reason, "processing failed; the original is kept");
                Record::ProcessingFailed {
                    layer: shot.layer,
                    phase: shot.phase,
                    light: shot.light,
                    take: Some(take),
                    reason,
                    at: clock.now(),
                }
            }
        };
        if let Ok(mut journal) = self.journal.lock() {
            if let Err(e) = journal.append(&record) {
                error!(error = %Chain(&e), "processing: cannot journal the result");
            }
        }
        // Before anything else: journaled, it waits no more and is counted for its layer's
        // line, whatever happens next (the callbacks after them).
        state.waiting.done(shot, take);
        let ok = !matches!(record, Record::ProcessingFailed { .. });
        if !ok {
            if let Ok(mut failed) = state.failed.lock() {
                failed.insert((shot, take));
            }
        }
        let end = clock.elapsed();
        let lag = submitted.map(|at| end.saturating_sub(at));
        if let Some(lag) = lag {
            state.lag_ms.store(lag.as_millis() as u64, Ordering::SeqCst);
        }
        if let Ok(mut open) = self.tally.tally.lock() {
            log_layers(open.add(&shot, ok, (start, end), lag), state.waiting.len());
        }
        if let (Some(written), Record::Processed { .. } | Record::SliceTake { .. }) =
            (&state.written, &record)
        {
            written();
        }
        self.plant.processed(end.saturating_sub(start), lag);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::journal::{Record, Replay};
    use crate::shot::{Light, Phase};

    #[test]
    fn a_frame_the_full_disk_left_for_the_catch_up_does_not_hold_the_layer_lines_after_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let (journal, _) = Journal::open(&path, false).unwrap();
        let (state, _changes) = queue_state(None);
        let ends = Ends {
            state: &state,
            journal: &Mutex::new(journal),
            clock: &crate::clock::SystemClock::shared(),
            tally: TallyGuard {
                tally: Mutex::new(LayerTally::new(2)),
                state: &state,
            },
            plant: &crate::plant::PlantSink::off(),
        };
        let full = || -> crate::series::ProcessError {
            Box::new(std::io::Error::from_raw_os_error(libc::ENOSPC))
        };
        let shots = [(1, Light::Front), (1, Light::Side), (2, Light::Front)]
            .map(|(layer, light)| Shot::new(layer, Phase::Post, light));
        for (k, shot) in shots.into_iter().enumerate() {
            ends.tally.tally.lock().unwrap().begin(&shot);
            let result = if k == 0 { Err(full()) } else { Ok(()) };
            ends.conclude(shot, 1, Duration::ZERO, result, None);
        }
        assert!(state.paused(), "derived data paused");
        assert!(
            state.slice_found_disk_full.load(Ordering::SeqCst),
            "said to the guard"
        );
        let again = state.again.lock().unwrap().clone();
        assert_eq!(again, BTreeSet::from([(shots[0], 1)]), "taken again");
        // Layer 1's line (one frame processed, one deferred) is logged; before, the deferred
        // frame stayed in flight for good and held every later layer's line.
        let open = ends.tally.tally.lock().unwrap().open_layers();
        assert_eq!(open, [(2, Phase::Post)]);
        // The catch-up processes it later: its line comes with the next complete layer.
        for shot in [shots[0], Shot::new(2, Phase::Post, Light::Side)] {
            ends.tally.tally.lock().unwrap().begin(&shot);
            ends.conclude(shot, 1, Duration::ZERO, Ok(()), None);
        }
        assert!(ends.tally.tally.lock().unwrap().open_layers().is_empty());
        let replay = Journal::read(&path).unwrap();
        assert!(replay.processed.contains(&shots[0]));
        assert_eq!(replay.processed.len(), 4);
    }

    fn queue_state(written: Option<OnWritten>) -> (QueueState, crossbeam_channel::Receiver<()>) {
        let (pause_changed, changes) = crossbeam_channel::bounded(1);
        let state = QueueState::new(Waiting::default(), pause_changed, written);
        (state, changes)
    }

    #[test]
    fn a_take_journaled_is_counted_for_its_layer_line_before_a_callback_can_panic() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let (journal, _) = Journal::open(&path, false).unwrap();
        let woken = AtomicBool::new(false);
        let wake = move || {
            assert!(
                woken.swap(true, Ordering::SeqCst),
                "a wake that panics once"
            )
        };
        let (state, _changes) = queue_state(Some(Arc::new(wake)));
        let ends = Ends {
            state: &state,
            journal: &Mutex::new(journal),
            clock: &crate::clock::SystemClock::shared(),
            tally: TallyGuard {
                tally: Mutex::new(LayerTally::new(1)),
                state: &state,
            },
            plant: &crate::plant::PlantSink::off(),
        };
        let shot = Shot::new(1, Phase::Post, Light::Top);
        state.waiting.add(shot, 1);
        ends.tally.tally.lock().unwrap().begin(&shot);
        let concluded = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            ends.conclude(shot, 1, Duration::ZERO, Ok(()), None)
        }));
        assert!(concluded.is_err());
        assert!(Journal::read(&path).unwrap().processed.contains(&shot));
        assert!(!state.waiting.holds(shot, 1));
        // Its layer's line is logged, so the next layer's comes as soon as it is processed:
        // before, the wake came first, and layer 1 stayed in flight, holding every later line.
        let next = Shot::new(2, Phase::Post, Light::Top);
        ends.tally.tally.lock().unwrap().begin(&next);
        ends.conclude(next, 1, Duration::ZERO, Ok(()), None);
        assert!(ends.tally.tally.lock().unwrap().open_layers().is_empty());
    }

    #[test]
    fn a_take_waits_until_it_or_a_later_take_of_its_shot_ends_or_the_journal_shows_it_processed() {
        let [a, b] = [Light::Front, Light::Side].map(|l| Shot::new(1, Phase::Post, l));
        let waiting = Waiting::new([(a, 1), (a, 2), (a, 3), (b, 1)]);
        // A later take's slice replaces the earlier ones': they wait no more.
        waiting.done(a, 2);
        assert_eq!(waiting.len(), 2);
        // Handed over after a catch-up processed it from its record: the journal lets it go,
        // and keeps what it does not show processed.
        waiting.add(b, 2);
        let mut replay = Replay::default();
        for record in [
            Record::Processed {
                layer: 1,
                phase: Phase::Post,
                light: Light::Side,
                at: chrono::Utc::now(),
            },
            Record::SliceTake {
                layer: 1,
                phase: Phase::Post,
                light: Light::Side,
                take: 2,
                at: chrono::Utc::now(),
            },
        ] {
            replay.apply(&record);
        }
        waiting.settle_with(&replay);
        assert_eq!(
            waiting.0.lock().unwrap().iter().collect::<Vec<_>>(),
            [&(a, 3)]
        );
    }
}
