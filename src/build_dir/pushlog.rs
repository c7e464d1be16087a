//! The push log of a build (or an export folder) to one archive: `pacs/<name>.jsonl`, one JSON
//! object per instance the archive confirmed or rejected, appended and fsynced, plus the errors
//! that kept the archive out of reach. What is still to push is every DICOM file on disk not in
//! the log, so the queue survives any stop: nothing is forgotten, nothing confirmed is sent again.

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use super::lines::MAX_LOG_BYTES;

/// The folder of the push logs, inside the build directory or export folder.
pub const PACS_DIR: &str = "pacs";

/// The log of destination `name` under `root`.
pub fn log_path(root: &Path, name: &str) -> PathBuf {
    root.join(PACS_DIR).join(format!("{name}.jsonl"))
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum PushRecord {
    /// The archive confirmed it holds the instance.
    Stored {
        file: String,
        sop_instance_uid: String,
        at: DateTime<Utc>,
    },
    /// The archive refused the instance, for this reason: not sent again unless asked.
    Rejected {
        file: String,
        sop_instance_uid: String,
        reason: String,
        at: DateTime<Utc>,
    },
    /// The archive could not be reached or refused the association or the credentials.
    Error { message: String, at: DateTime<Utc> },
}

/// Where the push to one destination stands, from its log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PushState {
    pub stored: BTreeSet<String>,
    /// File → the archive's reason.
    pub rejected: BTreeMap<String, String>,
    pub last_error: Option<(String, DateTime<Utc>)>,
    pub last_stored_at: Option<DateTime<Utc>>,
    /// File → the SOP Instance UID the archive confirmed for it, and when: a file rewritten
    /// since with another instance (a retake's slice, `[series] take = "last"`) is pushed again.
    pub stored_instances: BTreeMap<String, (String, DateTime<Utc>)>,
}

impl PushState {
    pub fn apply(&mut self, record: &PushRecord) {
        match record {
            PushRecord::Stored {
                file,
                sop_instance_uid,
                at,
            } => {
                self.rejected.remove(file);
                self.stored.insert(file.clone());
                self.stored_instances
                    .insert(file.clone(), (sop_instance_uid.clone(), *at));
                self.last_stored_at = Some(*at);
            }
            PushRecord::Rejected { file, reason, .. } => {
                if !self.stored.contains(file) {
                    self.rejected.insert(file.clone(), reason.clone());
                }
            }
            PushRecord::Error { message, at } => self.last_error = Some((message.clone(), *at)),
        }
    }

    /// Whether `file` needs no push: confirmed, or rejected (unless rejected ones are retried).
    pub fn is_done(&self, file: &str, retry_rejected: bool) -> bool {
        self.stored.contains(file) || (!retry_rejected && self.rejected.contains_key(file))
    }

    /// Whether `file` (under `root`) was confirmed but has been rewritten since with another
    /// instance: its modification time is after the confirmation and its SOP Instance UID is
    /// not the confirmed one. Only rewritten files are read.
    pub fn replaced(&self, root: &Path, file: &str) -> bool {
        let Some((uid, at)) = self.stored_instances.get(file) else {
            return false;
        };
        let path = root.join(file);
        let modified = std::fs::metadata(&path)
            .and_then(|m| m.modified())
            .map(DateTime::<Utc>::from);
        match modified {
            Ok(modified) if modified >= *at => {
                crate::dicom::file_instance_uid(&path).is_some_and(|now| now != *uid)
            }
            _ => false,
        }
    }
}

#[derive(Debug, thiserror::Error)]
#[error("push log {path}: cannot read or write")]
pub struct PushLogError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// An open push log, appended to with fsync.
pub struct PushLog {
    path: PathBuf,
    file: File,
}

impl PushLog {
    /// Opens (creating) the log and replays it; a torn last line (a crash in mid-write) is cut.
    pub fn open(path: &Path) -> Result<(PushLog, PushState), PushLogError> {
        let io = |source| PushLogError {
            path: path.to_path_buf(),
            source,
        };
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let mut file = super::lines::open_append(path).map_err(io)?;
        crate::fsutil::check_size(&file, MAX_LOG_BYTES).map_err(io)?;
        let mut data = Vec::new();
        file.read_to_end(&mut data).map_err(io)?;
        let (state, good_end) = replay(&data);
        if good_end < data.len() {
            file.set_len(good_end as u64).map_err(io)?;
        }
        Ok((
            PushLog {
                path: path.to_path_buf(),
                file,
            },
            state,
        ))
    }

    pub fn append(&mut self, record: &PushRecord) -> Result<(), PushLogError> {
        let io = |source| PushLogError {
            path: self.path.clone(),
            source,
        };
        let mut line = serde_json::to_vec(record).map_err(|e| io(std::io::Error::other(e)))?;
        line.push(b'\n');
        self.file.write_all(&line).map_err(io)?;
        self.file.sync_data().map_err(io)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// The state of a log's bytes and the end of its last complete, readable line. A damaged line
/// is skipped: the worst it can cost is one instance sent again, which archives take as a no-op.
fn replay(data: &[u8]) -> (PushState, usize) {
    let mut state = PushState::default();
    let mut offset = 0;
    let mut good_end = 0;
    while let Some(i) = data[offset..].iter().position(|&b| b == b'\n') {
        if let Ok(record) = serde_json::from_slice::<PushRecord>(&data[offset..offset + i]) {
            state.apply(&record);
        }
        offset += i + 1;
        good_end = offset;
    }
    (state, good_end)
}

/// The log's state without opening it for writing (for `layerwise status`); no log, no pushes.
/// A log that is not a regular file of at most [`MAX_LOG_BYTES`] is read as none (the push
/// itself refuses it, naming it).
pub fn read(path: &Path) -> PushState {
    let Ok(Some(file)) = super::lines::open_read(path, MAX_LOG_BYTES) else {
        return PushState::default();
    };
    crate::fsutil::read_file_bounded(file, MAX_LOG_BYTES)
        .map(|data| replay(&data).0)
        .unwrap_or_default()
}

/// The DICOM instances of `root`, as paths relative to it, sorted: the live series under
/// `dicom/` of a build directory, or every `*.dcm` below an export folder. Temporary files of
/// atomic writes are not instances yet.
pub fn instances(root: &Path) -> Vec<String> {
    let base = if root.join(super::JOURNAL).exists() {
        root.join(super::DICOM_DIR)
    } else {
        root.to_path_buf()
    };
    let mut out = Vec::new();
    collect(root, &base, &mut out);
    out.sort();
    out
}

fn collect(root: &Path, dir: &Path, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        match entry.file_type() {
            Ok(t) if t.is_dir() && name != PACS_DIR => collect(root, &entry.path(), out),
            Ok(t)
                if t.is_file()
                    && name.to_ascii_lowercase().ends_with(".dcm")
                    && !crate::fsutil::is_temporary(&name) =>
            {
                if let Ok(relative) = entry.path().strip_prefix(root) {
                    out.push(relative.to_string_lossy().into_owned());
                }
            }
            _ => {}
        }
    }
}

/// One destination's push as `layerwise status` shows it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PushSummary {
    pub destination: String,
    pub pushed: usize,
    pub pending: usize,
    pub failed: usize,
    /// The first rejections with the archive's reason: `dicom/pre_top/L00003.dcm: …`.
    pub rejected: Vec<String>,
    pub last_error: Option<String>,
    pub last_error_at: Option<DateTime<Utc>>,
    pub last_pushed_at: Option<DateTime<Utc>>,
}

/// The summary of every push log under `root` (one per destination ever pushed to).
pub fn summaries(root: &Path) -> Vec<PushSummary> {
    let names = log_names(root);
    if names.is_empty() {
        return Vec::new();
    }
    let files = instances(root);
    names
        .into_iter()
        .map(|name| summary(&name, &read(&log_path(root, &name)), &files))
        .collect()
}

/// The summary of one destination's state against the instances on disk.
pub fn summary(name: &str, state: &PushState, files: &[String]) -> PushSummary {
    PushSummary {
        destination: name.to_string(),
        pushed: state.stored.len(),
        pending: files.iter().filter(|f| !state.is_done(f, false)).count(),
        failed: state.rejected.len(),
        rejected: state
            .rejected
            .iter()
            .take(10)
            .map(|(f, r)| format!("{f}: {r}"))
            .collect(),
        last_error: state.last_error.as_ref().map(|(m, _)| m.clone()),
        last_error_at: state.last_error.as_ref().map(|(_, at)| *at),
        last_pushed_at: state.last_stored_at,
    }
}

impl std::fmt::Display for PushSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "pacs       {}: {} pushed, {} pending, {} failed",
            self.destination, self.pushed, self.pending, self.failed
        )?;
        if let Some(at) = self.last_pushed_at {
            write!(f, ", last push {}", at.format("%Y-%m-%d %H:%M:%S"))?;
        }
        writeln!(f)?;
        for r in &self.rejected {
            writeln!(f, "  rejected {r}")?;
        }
        if let (Some(message), Some(at)) = (&self.last_error, self.last_error_at) {
            writeln!(
                f,
                "  last error {}: {message}",
                at.format("%Y-%m-%d %H:%M:%S")
            )?;
        }
        Ok(())
    }
}

/// The destinations `root` has push logs for (`pacs/<name>.jsonl`), sorted.
pub fn log_names(root: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(root.join(PACS_DIR)) else {
        return Vec::new();
    };
    let mut names: Vec<String> = entries
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
        .filter_map(|e| {
            e.file_name()
                .to_str()
                .and_then(|n| n.strip_suffix(".jsonl"))
                .map(str::to_string)
        })
        .collect();
    names.sort();
    names
}

/// Where forgotten push logs are kept: `pacs/forgotten/`, out of `status` and of the queue.
pub const FORGOTTEN_DIR: &str = "forgotten";

/// Forgets the destination `name` of `root` (a mistaken archive, one retired): its push log
/// moves to `pacs/forgotten/<name>-<time>.jsonl`, so `status` no longer counts its pending
/// instances and nothing in it is lost. Returns where the log went.
pub fn forget(root: &Path, name: &str, at: DateTime<Utc>) -> Result<PathBuf, PushLogError> {
    let from = log_path(root, name);
    let dir = root.join(PACS_DIR).join(FORGOTTEN_DIR);
    let to = dir.join(format!("{name}-{}.jsonl", at.format("%Y%m%dT%H%M%SZ")));
    std::fs::create_dir_all(&dir)
        .and_then(|()| std::fs::rename(&from, &to))
        .map_err(|source| PushLogError { path: from, source })?;
    Ok(to)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stored(file: &str) -> PushRecord {
        PushRecord::Stored {
            file: file.into(),
            sop_instance_uid: "1.2".into(),
            at: Utc::now(),
        }
    }

    #[test]
    fn the_log_survives_a_torn_line_and_pending_is_disk_minus_log() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        std::fs::write(root.join(super::super::JOURNAL), b"").unwrap();
        let series = root.join("dicom/pre_top");
        std::fs::create_dir_all(&series).unwrap();
        for name in [
            "L00001.dcm",
            "L00002.dcm",
            "L00003.dcm",
            ".L00004.dcm.1.0.tmp",
        ] {
            std::fs::write(series.join(name), b"x").unwrap();
        }
        let path = log_path(root, "orthanc");
        let (mut log, state) = PushLog::open(&path).unwrap();
        assert_eq!(state, PushState::default());
        log.append(&stored("dicom/pre_top/L00001.dcm")).unwrap();
        log.append(&PushRecord::Rejected {
            file: "dicom/pre_top/L00002.dcm".into(),
            sop_instance_uid: "1.3".into(),
            reason: "no".into(),
            at: Utc::now(),
        })
        .unwrap();
        drop(log);
        // A crash in the middle of the next line.
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        file.write_all(b"{\"kind\":\"stored\",\"fi").unwrap();
        drop(file);
        let (mut log, state) = PushLog::open(&path).unwrap();
        assert_eq!(state.stored.len(), 1);
        assert_eq!(state.rejected.len(), 1);
        log.append(&stored("dicom/pre_top/L00003.dcm")).unwrap();
        let all = summaries(root);
        assert_eq!(all.len(), 1);
        assert_eq!((all[0].pushed, all[0].pending, all[0].failed), (2, 0, 1));
        assert_eq!(instances(root).len(), 3, "{:?}", instances(root));
        // A forgotten destination leaves status, its log kept aside.
        let kept = forget(root, "orthanc", Utc::now()).unwrap();
        assert!(kept.is_file() && summaries(root).is_empty());
        assert_eq!(instances(root).len(), 3);
        assert!(forget(root, "orthanc", Utc::now()).is_err(), "nothing left");
        let path = kept;
        // The torn line was cut, so every line of the log parses.
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text
            .lines()
            .all(|l| serde_json::from_str::<PushRecord>(l).is_ok()));
    }
}
