//! What a run did.

use crate::shutdown::StopReason;
use std::path::PathBuf;

/// What a run did.
#[derive(Clone, Debug)]
pub struct RunSummary {
    pub build_dir: PathBuf,
    /// Frames stored (first takes).
    pub stored: u64,
    /// Frames taken again for repeated signals, kept beside the first takes.
    pub retakes: u64,
    pub missing: u64,
    pub skipped: u64,
    /// Why the run stopped (set when it has).
    pub stop_reason: Option<StopReason>,
}

impl RunSummary {
    pub(super) fn new(build_dir: PathBuf) -> RunSummary {
        RunSummary {
            build_dir,
            stored: 0,
            retakes: 0,
            missing: 0,
            skipped: 0,
            stop_reason: None,
        }
    }

    /// Stopped because the operator ended the build or started the next one (not by the
    /// trigger, a signal or a failure).
    pub fn stopped_on_request(&self) -> bool {
        matches!(self.stop_reason, Some(StopReason::BuildStopped { .. }))
    }
}
