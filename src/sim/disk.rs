//! A simulated build disk: the free space a test sets, for the daemon's disk guard
//! (`RunOptions::free_space`) without filling a real filesystem.

use crate::fsutil::FreeSpace;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// Free space as a test says; clones share it.
#[derive(Clone, Debug)]
pub struct SimulatedDisk {
    free: Arc<AtomicU64>,
}

impl SimulatedDisk {
    pub fn with_free(bytes: u64) -> SimulatedDisk {
        SimulatedDisk {
            free: Arc::new(AtomicU64::new(bytes)),
        }
    }

    pub fn set_free(&self, bytes: u64) {
        self.free.store(bytes, Ordering::SeqCst);
    }
}

impl FreeSpace for SimulatedDisk {
    fn free_bytes(&self, _path: &Path) -> std::io::Result<u64> {
        Ok(self.free.load(Ordering::SeqCst))
    }
}
