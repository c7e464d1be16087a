//! Processing of stored frames (rectification and DICOM) behind a bounded queue of references.
//! Capture never waits for it: when the queue is full, frames simply wait on disk and the worker
//! finds them again from the journal once it has caught up. While the disk is low the worker is
//! paused (derived data waits; originals come first) and catches up from the journal afterwards.
//!
//! The worker waits on its channels, never on a timer: a frame handed over, a change of pause
//! (`set_paused`), its stop (a [`Shutdown`] requested by [`ProcessingQueue::stop`]), or the
//! sequencer hanging up ([`ProcessingQueue::drain`]: everything handed over is processed first).
//!
//! It runs one frame per core (its lanes), each up to its slice written beside its place
//! ([`FrameProcessor::process_take_then`]); a commit thread beside it makes each slice durable
//! and puts it in place, then journals the take, in the order the lanes handed them over, while
//! the lanes go on with the next frames instead of waiting for the disk's fsync.

pub use super::commit::OnWritten;
use super::commit::{disk_full, Commit, Ended, Ends, QueueState, TallyGuard};
use super::layer_tally::LayerTally;
use crate::build_dir::Journal;
use crate::clock::SharedClock;
use crate::logging::Chain;
pub use crate::series::{FrameProcessor, KeepOriginals, Then};
use crate::shot::{SeriesTake, Shot};
use crate::shutdown::{Shutdown, StopReason};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tracing::{error, info};

/// A stored frame handed over: its shot, take (1: the frame, more: a retake), file, and when
/// (on the clock's monotonic time) it was.
type Item = (Shot, u32, PathBuf, Option<Duration>);

pub struct ProcessingQueue {
    sender: Option<Sender<Item>>,
    state: Arc<QueueState>,
    /// Stops the worker after the frame in hand.
    stop: Shutdown,
    worker: Option<JoinHandle<()>>,
    /// Which take a retaken shot's slice shows: retakes are processed only with `Last`.
    take: SeriesTake,
}

/// What the worker starts with, and how the build's frames come.
pub struct WorkerPlan {
    /// The frames the journal says are not processed yet, with their take and file
    /// ([`crate::build_dir::journal::Replay::unprocessed_takes`]).
    pub backlog: Vec<(Shot, u32, String)>,
    /// Whether retakes replace their slice.
    pub take: SeriesTake,
    /// The frames of one layer signal (the lights of a phase): a layer's line is logged once
    /// they are processed.
    pub frames_per_signal: usize,
    /// Told how long each frame took (the processing histograms of `/metrics`).
    pub plant: crate::plant::PlantSink,
}

/// The worker's channels.
struct Inbox {
    frames: Receiver<Item>,
    pause_changed: Receiver<()>,
    stop: Shutdown,
}

impl ProcessingQueue {
    /// Starts the worker on `plan`'s backlog.
    pub fn start(
        processor: Arc<dyn FrameProcessor>,
        capacity: usize,
        build_dir: PathBuf,
        journal: Arc<Mutex<Journal>>,
        plan: WorkerPlan,
        clock: SharedClock,
        written: Option<OnWritten>,
    ) -> ProcessingQueue {
        let take = plan.take;
        let (sender, frames) = crossbeam_channel::bounded(capacity);
        let (pause_changed, pause_changes) = crossbeam_channel::bounded(1);
        let state = Arc::new(QueueState {
            depth: AtomicUsize::new(plan.backlog.len()),
            overflowed: AtomicBool::new(false),
            paused: AtomicBool::new(false),
            pause_changed,
            lag_ms: AtomicU64::new(0),
            written,
            build_over: AtomicBool::new(false),
        });
        let stop = Shutdown::new();
        let inbox = Inbox {
            frames,
            pause_changed: pause_changes,
            stop: stop.clone(),
        };
        let worker_state = state.clone();
        let worker = std::thread::Builder::new()
            .name("processing".into())
            .spawn(move || {
                let ends = Ends {
                    state: &worker_state,
                    journal: &journal,
                    clock: &clock,
                    tally: TallyGuard {
                        tally: Mutex::new(LayerTally::new(plan.frames_per_signal)),
                        state: &worker_state,
                    },
                    plant: &plan.plant,
                };
                let drained = std::thread::scope(|scope| {
                    let worker = Worker {
                        processor: processor.as_ref(),
                        state: &worker_state,
                        build_dir: &build_dir,
                        journal: &journal,
                        clock: &clock,
                        ends: &ends,
                        commits: ends.start_committing(scope),
                    };
                    worker.run(inbox, plan.backlog, plan.take)
                    // The worker dropped here hangs up on the commit thread: it commits what
                    // it was handed, and the scope waits for it.
                });
                // A processor with threads of its own (the inspection's alarm) stops them now;
                // at the build's end, with every frame processed (the worker drained, not
                // stopped or paused, and no frame counted as still to come), what waits for
                // frames that will not come is completed first.
                let ended = worker_state.build_over.load(Ordering::SeqCst)
                    && drained
                    && worker_state.depth.load(Ordering::SeqCst) == 0;
                processor.finish(ended);
            })
            .map_err(
                |e| error!(error = %e, "processing: cannot start the worker; frames stay on disk"),
            )
            .ok();
        ProcessingQueue {
            sender: Some(sender),
            state,
            stop,
            worker,
            take,
        }
    }

    /// Hands a stored frame over without ever blocking; `now` is the clock's monotonic time.
    pub fn submit(&self, shot: Shot, original: PathBuf, now: Duration) {
        self.submit_take(shot, 1, original, now);
    }

    /// Hands take `take` of a stored frame over without ever blocking: a retake (take > 1)
    /// only when it replaces the slice (`[series] take = "last"`).
    pub fn submit_take(&self, shot: Shot, take: u32, original: PathBuf, now: Duration) {
        if take > 1 && self.take != SeriesTake::Last {
            return;
        }
        self.state.depth.fetch_add(1, Ordering::SeqCst);
        let Some(sender) = &self.sender else { return };
        match sender.try_send((shot, take, original, Some(now))) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) | Err(TrySendError::Disconnected(_)) => {
                self.state.overflowed.store(true, Ordering::SeqCst);
            }
        }
    }

    /// Frames stored but not processed yet (in the queue or waiting on disk).
    pub fn depth(&self) -> usize {
        self.state.depth.load(Ordering::SeqCst)
    }

    /// How long the last frame processed waited from its capture to the end of its processing.
    pub fn lag(&self) -> Duration {
        Duration::from_millis(self.state.lag_ms.load(Ordering::SeqCst))
    }

    /// Pauses the derived data (the disk is low) or resumes it; on resuming, the frames left
    /// waiting are caught up from the journal.
    pub fn set_paused(&self, paused: bool) {
        if !paused {
            // Set before the worker is woken, so it catches up.
            if self.state.paused() {
                self.state.overflowed.store(true, Ordering::SeqCst);
            }
        }
        self.state.set_paused(paused);
    }

    pub fn paused(&self) -> bool {
        self.state.paused()
    }

    /// At the build's end: waits until every submitted frame is processed, then stops the
    /// worker (the processor is told the build is over). A worker paused for disk space stops
    /// at once: its frames wait on disk for the next start.
    pub fn drain(mut self) {
        self.state.build_over.store(true, Ordering::SeqCst);
        self.sender.take();
        self.join();
    }

    /// Stops after the frame in hand; the rest stays on disk for the next start.
    pub fn stop(mut self, reason: StopReason) {
        self.stop.request(reason);
        self.sender.take();
        self.join();
    }

    fn join(&mut self) {
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

/// The processing thread's work.
struct Worker<'a> {
    processor: &'a dyn FrameProcessor,
    state: &'a QueueState,
    build_dir: &'a Path,
    journal: &'a Mutex<Journal>,
    clock: &'a SharedClock,
    /// How a take ends.
    ends: &'a Ends<'a>,
    /// The commit thread's queue; none if it could not start (each take then ends on its lane).
    commits: Option<Sender<Commit<'a>>>,
}

/// How a catch-up pass from the journal ended.
enum CatchUp {
    Done,
    /// Paused for disk space: what is left waits on disk.
    Paused,
    Stopped,
}

impl<'a> Worker<'a> {
    /// The backlog, then what is handed over, until stopped, or hung up and done; whether it
    /// drained (hung up with nothing left waiting on disk), not stopped or paused.
    fn run(&self, inbox: Inbox, backlog: Vec<(Shot, u32, String)>, choice: SeriesTake) -> bool {
        let state = self.state;
        if !backlog.is_empty() {
            info!(
                frames = backlog.len(),
                "processing: catching up on frames stored before the restart"
            );
        }
        for (i, (shot, take, original)) in backlog.iter().enumerate() {
            if inbox.stop.is_requested() {
                return false;
            }
            if state.paused() {
                // The rest waits on disk; the catch-up after the pause finds it in the journal.
                info!(
                    frames = backlog.len() - i,
                    "processing: disk low, catching up later"
                );
                state.overflowed.store(true, Ordering::SeqCst);
                break;
            }
            self.process_recorded(*shot, *take, original);
        }
        // Shots a catch-up pass processed while they were still queued: skipped when they come
        // out.
        let mut caught_up = std::collections::BTreeSet::new();
        loop {
            if inbox.stop.is_requested() {
                return false;
            }
            if state.paused() {
                crossbeam_channel::select! {
                    recv(inbox.pause_changed) -> _ => {}
                    recv(inbox.stop.receiver()) -> _ => return false,
                    recv(inbox.frames) -> item => match item {
                        // It waits on disk and is caught up from the journal after the pause.
                        Ok(_) => state.overflowed.store(true, Ordering::SeqCst),
                        // Hung up while paused: the frames wait on disk for the next start.
                        Err(_) => return false,
                    },
                }
                continue;
            }
            crossbeam_channel::select! {
                recv(inbox.frames) -> first => match first {
                    Ok(first) => self.batch(first, &inbox.frames, &mut caught_up),
                    Err(_) => {
                        if !state.overflowed.load(Ordering::SeqCst) {
                            return true;
                        }
                    }
                },
                recv(inbox.pause_changed) -> _ => {}
                recv(inbox.stop.receiver()) -> _ => return false,
            }
            // The queue overflowed: once it is empty, pick up what waits on disk from the journal.
            if !state.paused() && state.overflowed.swap(false, Ordering::SeqCst) {
                match self.catch_up(&inbox, &mut caught_up, choice) {
                    CatchUp::Done => {}
                    CatchUp::Paused => state.overflowed.store(true, Ordering::SeqCst),
                    CatchUp::Stopped => return false,
                }
            }
        }
    }

    /// `first` and whatever else is queued, one frame per core.
    fn batch(
        &self,
        first: Item,
        frames: &Receiver<Item>,
        caught_up: &mut std::collections::BTreeSet<(Shot, u32)>,
    ) {
        // One frame per core at a time: decoding a frame is single-threaded, so a second frame
        // keeps the other core busy.
        let mut batch = vec![first];
        while batch.len() < rayon::current_num_threads().max(1) {
            match frames.try_recv() {
                Ok(item) => batch.push(item),
                Err(_) => break,
            }
        }
        if self.state.paused() {
            // Paused while waiting: these wait on disk and are caught up from the journal after
            // the pause.
            self.state.overflowed.store(true, Ordering::SeqCst);
            return;
        }
        batch.retain(|(shot, take, _, _)| !caught_up.remove(&(*shot, *take)));
        // The takes of one shot in order (a retake's slice replaces the first's), shots in
        // parallel.
        batch.sort_by_key(|(shot, take, _, _)| (*shot, *take));
        batch
            .chunk_by(|a, b| a.0 == b.0)
            .collect::<Vec<_>>()
            .par_iter()
            .for_each(|takes| {
                for (shot, take, original, at) in takes.iter() {
                    self.process(*shot, *take, original, *at);
                }
            });
    }

    /// Every frame the journal says is not processed, in build order, the queued ones among
    /// them too: a frame that overflowed the queue is older than the frames queued after it,
    /// and a layer's views must come before a later layer's, or the inspection would take the
    /// later layer's completion for the end of the earlier one's and inspect it without the
    /// views still waiting on disk.
    fn catch_up(
        &self,
        inbox: &Inbox,
        caught_up: &mut std::collections::BTreeSet<(Shot, u32)>,
        choice: SeriesTake,
    ) -> CatchUp {
        // Taken out of the channel, to be processed in the journal's order. Each one is in the
        // journal (a frame is journaled before it is handed over).
        let mut queued = Vec::new();
        while let Ok(item) = inbox.frames.try_recv() {
            if !caught_up.remove(&(item.0, item.1)) {
                queued.push(item);
            }
        }
        // The channel is drained, so nothing left in the set can still come out of it.
        caught_up.clear();
        // What is still being committed is not in the journal yet.
        self.settle();
        let pass = self.unprocessed(choice);
        let in_pass: std::collections::BTreeSet<Shot> = pass.iter().map(|p| p.0).collect();
        for (shot, take, recorded) in pass {
            if let Some(end) = self.interrupted(inbox) {
                return end;
            }
            match queued.iter().position(|q| q.0 == shot && q.1 == take) {
                Some(i) => {
                    let (_, _, original, at) = queued.remove(i);
                    self.process(shot, take, &original, at);
                }
                None => {
                    self.process_recorded(shot, take, &recorded);
                    caught_up.insert((shot, take));
                }
            }
        }
        // Queued takes the pass did not cover (the journal unreadable): in their order. A take
        // of a shot the pass processed is left out (the pass took the take the series shows).
        for (shot, take, original, at) in queued {
            if in_pass.contains(&shot) {
                continue;
            }
            if let Some(end) = self.interrupted(inbox) {
                return end;
            }
            self.process(shot, take, &original, at);
        }
        CatchUp::Done
    }

    /// How a catch-up ends early: stopped, or paused (what is left waits on disk; the journal
    /// finds it after the pause).
    fn interrupted(&self, inbox: &Inbox) -> Option<CatchUp> {
        if inbox.stop.is_requested() {
            Some(CatchUp::Stopped)
        } else if self.state.paused() {
            Some(CatchUp::Paused)
        } else {
            None
        }
    }

    /// The takes the journal says are not processed, in build order, with the file each record
    /// names; none if the journal cannot be read (said at ERROR).
    fn unprocessed(&self, choice: SeriesTake) -> Vec<(Shot, u32, String)> {
        // The path only: the recorder journals under the lock, and must not wait for the read.
        let Ok(path) = self.journal.lock().map(|j| j.path().to_path_buf()) else {
            return Vec::new();
        };
        let replay = match Journal::read(&path) {
            Ok(replay) => replay,
            Err(e) => {
                error!(error = %Chain(&e), "processing: cannot read the journal to catch up");
                return Vec::new();
            }
        };
        replay
            .unprocessed_takes(choice)
            .into_iter()
            .filter_map(|(shot, take)| {
                let entry = replay.take_entry(&shot, take)?;
                Some((shot, take, entry.file.clone()))
            })
            .collect()
    }

    /// Processes the take a journal record names: only its own file in `raw/`
    /// (build_dir::original); a record naming anything else is a failure of the frame,
    /// journaled as such.
    fn process_recorded(&self, shot: Shot, take: u32, recorded: &str) {
        match crate::build_dir::original::recorded_path(self.build_dir, &shot, take, recorded) {
            Ok(original) => self.process(shot, take, &original, None),
            Err(refused) => self.end(Ended {
                shot,
                take,
                start: self.clock.elapsed(),
                outcome: Err(Box::new(refused)),
                submitted: None,
            }),
        }
    }

    /// Processes one take up to its slice's commit, and hands the rest to the commit thread.
    fn process(&self, shot: Shot, take: u32, original: &Path, submitted: Option<Duration>) {
        // Its layer's line waits for it while other lanes finish later layers.
        if let Ok(mut tally) = self.ends.tally.tally.lock() {
            tally.begin(&shot);
        }
        let start = self.clock.elapsed();
        let processor: &'a dyn FrameProcessor = self.processor;
        let outcome = processor.process_take_then(self.build_dir, shot, take, original);
        self.end(Ended {
            shot,
            take,
            start,
            outcome,
            submitted,
        });
    }

    /// Hands a take's end to the commit thread (in the order of the hand-overs), or ends it here
    /// without one.
    fn end(&self, ended: Ended<'a>) {
        if matches!(&ended.outcome, Err(reason) if disk_full(reason)) {
            // Paused at once, not once the commit thread comes to it: the lanes must not fill
            // the room the originals need with more slices meanwhile.
            self.state.set_paused(true);
            self.state.overflowed.store(true, Ordering::SeqCst);
        }
        let unsent = match &self.commits {
            Some(commits) => match commits.send(Commit::Take(ended)) {
                Ok(()) => return,
                Err(crossbeam_channel::SendError(Commit::Take(ended))) => ended,
                Err(_) => return,
            },
            None => ended,
        };
        self.ends.commit(unsent);
    }

    /// Waits until every take handed to the commit thread is journaled (before the journal is
    /// read for what is not processed).
    fn settle(&self) {
        if let Some(commits) = &self.commits {
            let (done, settled) = crossbeam_channel::bounded(1);
            if commits.send(Commit::Settled(done)).is_ok() {
                let _ = settled.recv();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::series::ProcessError;
    use crate::shot::{Light, Phase};

    /// Tells each take processed and each commit; the first shot's commit waits to be
    /// released.
    struct Gated {
        events: Sender<String>,
        release: Receiver<()>,
        held: Shot,
    }

    impl FrameProcessor for Gated {
        fn process(&self, _: &Path, shot: Shot, _: &Path) -> Result<(), ProcessError> {
            self.process_take_then(Path::new("."), shot, 1, Path::new("."))?()
        }

        fn process_take_then(
            &self,
            _: &Path,
            shot: Shot,
            _: u32,
            _: &Path,
        ) -> Result<Then<'_>, ProcessError> {
            self.events.send(format!("processed {}", shot.light))?;
            Ok(Box::new(move || {
                if shot == self.held {
                    self.release.recv()?;
                }
                self.events.send(format!("committed {}", shot.light))?;
                Ok(())
            }))
        }
    }

    /// A commit that panics for the front view.
    #[derive(Default)]
    struct PanicsOnFront {
        finished: AtomicBool,
    }

    impl FrameProcessor for PanicsOnFront {
        fn finish(&self, _ended: bool) {
            self.finished.store(true, Ordering::SeqCst);
        }

        fn process(&self, _: &Path, _: Shot, _: &Path) -> Result<(), ProcessError> {
            Ok(())
        }

        fn process_take_then(
            &self,
            _: &Path,
            shot: Shot,
            _: u32,
            _: &Path,
        ) -> Result<Then<'_>, ProcessError> {
            Ok(Box::new(move || {
                assert!(shot.light != Light::Front, "a commit that panics");
                Ok(())
            }))
        }
    }

    fn queue(processor: Arc<dyn FrameProcessor>, dir: &Path) -> ProcessingQueue {
        let (journal, _) = Journal::open(&dir.join(crate::build_dir::JOURNAL), false).unwrap();
        queue_on(processor, dir, 8, Arc::new(Mutex::new(journal)))
    }

    fn queue_on(
        processor: Arc<dyn FrameProcessor>,
        dir: &Path,
        capacity: usize,
        journal: Arc<Mutex<Journal>>,
    ) -> ProcessingQueue {
        ProcessingQueue::start(
            processor,
            capacity,
            dir.to_path_buf(),
            journal,
            WorkerPlan {
                backlog: Vec::new(),
                take: SeriesTake::First,
                frames_per_signal: 2,
                plant: crate::plant::PlantSink::off(),
            },
            crate::clock::SystemClock::shared(),
            None,
        )
    }

    #[test]
    fn a_commit_that_panics_leaves_its_frame_unjournaled_and_the_next_ones_go_on() {
        let dir = tempfile::tempdir().unwrap();
        let processor = Arc::new(PanicsOnFront::default());
        let queue = queue(processor.clone(), dir.path());
        let shots = [Light::Front, Light::Side, Light::Top].map(|l| Shot::new(1, Phase::Pre, l));
        for shot in shots {
            queue.submit(shot, dir.path().join("x.jpg"), Duration::ZERO);
        }
        queue.drain();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        // The front frame is neither processed nor failed: it waits for the catch-up.
        assert_eq!(
            Journal::read(&path)
                .unwrap()
                .processed
                .into_iter()
                .collect::<Vec<_>>(),
            shots[1..].to_vec()
        );
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().count(), 2, "{text}");
        // The worker ended as it should (the alarm's flush ran), not by the panic.
        assert!(processor.finished.load(Ordering::SeqCst));
    }

    /// Records what the worker's end told it.
    #[derive(Default)]
    struct TellsTheEnd {
        ended: Mutex<Option<bool>>,
    }

    impl FrameProcessor for TellsTheEnd {
        fn finish(&self, ended: bool) {
            *self.ended.lock().unwrap() = Some(ended);
        }

        fn process(&self, _: &Path, _: Shot, _: &Path) -> Result<(), ProcessError> {
            Ok(())
        }
    }

    #[test]
    fn only_a_queue_drained_at_the_build_end_tells_the_processor_the_build_ended() {
        let shot = Shot::new(1, Phase::Pre, Light::Top);
        for drained in [true, false] {
            let dir = tempfile::tempdir().unwrap();
            let processor = Arc::new(TellsTheEnd::default());
            let queue = queue(processor.clone(), dir.path());
            queue.submit(shot, dir.path().join("x.jpg"), Duration::ZERO);
            if drained {
                queue.drain();
            } else {
                queue.stop(StopReason::Terminated(crate::shutdown::TermSignal::Term));
            }
            assert_eq!(*processor.ended.lock().unwrap(), Some(drained));
        }
    }

    #[test]
    fn a_lane_goes_on_while_a_slice_commits_and_the_journal_waits_for_the_commit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let (events, told) = crossbeam_channel::unbounded();
        let (release, released) = crossbeam_channel::unbounded();
        let (front, side) = (
            Shot::new(1, Phase::Post, Light::Front),
            Shot::new(1, Phase::Post, Light::Side),
        );
        let processor = Gated {
            events,
            release: released,
            held: front,
        };
        let queue = queue(Arc::new(processor), dir.path());
        let next = || told.recv_timeout(Duration::from_secs(10)).unwrap();
        let journaled = || Journal::read(&path).unwrap().processed;

        queue.submit(front, dir.path().join("a.jpg"), Duration::ZERO);
        assert_eq!(next(), "processed front");
        // The front slice's commit waits; the side frame is processed meanwhile (in the code
        // before the commit thread the worker was held here, and this timed out).
        queue.submit(side, dir.path().join("b.jpg"), Duration::ZERO);
        assert_eq!(next(), "processed side");
        // Neither is journaled before its commit (the side's comes after the front's).
        assert!(journaled().is_empty());
        assert_eq!(queue.depth(), 2);

        release.send(()).unwrap();
        assert_eq!(next(), "committed front");
        assert_eq!(next(), "committed side");
        // Draining waits for the commits and their records.
        queue.drain();
        assert_eq!(
            journaled().into_iter().collect::<Vec<_>>(),
            vec![front, side]
        );
        let text = std::fs::read_to_string(&path).unwrap();
        let (at_front, at_side) = (text.find("front").unwrap(), text.find("side").unwrap());
        assert!(at_front < at_side, "journaled in the order handed over");
    }

    /// Tells each take as its processing starts; the held shots wait to be released first.
    struct Held {
        events: Sender<Shot>,
        release: Receiver<()>,
        held: Vec<Shot>,
    }

    /// All its work before the commit: the defaults leave the commit nothing to do.
    impl FrameProcessor for Held {
        fn process(&self, _: &Path, shot: Shot, _: &Path) -> Result<(), ProcessError> {
            self.events.send(shot)?;
            if self.held.contains(&shot) {
                self.release.recv()?;
            }
            Ok(())
        }
    }

    #[test]
    fn a_frame_that_overflowed_the_queue_is_processed_before_the_frames_queued_after_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let (journal, _) = Journal::open(&path, false).unwrap();
        let journal = Arc::new(Mutex::new(journal));
        let shots = [
            (1, Light::Front),
            (1, Light::Side),
            (1, Light::Top),
            (2, Light::Front),
        ]
        .map(|(layer, light)| Shot::new(layer, Phase::Post, light));
        let (events, told) = crossbeam_channel::unbounded();
        let (release, released) = crossbeam_channel::unbounded();
        let processor = Held {
            events,
            release: released,
            held: shots[..2].to_vec(),
        };
        let queue = queue_on(Arc::new(processor), dir.path(), 1, journal.clone());
        let next = || told.recv_timeout(Duration::from_secs(10)).unwrap();
        // Journaled, then handed over, as the recorder does.
        let store = |shot: Shot| {
            let file = format!("raw/{}.jpg", shot.take_stem(1));
            let record = crate::build_dir::journal::Record::Frame {
                layer: shot.layer,
                phase: shot.phase,
                light: shot.light,
                file: file.clone(),
                bytes: 1,
                sha256: String::new(),
                at: chrono::Utc::now(),
            };
            journal.lock().unwrap().append(&record).unwrap();
            queue.submit(shot, dir.path().join(file), Duration::ZERO);
        };

        store(shots[0]);
        assert_eq!(next(), shots[0]);
        // Layer 1's side view waits in the queue (one place); its top view overflows it and
        // waits on disk.
        store(shots[1]);
        store(shots[2]);
        release.send(()).unwrap();
        // The catch-up takes the side view; layer 2's front view is stored meanwhile, and the
        // queue has room for it.
        assert_eq!(next(), shots[1]);
        store(shots[3]);
        release.send(()).unwrap();
        // Layer 1's top view comes before layer 2's front view (the code before took the queue
        // first: layer 2 came before it, and the inspection took layer 1 as done without it).
        assert_eq!(next(), shots[2]);
        assert_eq!(next(), shots[3]);
        queue.drain();
        assert!(told.try_recv().is_err(), "each frame processed once");
        assert_eq!(Journal::read(&path).unwrap().processed.len(), 4);
    }
}
