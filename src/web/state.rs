//! What the page's handlers share: the build directory, what is known of the build, the
//! timeline, the status report, the picture cache and the open event streams.

use super::preview::{Pictures, Rectification};
use super::timeline::{Tails, Timeline};
use crate::build_dir::status::{self, StatusReport};
use crate::config::WebConfig;
use crate::fsutil::FileIdentity;
use crate::geometry::Grid;
use crate::series::BuildRecord;
use crate::shot::View;
use crate::shutdown::Shutdown;
use crate::vectors::{LayerIndex, VectorError};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex, OnceLock, RwLock};
use tokio::sync::{watch, Semaphore};

/// What is known of the build from its configuration snapshot (once the daemon wrote it).
pub(crate) struct BuildInfo {
    pub views: Vec<View>,
    pub grid: Grid,
    pub rectification: Option<Rectification>,
    /// What the pictures are made with (the grid, the calibration, this program's version), as
    /// a digest: part of each picture's validator, so a calibration changed since is another
    /// picture.
    pub made_with: String,
    pub vectors_file: Option<PathBuf>,
    /// How printer layers pair with the vector file's layers (docs/frames.md).
    pub numbering: crate::vectors::LayerNumbering,
    pub vectors: OnceLock<Result<LayerIndex, Arc<VectorError>>>,
    /// What the status report takes from the build's configuration.
    pub report: status::ReportSettings,
    /// The build's inspection settings (the trends' drift baseline).
    pub inspection: crate::config::inspection::InspectionConfig,
}

impl BuildInfo {
    fn open(dir: &Path) -> Option<BuildInfo> {
        let record = BuildRecord::open(dir).ok()?;
        let made_with = format!(
            "{:?}|{:?}|{}",
            record.grid,
            record.calibration,
            env!("CARGO_PKG_VERSION")
        );
        Some(BuildInfo {
            made_with: crate::fsutil::sha256_hex(made_with.as_bytes()),
            views: record.config.views.all(),
            grid: record.grid,
            rectification: record.calibration.map(|calibration| Rectification {
                calibration,
                grid: record.grid,
            }),
            vectors_file: record.config.build.vectors.clone(),
            numbering: record.config.build.numbering(),
            vectors: OnceLock::new(),
            report: crate::series::report_settings(Some(&record.config)),
            inspection: record.config.inspection.clone(),
        })
    }

    /// The vector file's layer index, read once.
    pub fn vectors(&self) -> Option<Result<&LayerIndex, Arc<VectorError>>> {
        let path = self.vectors_file.as_ref()?;
        Some(
            self.vectors
                .get_or_init(|| LayerIndex::build(path).map_err(Arc::new))
                .as_ref()
                .map_err(Arc::clone),
        )
    }
}

/// Everything the handlers share.
pub(crate) struct PageState {
    pub dir: PathBuf,
    pub config: WebConfig,
    pub token: Option<String>,
    pub timeline: RwLock<Timeline>,
    /// The logs' readers: only the watch reads, outside the timeline's lock.
    pub tails: Mutex<Tails>,
    pub status: RwLock<Option<Arc<StatusReport>>>,
    /// The build's settings as last read, with the identity of the files they were read from
    /// and when ([`PageState::info`]).
    pub(super) info: Mutex<Option<ReadInfo>>,
    pub pictures: Pictures,
    /// Pictures are made one at a time: the page never takes more than one core.
    pub encode: Semaphore,
    /// The open connections (who gives way when they run out).
    pub clients: Arc<super::clients::Clients>,
    pub updates: watch::Sender<u64>,
    pub streams: AtomicUsize,
    /// The server's stop: open event streams end on it.
    pub stop: Shutdown,
}

/// The build's settings as read: from which files (the configuration snapshot and the
/// calibration copy, as they were), when, and what they gave.
pub(crate) struct ReadInfo {
    files: [Option<FileIdentity>; 2],
    at: std::time::Instant,
    info: Option<Arc<BuildInfo>>,
}

/// How long settings that could not be read are not tried again (each request would read them
/// again meanwhile, a vector file among them).
const RETRY_SETTINGS: std::time::Duration = std::time::Duration::from_secs(5);

impl PageState {
    /// The build's configuration snapshot and calibration, read again when either file changes
    /// (a daemon started again with a new calibration; a new build writes the configuration
    /// first, the calibration after it). Settings that could not be read are tried again after
    /// [`RETRY_SETTINGS`]. Pictures made with other settings are forgotten.
    pub fn info(&self) -> Option<Arc<BuildInfo>> {
        let identity = |name: &str| {
            let m = std::fs::metadata(self.dir.join(name)).ok()?;
            Some(FileIdentity::of(&m))
        };
        let files = [
            identity(crate::build_dir::CONFIG_SNAPSHOT),
            identity(crate::build_dir::CALIBRATION_COPY),
        ];
        let mut read = self.info.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(r) = read.as_ref() {
            if r.files == files && (r.info.is_some() || r.at.elapsed() < RETRY_SETTINGS) {
                return r.info.clone();
            }
        }
        let info = BuildInfo::open(&self.dir).map(Arc::new);
        let made_with = |r: &ReadInfo| r.info.as_ref().map(|i| i.made_with.clone());
        let before = read.as_ref().and_then(made_with);
        let now = ReadInfo {
            files,
            at: std::time::Instant::now(),
            info: info.clone(),
        };
        if before.is_some() && before != made_with(&now) {
            self.pictures.forget_all();
        }
        *read = Some(now);
        info
    }

    /// The build's settings for its status report (the configuration's defaults until its
    /// snapshot exists).
    fn report_settings(&self) -> status::ReportSettings {
        self.info()
            .map_or_else(|| crate::series::report_settings(None), |i| i.report)
    }

    /// Makes the status report again (blocking).
    pub fn refresh_status(&self) -> Option<Arc<StatusReport>> {
        let report = status::report(&self.dir, self.report_settings())
            .ok()
            .map(Arc::new);
        *self.status.write().unwrap_or_else(|e| e.into_inner()) = report.clone();
        report
    }
}
