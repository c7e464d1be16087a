//! The disk guard: keeps the originals coming for as long as the build disk allows.
//!
//! Below `storage.min_free_gb` the daemon warns once and pauses the derived data (the rectified
//! DICOM series and the inspection, which the processing worker catches up from the journal once
//! space returns, or the next start does); originals are still captured. When an original cannot
//! be written (ENOSPC) the guard gives up its reserve (a file of [`RESERVE_BYTES`] in the build
//! directory) so the journal and status.json can still be written, the frames are recorded as
//! missing, and free space is probed again with a growing back-off until there is room for the
//! reserve and a few frames; then capture resumes.

use crate::build_dir::status::{DiskHealth, DiskState};
use crate::clock::{Backoff, SharedClock};
use crate::fsutil::FreeSpace;
use chrono::{DateTime, Utc};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;
use tracing::{error, info, warn};

/// Space held in reserve for the journal and status.json while the disk is full.
pub const RESERVE_BYTES: u64 = 1 << 20;

/// Frames of room wanted, beyond the reserve, before capturing again after the disk filled.
const FRAMES_OF_ROOM: u64 = 8;

/// Back-off between probes while the disk is full.
const FULL_BACKOFF: (Duration, Duration) = (Duration::from_millis(500), Duration::from_secs(5));

pub struct DiskGuard {
    probe: Arc<dyn FreeSpace>,
    dir: PathBuf,
    min_free: u64,
    state: DiskState,
    free: Option<u64>,
    largest_frame: u64,
    backoff: Backoff,
    /// While full: when (on the clock's monotonic time) to probe again.
    next_probe: Duration,
    since: Option<DateTime<Utc>>,
    missed: u64,
    /// The free space when a slice (derived data) could not be written for want of space
    /// while the guard saw room: the derived data waits until the free space has grown past
    /// it (by [`RESERVE_BYTES`]), rather than trying the slice again each second.
    derived_full_at: Option<u64>,
    clock: SharedClock,
}

impl DiskGuard {
    /// Measures the disk holding `dir` and puts the reserve in place (or starts full when there
    /// is no room for it).
    pub fn open(
        dir: PathBuf,
        probe: Arc<dyn FreeSpace>,
        min_free: u64,
        clock: SharedClock,
    ) -> DiskGuard {
        let mut guard = DiskGuard {
            probe,
            dir,
            min_free,
            state: DiskState::Ok,
            free: None,
            largest_frame: 0,
            backoff: Backoff::new(FULL_BACKOFF.0, FULL_BACKOFF.1),
            next_probe: Duration::ZERO,
            since: None,
            missed: 0,
            derived_full_at: None,
            clock,
        };
        if let Err(e) = guard.make_reserve() {
            if crate::fsutil::is_disk_full(&e) {
                guard.filled();
            } else {
                warn!(error = %e, "disk: cannot keep a reserve in the build directory");
            }
        }
        guard.poll();
        guard
    }

    fn reserve_path(&self) -> PathBuf {
        self.dir.join(crate::build_dir::DISK_RESERVE)
    }

    /// The reserve, written for real (zeros, fsynced) so it holds blocks a full disk lacks.
    fn make_reserve(&self) -> std::io::Result<()> {
        let path = self.reserve_path();
        if std::fs::metadata(&path).is_ok_and(|m| m.len() == RESERVE_BYTES) {
            return Ok(());
        }
        crate::fsutil::write_atomic(&path, &vec![0u8; RESERVE_BYTES as usize], true)
            .map_err(|e| e.source)
    }

    /// Free space wanted before capturing again after the disk filled.
    pub fn need_bytes(&self) -> u64 {
        RESERVE_BYTES + FRAMES_OF_ROOM * self.largest_frame.max(64 * 1024)
    }

    pub fn state(&self) -> DiskState {
        self.state
    }

    /// Whether originals may be written (not while the disk is full).
    pub fn may_capture(&self) -> bool {
        self.state != DiskState::Full
    }

    /// Whether derived data (series, inspection) may be written.
    pub fn derived_allowed(&self) -> bool {
        self.state == DiskState::Ok && self.derived_full_at.is_none()
    }

    /// A slice could not be written for want of space (the processing worker paused itself):
    /// the derived data waits until the free space grows (probed by [`DiskGuard::poll`]), even
    /// while the free space stays above `storage.min_free_gb`. Returns whether this is news.
    pub fn derived_filled(&mut self) -> bool {
        let free = self.probe.free_bytes(&self.dir).ok().or(self.free);
        self.free = free.or(self.free);
        let free = free.unwrap_or(0);
        let news = self.derived_full_at.is_none();
        self.derived_full_at = Some(self.derived_full_at.map_or(free, |at| at.min(free)));
        // Low or full, the guard's own state says why the derived data waits.
        if news && self.state == DiskState::Ok {
            error!(
                free_mb = free / 1_000_000,
                "disk: a slice found the disk full ({} free): DICOM series and inspection wait \
                 until the free space grows (originals are still captured); free space on the \
                 build disk",
                crate::build_dir::health::mb(free)
            );
        }
        news
    }

    /// An original of `bytes` was stored.
    pub fn stored(&mut self, bytes: u64) {
        self.largest_frame = self.largest_frame.max(bytes);
    }

    /// A frame was not captured because the disk is full.
    pub fn missed(&mut self) {
        self.missed += 1;
    }

    /// Probes the free space (while full: only when the back-off allows) and moves between
    /// states; returns the new state when it changed.
    pub fn poll(&mut self) -> Option<DiskState> {
        if self.state == DiskState::Full {
            if self.clock.elapsed() < self.next_probe {
                return None;
            }
            self.next_probe = self.clock.elapsed() + self.backoff.advance();
        }
        let free = match self.probe.free_bytes(&self.dir) {
            Ok(free) => free,
            Err(e) => {
                warn!(dir = %self.dir.display(), error = %e, "disk: cannot measure the free space");
                return None;
            }
        };
        self.free = Some(free);
        if self
            .derived_full_at
            .is_some_and(|at| free >= at.saturating_add(RESERVE_BYTES))
        {
            self.derived_full_at = None;
            info!(
                free_mb = free / 1_000_000,
                "disk: the free space has grown since a slice found the disk full: catching up \
                 the derived data"
            );
        }
        // Leaving "low" wants the reserve's worth above the limit, so the state does not flap
        // with every frame written.
        let above_min = match self.state {
            DiskState::Low => free >= self.min_free.saturating_add(RESERVE_BYTES),
            _ => free >= self.min_free,
        };
        let next = match self.state {
            DiskState::Full if free < self.need_bytes() => DiskState::Full,
            DiskState::Full => match self.make_reserve() {
                Ok(()) if above_min => DiskState::Ok,
                Ok(()) => DiskState::Low,
                Err(e) => {
                    warn!(error = %e, "disk: space is back but the reserve cannot be made yet");
                    DiskState::Full
                }
            },
            _ if above_min => DiskState::Ok,
            _ => DiskState::Low,
        };
        self.set(next)
    }

    /// An original could not be written for want of space: the reserve is given up (so the
    /// journal and status.json can still be written) and capture waits for space.
    pub fn filled(&mut self) -> Option<DiskState> {
        let _ = std::fs::remove_file(self.reserve_path());
        self.free = self.probe.free_bytes(&self.dir).ok();
        self.backoff.reset();
        self.next_probe = self.clock.elapsed() + self.backoff.advance();
        self.set(DiskState::Full)
    }

    fn set(&mut self, next: DiskState) -> Option<DiskState> {
        if next == self.state {
            return None;
        }
        let previous = std::mem::replace(&mut self.state, next);
        self.since = Some(self.clock.now());
        let message = self.health().health().warning;
        match (previous, next) {
            (_, DiskState::Full) => {
                self.missed = 0;
                error!("{}", message.unwrap_or_default());
            }
            (_, DiskState::Low) => warn!("{}", message.unwrap_or_default()),
            (DiskState::Full, DiskState::Ok) => info!(
                free_mb = self.free.unwrap_or(0) / 1_000_000,
                missed = self.missed,
                "disk space is back: capturing again, catching up the derived data"
            ),
            (_, DiskState::Ok) => info!(
                free_mb = self.free.unwrap_or(0) / 1_000_000,
                "disk above storage.min_free_gb again: catching up the derived data"
            ),
        }
        if previous == DiskState::Full {
            self.backoff.reset();
        }
        Some(next)
    }

    /// What status.json says of the disk.
    pub fn health(&self) -> DiskHealth {
        DiskHealth {
            state: self.state,
            free_bytes: self.free,
            min_free_bytes: self.min_free,
            need_bytes: self.need_bytes(),
            since: self.since,
            frames_missed: self.missed,
            derived_paused: !self.derived_allowed(),
            journal_held: 0,
        }
    }

    /// Why a frame is not captured while the disk is full.
    pub fn missing_reason(&self) -> String {
        format!(
            "not captured: the disk is full ({} MB free, capture resumes at {} MB)",
            self.free.unwrap_or(0) / 1_000_000,
            self.need_bytes().div_ceil(1_000_000)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::clock::ManualClock;
    use std::path::Path;
    use std::sync::atomic::{AtomicU64, Ordering};

    struct Probe(Arc<AtomicU64>);
    impl FreeSpace for Probe {
        fn free_bytes(&self, _: &Path) -> std::io::Result<u64> {
            Ok(self.0.load(Ordering::SeqCst))
        }
    }

    /// A guard of a limit of 50 MB over a probe that says 100 MB free, on a clock tests move.
    fn guard(dir: &Path) -> (DiskGuard, Arc<AtomicU64>, Arc<ManualClock>) {
        let free = Arc::new(AtomicU64::new(100_000_000));
        let clock = Arc::new(ManualClock::new());
        let guard = DiskGuard::open(
            dir.to_path_buf(),
            Arc::new(Probe(free.clone())),
            50_000_000,
            clock.clone(),
        );
        (guard, free, clock)
    }

    #[test]
    fn low_full_and_back_with_a_reserve_and_backoff() {
        let dir = tempfile::tempdir().unwrap();
        let (mut guard, free, clock) = guard(dir.path());
        let reserve = dir.path().join(crate::build_dir::DISK_RESERVE);
        assert_eq!(std::fs::metadata(&reserve).unwrap().len(), RESERVE_BYTES);
        assert_eq!(guard.state(), DiskState::Ok);
        guard.stored(200_000);
        // Below the limit: low once, derived data paused, originals still captured.
        free.store(40_000_000, Ordering::SeqCst);
        assert_eq!(guard.poll(), Some(DiskState::Low));
        assert_eq!(guard.poll(), None, "warned once per crossing");
        assert!(guard.may_capture() && !guard.derived_allowed());
        // Just above the limit is not enough to leave "low" (no flapping).
        free.store(50_500_000, Ordering::SeqCst);
        assert_eq!(guard.poll(), None);
        // Full: the reserve is given up, capture waits.
        free.store(10_000, Ordering::SeqCst);
        assert_eq!(guard.filled(), Some(DiskState::Full));
        assert!(!reserve.exists() && !guard.may_capture());
        guard.missed();
        let warning = guard.health().health().warning.unwrap();
        assert!(
            warning.starts_with("waiting for disk space: 0.0 MB free, need 2.6 MB"),
            "{warning}"
        );
        // Space back, but probing waits for its back-off.
        free.store(60_000_000, Ordering::SeqCst);
        assert_eq!(guard.poll(), None);
        clock.advance(Duration::from_millis(499));
        assert_eq!(guard.poll(), None);
        clock.advance(Duration::from_millis(1));
        assert_eq!(guard.poll(), Some(DiskState::Ok));
        assert!(reserve.exists() && guard.derived_allowed());
    }

    #[test]
    fn a_slice_that_found_the_disk_full_holds_the_derived_data_until_the_free_space_grows() {
        let dir = tempfile::tempdir().unwrap();
        let (mut guard, free, _clock) = guard(dir.path());
        assert!(guard.derived_allowed());
        // Above storage.min_free_gb, yet a slice could not be written.
        assert!(guard.derived_filled(), "news once");
        free.store(99_000_000, Ordering::SeqCst);
        assert!(!guard.derived_filled(), "said once");
        assert!(!guard.derived_allowed() && guard.may_capture());
        assert_eq!(guard.state(), DiskState::Ok);
        let health = guard.health();
        assert!(health.derived_paused);
        let warning = health.health().warning.unwrap();
        assert!(warning.contains("a slice found the disk full"), "{warning}");
        // Probing on: the free space falls (originals), then grows a little: still held.
        free.store(90_000_000, Ordering::SeqCst);
        assert_eq!(guard.poll(), None);
        free.store(99_500_000, Ordering::SeqCst);
        guard.poll();
        assert!(
            !guard.derived_allowed(),
            "not above the lowest free space by the reserve"
        );
        // Room made: the derived data goes on.
        free.store(99_000_000 + RESERVE_BYTES, Ordering::SeqCst);
        guard.poll();
        assert!(guard.derived_allowed());
        assert!(guard.health().health().warning.is_none());
    }
}
