//! The append-only journal of a build: every signal, frame, missing frame and processing result,
//! one JSON object per line, fsynced. Replaying it after a crash restores where the build stands.

use crate::shot::{Light, Phase, Shot};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use tracing::warn;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Record {
    Start {
        at: DateTime<Utc>,
        pid: u32,
        version: String,
    },
    Event {
        layer: u32,
        phase: Phase,
        at: DateTime<Utc>,
    },
    Frame {
        layer: u32,
        phase: Phase,
        light: Light,
        file: String,
        bytes: u64,
        sha256: String,
        at: DateTime<Utc>,
    },
    Missing {
        layer: u32,
        phase: Phase,
        light: Light,
        reason: String,
        at: DateTime<Utc>,
    },
    Processed {
        layer: u32,
        phase: Phase,
        light: Light,
        at: DateTime<Utc>,
    },
    ProcessingFailed {
        layer: u32,
        phase: Phase,
        light: Light,
        reason: String,
        at: DateTime<Utc>,
    },
    Stop {
        reason: String,
        at: DateTime<Utc>,
    },
}

#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: line {line}: not a journal record ({message}); move the file aside to start a new build, or fix that line")]
    Corrupt {
        path: PathBuf,
        line: usize,
        message: String,
    },
}

/// A captured frame as the journal knows it.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameEntry {
    pub file: String,
    pub bytes: u64,
    pub at: DateTime<Utc>,
}

/// Where the build stands, from replaying the journal.
#[derive(Clone, Debug, Default)]
pub struct Replay {
    pub frames: BTreeMap<Shot, FrameEntry>,
    pub missing: BTreeMap<Shot, String>,
    pub processed: BTreeSet<Shot>,
    pub last_event: Option<(u32, Phase)>,
    pub starts: u32,
}

impl Replay {
    pub fn apply(&mut self, record: &Record) {
        match record {
            Record::Start { .. } => self.starts += 1,
            Record::Event { layer, phase, .. } => self.last_event = Some((*layer, *phase)),
            Record::Frame {
                layer,
                phase,
                light,
                file,
                bytes,
                at,
                ..
            } => {
                let shot = Shot {
                    layer: *layer,
                    phase: *phase,
                    light: *light,
                };
                self.missing.remove(&shot);
                self.frames.insert(
                    shot,
                    FrameEntry {
                        file: file.clone(),
                        bytes: *bytes,
                        at: *at,
                    },
                );
            }
            Record::Missing {
                layer,
                phase,
                light,
                reason,
                ..
            } => {
                let shot = Shot {
                    layer: *layer,
                    phase: *phase,
                    light: *light,
                };
                if !self.frames.contains_key(&shot) {
                    self.missing.insert(shot, reason.clone());
                }
            }
            Record::Processed {
                layer,
                phase,
                light,
                ..
            } => {
                self.processed.insert(Shot {
                    layer: *layer,
                    phase: *phase,
                    light: *light,
                });
            }
            Record::ProcessingFailed { .. } | Record::Stop { .. } => {}
        }
    }

    /// A shot that needs no capture: stored, or given up on.
    pub fn is_done(&self, shot: &Shot) -> bool {
        self.frames.contains_key(shot) || self.missing.contains_key(shot)
    }

    /// Stored frames not yet processed, in build order.
    pub fn unprocessed(&self) -> Vec<Shot> {
        self.frames
            .keys()
            .filter(|s| !self.processed.contains(s))
            .copied()
            .collect()
    }
}

pub struct Journal {
    path: PathBuf,
    file: File,
    fsync: bool,
}

impl Journal {
    /// Opens (creating) the journal and replays it. A torn last line, left by a crash in the middle
    /// of a write, is cut off; damage anywhere else is an error, since it may hide frames.
    pub fn open(path: &Path, fsync: bool) -> Result<(Journal, Replay), JournalError> {
        let io = |source| JournalError::Io {
            path: path.to_path_buf(),
            source,
        };
        let mut file = OpenOptions::new()
            .create(true)
            .read(true)
            .append(true)
            .open(path)
            .map_err(io)?;
        let replay = Self::replay_file(path, &mut file)?;
        Ok((
            Journal {
                path: path.to_path_buf(),
                file,
                fsync,
            },
            replay,
        ))
    }

    /// Replays a journal without opening it for writing (for `layerwise status`).
    pub fn read(path: &Path) -> Result<Replay, JournalError> {
        let mut file = File::open(path).map_err(|source| JournalError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut replay = Replay::default();
        Self::scan(path, &mut file, |r| replay.apply(&r), false)?;
        Ok(replay)
    }

    fn replay_file(path: &Path, file: &mut File) -> Result<Replay, JournalError> {
        let mut replay = Replay::default();
        let good_end = Self::scan(path, file, |r| replay.apply(&r), true)?;
        let len = file
            .metadata()
            .map_err(|source| JournalError::Io {
                path: path.to_path_buf(),
                source,
            })?
            .len();
        if good_end < len {
            warn!(journal = %path.display(), bytes = len - good_end, "journal: cutting off a torn last record left by a crash");
            file.set_len(good_end).map_err(|source| JournalError::Io {
                path: path.to_path_buf(),
                source,
            })?;
        }
        Ok(replay)
    }

    /// Calls `each` for every record; returns the byte offset after the last good line.
    fn scan(
        path: &Path,
        file: &mut File,
        mut each: impl FnMut(Record),
        tolerate_torn_tail: bool,
    ) -> Result<u64, JournalError> {
        let io = |source| JournalError::Io {
            path: path.to_path_buf(),
            source,
        };
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        let mut reader = BufReader::new(&mut *file);
        let mut line = String::new();
        let mut offset = 0u64;
        let mut number = 0usize;
        loop {
            line.clear();
            let n = match reader.read_line(&mut line) {
                Ok(n) => n,
                // Invalid UTF-8 in the last line is a torn write too.
                Err(e) if e.kind() == std::io::ErrorKind::InvalidData && tolerate_torn_tail => {
                    return Ok(offset)
                }
                Err(e) => return Err(io(e)),
            };
            if n == 0 {
                return Ok(offset);
            }
            number += 1;
            let complete = line.ends_with('\n');
            match serde_json::from_str::<Record>(line.trim_end()) {
                Ok(record) if complete || !tolerate_torn_tail => {
                    each(record);
                    offset += n as u64;
                }
                Ok(_) => return Ok(offset),
                Err(e) => {
                    let at_end = {
                        let mut rest = String::new();
                        matches!(reader.read_line(&mut rest), Ok(0))
                    };
                    if at_end && tolerate_torn_tail {
                        return Ok(offset);
                    }
                    return Err(JournalError::Corrupt {
                        path: path.to_path_buf(),
                        line: number,
                        message: e.to_string(),
                    });
                }
            }
        }
    }

    pub fn append(&mut self, record: &Record) -> Result<(), JournalError> {
        let io = |source| JournalError::Io {
            path: self.path.clone(),
            source,
        };
        let mut line = serde_json::to_vec(record).map_err(|e| io(std::io::Error::other(e)))?;
        line.push(b'\n');
        self.file.write_all(&line).map_err(io)?;
        if self.fsync {
            self.file.sync_data().map_err(io)?;
        }
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(layer: u32) -> Record {
        Record::Frame {
            layer,
            phase: Phase::Post,
            light: Light::Top,
            file: format!("raw/L{layer:05}_post_top.jpg"),
            bytes: 10,
            sha256: "00".into(),
            at: Utc::now(),
        }
    }

    #[test]
    fn replays_and_cuts_a_torn_tail() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.jsonl");
        {
            let (mut j, replay) = Journal::open(&path, true).unwrap();
            assert!(replay.frames.is_empty());
            j.append(&Record::Event {
                layer: 1,
                phase: Phase::Post,
                at: Utc::now(),
            })
            .unwrap();
            j.append(&frame(1)).unwrap();
        }
        let good = std::fs::metadata(&path).unwrap().len();
        std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap()
            .write_all(b"{\"kind\":\"frame\",\"lay")
            .unwrap();
        let (mut j, replay) = Journal::open(&path, true).unwrap();
        assert_eq!(std::fs::metadata(&path).unwrap().len(), good);
        assert_eq!(replay.last_event, Some((1, Phase::Post)));
        assert!(replay.is_done(&Shot {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top
        }));
        assert_eq!(replay.unprocessed().len(), 1);
        j.append(&frame(2)).unwrap();
        assert_eq!(Journal::read(&path).unwrap().frames.len(), 2);
    }

    #[test]
    fn damage_in_the_middle_is_an_error_naming_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.jsonl");
        let good = serde_json::to_string(&frame(1)).unwrap();
        std::fs::write(&path, format!("{good}\ngarbage\n{good}\n")).unwrap();
        let err = Journal::open(&path, false).err().unwrap().to_string();
        assert!(
            err.contains("journal.jsonl") && err.contains("line 2"),
            "{err}"
        );
        assert_eq!(
            std::fs::read_to_string(&path).unwrap().lines().count(),
            3,
            "nothing was cut"
        );
    }

    #[test]
    fn a_frame_overrides_missing() {
        let mut r = Replay::default();
        let shot = Shot {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
        };
        r.apply(&Record::Missing {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
            reason: "x".into(),
            at: Utc::now(),
        });
        r.apply(&frame(1));
        assert!(r.missing.is_empty() && r.frames.contains_key(&shot));
    }
}
