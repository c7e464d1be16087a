//! The live push beside the daemon: one thread per archive that looks for new instances every
//! `poll`, pushes them, and backs off while the archive is unreachable. It shares nothing with
//! capture or processing but the files on disk, so neither ever waits for an archive.

use super::{Destination, PacsError, Queue};
use crate::clock::{Backoff, SharedClock};
use crossbeam_channel::{select, unbounded, Receiver, Sender};
use std::path::Path;
use std::thread::JoinHandle;
use std::time::Duration;
use tracing::{error, info, warn};

enum Control {
    /// Look for new instances now.
    Wake,
    /// Push what is pending for at most this long, then stop.
    Finish(Duration),
}

/// The running push threads.
pub struct Pusher {
    threads: Vec<(Sender<Control>, JoinHandle<()>)>,
}

impl Pusher {
    /// Opens each destination's log under `root` and starts its thread.
    pub fn start(
        root: &Path,
        destinations: Vec<Destination>,
        clock: SharedClock,
        poll: Duration,
    ) -> Result<Pusher, PacsError> {
        let mut threads = Vec::new();
        for destination in destinations {
            let name = destination.name.clone();
            let queue = Queue::open(root, destination)?;
            let (control, inbox) = unbounded();
            let clock = clock.clone();
            let thread = std::thread::Builder::new()
                .name(format!("pacs-{name}"))
                .spawn(move || push_loop(queue, inbox, clock, poll))
                .map_err(|e| PacsError::Transport {
                    destination: name,
                    message: format!("cannot start the push thread: {e}"),
                })?;
            threads.push((control, thread));
        }
        Ok(Pusher { threads })
    }

    /// Makes every thread look for new instances now.
    pub fn wake(&self) {
        for (control, _) in &self.threads {
            let _ = control.send(Control::Wake);
        }
    }

    /// Lets every thread push what is pending for up to `grace`, then waits for them to stop.
    /// What is left stays pending in the logs for the next start or `layerwise push`.
    pub fn finish(self, grace: Duration) {
        for (control, _) in &self.threads {
            let _ = control.send(Control::Finish(grace));
        }
        for (_, thread) in self.threads {
            let _ = thread.join();
        }
    }
}

fn push_loop(mut queue: Queue, inbox: Receiver<Control>, clock: SharedClock, poll: Duration) {
    let [first, longest] = queue.destination.backoff;
    let mut backoff = Backoff::new(first, longest);
    let mut sender = queue.destination.connect();
    let mut deadline: Option<Duration> = None;
    let name = queue.destination.name.clone();
    loop {
        let wait = match queue.push_pending(sender.as_mut(), false, clock.as_ref()) {
            Ok(_) => {
                backoff.reset();
                if deadline.is_some() && queue.pending(false).is_empty() {
                    info!(destination = %name, "pacs: everything pushed");
                    return;
                }
                poll
            }
            Err(PacsError::Transport { .. }) => backoff.advance(),
            Err(e) => {
                error!(destination = %name, error = %e, "pacs: cannot record the push");
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
            recv(inbox) -> message => match message {
                Ok(Control::Wake) => {}
                Ok(Control::Finish(grace)) => deadline = Some(clock.elapsed() + grace),
                Err(_) => return,
            },
            recv(timer) -> _ => {}
        }
    }
}
