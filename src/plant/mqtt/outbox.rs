//! The MQTT messages waiting for the broker: on disk, in order, bounded. rumqttc keeps unacknowledged
//! publishes in memory only and forgets them when the broker comes back without our session
//! (always, with a clean session), so the daemon keeps its own queue:
//!
//! - segment files `q-<first seq>.jsonl` (one JSON line per message, appended in one write each;
//!   a torn last line, left by a crash, is cut when the segment is opened again);
//! - `acked`: the highest sequence number the broker acknowledged with every one before it
//!   (rewritten atomically, at most every [`CURSOR_PERIOD`] and at the stop); segments whose
//!   messages are all acknowledged are deleted;
//! - at most `max_bytes` on disk: beyond it the oldest segment is deleted, its messages counted
//!   as dropped, and a `gap` message queued that says which sequence numbers were lost.
//!
//! Delivery is at least once: after a crash or a lost acknowledgement a message is sent again
//! with its sequence number, which consumers use to drop duplicates.

use crate::build_dir::lines::{append_line, open_lines, JournalError, MAX_LOG_BYTES};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};
use tracing::warn;

/// How often the acknowledged cursor is written at most.
pub const CURSOR_PERIOD: Duration = Duration::from_millis(200);
/// The largest segment file.
const SEGMENT_BYTES: u64 = 1 << 20;
const CURSOR: &str = "acked";

/// One queued message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    pub seq: u64,
    pub topic: String,
    /// The JSON payload, as sent.
    pub payload: String,
}

#[derive(Debug, thiserror::Error)]
pub enum OutboxError {
    #[error("{}: cannot use the MQTT queue directory (mqtt.queue_dir)", path.display())]
    Dir {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("MQTT queue")]
    Segment(#[from] JournalError),
}

struct Segment {
    path: PathBuf,
    last_seq: u64,
    bytes: u64,
    messages: u64,
}

pub struct Outbox {
    dir: PathBuf,
    max_bytes: u64,
    segment_bytes: u64,
    /// By first sequence number.
    segments: BTreeMap<u64, Segment>,
    /// The segment being appended to (the last one).
    writer: Option<File>,
    next_seq: u64,
    acked: u64,
    cursor_written: u64,
    cursor_at: Option<Instant>,
    /// Unacknowledged messages of the oldest segment that has any, read from disk on demand.
    cache: VecDeque<Entry>,
    /// The segment `cache` holds (its first sequence number).
    cached: Option<u64>,
    /// Messages dropped because the queue was full (since it was opened).
    pub dropped: u64,
}

fn segment_name(first: u64) -> String {
    format!("q-{first:020}.jsonl")
}

impl Outbox {
    /// Opens (creating) the queue in `dir`, holding at most `max_bytes`.
    pub fn open(dir: &Path, max_bytes: u64) -> Result<Outbox, OutboxError> {
        let dir_error = |source| OutboxError::Dir {
            path: dir.to_path_buf(),
            source,
        };
        std::fs::create_dir_all(dir).map_err(dir_error)?;
        let acked = std::fs::read_to_string(dir.join(CURSOR))
            .ok()
            .and_then(|t| t.trim().parse().ok())
            .unwrap_or(0);
        let mut firsts: Vec<u64> = std::fs::read_dir(dir)
            .map_err(dir_error)?
            .flatten()
            .filter_map(|e| {
                let name = e.file_name().into_string().ok()?;
                name.strip_prefix("q-")?
                    .strip_suffix(".jsonl")?
                    .parse()
                    .ok()
            })
            .collect();
        firsts.sort_unstable();
        let mut outbox = Outbox {
            dir: dir.to_path_buf(),
            max_bytes,
            segment_bytes: SEGMENT_BYTES.min(max_bytes / 4).max(4096),
            segments: BTreeMap::new(),
            writer: None,
            next_seq: acked + 1,
            acked,
            cursor_written: acked,
            cursor_at: None,
            cache: VecDeque::new(),
            cached: None,
            dropped: 0,
        };
        let last = firsts.last().copied();
        for first in firsts {
            let path = dir.join(segment_name(first));
            let mut segment = Segment {
                path: path.clone(),
                last_seq: first.saturating_sub(1),
                bytes: 0,
                messages: 0,
            };
            let opened = open_lines(&path, MAX_LOG_BYTES, |entry: Entry| {
                segment.last_seq = entry.seq;
                segment.messages += 1;
            });
            let file = match opened {
                Ok(file) => file,
                Err(e) => {
                    // A damaged segment is set aside, not sent half: its messages count as lost.
                    warn!(error = %crate::logging::Chain(&e), "MQTT queue: a damaged segment is set aside (.damaged) and its messages dropped");
                    let _ = std::fs::rename(&path, path.with_extension("damaged"));
                    continue;
                }
            };
            segment.bytes = file.metadata().map_or(0, |m| m.len());
            outbox.next_seq = outbox.next_seq.max(segment.last_seq + 1);
            if segment.messages == 0 || segment.last_seq <= acked {
                let _ = std::fs::remove_file(&path);
                continue;
            }
            if Some(first) == last {
                outbox.writer = Some(file);
            }
            outbox.segments.insert(first, segment);
        }
        Ok(outbox)
    }

    /// Messages waiting (sent or not) and their bytes on disk.
    pub fn pending(&self) -> (u64, u64) {
        let messages = self.next_seq.saturating_sub(self.acked + 1);
        let bytes = self.segments.values().map(|s| s.bytes).sum();
        (messages, bytes)
    }

    /// Appends a message: `make` gets its sequence number and gives its topic and payload.
    /// When the queue is full the oldest segment goes first (and a `gap` message follows).
    pub fn push(&mut self, make: impl FnOnce(u64) -> (String, String)) -> Result<u64, OutboxError> {
        let seq = self.next_seq;
        let (topic, payload) = make(seq);
        self.push_entry(Entry {
            seq,
            topic,
            payload,
        })
    }

    fn push_entry(&mut self, entry: Entry) -> Result<u64, OutboxError> {
        let seq = entry.seq;
        let size = serde_json::to_string(&entry).map_or(0, |s| s.len() as u64 + 1);
        let gap = self.make_room(size);
        self.append(entry)?;
        if let Some((from, to, dropped, topic)) = gap {
            let seq = self.next_seq;
            let payload = serde_json::json!({
                "seq": seq, "from": from, "to": to, "dropped": dropped,
                "at": chrono::Utc::now(),
            });
            self.push_entry(Entry {
                seq,
                topic,
                payload: payload.to_string(),
            })?;
        }
        Ok(seq)
    }

    fn append(&mut self, entry: Entry) -> Result<(), OutboxError> {
        let rotate = self
            .segments
            .last_key_value()
            .is_none_or(|(_, s)| s.bytes >= self.segment_bytes);
        if rotate || self.writer.is_none() {
            let path = self.dir.join(segment_name(entry.seq));
            let file = open_lines(&path, MAX_LOG_BYTES, |_: Entry| {})?;
            self.writer = Some(file);
            self.segments.insert(
                entry.seq,
                Segment {
                    path,
                    last_seq: entry.seq - 1,
                    bytes: 0,
                    messages: 0,
                },
            );
        }
        let (first, segment) = self.segments.iter_mut().next_back().expect("just made");
        let file = self.writer.as_mut().expect("just opened");
        let before = file.metadata().map_or(segment.bytes, |m| m.len());
        append_line(file, &segment.path, false, &entry)?;
        segment.bytes = file.metadata().map_or(before, |m| m.len());
        segment.last_seq = entry.seq;
        segment.messages += 1;
        if self.cached == Some(*first) {
            self.cache.push_back(entry.clone());
        }
        self.next_seq = entry.seq + 1;
        Ok(())
    }

    /// Deletes the oldest segments until `size` more bytes fit; the gap they leave (first and
    /// last sequence number lost, how many, and a topic for the `gap` message).
    fn make_room(&mut self, size: u64) -> Option<(u64, u64, u64, String)> {
        let mut gap: Option<(u64, u64, u64, String)> = None;
        while self.pending().1 + size > self.max_bytes && self.segments.len() > 1 {
            let topic = self
                .segments
                .keys()
                .next()
                .and_then(|first| self.topic_of(*first))
                .unwrap_or_default();
            let (first, segment) = self.segments.pop_first().expect("more than one");
            let from = first.max(self.acked + 1);
            let lost = (segment.last_seq + 1).saturating_sub(from);
            let _ = std::fs::remove_file(&segment.path);
            if self.cached == Some(first) {
                self.cache.clear();
                self.cached = None;
            }
            self.acked = self.acked.max(segment.last_seq);
            if lost == 0 {
                continue;
            }
            self.dropped += lost;
            gap = Some(match gap {
                Some((a, _, n, t)) => (a, segment.last_seq, n + lost, t),
                None => (from, segment.last_seq, lost, topic),
            });
        }
        if let Some((from, to, lost, _)) = &gap {
            warn!(
                from,
                to,
                dropped = lost,
                "MQTT queue full (mqtt.max_queue_mb): the oldest messages are dropped; a gap message says which"
            );
        }
        gap.map(|(from, to, lost, topic)| {
            let prefix = topic.rsplit_once('/').map_or("", |(p, _)| p).to_string();
            (from, to, lost, format!("{prefix}/gap"))
        })
    }

    /// The topic of the first message of a segment (for the gap message's prefix).
    fn topic_of(&self, first: u64) -> Option<String> {
        let segment = self.segments.get(&first)?;
        let mut topic = None;
        let _ = crate::build_dir::lines::LinesLog::<Entry>::read(&segment.path).map(|entries| {
            topic = entries.into_iter().next().map(|e| e.topic);
        });
        topic
    }

    /// The oldest message not acknowledged yet.
    pub fn oldest(&mut self) -> Result<Option<&Entry>, OutboxError> {
        let wanted = self.acked + 1;
        if wanted >= self.next_seq {
            return Ok(None);
        }
        while self.cache.front().is_some_and(|e| e.seq < wanted) {
            self.cache.pop_front();
        }
        if self.cache.is_empty() {
            let Some((&first, segment)) = self.segments.range(..=wanted).next_back() else {
                // Nothing on disk holds it (deleted meanwhile): go on after it.
                return Ok(None);
            };
            if segment.last_seq < wanted {
                return Ok(None);
            }
            let entries = crate::build_dir::lines::LinesLog::<Entry>::read(&segment.path)?;
            self.cache = entries.into_iter().filter(|e| e.seq >= wanted).collect();
            self.cached = Some(first);
        }
        Ok(self.cache.front())
    }

    /// The broker acknowledged `seq`: when it is the oldest one waiting, the queue moves on (and
    /// drops the segments it is done with).
    pub fn ack(&mut self, seq: u64) {
        if seq != self.acked + 1 {
            return;
        }
        self.acked = seq;
        if self.cache.front().is_some_and(|e| e.seq == seq) {
            self.cache.pop_front();
        }
        let done: Vec<u64> = self
            .segments
            .iter()
            .filter(|(_, s)| s.last_seq <= self.acked)
            .map(|(first, _)| *first)
            .collect();
        for first in done {
            // The segment being appended to stays until the next one begins.
            if self.segments.len() == 1 {
                break;
            }
            if let Some(segment) = self.segments.remove(&first) {
                let _ = std::fs::remove_file(&segment.path);
            }
            if self.cached == Some(first) {
                self.cached = None;
                self.cache.clear();
            }
        }
    }

    /// Writes the acknowledged cursor when it moved and [`CURSOR_PERIOD`] has passed (or `now`).
    pub fn save_cursor(&mut self, force: bool) {
        if self.acked == self.cursor_written {
            return;
        }
        if !force && self.cursor_at.is_some_and(|t| t.elapsed() < CURSOR_PERIOD) {
            return;
        }
        self.cursor_at = Some(Instant::now());
        let path = self.dir.join(CURSOR);
        match crate::fsutil::write_atomic(&path, self.acked.to_string().as_bytes(), false) {
            Ok(()) => self.cursor_written = self.acked,
            Err(e) => {
                warn!(error = %crate::logging::Chain(&e), "MQTT queue: cannot write its cursor")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn message(seq: u64) -> (String, String) {
        ("lw/b/layer".into(), format!("{{\"seq\":{seq}}}"))
    }

    fn drain(outbox: &mut Outbox) -> Vec<u64> {
        let mut seen = Vec::new();
        while let Some(entry) = outbox.oldest().unwrap() {
            let seq = entry.seq;
            seen.push(seq);
            outbox.ack(seq);
        }
        seen
    }

    #[test]
    fn messages_survive_a_restart_in_order_and_acknowledged_ones_are_gone() {
        let dir = tempfile::tempdir().unwrap();
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        for _ in 0..5 {
            outbox.push(message).unwrap();
        }
        assert_eq!(outbox.oldest().unwrap().unwrap().seq, 1);
        outbox.ack(2); // out of order: ignored
        outbox.ack(1);
        outbox.save_cursor(true);
        drop(outbox);
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(outbox.pending().0, 4);
        outbox.push(message).unwrap();
        assert_eq!(drain(&mut outbox), vec![2, 3, 4, 5, 6]);
        outbox.save_cursor(true);
        drop(outbox);
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(outbox.pending().0, 0);
        assert_eq!(outbox.push(message).unwrap(), 7, "numbers go on");
    }

    #[test]
    fn a_full_queue_drops_the_oldest_segment_and_says_so_in_a_gap_message() {
        let dir = tempfile::tempdir().unwrap();
        // 16 KiB at most: segments of 4 KiB.
        let mut outbox = Outbox::open(dir.path(), 16 << 10).unwrap();
        let big = "x".repeat(500);
        for _ in 0..200 {
            outbox
                .push(|seq| {
                    (
                        "lw/b/flag".into(),
                        format!("{{\"seq\":{seq},\"m\":\"{big}\"}}"),
                    )
                })
                .unwrap();
        }
        assert!(outbox.pending().1 <= 16 << 10, "{:?}", outbox.pending());
        assert!(outbox.dropped > 100);
        let mut gaps = Vec::new();
        let mut seen = Vec::new();
        while let Some(entry) = outbox.oldest().unwrap() {
            if entry.topic == "lw/b/gap" {
                gaps.push(entry.payload.clone());
            }
            seen.push(entry.seq);
            let seq = entry.seq;
            outbox.ack(seq);
        }
        assert!(seen.windows(2).all(|w| w[0] < w[1]), "in order: {seen:?}");
        assert!(!gaps.is_empty());
        let gap: serde_json::Value = serde_json::from_str(gaps.last().unwrap()).unwrap();
        assert!(gap["dropped"].as_u64().unwrap() > 0, "{gap}");
    }

    #[test]
    fn a_torn_last_line_is_cut_and_a_damaged_segment_set_aside() {
        let dir = tempfile::tempdir().unwrap();
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        outbox.push(message).unwrap();
        drop(outbox);
        let segment = dir.path().join(segment_name(1));
        let mut text = std::fs::read_to_string(&segment).unwrap();
        text.push_str("{\"seq\":2,\"top");
        std::fs::write(&segment, &text).unwrap();
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        assert_eq!(drain(&mut outbox), vec![1]);
        outbox.push(message).unwrap();
        drop(outbox);
        std::fs::write(&segment, "garbage\n{\"seq\":1}\n").unwrap();
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        assert!(segment.with_extension("damaged").exists());
        assert_eq!(outbox.oldest().unwrap(), None);
    }
}
