//! The queue and its worker: commits, the build's end, catch-ups and what it counts as waiting.

use super::*;
use crate::series::ProcessError;
use crate::shot::{Light, Phase};
use std::sync::atomic::AtomicBool;

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

/// Panics for the front view: in its commit, or (`early`) in its processing before it.
#[derive(Default)]
struct PanicsOnFront {
    finished: AtomicBool,
    early: bool,
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
        let front = shot.light == Light::Front;
        assert!(!(self.early && front), "a frame whose processing panics");
        Ok(Box::new(move || {
            assert!(!front, "a commit that panics");
            Ok(())
        }))
    }
}

#[test]
fn a_frame_whose_processing_panics_is_journaled_failed_and_the_worker_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let processor = Arc::new(PanicsOnFront {
        early: true,
        ..PanicsOnFront::default()
    });
    let queue = queue(processor.clone(), dir.path());
    let shots: Vec<Shot> = (1..=3)
        .flat_map(|layer| [Light::Front, Light::Side].map(|l| Shot::new(layer, Phase::Pre, l)))
        .collect();
    for shot in &shots {
        queue.submit(*shot, dir.path().join("x.jpg"), Duration::ZERO);
    }
    queue.drain();
    // Before, the panic ended the worker on its lane: no later frame had a slice or a record.
    let journal = Journal::read(&dir.path().join(crate::build_dir::JOURNAL)).unwrap();
    let sides: Vec<Shot> = shots
        .iter()
        .copied()
        .filter(|s| s.light == Light::Side)
        .collect();
    assert_eq!(journal.processed.iter().copied().collect::<Vec<_>>(), sides);
    for front in shots.iter().filter(|s| s.light == Light::Front) {
        let reason = journal.failure(front, 1).unwrap_or_default();
        assert!(
            reason.contains("its processing panicked: a frame whose processing panics"),
            "{reason}"
        );
    }
    assert!(
        processor.finished.load(Ordering::SeqCst),
        "the worker ended as it should"
    );
}

fn queue(processor: Arc<dyn FrameProcessor>, dir: &Path) -> ProcessingQueue {
    let (journal, _) = Journal::open(&dir.join(crate::build_dir::JOURNAL), false).unwrap();
    queue_on(
        processor,
        dir,
        8,
        Arc::new(Mutex::new(journal)),
        SeriesTake::First,
    )
}

fn queue_on(
    processor: Arc<dyn FrameProcessor>,
    dir: &Path,
    capacity: usize,
    journal: Arc<Mutex<Journal>>,
    take: SeriesTake,
) -> ProcessingQueue {
    queue_with(processor, dir, capacity, journal, take, Vec::new())
}

fn queue_with(
    processor: Arc<dyn FrameProcessor>,
    dir: &Path,
    capacity: usize,
    journal: Arc<Mutex<Journal>>,
    take: SeriesTake,
    backlog: Vec<(Shot, u32, String)>,
) -> ProcessingQueue {
    ProcessingQueue::start(
        processor,
        capacity,
        dir.to_path_buf(),
        journal,
        WorkerPlan {
            backlog,
            take,
            frames_per_signal: 2,
            plant: crate::plant::PlantSink::off(),
        },
        crate::clock::SystemClock::shared(),
        None,
    )
}

#[test]
fn a_commit_that_panics_is_journaled_failed_and_the_next_ones_go_on() {
    let dir = tempfile::tempdir().unwrap();
    let processor = Arc::new(PanicsOnFront::default());
    let queue = queue(processor.clone(), dir.path());
    let shots = [Light::Front, Light::Side, Light::Top].map(|l| Shot::new(1, Phase::Pre, l));
    for shot in shots {
        queue.submit(shot, dir.path().join("x.jpg"), Duration::ZERO);
    }
    let state = queue.state.clone();
    queue.drain();
    let path = dir.path().join(crate::build_dir::JOURNAL);
    let journal = Journal::read(&path).unwrap();
    assert_eq!(
        journal.processed.iter().copied().collect::<Vec<_>>(),
        shots[1..].to_vec()
    );
    // The front frame failed, with the panic's message: a catch-up does not try it again (before,
    // it waited for one, and a commit that always panics was tried at every catch-up; the next
    // start tries it).
    let reason = journal.failure(&shots[0], 1).unwrap_or_default();
    assert_eq!(
        reason,
        "committing its slice panicked: a commit that panics"
    );
    assert!(state.failed.lock().unwrap().contains(&(shots[0], 1)));
    assert_eq!(state.waiting.len(), 0);
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

/// Tells each take as its processing starts; the held shots wait to be released first, the
/// failing ones fail; at the probed shot's commit (on the commit thread, in the order of the
/// hand-overs: every take handed over before it has ended), it notes how many takes the queue
/// counts as waiting.
#[derive(Default)]
struct Scripted {
    events: Option<Sender<(Shot, u32)>>,
    release: Option<Receiver<()>>,
    held: Vec<Shot>,
    fails: Vec<Shot>,
    /// Find the disk full (ENOSPC) the first time.
    full_once: Mutex<Vec<Shot>>,
    probe: Option<Shot>,
    state: std::sync::OnceLock<Arc<QueueState>>,
    seen: Mutex<Option<usize>>,
}

impl FrameProcessor for Scripted {
    fn process(&self, _: &Path, _: Shot, _: &Path) -> Result<(), ProcessError> {
        unreachable!("the worker processes takes")
    }

    fn process_take_then(
        &self,
        _: &Path,
        shot: Shot,
        take: u32,
        _: &Path,
    ) -> Result<Then<'_>, ProcessError> {
        if let Some(events) = &self.events {
            events.send((shot, take))?;
        }
        if let (true, Some(release)) = (self.held.contains(&shot), &self.release) {
            release.recv()?;
        }
        if self.fails.contains(&shot) {
            return Err("a frame that fails".into());
        }
        let mut full = self.full_once.lock().unwrap();
        if let Some(k) = full.iter().position(|s| *s == shot) {
            full.remove(k);
            return Err(Box::new(std::io::Error::from_raw_os_error(libc::ENOSPC)));
        }
        Ok(Box::new(move || {
            if self.probe == Some(shot) {
                *self.seen.lock().unwrap() = self.state.get().map(|state| state.waiting.len());
            }
            Ok(())
        }))
    }
}

/// A queue of one place and its journal, a scripted processor, and what it tells.
struct Rig {
    dir: tempfile::TempDir,
    journal: Arc<Mutex<Journal>>,
    queue: ProcessingQueue,
    processor: Arc<Scripted>,
    told: Receiver<(Shot, u32)>,
    release: Sender<()>,
}

impl Rig {
    fn new(processor: Scripted, take: SeriesTake) -> Rig {
        Rig::after_restart(processor, take, &[])
    }

    /// A rig whose journal has first takes of `stored` (the `true` ones journaled processed)
    /// from before a restart, the worker starting on all of them as its backlog.
    fn after_restart(processor: Scripted, take: SeriesTake, stored: &[(Shot, bool)]) -> Rig {
        use crate::build_dir::journal::Record;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let (mut journal, _) = Journal::open(&path, false).unwrap();
        let mut backlog = Vec::new();
        for &(shot, processed) in stored {
            let file = format!("raw/{}.jpg", shot.take_stem(1));
            let (layer, phase, light, at) =
                (shot.layer, shot.phase, shot.light, chrono::Utc::now());
            let (bytes, sha256) = (1, String::new());
            let frame = Record::Frame {
                layer,
                phase,
                light,
                file: file.clone(),
                bytes,
                sha256,
                at,
            };
            journal.append(&frame).unwrap();
            if processed {
                let record = Record::Processed {
                    layer,
                    phase,
                    light,
                    at,
                };
                journal.append(&record).unwrap();
            }
            backlog.push((shot, 1, file));
        }
        let journal = Arc::new(Mutex::new(journal));
        let (events, told) = crossbeam_channel::unbounded();
        let (release, released) = crossbeam_channel::unbounded();
        let processor = Arc::new(Scripted {
            events: Some(events),
            release: Some(released),
            ..processor
        });
        let queue = queue_with(
            processor.clone(),
            dir.path(),
            1,
            journal.clone(),
            take,
            backlog,
        );
        let _ = processor.state.set(queue.state.clone());
        Rig {
            dir,
            journal,
            queue,
            processor,
            told,
            release,
        }
    }

    fn next(&self) -> (Shot, u32) {
        self.told.recv_timeout(Duration::from_secs(10)).unwrap()
    }

    /// Journals take `take` of a stored frame, then hands it over, as the recorder does.
    fn store(&self, shot: Shot, take: u32) {
        use crate::build_dir::journal::Record;
        let file = format!("raw/{}.jpg", shot.take_stem(take));
        let (layer, phase, light) = (shot.layer, shot.phase, shot.light);
        let (bytes, sha256, at) = (1, String::new(), chrono::Utc::now());
        let record = match take {
            1 => Record::Frame {
                layer,
                phase,
                light,
                file: file.clone(),
                bytes,
                sha256,
                at,
            },
            _ => Record::Retake {
                layer,
                phase,
                light,
                take,
                file: file.clone(),
                bytes,
                sha256,
                at,
            },
        };
        self.journal.lock().unwrap().append(&record).unwrap();
        let original = self.dir.path().join(file);
        self.queue.submit_take(shot, take, original, Duration::ZERO);
    }

    /// Drains the queue; the count of takes it leaves waiting, and what the journal says.
    fn drain(self) -> (usize, crate::build_dir::journal::Replay) {
        let state = self.queue.state.clone();
        self.queue.drain();
        assert!(self.told.try_recv().is_err(), "each take processed once");
        let journal = self.dir.path().join(crate::build_dir::JOURNAL);
        (state.waiting.len(), Journal::read(&journal).unwrap())
    }
}

fn posts(shots: &[(u32, Light)]) -> Vec<Shot> {
    shots
        .iter()
        .map(|&(layer, light)| Shot::new(layer, Phase::Post, light))
        .collect()
}

#[test]
fn a_frame_that_overflowed_the_queue_is_processed_before_the_frames_queued_after_it() {
    let shots = posts(&[
        (1, Light::Front),
        (1, Light::Side),
        (1, Light::Top),
        (2, Light::Front),
    ]);
    let processor = Scripted {
        held: shots[..2].to_vec(),
        ..Scripted::default()
    };
    let rig = Rig::new(processor, SeriesTake::First);

    rig.store(shots[0], 1);
    assert_eq!(rig.next(), (shots[0], 1));
    // Layer 1's side view waits in the queue (one place); its top view overflows it and
    // waits on disk.
    rig.store(shots[1], 1);
    rig.store(shots[2], 1);
    rig.release.send(()).unwrap();
    // The catch-up takes the side view; layer 2's front view is stored meanwhile, and the
    // queue has room for it.
    assert_eq!(rig.next(), (shots[1], 1));
    rig.store(shots[3], 1);
    rig.release.send(()).unwrap();
    // Layer 1's top view comes before layer 2's front view (the code before took the queue
    // first: layer 2 came before it, and the inspection took layer 1 as done without it).
    assert_eq!(rig.next(), (shots[2], 1));
    assert_eq!(rig.next(), (shots[3], 1));
    let (waiting, journal) = rig.drain();
    assert_eq!((waiting, journal.processed.len()), (0, 4));
}

#[test]
fn a_failed_frame_is_not_tried_again_by_a_catch_up_nor_hides_the_frames_still_waiting() {
    let [failing, held, probed, last] = posts(&[
        (1, Light::Front),
        (1, Light::Side),
        (1, Light::Top),
        (2, Light::Front),
    ])[..] else {
        unreachable!()
    };
    let processor = Scripted {
        held: vec![held],
        fails: vec![failing],
        probe: Some(probed),
        ..Scripted::default()
    };
    let rig = Rig::new(processor, SeriesTake::First);
    rig.store(failing, 1);
    assert_eq!(rig.next(), (failing, 1));
    rig.store(held, 1);
    assert_eq!(rig.next(), (held, 1));
    // The queue's place is taken; the last frame overflows it and waits on disk.
    rig.store(probed, 1);
    rig.store(last, 1);
    rig.release.send(()).unwrap();
    // The catch-up leaves the failed frame (the journal has it unprocessed, but it failed this
    // run: the next start tries it) and takes the rest in build order. Before, each catch-up
    // decoded it again, journaled a second failure and logged its layer's line again.
    assert_eq!(rig.next(), (probed, 1));
    assert_eq!(rig.next(), (last, 1));
    let Rig {
        dir,
        queue,
        processor,
        told,
        ..
    } = rig;
    let state = queue.state.clone();
    queue.drain();
    assert!(told.try_recv().is_err(), "each take processed once");
    assert_eq!(state.waiting.len(), 0);
    // At the probed frame's commit, it and the last frame still waited.
    assert_eq!(*processor.seen.lock().unwrap(), Some(2));
    let path = dir.path().join(crate::build_dir::JOURNAL);
    let journal = Journal::read(&path).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    assert_eq!(text.matches("processing_failed").count(), 1, "{text}");
    assert_eq!(journal.failure(&failing, 1), Some("a frame that fails"));
    assert!(journal
        .unprocessed_takes(SeriesTake::First)
        .contains(&(failing, 1)));
}

#[test]
fn a_first_take_the_catch_up_skips_for_its_retake_is_not_left_counted_as_waiting() {
    let [held, queued, retaken] =
        posts(&[(1, Light::Front), (1, Light::Side), (1, Light::Top)])[..]
    else {
        unreachable!()
    };
    let processor = Scripted {
        held: vec![held],
        ..Scripted::default()
    };
    let rig = Rig::new(processor, SeriesTake::Last);
    rig.store(held, 1);
    assert_eq!(rig.next(), (held, 1));
    // The queue's place is taken; the top view's frame and its retake overflow it.
    rig.store(queued, 1);
    rig.store(retaken, 1);
    rig.store(retaken, 2);
    assert_eq!(rig.queue.depth(), 4);
    rig.release.send(()).unwrap();
    // The catch-up processes the take the slice shows, the retake, and never the first.
    assert_eq!(rig.next(), (queued, 1));
    assert_eq!(rig.next(), (retaken, 2));
    // Before, the first take stayed counted for good: a backlog of 1 in `status` and the
    // service's status line to the end of the build.
    let (waiting, journal) = rig.drain();
    assert_eq!(waiting, 0);
    assert_eq!(journal.slice_takes.get(&retaken), Some(&2));
}

#[test]
fn a_take_the_start_wants_again_is_processed_after_a_pause_that_interrupted_the_backlog() {
    let [first, inspected_again, unprocessed] =
        posts(&[(1, Light::Front), (1, Light::Side), (2, Light::Front)])[..]
    else {
        unreachable!()
    };
    let processor = Scripted {
        held: vec![first],
        ..Scripted::default()
    };
    // The middle take is processed already; the processor wants it again (the inspection of a
    // layer a stop left uninspected).
    let stored = [
        (first, false),
        (inspected_again, true),
        (unprocessed, false),
    ];
    let rig = Rig::after_restart(processor, SeriesTake::First, &stored);
    assert_eq!(rig.next(), (first, 1));
    // The disk runs low while the first take is processed: the rest of the backlog waits.
    rig.queue.set_paused(true);
    rig.release.send(()).unwrap();
    assert!(
        rig.told.recv_timeout(Duration::from_millis(300)).is_err(),
        "paused"
    );
    // Space is back: the catch-up takes the rest of the backlog with the journal's, at once
    // (no frame handed over). Before, the journal alone named what to catch up, and the take
    // it has processed already was never processed again.
    rig.queue.set_paused(false);
    assert_eq!(rig.next(), (inspected_again, 1));
    assert_eq!(rig.next(), (unprocessed, 1));
    let (waiting, journal) = rig.drain();
    assert_eq!((waiting, journal.processed.len()), (0, 3));
}

#[test]
fn a_take_wanted_again_whose_slice_finds_the_disk_full_is_taken_again_after_the_pause() {
    let [again, next] = posts(&[(1, Light::Front), (2, Light::Front)])[..] else {
        unreachable!()
    };
    let processor = Scripted {
        full_once: Mutex::new(vec![again]),
        ..Scripted::default()
    };
    // Processed before the stop, wanted again (its layer never inspected).
    let rig = Rig::after_restart(processor, SeriesTake::First, &[(again, true)]);
    assert_eq!(rig.next(), (again, 1));
    // Its slice found the disk full: the worker paused itself, and holds the pause until the
    // disk guard is told.
    assert!(
        rig.told.recv_timeout(Duration::from_millis(300)).is_err(),
        "paused"
    );
    rig.queue.set_paused(false);
    assert!(rig.queue.paused(), "held until the guard is told");
    assert!(rig.queue.slice_found_disk_full());
    rig.store(next, 1);
    // Room again: the catch-up takes it again, though the journal counts it processed (before,
    // the journal alone named what to catch up, and it was never processed again this run).
    rig.queue.set_paused(false);
    assert_eq!(rig.next(), (again, 1));
    assert_eq!(rig.next(), (next, 1));
    let (waiting, journal) = rig.drain();
    assert_eq!((waiting, journal.processed.len()), (0, 2));
}
