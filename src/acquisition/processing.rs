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
use super::commit::{disk_full, Commit, Ended, Ends, QueueState, TallyGuard, Waiting};
use super::layer_tally::LayerTally;
use crate::build_dir::Journal;
use crate::clock::SharedClock;
use crate::logging::Chain;
pub use crate::series::{FrameProcessor, KeepOriginals, Then};
use crate::shot::{SeriesTake, Shot};
use crate::shutdown::{Shutdown, StopReason};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use rayon::prelude::*;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;
use tracing::{error, info};

/// A stored frame handed over: its shot, take (1: the frame, more: a retake), file, and when
/// (on the clock's monotonic time) it was.
type Item = (Shot, u32, PathBuf, Option<Duration>);

/// A take the journal names: its shot, take and the file its record names.
type Recorded = (Shot, u32, String);

pub struct ProcessingQueue {
    sender: Option<Sender<Item>>,
    state: Arc<QueueState>,
    /// Stops the worker after the frame in hand.
    stop: Shutdown,
    worker: Option<JoinHandle<()>>,
    /// Which take a retaken shot's slice shows: retakes are processed only with `Last`.
    take: SeriesTake,
    /// Asked for its faults ([`FrameProcessor::fault`]).
    processor: Arc<dyn FrameProcessor>,
}

/// A frame whose processing panicked: journaled as its failure (the original is kept, the next
/// start tries it again), and the worker goes on.
#[derive(Debug, thiserror::Error)]
#[error("its processing panicked: {0}")]
struct ProcessingPanicked(String);

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
        let waiting = Waiting::new(plan.backlog.iter().map(|(shot, take, _)| (*shot, *take)));
        let state = Arc::new(QueueState::new(waiting, pause_changed, written));
        let stop = Shutdown::new();
        let inbox = Inbox {
            frames,
            pause_changed: pause_changes,
            stop: stop.clone(),
        };
        let worker_state = state.clone();
        let worker_processor = processor.clone();
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
                        processor: worker_processor.as_ref(),
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
                    && worker_state.waiting.len() == 0;
                worker_processor.finish(ended);
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
            processor,
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
        self.state.waiting.add(shot, take);
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
        self.state.waiting.len()
    }

    /// What of the processor's own parts is at fault now ([`FrameProcessor::fault`]).
    pub fn fault(&self) -> Option<String> {
        self.processor.fault()
    }

    /// The processor, to ask for its faults once the queue is gone.
    pub(super) fn processor(&self) -> Arc<dyn FrameProcessor> {
        self.processor.clone()
    }

    /// How long the last frame processed waited from its capture to the end of its processing.
    pub fn lag(&self) -> Duration {
        Duration::from_millis(self.state.lag_ms.load(Ordering::SeqCst))
    }

    /// Pauses the derived data (the disk is low) or resumes it; on resuming, the frames left
    /// waiting are caught up from the journal.
    pub fn set_paused(&self, paused: bool) {
        let held = || self.state.slice_found_disk_full.load(Ordering::SeqCst);
        if !paused {
            // A slice found the disk full since the caller asked: its pause stays until the
            // disk guard has been told ([`ProcessingQueue::slice_found_disk_full`]).
            if held() {
                return;
            }
            // Set before the worker is woken, so it catches up.
            if self.state.paused() {
                self.state.overflowed.store(true, Ordering::SeqCst);
            }
        }
        self.state.set_paused(paused);
        // The worker says a full disk before it pauses: one said meanwhile pauses again.
        if !paused && held() {
            self.state.set_paused(true);
        }
    }

    pub fn paused(&self) -> bool {
        self.state.paused()
    }

    /// Whether a slice found the disk full since the last call (the worker paused itself).
    pub fn slice_found_disk_full(&self) -> bool {
        self.state
            .slice_found_disk_full
            .swap(false, Ordering::SeqCst)
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
        // The backlog's rest a pause left: the catch-up after it takes it with the journal's
        // (the journal alone would not name the takes a processor wants again).
        let mut left = Vec::new();
        for (i, (shot, take, original)) in backlog.iter().enumerate() {
            if inbox.stop.is_requested() {
                return false;
            }
            if state.paused() {
                info!(
                    frames = backlog.len() - i,
                    "processing: disk low, catching up later"
                );
                left = backlog[i..].to_vec();
                state.overflowed.store(true, Ordering::SeqCst);
                break;
            }
            self.process_recorded(*shot, *take, original);
        }
        // Shots a catch-up pass processed while they were still queued: skipped when they come
        // out.
        let mut caught_up = BTreeSet::new();
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
            // The queue overflowed, or a pause ended: what waits on disk is picked up from the
            // journal now, not once the next frame comes.
            if state.overflowed.swap(false, Ordering::SeqCst) {
                match self.catch_up(&inbox, &mut caught_up, &mut left, choice) {
                    CatchUp::Done => {}
                    CatchUp::Paused => state.overflowed.store(true, Ordering::SeqCst),
                    CatchUp::Stopped => return false,
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
        }
    }

    /// `first` and whatever else is queued, one frame per core.
    fn batch(&self, first: Item, frames: &Receiver<Item>, caught_up: &mut BTreeSet<(Shot, u32)>) {
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
        batch.retain(|(shot, take, _, _)| !self.processed_already(caught_up, *shot, *take));
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
    /// `left`: the start's backlog a pause interrupted, taken with the journal's takes and the
    /// takes the full disk left unwritten (one take per shot, the later); what of them an
    /// interruption leaves is kept there.
    fn catch_up(
        &self,
        inbox: &Inbox,
        caught_up: &mut BTreeSet<(Shot, u32)>,
        left: &mut Vec<Recorded>,
        choice: SeriesTake,
    ) -> CatchUp {
        // Taken out of the channel, to be processed in the journal's order. Each one is in the
        // journal (a frame is journaled before it is handed over).
        let mut queued = Vec::new();
        while let Ok(item) = inbox.frames.try_recv() {
            if !self.processed_already(caught_up, item.0, item.1) {
                queued.push(item);
            }
        }
        // The channel is drained, so nothing left in the set can still come out of it.
        caught_up.clear();
        // What is still being committed is not in the journal yet.
        self.settle();
        let again = self
            .state
            .again
            .lock()
            .map(|mut again| std::mem::take(&mut *again))
            .unwrap_or_default();
        let (mut pass, again) = self.unprocessed(choice, again);
        // Takes the journal counts processed that are wanted again: the start's backlog a
        // pause left, and the takes the full disk left unwritten.
        let held: BTreeSet<Recorded> = std::mem::take(left).into_iter().chain(again).collect();
        pass.extend(held.iter().cloned());
        pass.sort_by_key(|p| (p.0, std::cmp::Reverse(p.1)));
        pass.dedup_by(|a, b| a.0 == b.0);
        // The take the pass processes, per shot.
        let in_pass: std::collections::BTreeMap<Shot, u32> =
            pass.iter().map(|p| (p.0, p.1)).collect();
        for (i, (shot, take, recorded)) in pass.iter().cloned().enumerate() {
            if let Some(end) = self.interrupted(inbox) {
                left.extend(pass[i..].iter().filter(|p| held.contains(p)).cloned());
                return end;
            }
            match queued.iter().position(|q| q.0 == shot && q.1 == take) {
                Some(q) => {
                    let (_, _, original, at) = queued.remove(q);
                    self.process(shot, take, &original, at);
                }
                None => {
                    self.process_recorded(shot, take, &recorded);
                    caught_up.insert((shot, take));
                }
            }
        }
        // Queued takes the pass did not cover (the journal unreadable, or missing a record the
        // disk had no room for): in their order. An earlier take of a shot the pass processed is
        // left out (the pass took the take the series shows).
        for (shot, take, original, at) in queued {
            if in_pass.get(&shot).is_some_and(|&passed| take <= passed) {
                self.state.waiting.done(shot, take);
                continue;
            }
            if let Some(end) = self.interrupted(inbox) {
                return end;
            }
            self.process(shot, take, &original, at);
        }
        CatchUp::Done
    }

    /// Whether a take that came out of the queue was processed already by a catch-up pass (it is
    /// let go of: handed over after the pass found it in the journal, it was counted again).
    fn processed_already(
        &self,
        caught_up: &mut BTreeSet<(Shot, u32)>,
        shot: Shot,
        take: u32,
    ) -> bool {
        let already = caught_up.remove(&(shot, take));
        if already {
            self.state.waiting.done(shot, take);
        }
        already
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
    /// names, and those of `again` (the takes the full disk left unwritten) the same way; none
    /// if the journal cannot be read (said at ERROR; `again` is kept for the next catch-up).
    fn unprocessed(
        &self,
        choice: SeriesTake,
        again: BTreeSet<(Shot, u32)>,
    ) -> (Vec<Recorded>, Vec<Recorded>) {
        let keep = |again: BTreeSet<(Shot, u32)>| {
            if let Ok(mut kept) = self.state.again.lock() {
                kept.extend(again);
            }
            (Vec::new(), Vec::new())
        };
        // The path only: the recorder journals under the lock, and must not wait for the read.
        let Ok(path) = self.journal.lock().map(|j| j.path().to_path_buf()) else {
            return keep(again);
        };
        let replay = match Journal::read(&path) {
            Ok(replay) => replay,
            Err(e) => {
                error!(error = %Chain(&e), "processing: cannot read the journal to catch up");
                return keep(again);
            }
        };
        self.state.waiting.settle_with(&replay);
        let failed = self
            .state
            .failed
            .lock()
            .map(|f| f.clone())
            .unwrap_or_default();
        let recorded = |takes: Vec<(Shot, u32)>| -> Vec<Recorded> {
            takes
                .into_iter()
                .filter(|take| !failed.contains(take))
                .filter_map(|(shot, take)| {
                    let entry = replay.take_entry(&shot, take)?;
                    Some((shot, take, entry.file.clone()))
                })
                .collect()
        };
        (
            recorded(replay.unprocessed_takes(choice)),
            recorded(again.into_iter().collect()),
        )
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
        // A panic is this frame's failure, not the worker's end: on a lane it would end the
        // worker for good, and with it every later frame's slice, inspection and alarm.
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            processor.process_take_then(self.build_dir, shot, take, original)
        }))
        .unwrap_or_else(|panic| {
            let message = crate::logging::panic_message(&*panic);
            Err(Box::new(ProcessingPanicked(message)))
        });
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
            // the room the originals need with more slices meanwhile. The disk guard is told
            // first, so that it holds the pause rather than lift it at its next probe.
            self.state
                .slice_found_disk_full
                .store(true, Ordering::SeqCst);
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
mod tests;
