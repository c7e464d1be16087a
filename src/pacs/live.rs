//! The live push beside the daemon: one thread per archive that looks for new instances every
//! `poll`, pushes them, and backs off while the archive is unreachable. It shares nothing with
//! capture or processing but the files on disk, so neither ever waits for an archive.

use super::destination::Destination;
use super::error::PacsError;
use super::queue::Queue;
use crate::clock::{Backoff, SharedClock};
use crate::logging::Chain;
use crate::shutdown::Shutdown;
use crossbeam_channel::{bounded, select, Receiver, Sender};
use std::path::Path;
use std::thread::JoinHandle;
use std::time::Duration;
use tracing::{error, info, warn};

/// The running push threads.
pub struct Pusher {
    threads: Vec<JoinHandle<()>>,
    waker: PushWaker,
}

/// Wakes the push threads when an instance is written, so it is pushed at once rather than at
/// the next poll. Never blocks: one wake waits per thread (a channel of one), more coalesce.
#[derive(Clone, Default)]
pub struct PushWaker {
    wakes: Vec<Sender<()>>,
}

impl PushWaker {
    pub fn wake(&self) {
        for wake in &self.wakes {
            let _ = wake.try_send(());
        }
    }
}

/// How a push thread runs and when it stops.
#[derive(Clone)]
pub struct PushPlan {
    /// How often it looks for new instances without a wake.
    pub poll: Duration,
    /// When requested, each thread pushes what is pending for at most `grace`, then stops; what
    /// is left stays pending in the logs for the next start or `layerwise push`.
    pub shutdown: Shutdown,
    pub grace: Duration,
}

impl Pusher {
    /// Opens each destination's log under `root` and starts its thread.
    pub fn start(
        root: &Path,
        destinations: Vec<Destination>,
        clock: SharedClock,
        plan: PushPlan,
    ) -> Result<Pusher, PacsError> {
        let with_senders = destinations
            .into_iter()
            .map(|d| {
                let sender = d.connect();
                (d, sender)
            })
            .collect();
        Pusher::start_with(root, with_senders, clock, plan)
    }

    /// [`Pusher::start`] with the sender of each destination given.
    pub fn start_with(
        root: &Path,
        destinations: Vec<(Destination, Box<dyn super::instance::Sender>)>,
        clock: SharedClock,
        plan: PushPlan,
    ) -> Result<Pusher, PacsError> {
        let mut threads = Vec::new();
        let mut waker = PushWaker::default();
        for (destination, sender) in destinations {
            let name = destination.name.clone();
            let queue = Queue::open(root, destination)?;
            let (wake, woken) = bounded(1);
            let (clock, plan) = (clock.clone(), plan.clone());
            let thread = std::thread::Builder::new()
                .name(format!("pacs-{name}"))
                .spawn(move || push_loop(queue, sender, woken, clock, plan))
                .map_err(|source| PacsError::Thread {
                    destination: name,
                    source,
                })?;
            threads.push(thread);
            waker.wakes.push(wake);
        }
        Ok(Pusher { threads, waker })
    }

    /// A handle that wakes the threads without blocking (for the processing worker).
    pub fn waker(&self) -> PushWaker {
        self.waker.clone()
    }

    /// Waits for every thread to stop (they do once the plan's shutdown is requested, within its
    /// grace).
    pub fn join(self) {
        for thread in self.threads {
            let _ = thread.join();
        }
    }
}

fn push_loop(
    mut queue: Queue,
    mut sender: Box<dyn super::instance::Sender>,
    mut woken: Receiver<()>,
    clock: SharedClock,
    plan: PushPlan,
) {
    let [first, longest] = queue.destination.backoff;
    let mut backoff = Backoff::new(first, longest);
    let mut deadline: Option<Duration> = None;
    let mut stopping = plan.shutdown.receiver().clone();
    let name = queue.destination.name.clone();
    loop {
        let mut backing_off = true;
        // Stopping, the grace bounds the push itself, not only the waits between its passes.
        let wait = match queue.push_pending(sender.as_mut(), false, clock.as_ref(), deadline) {
            Ok(_) => {
                backing_off = false;
                backoff.reset();
                if deadline.is_some() && queue.pending(false).is_empty() {
                    info!(destination = %name, "pacs: everything pushed");
                    return;
                }
                plan.poll
            }
            Err(PacsError::Transport { .. } | PacsError::RunDeadline { .. }) => backoff.advance(),
            Err(e) => {
                error!(destination = %name, error = %Chain(&e), "pacs: cannot record the push");
                backoff.advance()
            }
        };
        let wait = match deadline {
            Some(end) => {
                let now = clock.elapsed();
                if now >= end {
                    warn!(destination = %name, pending = queue.pending(false).len(), "pacs: stopping with instances still to push; they are pushed at the next start or by `layerwise push`");
                    return;
                }
                wait.min(end - now)
            }
            None => wait,
        };
        let timer = clock.after(wait);
        select! {
            // Stopping: what is pending is pushed for at most the grace.
            recv(stopping) -> _ => {
                deadline = Some(clock.elapsed() + plan.grace);
                stopping = crossbeam_channel::never();
            }
            // An instance was written: push it now, unless the archive is unreachable (then the
            // back-off stands).
            recv(woken) -> wake => match wake {
                Ok(()) if !backing_off => {}
                Ok(()) => {
                    // Wait out the back-off; a wake meanwhile changes nothing.
                    select! {
                        recv(stopping) -> _ => {
                            deadline = Some(clock.elapsed() + plan.grace);
                            stopping = crossbeam_channel::never();
                        }
                        recv(timer) -> _ => {}
                    }
                }
                Err(_) => woken = crossbeam_channel::never(),
            },
            recv(timer) -> _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use crate::pacs::{Instance, Outcome, Sender as PacsSender, Target};

    /// An archive that stores everything and tells the test what it received.
    struct Recording(crossbeam_channel::Sender<String>);

    impl PacsSender for Recording {
        fn send(
            &mut self,
            batch: &[Instance],
            _: Duration,
        ) -> Result<Vec<Outcome>, crate::pacs::Unfinished> {
            for instance in batch {
                let _ = self.0.send(instance.file.clone());
            }
            Ok(batch.iter().map(|_| Outcome::Stored).collect())
        }
    }

    fn slice(root: &Path, layer: u32) -> String {
        let study = crate::dicom::Study {
            study_instance_uid: "2.25.1".into(),
            frame_of_reference_uid: "2.25.2".into(),
            date: "20261202".into(),
            time: "040000".into(),
            patient_name: "wake^".into(),
            patient_id: "wake".into(),
            study_id: "1".into(),
            description: "wake".into(),
        };
        let series = crate::dicom::Series::named(&study, 1, "post_top");
        let pixels = vec![0u16; 4];
        let slice = crate::dicom::Slice {
            layer,
            plane: crate::dicom::Plane {
                origin: [0.0, 0.0, layer as f64],
                pixel_mm: 1.0,
                rows: 2,
                columns: 2,
                thickness_mm: 1.0,
            },
            pixels: (&pixels).into(),
            acquired: None,
            window: (0.0, 1.0),
            derivation: "test",
        };
        let file = format!("L{layer:05}.dcm");
        crate::dicom::write_slice(
            &root.join(&file),
            &study,
            &series,
            &slice,
            crate::dicom::Compression::None,
        )
        .unwrap();
        file
    }

    #[test]
    fn a_wake_pushes_a_new_instance_without_waiting_for_the_poll() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let first = slice(root, 1);
        let (tx, received) = crossbeam_channel::unbounded();
        let destination = Destination {
            name: "fake".into(),
            target: Target::Stow {
                url: "http://127.0.0.1:9/dicom-web".into(),
                authorization: None,
            },
            timeout: Duration::from_secs(1),
            deadline: Duration::from_secs(1),
            backoff: [Duration::from_secs(1), Duration::from_secs(60)],
        };
        // A manual clock that is never advanced: the poll (an hour) never comes.
        let clock: SharedClock = std::sync::Arc::new(ManualClock::new());
        let shutdown = Shutdown::new();
        let plan = PushPlan {
            poll: Duration::from_secs(3600),
            shutdown: shutdown.clone(),
            grace: Duration::ZERO,
        };
        let pusher = Pusher::start_with(
            root,
            vec![(destination, Box::new(Recording(tx)))],
            clock,
            plan,
        )
        .unwrap();
        // The first pass pushes what is on disk, then the thread waits for the poll or a wake.
        assert_eq!(received.recv_timeout(Duration::from_secs(30)), Ok(first));
        let waker = pusher.waker();
        let second = slice(root, 2);
        waker.wake();
        // Waking again before the thread ran never blocks (the wakes coalesce).
        waker.wake();
        waker.wake();
        assert_eq!(received.recv_timeout(Duration::from_secs(30)), Ok(second));
        shutdown.request(crate::shutdown::StopReason::TriggerEnded);
        pusher.join();
    }
}
