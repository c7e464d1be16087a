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
    pub(super) overflowed: AtomicBool,
    /// Derived data waits (the disk is low).
    pub(super) paused: AtomicBool,
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
                            let committed = std::panic::catch_unwind(std::panic::AssertUnwindSafe(
                                || self.commit(ended),
                            ));
                            if committed.is_err() {
                                // The thread goes on with the takes behind it; this one waits
                                // on disk for the catch-up from the journal.
                                error!(layer = shot.layer, phase = %shot.phase, light = %shot.light, take, "processing: committing the frame's slice panicked; the frame waits on disk and is caught up");
                                self.state.overflowed.store(true, Ordering::SeqCst);
                                self.tally.forget(&shot);
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

    /// Commits a take's slice (the rest of its processing), then concludes it.
    pub(super) fn commit(&self, ended: Ended<'_>) {
        let result = ended.outcome.and_then(|then| then());
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
                state.set_paused(true);
                state.overflowed.store(true, Ordering::SeqCst);
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
        // Before anything else: journaled, it waits no more, whatever happens next.
        state.waiting.done(shot, take);
        if matches!(record, Record::ProcessingFailed { .. }) {
            if let Ok(mut failed) = state.failed.lock() {
                failed.insert((shot, take));
            }
        }
        if let (Some(written), Record::Processed { .. } | Record::SliceTake { .. }) =
            (&state.written, &record)
        {
            written();
        }
        let end = clock.elapsed();
        let lag = submitted.map(|at| end.saturating_sub(at));
        if let Some(lag) = lag {
            state.lag_ms.store(lag.as_millis() as u64, Ordering::SeqCst);
        }
        self.plant.processed(end.saturating_sub(start), lag);
        let ok = !matches!(record, Record::ProcessingFailed { .. });
        if let Ok(mut open) = self.tally.tally.lock() {
            log_layers(open.add(&shot, ok, (start, end), lag), state.waiting.len());
        }
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
        let (pause_changed, _changes) = crossbeam_channel::bounded(1);
        let state = QueueState {
            waiting: Waiting::default(),
            failed: Mutex::default(),
            overflowed: AtomicBool::new(false),
            paused: AtomicBool::new(false),
            pause_changed,
            lag_ms: AtomicU64::new(0),
            written: None,
            build_over: AtomicBool::new(false),
        };
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
