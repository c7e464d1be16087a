//! The build directory: its layout (docs/frames.md names every file), the manifest fixed at the
//! build's start, the append-only journal and the live status. The daemon writes it; `status`,
//! export, locate and registration read it.

pub mod alarm;
pub mod health;
pub mod inspection;
pub mod journal;
pub mod lifecycle;
pub mod lines;
pub mod manifest;
pub mod original;
pub mod progress;
pub mod pushlog;
pub mod status;

pub use journal::{IrregularSignal, Journal, JournalError, Record, Replay};
pub use manifest::BuildManifest;
pub use progress::Progress;

use crate::shot::View;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const MANIFEST: &str = "build.json";
pub const STATUS: &str = "status.json";
pub const JOURNAL: &str = "journal.jsonl";
/// One record per inspected layer (build_dir::inspection).
pub const INSPECTION: &str = "inspection.jsonl";
/// The inspection alarm's history: raised, acknowledged, cleared (build_dir::alarm).
pub const ALARM: &str = "alarm.jsonl";
/// The operators' verdicts on flags, confirmed or a false alarm (learn::verdicts).
pub const VERDICTS: &str = "verdicts.jsonl";
/// The configuration the daemon last ran with.
pub const CONFIG_SNAPSHOT: &str = "config.toml";
/// The calibration the daemon last ran with.
pub const CALIBRATION_COPY: &str = "calibration.toml";

/// Space the daemon keeps in hand (real blocks, zeros) and gives up when the disk fills, so that
/// it can still journal the frames it misses and say so in status.json.
pub const DISK_RESERVE: &str = ".disk-reserve";

/// Originals and their sidecars: `raw/L{layer:05}_{phase}_{light}.{ext}` and `.json`.
pub const RAW_DIR: &str = "raw";
/// The live series, one folder per view.
pub const DICOM_DIR: &str = "dicom";

/// The largest small file of a build directory read whole (build.json, status.json, a
/// sidecar): each is a few KB.
pub const MAX_RECORD_BYTES: u64 = 16 << 20;

/// Reads one of the build directory's small files whole (build.json, status.json, a sidecar):
/// a regular file of at most [`MAX_RECORD_BYTES`], never through a symbolic link (a FIFO, a
/// device or a planted link is refused, never waited on or followed).
pub fn read_record_file(path: &Path) -> std::io::Result<Vec<u8>> {
    crate::fsutil::read_file_bounded(
        crate::fsutil::open_regular_nofollow(path)?,
        MAX_RECORD_BYTES,
    )
}

/// A folder that is not a build directory where one is expected.
#[derive(Debug, thiserror::Error)]
#[error(
    "{}: not a layerwise build directory (no {JOURNAL}); pass the build's folder (the daemon's \
     build.output_dir, or a folder under [build] builds_dir)",
    .0.display()
)]
pub struct NotABuild(pub PathBuf);

/// Whether `dir` is a build directory (it holds the journal): every command that reads or
/// writes a build's own files asks first, so a mistyped folder is an error, never "nothing
/// there".
pub fn require_build(dir: &Path) -> Result<(), NotABuild> {
    if dir.join(JOURNAL).is_file() {
        Ok(())
    } else {
        Err(NotABuild(dir.to_path_buf()))
    }
}

/// The series folder of a view: `dicom/<phase>_<light>/` (docs/frames.md).
pub fn series_dir(build_dir: &Path, view: View) -> PathBuf {
    build_dir.join(DICOM_DIR).join(view.to_string())
}

/// The extensions an original may have (camera JPEG, raw NEF, PNG and TIFF frames).
pub const FRAME_EXTENSIONS: [&str; 5] = ["jpg", "jpeg", "nef", "png", "tif"];

/// The stored original of a shot (first take), whatever its extension, if it is on disk.
pub fn original_path(build_dir: &Path, shot: &crate::shot::Shot) -> Option<PathBuf> {
    FRAME_EXTENSIONS
        .iter()
        .map(|ext| build_dir.join(format!("{RAW_DIR}/{}.{ext}", shot.stem())))
        .find(|p| p.exists())
}

/// What the sidecar next to each original says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    pub layer: u32,
    pub phase: crate::shot::Phase,
    pub light: crate::shot::Light,
    pub file: String,
    pub bytes: u64,
    pub sha256: String,
    pub event_at: DateTime<Utc>,
    pub captured_at: DateTime<Utc>,
    pub capture_ms: f64,
    pub download_ms: f64,
    pub attempts: u32,
    pub camera: BTreeMap<String, String>,
}
