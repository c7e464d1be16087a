//! One destination's push log and what is pending: batches sent through a [`Sender`], every
//! answer recorded.

use super::destination::Destination;
use super::error::PacsError;
use super::instance::{Instance, Outcome, Sender, Unfinished};
use crate::build_dir::pushlog::{self, PushLog, PushRecord, PushState};
use crate::clock::Clock;
use std::path::{Path, PathBuf};
use std::time::Duration;
use tracing::{info, warn};

/// Batches stay below this many bytes (and [`BATCH_FILES`] files).
const BATCH_BYTES: usize = 32 << 20;
const BATCH_FILES: usize = 64;

/// What one push did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PushCount {
    pub stored: usize,
    pub rejected: Vec<(String, String)>,
    pub bytes: u64,
}

/// One destination's log and state, opened for pushing.
pub struct Queue {
    pub root: PathBuf,
    pub destination: Destination,
    log: PushLog,
    pub state: PushState,
    last_logged_error: Option<String>,
}

impl Queue {
    pub fn open(root: &Path, destination: Destination) -> Result<Queue, PacsError> {
        let (log, state) = PushLog::open(&pushlog::log_path(root, &destination.name))?;
        Ok(Queue {
            root: root.to_path_buf(),
            destination,
            log,
            state,
            last_logged_error: None,
        })
    }

    /// The instances on disk the archive does not have yet.
    pub fn pending(&self, retry_rejected: bool) -> Vec<String> {
        pushlog::instances(&self.root)
            .into_iter()
            .filter(|f| {
                !self.state.is_done(f, retry_rejected) || self.state.replaced(&self.root, f)
            })
            .collect()
    }

    /// Pushes every pending instance through `sender`, logging each outcome as it comes;
    /// stops at the first transport error (logged once per distinct message) and returns it.
    /// Each batch has `deadline_s` per instance; with `until` (on `clock`'s elapsed time) the
    /// push stops there too, what is left pending.
    pub fn push_pending(
        &mut self,
        sender: &mut dyn Sender,
        retry_rejected: bool,
        clock: &dyn Clock,
        until: Option<Duration>,
    ) -> Result<PushCount, PacsError> {
        let mut count = PushCount::default();
        let pending = self.pending(retry_rejected);
        let started = clock.elapsed();
        let mut next = 0;
        while next < pending.len() {
            let left = until.map(|end| end.saturating_sub(clock.elapsed()));
            if left == Some(Duration::ZERO) {
                return Err(PacsError::RunDeadline {
                    destination: self.destination.name.clone(),
                    seconds: until
                        .unwrap_or_default()
                        .saturating_sub(started)
                        .as_secs_f64(),
                    pending: pending.len() - next,
                });
            }
            let mut batch = Vec::new();
            let mut bytes = 0;
            while next < pending.len() && batch.len() < BATCH_FILES && bytes < BATCH_BYTES {
                let file = &pending[next];
                next += 1;
                match Instance::read(&self.root, file) {
                    Ok(instance) => {
                        bytes += instance.bytes.len();
                        batch.push(instance);
                    }
                    // The file vanished (a series rewritten): nothing to push.
                    Err(_) if !self.root.join(file).exists() => {}
                    Err(e) => {
                        let reason = crate::logging::chain(&e);
                        self.record(&PushRecord::Rejected {
                            file: file.clone(),
                            sop_instance_uid: String::new(),
                            reason: reason.clone(),
                            at: clock.now(),
                        })?;
                        count.rejected.push((file.clone(), reason));
                    }
                }
            }
            if batch.is_empty() {
                continue;
            }
            let per_instance = self.destination.deadline.saturating_mul(batch.len() as u32);
            let deadline = left.map_or(per_instance, |left| left.min(per_instance));
            let outcomes = match sender.send(&batch, deadline) {
                Ok(outcomes) => outcomes,
                // What the archive answered for is logged (not sent again); the rest's fate is
                // unknown: a transport error, retried.
                Err(Unfinished {
                    answered,
                    error: source,
                }) => {
                    if !answered.is_empty() {
                        warn!(destination = %self.destination.name, answered = answered.len(), batch = batch.len(), "pacs: the archive answered for part of the batch; that part is logged, the rest sent again");
                    }
                    for (i, outcome) in answered {
                        if let Some(instance) = batch.get(i) {
                            self.log_outcome(instance, outcome, &mut count, clock)?;
                        }
                    }
                    let message = crate::logging::chain(&source);
                    if self.last_logged_error.as_deref() != Some(&message) {
                        warn!(destination = %self.destination.name, error = %message, "pacs: push failed; will retry");
                        self.record(&PushRecord::Error {
                            message: message.clone(),
                            at: clock.now(),
                        })?;
                        self.last_logged_error = Some(message);
                    }
                    return Err(PacsError::Transport {
                        destination: self.destination.name.clone(),
                        source: Box::new(source),
                    });
                }
            };
            self.last_logged_error = None;
            for (instance, outcome) in batch.iter().zip(outcomes) {
                self.log_outcome(instance, outcome, &mut count, clock)?;
            }
        }
        if count.stored > 0 {
            info!(destination = %self.destination.name, instances = count.stored, "pacs: pushed");
        }
        Ok(count)
    }

    /// Logs what the archive said of one instance, and counts it.
    fn log_outcome(
        &mut self,
        instance: &Instance,
        outcome: Outcome,
        count: &mut PushCount,
        clock: &dyn Clock,
    ) -> Result<(), PacsError> {
        let (record, rejected) = match outcome {
            Outcome::Stored => {
                count.stored += 1;
                count.bytes += instance.bytes.len() as u64;
                (
                    PushRecord::Stored {
                        file: instance.file.clone(),
                        sop_instance_uid: instance.sop_instance_uid.clone(),
                        at: clock.now(),
                    },
                    None,
                )
            }
            Outcome::Rejected(reason) => {
                warn!(destination = %self.destination.name, file = %instance.file, %reason, "pacs: instance rejected");
                (
                    PushRecord::Rejected {
                        file: instance.file.clone(),
                        sop_instance_uid: instance.sop_instance_uid.clone(),
                        reason: reason.clone(),
                        at: clock.now(),
                    },
                    Some(reason),
                )
            }
        };
        self.record(&record)?;
        if let Some(reason) = rejected {
            count.rejected.push((instance.file.clone(), reason));
        }
        Ok(())
    }

    fn record(&mut self, record: &PushRecord) -> Result<(), PacsError> {
        self.log.append(record)?;
        self.state.apply(record);
        Ok(())
    }
}
