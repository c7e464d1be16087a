//! `[storage]`: how the build's files are written and how much may wait for processing.

use super::Invalid;
use serde::{Deserialize, Serialize};

/// Largest processing queue: it holds references, but a bound keeps a typo from reserving memory.
pub const MAX_QUEUE: usize = 100_000;

/// A key left out takes its value from [`StorageConfig::default`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StorageConfig {
    /// fsync originals, sidecars and the journal (off only for throwaway demos on slow disks).
    pub fsync: bool,
    /// Frames waiting for processing held as references; beyond it they wait on disk.
    pub queue_capacity: usize,
    /// Warn when free space falls below this.
    pub min_free_gb: f64,
    /// Transfer syntax of the live DICOM series: none, deflate, or jpeg-ls (lossless).
    pub dicom: crate::dicom::Compression,
}

impl Default for StorageConfig {
    fn default() -> Self {
        StorageConfig {
            fsync: true,
            queue_capacity: 64,
            min_free_gb: 20.0,
            // Explicit VR little endian: what every reader and validator takes.
            dicom: crate::dicom::Compression::None,
        }
    }
}

impl StorageConfig {
    /// Checks the section: a free-space floor of 0 GB or more and a queue of 1 to [`MAX_QUEUE`].
    pub fn validate(&self) -> Result<(), Invalid> {
        if !(self.min_free_gb.is_finite() && self.min_free_gb >= 0.0) {
            return Err(Invalid::new(
                "storage.min_free_gb",
                "must be a finite number of GB, 0 or more",
            ));
        }
        if self.queue_capacity == 0 || self.queue_capacity > MAX_QUEUE {
            return Err(Invalid::new(
                "storage.queue_capacity",
                format!("must be 1 to {MAX_QUEUE} (frames wait on disk when the queue is full)"),
            ));
        }
        Ok(())
    }

    /// Whether this binary can write the configured transfer syntax (JPEG-LS needs the
    /// `jpegls` feature: without it every slice would fail).
    pub fn check_backend(&self) -> Result<(), Invalid> {
        if self.dicom == crate::dicom::Compression::JpegLs && cfg!(not(feature = "jpegls")) {
            return Err(Invalid::new(
                "storage.dicom",
                "\"jpeg-ls\" needs a layerwise built with the `jpegls` feature (cargo build \
                 --release --features jpegls, with cmake and g++ installed); this one was built \
                 without it: use \"deflate\" or \"none\"",
            ));
        }
        Ok(())
    }
}
