//! The append-only journal of a build: every signal, frame, missing frame and processing result,
//! one JSON object per line, fsynced. Replaying it after a crash restores where the build stands.

use crate::shot::{Light, Phase, Shot};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::fs::File;
use std::path::{Path, PathBuf};
use tracing::warn;

use super::lines::{append_line, open_lines, open_read, scan_lines, MAX_JOURNAL_BYTES};
pub use super::lines::{JournalError, LineError};

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
        /// The take whose processing failed; absent in journals written before it was
        /// recorded, which are read as before (the takes stored when the failure was
        /// journaled).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        take: Option<u32>,
        reason: String,
        at: DateTime<Utc>,
    },
    Stop {
        reason: String,
        at: DateTime<Utc>,
    },
    /// A frame taken again for a (layer, phase) already stored, kept beside the first take
    /// (`raw/L…_{phase}_{light}.r{take}.{ext}`); the series keep showing the first take.
    Retake {
        layer: u32,
        phase: Phase,
        light: Light,
        take: u32,
        file: String,
        bytes: u64,
        sha256: String,
        at: DateTime<Utc>,
    },
    /// The series slice of a shot now shows take `take` > 1, a retake (`[series] take = "last"`);
    /// a `Processed` record says the same of the first take.
    SliceTake {
        layer: u32,
        phase: Phase,
        light: Light,
        take: u32,
        at: DateTime<Utc>,
    },
    /// A layer signal out of the expected order: repeated, skipping layers, going backwards, or a
    /// layer number no printer uses.
    Irregular {
        layer: u32,
        phase: Phase,
        signal: IrregularSignal,
        detail: String,
        at: DateTime<Utc>,
    },
}

/// How a layer signal broke the expected order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IrregularSignal {
    /// The same (layer, phase) again: its frames are retaken.
    Repeated,
    /// Layers between the previous signal and this one never came.
    Skipped,
    /// A layer or phase before the previous signal.
    Backwards,
    /// Layer 0, or beyond the five digits of the file names: not captured.
    OutOfRange,
}

impl std::fmt::Display for IrregularSignal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            IrregularSignal::Repeated => "repeated signal",
            IrregularSignal::Skipped => "skipped layers",
            IrregularSignal::Backwards => "signal going backwards",
            IrregularSignal::OutOfRange => "layer out of range",
        })
    }
}

/// An irregular signal as `status` lists it.
#[derive(Clone, Debug, PartialEq)]
pub struct IrregularEntry {
    pub layer: u32,
    pub phase: Phase,
    pub signal: IrregularSignal,
    pub detail: String,
    pub at: DateTime<Utc>,
}

/// A captured frame as the journal knows it.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameEntry {
    pub file: String,
    pub bytes: u64,
    pub at: DateTime<Utc>,
}

impl FrameEntry {
    fn new(file: &str, bytes: u64, at: DateTime<Utc>) -> FrameEntry {
        FrameEntry {
            file: file.to_string(),
            bytes,
            at,
        }
    }
}

impl Record {
    /// The frame a record is about, for the records that are about one.
    pub fn shot(&self) -> Option<Shot> {
        match *self {
            Record::Frame {
                layer,
                phase,
                light,
                ..
            }
            | Record::Missing {
                layer,
                phase,
                light,
                ..
            }
            | Record::Processed {
                layer,
                phase,
                light,
                ..
            }
            | Record::ProcessingFailed {
                layer,
                phase,
                light,
                ..
            }
            | Record::Retake {
                layer,
                phase,
                light,
                ..
            }
            | Record::SliceTake {
                layer,
                phase,
                light,
                ..
            } => Some(Shot {
                layer,
                phase,
                light,
            }),
            _ => None,
        }
    }
}

/// Where the build stands, from replaying the journal.
#[derive(Clone, Debug, Default)]
pub struct Replay {
    pub frames: BTreeMap<Shot, FrameEntry>,
    pub missing: BTreeMap<Shot, String>,
    /// Every shot ever recorded missing while it had no frame, including those a retake stored
    /// later: what only grows (the missing frames counter of `/metrics`).
    pub ever_missing: BTreeSet<Shot>,
    pub processed: BTreeSet<Shot>,
    pub last_event: Option<(u32, Phase)>,
    pub starts: u32,
    /// Takes after the first, per shot, in order.
    pub retakes: BTreeMap<Shot, Vec<FrameEntry>>,
    pub irregular: Vec<IrregularEntry>,
    /// The take a shot's series slice shows when it is a retake (`Record::SliceTake`).
    pub slice_takes: BTreeMap<Shot, u32>,
    /// Shots whose processing failed last (`Record::ProcessingFailed`, none since processed):
    /// the take that failed, and why.
    pub failed: BTreeMap<Shot, (u32, String)>,
}

impl Replay {
    pub fn apply(&mut self, record: &Record) {
        match (record, record.shot()) {
            (Record::Start { .. }, _) => self.starts += 1,
            // A layer no printer uses (flagged out of range) does not move the build on.
            (Record::Event { layer, phase, .. }, _)
                if (1..=crate::shot::MAX_LAYER).contains(layer) =>
            {
                self.last_event = Some((*layer, *phase))
            }
            (
                Record::Frame {
                    file, bytes, at, ..
                },
                Some(shot),
            ) => {
                self.missing.remove(&shot);
                self.frames.insert(shot, FrameEntry::new(file, *bytes, *at));
            }
            (Record::Missing { reason, .. }, Some(shot)) if !self.frames.contains_key(&shot) => {
                self.missing.insert(shot, reason.clone());
                self.ever_missing.insert(shot);
            }
            (Record::Processed { .. }, Some(shot)) => {
                self.processed.insert(shot);
                self.failed.remove(&shot);
            }
            (Record::SliceTake { take, .. }, Some(shot)) => {
                self.slice_takes.insert(shot, *take);
                self.failed.remove(&shot);
            }
            (Record::ProcessingFailed { take, reason, .. }, Some(shot)) => {
                let take = take.unwrap_or_else(|| self.takes(&shot));
                self.failed.insert(shot, (take, reason.clone()));
            }
            (
                Record::Retake {
                    file, bytes, at, ..
                },
                Some(shot),
            ) => self
                .retakes
                .entry(shot)
                .or_default()
                .push(FrameEntry::new(file, *bytes, *at)),
            (
                Record::Irregular {
                    layer,
                    phase,
                    signal,
                    detail,
                    at,
                },
                _,
            ) => self.irregular.push(IrregularEntry {
                layer: *layer,
                phase: *phase,
                signal: *signal,
                detail: detail.clone(),
                at: *at,
            }),
            _ => {}
        }
    }

    /// A shot that needs no capture: stored, or given up on.
    pub fn is_done(&self, shot: &Shot) -> bool {
        self.frames.contains_key(shot) || self.missing.contains_key(shot)
    }

    /// How many takes of `shot` are stored (0, 1 or more).
    pub fn takes(&self, shot: &Shot) -> u32 {
        let first = u32::from(self.frames.contains_key(shot));
        first + self.retakes.get(shot).map_or(0, |r| r.len() as u32)
    }

    /// The stored take `n` of `shot` (1: the frame, more: its retakes).
    pub fn take_entry(&self, shot: &Shot, n: u32) -> Option<&FrameEntry> {
        match n {
            0 => None,
            1 => self.frames.get(shot),
            n => self.retakes.get(shot)?.get(n as usize - 2),
        }
    }

    /// The take of `shot` its series slice shows now (0: none written yet).
    pub fn slice_take(&self, shot: &Shot) -> u32 {
        self.slice_takes
            .get(shot)
            .copied()
            .unwrap_or(u32::from(self.processed.contains(shot)))
    }

    /// Stored frames whose series slice does not show the take `choice` picks yet, with that
    /// take, in build order: with `First` the frames not processed, with `Last` also the shots
    /// retaken since their slice was written.
    pub fn unprocessed_takes(&self, choice: crate::shot::SeriesTake) -> Vec<(Shot, u32)> {
        self.frames
            .keys()
            .filter_map(|shot| {
                let wanted = choice.shown(self.takes(shot));
                (self.slice_take(shot) < wanted).then_some((*shot, wanted))
            })
            .collect()
    }

    /// Why the processing of take `take` of `shot` failed, if it did (that take or a later one
    /// failed, and nothing was processed since): a failure, not a frame waiting. The next start
    /// tries it again.
    pub fn failure(&self, shot: &Shot, take: u32) -> Option<&str> {
        let (failed_take, reason) = self.failed.get(shot)?;
        (*failed_take >= take).then_some(reason.as_str())
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
    /// Records that could not be written because the disk was full, oldest first: written
    /// before anything else once space returns.
    held: Vec<Record>,
}

impl Journal {
    /// Opens (creating) the journal and replays it. A torn last line, left by a crash in the middle
    /// of a write, is cut off; damage anywhere else is an error, since it may hide frames.
    pub fn open(path: &Path, fsync: bool) -> Result<(Journal, Replay), JournalError> {
        let mut replay = Replay::default();
        let journal = Journal::open_with(path, fsync, |r| replay.apply(&r))?;
        Ok((journal, replay))
    }

    /// Opens the journal as [`Journal::open`] does, handing each record replayed to `each`
    /// instead of keeping them (the daemon folds them into a compact
    /// [`Progress`](super::progress::Progress)).
    pub fn open_with(
        path: &Path,
        fsync: bool,
        each: impl FnMut(Record),
    ) -> Result<Journal, JournalError> {
        let file = open_lines(path, MAX_JOURNAL_BYTES, each)?;
        Ok(Journal {
            path: path.to_path_buf(),
            file,
            fsync,
            held: Vec::new(),
        })
    }

    /// Replays a journal without opening it for writing (for `layerwise status`): the same
    /// records the daemon would replay, a torn last record ignored as the daemon would cut it.
    pub fn read(path: &Path) -> Result<Replay, JournalError> {
        let mut file = open_read(path, MAX_JOURNAL_BYTES)?.ok_or_else(|| JournalError::Io {
            path: path.to_path_buf(),
            source: std::io::ErrorKind::NotFound.into(),
        })?;
        let mut replay = Replay::default();
        Self::scan(path, &mut file, |r| replay.apply(&r))?;
        Ok(replay)
    }

    /// Calls `each` for every record and returns the byte offset after the last good one. Only
    /// the last line may be damaged (a write torn by a crash: cut short, or garbage after the last
    /// newline); damage anywhere before it is [`JournalError::Corrupt`], never skipped.
    fn scan(path: &Path, file: &mut File, each: impl FnMut(Record)) -> Result<u64, JournalError> {
        scan_lines(path, file, each)
    }
}

impl Journal {
    /// Appends a record. On a full disk the record is held in memory (nothing torn is left in
    /// the file) and written, in order, before the next record once space returns; a crash in
    /// between loses only held records, whose originals `Storage::recover` adopts again.
    pub fn append(&mut self, record: &Record) -> Result<(), JournalError> {
        let result = self
            .flush_held()
            .and_then(|()| append_line(&mut self.file, &self.path, self.fsync, record));
        match result {
            Err(e) if e.is_disk_full() => {
                if self.held.is_empty() {
                    warn!(file = %self.path.display(), "disk full: journal records are held in memory until space returns");
                }
                self.held.push(record.clone());
                Ok(())
            }
            other => other,
        }
    }

    /// Writes the records held while the disk was full; stops (keeping the rest) while it
    /// still is.
    pub fn flush_held(&mut self) -> Result<(), JournalError> {
        while let Some(record) = self.held.first() {
            append_line(&mut self.file, &self.path, self.fsync, record)?;
            self.held.remove(0);
        }
        Ok(())
    }

    /// Records waiting for disk space.
    pub fn held(&self) -> usize {
        self.held.len()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

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
    fn the_take_a_slice_shows_is_replayed_for_either_choice() {
        use crate::shot::SeriesTake;
        let shot = Shot {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
        };
        let mut replay = Replay::default();
        replay.apply(&frame(1));
        replay.apply(&frame(2));
        let (one, two) = (shot, Shot { layer: 2, ..shot });
        for choice in [SeriesTake::First, SeriesTake::Last] {
            assert_eq!(replay.unprocessed_takes(choice), vec![(one, 1), (two, 1)]);
        }
        replay.apply(&Record::Processed {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
            at: Utc::now(),
        });
        replay.apply(&Record::Retake {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
            take: 2,
            file: "raw/L00001_post_top.r2.jpg".into(),
            bytes: 10,
            sha256: "11".into(),
            at: Utc::now(),
        });
        assert_eq!(replay.unprocessed_takes(SeriesTake::First), vec![(two, 1)]);
        // With "last", the retake still has to replace the slice (as after a kill -9).
        assert_eq!(
            replay.unprocessed_takes(SeriesTake::Last),
            vec![(one, 2), (two, 1)]
        );
        assert_eq!(
            replay.take_entry(&one, 2).map(|e| e.file.as_str()),
            Some("raw/L00001_post_top.r2.jpg")
        );
        assert!(replay.take_entry(&one, 3).is_none());
        replay.apply(&Record::SliceTake {
            layer: 1,
            phase: Phase::Post,
            light: Light::Top,
            take: 2,
            at: Utc::now(),
        });
        assert_eq!(replay.slice_take(&one), 2);
        assert_eq!(replay.unprocessed_takes(SeriesTake::Last), vec![(two, 1)]);
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
    fn journal_invalid_utf8_in_the_middle_is_an_error_with_its_byte_offset() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.jsonl");
        let good = serde_json::to_string(&frame(1)).unwrap();
        let missing = serde_json::to_string(&Record::Missing {
            layer: 2,
            phase: Phase::Post,
            light: Light::Top,
            reason: "camera failed".into(),
            at: Utc::now(),
        })
        .unwrap();
        let mut bytes = format!("{good}\n{good}\n{missing}\n").into_bytes();
        let second = good.len() + 1;
        bytes[second + 5] = 0xFF; // one invalid byte inside the second record
        std::fs::write(&path, &bytes).unwrap();
        let err = Journal::open(&path, false).err().unwrap().to_string();
        assert!(
            err.contains(&format!("byte {second}")) && err.contains("line 2"),
            "{err}"
        );
        assert_eq!(std::fs::read(&path).unwrap(), bytes, "nothing was cut");
        // `status` reads the journal the same way: the same error, not a silent partial replay.
        let status = Journal::read(&path).err().unwrap().to_string();
        assert!(status.contains(&format!("byte {second}")), "{status}");
    }

    #[test]
    fn journal_torn_tail_is_the_same_for_the_daemon_and_status() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.jsonl");
        let good = serde_json::to_string(&frame(1)).unwrap();
        for tail in [
            &b"{\"kind\":\"fra"[..],
            &b"\xFF\xFE garbage"[..],
            &b"garbage\n"[..],
        ] {
            let mut bytes = format!("{good}\n").into_bytes();
            bytes.extend_from_slice(tail);
            std::fs::write(&path, &bytes).unwrap();
            let status = Journal::read(&path).unwrap();
            let (_, daemon) = Journal::open(&path, false).unwrap();
            assert_eq!(status.frames.len(), 1);
            assert_eq!(daemon.frames, status.frames);
            assert_eq!(std::fs::read(&path).unwrap().len(), good.len() + 1);
        }
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

    #[test]
    fn a_failure_is_the_take_that_failed_and_an_old_record_without_it_reads_as_before() {
        let shot = Shot::new(2, Phase::Post, Light::Top);
        let at = chrono::Utc::now();
        let retake = Record::Retake {
            layer: 2,
            phase: Phase::Post,
            light: Light::Top,
            take: 2,
            file: "raw/L00002_post_top.r2.jpg".into(),
            bytes: 1,
            sha256: "00".into(),
            at,
        };
        // Take 1 failed; its record was journaled after the retake was stored (the commit
        // thread is behind the capture): take 2 still waits (before, it read as failed).
        let failed = Record::ProcessingFailed {
            layer: 2,
            phase: Phase::Post,
            light: Light::Top,
            take: Some(1),
            reason: "truncated".into(),
            at,
        };
        let mut replay = Replay::default();
        for record in [frame(2), retake.clone(), failed] {
            replay.apply(&record);
        }
        assert_eq!(replay.failure(&shot, 1), Some("truncated"));
        assert_eq!(replay.failure(&shot, 2), None);
        // A journal written before the take was recorded: the takes stored then.
        let old = r#"{"kind":"processing_failed","layer":2,"phase":"post","light":"top","reason":"truncated","at":"2026-12-01T00:00:00Z"}"#;
        let old: Record = serde_json::from_str(old).unwrap();
        let mut replay = Replay::default();
        for record in [frame(2), retake, old] {
            replay.apply(&record);
        }
        assert_eq!(replay.failure(&shot, 2), Some("truncated"));
    }
}
