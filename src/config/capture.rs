//! `[capture]`: how frames are taken: light settling, camera call bounds and retries.

use super::common::check_backoff;
use super::Invalid;
use serde::{Deserialize, Serialize};

/// How frames are taken: light settling, camera call bounds and retries. A key left out takes
/// its value from [`CaptureConfig::default`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CaptureConfig {
    /// Wait after switching a light before the exposure, so the lamp is at full brightness.
    pub settle_ms: u64,
    /// Longest a single camera call may take; past it the daemon exits for systemd to restart it.
    pub call_timeout_s: u64,
    /// How often a busy or timed-out capture is tried again before the frame is recorded missing.
    pub retries: u32,
    pub retry_backoff_ms: [u64; 2],
    /// How often to reopen a camera that dropped off USB before giving up on the frame.
    pub reopen_attempts: u32,
}

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            settle_ms: 0,
            call_timeout_s: 60,
            retries: 8,
            retry_backoff_ms: [100, 3000],
            reopen_attempts: 5,
        }
    }
}

impl CaptureConfig {
    /// Checks the section: a call timeout and a back-off that do not spin.
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.call_timeout_s == 0 {
            return Err(Invalid::new(
                "capture.call_timeout_s",
                "must be at least 1 second",
            ));
        }
        check_backoff("capture.retry_backoff_ms", self.retry_backoff_ms)
    }
}
