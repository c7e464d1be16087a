//! The build as the page shows it, layer by layer: read from the journal and the inspection log
//! as they grow (only the bytes appended since the last look), so a page on a long build costs no
//! full replay per update.

use crate::build_dir::inspection::{BedRecord, Flag, InspectionRecord, Severity};
use crate::build_dir::Record;
use crate::shot::{Shot, View};
use chrono::{DateTime, Utc};
use serde::Serialize;
use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// What happened to one view of one layer.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct ViewState {
    /// `stored` (waiting for processing), `processed`, `failed` or `missing`.
    pub state: &'static str,
    /// The original, relative to the build directory.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub captured_at: Option<DateTime<Utc>>,
    /// From capture to the rectified slice, in ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lag_ms: Option<i64>,
    /// Why the frame is missing or its processing failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Takes after the first (repeated signals).
    pub retakes: u32,
}

/// One layer: its views and signals.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LayerState {
    pub layer: u32,
    pub views: BTreeMap<String, ViewState>,
    /// When each phase's signal arrived.
    pub signals: BTreeMap<String, DateTime<Utc>>,
    /// Irregular signals of this layer.
    pub flags: Vec<String>,
    /// The layer inspection's flags (inspection.jsonl; the newest record of the layer).
    pub inspection: Vec<Flag>,
}

/// One line of the timeline.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct LayerSummary {
    pub layer: u32,
    pub stored: usize,
    pub processed: usize,
    pub missing: usize,
    pub failed: usize,
    /// The longest processing lag of the layer's views, in ms.
    pub lag_ms: Option<i64>,
    /// Irregular signals and inspection flags.
    pub flags: usize,
    /// The highest severity among the layer's inspection flags.
    pub worst: Option<Severity>,
}

impl LayerState {
    pub fn summary(&self) -> LayerSummary {
        let count = |s: &str| self.views.values().filter(|v| v.state == s).count();
        LayerSummary {
            layer: self.layer,
            stored: count("stored") + count("processed") + count("failed"),
            processed: count("processed"),
            missing: count("missing"),
            failed: count("failed"),
            lag_ms: self.views.values().filter_map(|v| v.lag_ms).max(),
            flags: self.flags.len() + self.inspection.len(),
            worst: self.inspection.iter().map(|f| f.severity).max(),
        }
    }

    /// The view's state, for views this layer has.
    pub fn view(&self, view: View) -> Option<&ViewState> {
        self.views.get(&view.to_string())
    }
}

/// A file of JSON lines read as it grows.
#[derive(Debug)]
struct Tail {
    path: PathBuf,
    offset: u64,
}

impl Tail {
    /// The complete lines appended since the last call, and whether the file shrank (a torn
    /// tail cut on restart) so that they are the whole file again. A line still being written
    /// is read on the next call.
    fn read(&mut self) -> std::io::Result<Option<(Vec<u8>, bool)>> {
        let mut file = match std::fs::File::open(&self.path) {
            Ok(f) => f,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(e),
        };
        let len = file.metadata()?.len();
        let restarted = len < self.offset;
        if restarted {
            self.offset = 0;
        }
        if len == self.offset {
            return Ok(restarted.then(|| (Vec::new(), true)));
        }
        file.seek(SeekFrom::Start(self.offset))?;
        let mut data = Vec::with_capacity((len - self.offset) as usize);
        file.take(len - self.offset).read_to_end(&mut data)?;
        let Some(end) = data.iter().rposition(|&b| b == b'\n') else {
            return Ok(restarted.then(|| (Vec::new(), true)));
        };
        self.offset += end as u64 + 1;
        data.truncate(end);
        Ok(Some((data, restarted)))
    }
}

/// The journal and inspection log read so far, as layers.
#[derive(Debug)]
pub struct Timeline {
    journal: Tail,
    inspection: Tail,
    pub layers: BTreeMap<u32, LayerState>,
    /// The powder beds the inspection settled, by the layer each settled on (the record that
    /// carries its outline); a layer shows the latest one settled at or before it.
    pub beds: BTreeMap<u32, BedRecord>,
    /// Records read that did not parse (a newer journal format); skipped.
    pub unreadable: usize,
}

impl Timeline {
    pub fn new(build_dir: &Path) -> Timeline {
        Timeline {
            journal: Tail {
                path: build_dir.join(crate::build_dir::JOURNAL),
                offset: 0,
            },
            inspection: Tail {
                path: build_dir.join(crate::build_dir::INSPECTION),
                offset: 0,
            },
            layers: BTreeMap::new(),
            beds: BTreeMap::new(),
            unreadable: 0,
        }
    }

    /// Reads what was appended to the journal and the inspection log since the last call; true
    /// when anything changed. A file that shrank (a torn tail cut on restart) is read again from
    /// the start. Only complete lines are taken.
    pub fn refresh(&mut self) -> std::io::Result<bool> {
        let mut changed = false;
        if let Some((data, restarted)) = self.journal.read()? {
            if restarted {
                self.layers.clear();
                self.beds.clear();
                self.inspection.offset = 0;
            }
            for line in data.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
                match serde_json::from_slice::<Record>(line) {
                    Ok(record) => self.apply(&record),
                    Err(_) => self.unreadable += 1,
                }
            }
            changed = true;
        }
        if let Some((data, restarted)) = self.inspection.read()? {
            if restarted {
                self.layers.values_mut().for_each(|l| l.inspection.clear());
                self.beds.clear();
            }
            for line in data.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
                match serde_json::from_slice::<InspectionRecord>(line) {
                    // A layer inspected again (`layerwise inspect`) shows its newest flags.
                    Ok(record) => {
                        self.settle_bed(record.layer, record.bed);
                        self.layer_mut(record.layer).inspection = record.flags;
                    }
                    Err(_) => self.unreadable += 1,
                }
            }
            changed = true;
        }
        Ok(changed)
    }

    /// Keeps the bed a record settled (the one with an outline). A bed settled again at an
    /// earlier layer is a new pass over the build (`layerwise inspect`): the beds the earlier
    /// pass settled after it no longer stand.
    fn settle_bed(&mut self, layer: u32, bed: Option<BedRecord>) {
        if let Some(bed) = bed.filter(|b| !b.outline_mm.is_empty()) {
            self.beds.retain(|l, _| *l < layer);
            self.beds.insert(layer, bed);
        }
    }

    /// The bed judged on `layer`: the latest settled at or before it, with the layer it settled
    /// on; none before the bed settled.
    pub fn bed_at(&self, layer: u32) -> Option<(u32, &BedRecord)> {
        self.beds.range(..=layer).next_back().map(|(l, b)| (*l, b))
    }

    fn view_mut(&mut self, shot: Shot) -> &mut ViewState {
        self.layer_mut(shot.layer)
            .views
            .entry(shot.view().to_string())
            .or_default()
    }

    fn layer_mut(&mut self, layer: u32) -> &mut LayerState {
        self.layers.entry(layer).or_insert_with(|| LayerState {
            layer,
            ..LayerState::default()
        })
    }

    fn apply(&mut self, record: &Record) {
        let shot = record.shot();
        match (record, shot) {
            (Record::Event { layer, phase, at }, _)
                if (1..=crate::shot::MAX_LAYER).contains(layer) =>
            {
                self.layer_mut(*layer)
                    .signals
                    .insert(phase.to_string(), *at);
            }
            (Record::Frame { file, at, .. }, Some(shot)) => {
                let v = self.view_mut(shot);
                *v = ViewState {
                    state: "stored",
                    file: Some(file.clone()),
                    captured_at: Some(*at),
                    retakes: v.retakes,
                    ..ViewState::default()
                };
            }
            (Record::Missing { reason, .. }, Some(shot)) => {
                let v = self.view_mut(shot);
                if v.file.is_none() {
                    v.state = "missing";
                    v.reason = Some(reason.clone());
                }
            }
            (Record::Processed { at, .. }, Some(shot)) => {
                let v = self.view_mut(shot);
                v.state = "processed";
                v.reason = None;
                v.lag_ms = v.captured_at.map(|c| (*at - c).num_milliseconds());
            }
            // A retake's slice written: processed, whatever the first take's processing gave.
            (Record::SliceTake { .. }, Some(shot)) => {
                let v = self.view_mut(shot);
                v.state = "processed";
                v.reason = None;
            }
            (Record::ProcessingFailed { reason, .. }, Some(shot)) => {
                let v = self.view_mut(shot);
                v.state = "failed";
                v.reason = Some(reason.clone());
            }
            (Record::Retake { .. }, Some(shot)) => self.view_mut(shot).retakes += 1,
            (
                Record::Irregular {
                    layer,
                    phase,
                    signal,
                    detail,
                    ..
                },
                _,
            ) if (1..=crate::shot::MAX_LAYER).contains(layer) => {
                let flag = format!("{phase}: {signal}: {detail}");
                self.layer_mut(*layer).flags.push(flag);
            }
            _ => {}
        }
    }

    /// The newest layer whose `views` frames are all stored or given up on: what an operator
    /// looks at while the next layer is being captured.
    pub fn newest_complete(&self, views: usize) -> Option<u32> {
        self.layers
            .values()
            .rev()
            .find(|l| {
                l.views
                    .values()
                    .filter(|v| v.file.is_some() || v.state == "missing")
                    .count()
                    >= views.max(1)
            })
            .map(|l| l.layer)
    }

    /// The newest layer with a stored frame.
    pub fn newest_with_frames(&self) -> Option<u32> {
        self.layers
            .values()
            .rev()
            .find(|l| l.views.values().any(|v| v.file.is_some()))
            .map(|l| l.layer)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::{Light, Phase};
    use std::io::Write;

    fn line(record: &Record) -> String {
        serde_json::to_string(record).unwrap() + "\n"
    }

    #[test]
    fn reads_only_what_was_appended_and_waits_for_whole_lines() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let at = Utc::now();
        let frame = Record::Frame {
            layer: 3,
            phase: Phase::Post,
            light: Light::Top,
            file: "raw/L00003_post_top.jpg".into(),
            bytes: 1,
            sha256: "00".into(),
            at,
        };
        let processed = Record::Processed {
            layer: 3,
            phase: Phase::Post,
            light: Light::Top,
            at: at + chrono::Duration::milliseconds(250),
        };
        let mut timeline = Timeline::new(dir.path());
        assert!(!timeline.refresh().unwrap(), "no journal yet");
        std::fs::write(&path, line(&frame)).unwrap();
        assert!(timeline.refresh().unwrap());
        assert_eq!(timeline.layers[&3].summary().stored, 1);
        assert_eq!(timeline.newest_with_frames(), Some(3));
        assert_eq!(timeline.newest_complete(1), Some(3));
        assert_eq!(timeline.newest_complete(6), None);
        let text = line(&processed);
        let (head, tail) = text.split_at(10);
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        file.write_all(head.as_bytes()).unwrap();
        assert!(!timeline.refresh().unwrap(), "half a line is not read");
        file.write_all(tail.as_bytes()).unwrap();
        assert!(timeline.refresh().unwrap());
        let summary = timeline.layers[&3].summary();
        assert_eq!((summary.processed, summary.lag_ms), (1, Some(250)));
        // A journal cut shorter (torn tail removed on restart) is read again.
        std::fs::write(&path, "").unwrap();
        timeline.refresh().unwrap();
        assert!(timeline.layers.is_empty());
    }

    #[test]
    fn a_retake_whose_slice_is_written_shows_processed_after_the_first_take_failed() {
        let dir = tempfile::tempdir().unwrap();
        let (layer, phase, light, at) = (3, Phase::Post, Light::Top, Utc::now());
        let records = [
            Record::Frame {
                layer,
                phase,
                light,
                file: "raw/L00003_post_top.jpg".into(),
                bytes: 1,
                sha256: "00".into(),
                at,
            },
            Record::ProcessingFailed {
                layer,
                phase,
                light,
                take: Some(1),
                reason: "truncated JPEG".into(),
                at,
            },
            Record::Retake {
                layer,
                phase,
                light,
                take: 2,
                file: "raw/L00003_post_top.r2.jpg".into(),
                bytes: 1,
                sha256: "00".into(),
                at,
            },
            Record::SliceTake {
                layer,
                phase,
                light,
                take: 2,
                at,
            },
        ];
        let path = dir.path().join(crate::build_dir::JOURNAL);
        std::fs::write(&path, records.iter().map(line).collect::<String>()).unwrap();
        let mut timeline = Timeline::new(dir.path());
        timeline.refresh().unwrap();
        let summary = timeline.layers[&3].summary();
        // Before, the page kept the first take's failure for good.
        assert_eq!((summary.processed, summary.failed), (1, 0));
        let view = timeline.layers[&3].views.values().next().unwrap();
        assert_eq!((view.retakes, view.reason.as_deref()), (1, None));
    }

    #[test]
    fn inspection_flags_join_their_layer_the_newest_record_wins() {
        use crate::build_dir::inspection::tests::{record_with as record, streak as flag};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::INSPECTION);
        let text = |records: &[InspectionRecord]| {
            records
                .iter()
                .map(|r| serde_json::to_string(r).unwrap() + "\n")
                .collect::<String>()
        };
        let mut timeline = Timeline::new(dir.path());
        std::fs::write(
            &path,
            text(&[
                record(4, vec![flag(Severity::Warning), flag(Severity::Critical)]),
                record(5, vec![]),
            ]),
        )
        .unwrap();
        assert!(timeline.refresh().unwrap());
        let summary = timeline.layers[&4].summary();
        assert_eq!(
            (summary.flags, summary.worst),
            (2, Some(Severity::Critical))
        );
        assert_eq!(timeline.layers[&5].summary().worst, None);
        assert!(!timeline.refresh().unwrap(), "nothing new");
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        file.write_all(text(&[record(4, vec![flag(Severity::Warning)])]).as_bytes())
            .unwrap();
        assert!(timeline.refresh().unwrap());
        assert_eq!(
            timeline.layers[&4].inspection,
            vec![flag(Severity::Warning)]
        );
    }
}
