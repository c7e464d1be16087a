//! The build as the page shows it, layer by layer: read from the journal and the inspection log
//! as they grow (only the bytes appended since the last look), so a page on a long build costs no
//! full replay per update.

use crate::build_dir::inspection::{BedRecord, Flag, InspectionRecord, Severity};
use crate::build_dir::lines::open_read;
use crate::build_dir::JournalError;
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

/// At most this much of a log is read in one look: the first look at a long build's journal
/// reads it in steps, not in one allocation of its size.
const MAX_READ: u64 = 16 << 20;

/// A file of JSON lines read as it grows.
#[derive(Debug)]
struct Tail {
    path: PathBuf,
    offset: u64,
    /// [`MAX_READ`], smaller in tests.
    max_read: u64,
    /// The largest such log the daemon reads back: a larger one is refused, not read on
    /// without end.
    max_bytes: u64,
    /// Inside a line longer than a whole read, skipping it.
    skipping: bool,
}

/// What one look at a log found: the complete lines appended since the last look, parsed.
#[derive(Debug)]
struct Lines<T> {
    records: Vec<T>,
    /// Lines that did not parse (a newer format, or a line over [`MAX_READ`]); skipped.
    unreadable: usize,
    /// The file shrank (a torn tail cut on restart): `records` start from its beginning again.
    restarted: bool,
}

impl Tail {
    /// The complete lines appended since the last call (at most [`MAX_READ`] bytes of them),
    /// whether there is more to read, and whether the file shrank so that they are the whole
    /// file again. A line still being written is read on the next call. Only a regular file is
    /// read, and never through a symbolic link (as the daemon writes it): a FIFO planted in its
    /// place is refused at once, never waited on.
    fn read<T: serde::de::DeserializeOwned>(
        &mut self,
    ) -> Result<(Option<Lines<T>>, bool), JournalError> {
        let Some(mut file) = open_read(&self.path, self.max_bytes)? else {
            return Ok((None, false));
        };
        let io = |source| JournalError::Io {
            path: self.path.clone(),
            source,
        };
        let len = file.metadata().map_err(io)?.len();
        let restarted = len < self.offset;
        if restarted {
            self.offset = 0;
            self.skipping = false;
        }
        let nothing = |restarted: bool| {
            restarted.then(|| Lines {
                records: Vec::new(),
                unreadable: 0,
                restarted: true,
            })
        };
        if len == self.offset {
            return Ok((nothing(restarted), false));
        }
        let want = (len - self.offset).min(self.max_read);
        file.seek(SeekFrom::Start(self.offset)).map_err(io)?;
        let mut data = Vec::with_capacity(want as usize);
        file.take(want).read_to_end(&mut data).map_err(io)?;
        // A whole read: there may be more after it (a file cut meanwhile gives less).
        let full = data.len() as u64 == self.max_read;
        let got = data.len() as u64;
        let mut unreadable = 0;
        // The rest of a line longer than a whole read: skipped up to its end.
        let mut start = 0;
        if self.skipping {
            match data.iter().position(|&b| b == b'\n') {
                Some(nl) => {
                    start = nl + 1;
                    self.skipping = false;
                }
                None => {
                    if full {
                        self.offset += got;
                    }
                    return Ok((None, full && self.offset < len));
                }
            }
        }
        match data[start..].iter().rposition(|&b| b == b'\n') {
            Some(end) => {
                self.offset += (start + end) as u64 + 1;
                data.truncate(start + end);
                data.drain(..start);
            }
            // A line longer than a whole read is no record: skipped, counted once.
            None if start == 0 && full => {
                self.offset += got;
                self.skipping = true;
                data.clear();
                unreadable += 1;
            }
            // The rest is a line still being written, or, after a whole read, more to read.
            None => {
                self.offset += start as u64;
                return Ok((nothing(restarted), full && self.offset < len));
            }
        }
        let mut records = Vec::new();
        for line in data.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
            match serde_json::from_slice::<T>(line) {
                Ok(record) => records.push(record),
                Err(_) => unreadable += 1,
            }
        }
        let lines = Lines {
            records,
            unreadable,
            restarted,
        };
        // More only past a whole read: what is left after a shorter one is a line being written.
        Ok((Some(lines), full && self.offset < len))
    }
}

/// The readers of the journal and the inspection log: they read and parse outside the
/// timeline's lock (a log on a stalled disk stalls the watch, never the page's requests).
#[derive(Debug)]
pub struct Tails {
    journal: Tail,
    inspection: Tail,
}

/// What [`Tails::read`] found, for [`Timeline::apply`].
#[derive(Debug)]
pub struct Appended {
    journal: Option<Lines<Record>>,
    inspection: Option<Lines<InspectionRecord>>,
    /// A log has more than one read took: look again at once.
    pub more: bool,
}

impl Tails {
    pub fn new(build_dir: &Path) -> Tails {
        use crate::build_dir::lines::{MAX_JOURNAL_BYTES, MAX_LOG_BYTES};
        let tail = |name: &str, max_bytes| Tail {
            path: build_dir.join(name),
            offset: 0,
            max_read: MAX_READ,
            max_bytes,
            skipping: false,
        };
        Tails {
            journal: tail(crate::build_dir::JOURNAL, MAX_JOURNAL_BYTES),
            inspection: tail(crate::build_dir::INSPECTION, MAX_LOG_BYTES),
        }
    }

    /// Reads what was appended to the journal and the inspection log since the last call. A
    /// file that shrank (a torn tail cut on restart) is read again from the start. Only complete
    /// lines are taken. What one log gave is kept when the other cannot be read (the error).
    pub fn read(&mut self) -> (Appended, Option<JournalError>) {
        fn take<T>(
            read: Result<(Option<Lines<T>>, bool), JournalError>,
            error: &mut Option<JournalError>,
        ) -> (Option<Lines<T>>, bool) {
            read.unwrap_or_else(|e| {
                error.get_or_insert(e);
                (None, false)
            })
        }
        let mut error = None;
        let (journal, more_journal) = take(self.journal.read::<Record>(), &mut error);
        // A journal read again from its start clears the layers, their flags with them.
        if journal.as_ref().is_some_and(|j| j.restarted) {
            self.inspection.offset = 0;
            self.inspection.skipping = false;
        }
        let (inspection, more_inspection) = take(self.inspection.read(), &mut error);
        let appended = Appended {
            journal,
            inspection,
            more: more_journal || more_inspection,
        };
        (appended, error)
    }
}

/// The journal and inspection log read so far, as layers.
#[derive(Debug, Default)]
pub struct Timeline {
    pub layers: BTreeMap<u32, LayerState>,
    /// The powder beds the inspection settled, by the layer each settled on (the record that
    /// carries its outline); a layer shows the latest one settled at or before it.
    pub beds: BTreeMap<u32, BedRecord>,
    /// Records read that did not parse (a newer journal format); skipped.
    pub unreadable: usize,
}

impl Timeline {
    /// Reads with `tails` to the logs' ends, [`MAX_READ`] at a time, and applies what they
    /// found: true when anything changed.
    pub fn refresh(&mut self, tails: &mut Tails) -> Result<bool, JournalError> {
        let mut changed = false;
        loop {
            let (appended, error) = tails.read();
            let more = appended.more;
            changed |= self.apply(appended);
            match error {
                Some(e) => return Err(e),
                None if !more => return Ok(changed),
                None => {}
            }
        }
    }

    /// Takes in what [`Tails::read`] found; true when anything changed.
    pub fn apply(&mut self, appended: Appended) -> bool {
        let mut changed = false;
        if let Some(lines) = appended.journal {
            if lines.restarted {
                self.layers.clear();
                self.beds.clear();
            }
            for record in &lines.records {
                self.apply_record(record);
            }
            self.unreadable += lines.unreadable;
            changed = true;
        }
        if let Some(lines) = appended.inspection {
            if lines.restarted {
                self.layers.values_mut().for_each(|l| l.inspection.clear());
                self.beds.clear();
            }
            for record in lines.records {
                // A layer inspected again (`layerwise inspect`) shows its newest flags.
                self.settle_bed(record.layer, record.bed);
                self.layer_mut(record.layer).inspection = record.flags;
            }
            self.unreadable += lines.unreadable;
            changed = true;
        }
        changed
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

    fn apply_record(&mut self, record: &Record) {
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
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        assert!(!timeline.refresh(&mut tails).unwrap(), "no journal yet");
        std::fs::write(&path, line(&frame)).unwrap();
        assert!(timeline.refresh(&mut tails).unwrap());
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
        assert!(
            !timeline.refresh(&mut tails).unwrap(),
            "half a line is not read"
        );
        file.write_all(tail.as_bytes()).unwrap();
        assert!(timeline.refresh(&mut tails).unwrap());
        let summary = timeline.layers[&3].summary();
        assert_eq!((summary.processed, summary.lag_ms), (1, Some(250)));
        // A journal cut shorter (torn tail removed on restart) is read again.
        std::fs::write(&path, "").unwrap();
        timeline.refresh(&mut tails).unwrap();
        assert!(timeline.layers.is_empty());
    }

    #[test]
    fn a_long_journal_is_read_in_steps_and_a_line_longer_than_a_step_is_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let event = |layer| Record::Event {
            layer,
            phase: Phase::Pre,
            at: Utc::now(),
        };
        let mut text: String = (1..=40).map(|l| line(&event(l))).collect();
        text.push_str(&format!("{{\"junk\": \"{}\"}}\n", "x".repeat(1000)));
        text.push_str(&line(&event(41)));
        std::fs::write(&path, &text).unwrap();
        let mut tails = Tails::new(dir.path());
        tails.journal.max_read = 300;
        let mut timeline = Timeline::default();
        let (first, error) = tails.read();
        assert!(error.is_none());
        assert!(first.more, "one step of 300 bytes is not the whole journal");
        timeline.apply(first);
        let partial = timeline.layers.len();
        assert!((1..40).contains(&partial), "{partial}");
        assert!(timeline.refresh(&mut tails).unwrap());
        assert_eq!(timeline.layers.len(), 41);
        // The line of over 300 bytes: skipped, counted once.
        assert_eq!(timeline.unreadable, 1);
        assert!(!timeline.refresh(&mut tails).unwrap(), "nothing new");
        // A whole line and half of the next: the half waits for its end.
        let next = line(&event(42)) + &line(&event(43))[..20];
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        file.write_all(next.as_bytes()).unwrap();
        let (appended, _) = tails.read();
        assert!(!appended.more, "half a line is not more to read now");
        timeline.apply(appended);
        assert_eq!(timeline.layers.len(), 42);

        // A skipped line that ends inside a whole read, and a record after it that does not:
        // the rest is still read to the end.
        let dir = tempfile::tempdir().unwrap();
        let frame = Record::Frame {
            layer: 7,
            phase: Phase::Post,
            light: Light::Top,
            file: format!("raw/{}.jpg", "x".repeat(120)),
            bytes: 1,
            sha256: "00".into(),
            at: Utc::now(),
        };
        let junk = format!("{{\"junk\": \"{}\"}}\n", "y".repeat(390));
        let frame = line(&frame);
        assert!((200..300).contains(&frame.len()), "{}", frame.len());
        let text = junk + &frame + &line(&event(8));
        std::fs::write(dir.path().join(crate::build_dir::JOURNAL), text).unwrap();
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        tails.journal.max_read = 300;
        assert!(timeline.refresh(&mut tails).unwrap());
        assert_eq!(timeline.layers.keys().copied().collect::<Vec<_>>(), [7, 8]);
        assert_eq!(timeline.unreadable, 1);
    }

    /// Before, a log of any size was read on, 16 MiB at a time, without end (a sparse file of a
    /// terabyte: the page's start read it all).
    #[test]
    fn a_log_larger_than_the_daemon_reads_back_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::JOURNAL);
        let file = std::fs::File::create(&path).unwrap();
        file.set_len(crate::build_dir::lines::MAX_JOURNAL_BYTES + 1)
            .unwrap();
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        let err = crate::logging::Chain(&timeline.refresh(&mut tails).unwrap_err()).to_string();
        assert!(err.contains("larger than"), "{err}");
        assert!(
            err.contains(&path.display().to_string()),
            "names the file: {err}"
        );
        assert_eq!(tails.journal.offset, 0, "nothing read");
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
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        timeline.refresh(&mut tails).unwrap();
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
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        std::fs::write(
            &path,
            text(&[
                record(4, vec![flag(Severity::Warning), flag(Severity::Critical)]),
                record(5, vec![]),
            ]),
        )
        .unwrap();
        assert!(timeline.refresh(&mut tails).unwrap());
        let summary = timeline.layers[&4].summary();
        assert_eq!(
            (summary.flags, summary.worst),
            (2, Some(Severity::Critical))
        );
        assert_eq!(timeline.layers[&5].summary().worst, None);
        assert!(!timeline.refresh(&mut tails).unwrap(), "nothing new");
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap();
        file.write_all(text(&[record(4, vec![flag(Severity::Warning)])]).as_bytes())
            .unwrap();
        assert!(timeline.refresh(&mut tails).unwrap());
        assert_eq!(
            timeline.layers[&4].inspection,
            vec![flag(Severity::Warning)]
        );
    }
}
