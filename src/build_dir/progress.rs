//! Where a running build stands, compactly: what the daemon needs to decide whether a layer
//! signal is new, repeated or history (frames stored or given up on, takes, the last signal,
//! frames waiting for processing), in a few bits per shot instead of the journal's full
//! [`Replay`](super::Replay) with its file names. The daemon's memory stays flat however many
//! layers a build has; `status`, the web page and `export` keep reading the full replay.

use super::journal::Record;
use crate::shot::{Light, Phase, SeriesTake, Shot, MAX_LAYER};
use std::collections::BTreeMap;

const FRAME: u8 = 1;
const MISSING: u8 = 2;
const PROCESSED: u8 = 4;

/// The journal's records folded into flags per shot and counters; fed the same records as
/// [`Replay::apply`](super::Replay::apply), it answers the same questions the same way.
#[derive(Clone, Debug, Default)]
pub struct Progress {
    /// Flags per shot of layers 0..=MAX_LAYER, indexed by [`slot`]; grown as layers come.
    flags: Vec<u8>,
    /// Flags of shots beyond MAX_LAYER (only an old journal can hold such a frame).
    beyond: BTreeMap<Shot, u8>,
    frames: usize,
    missing: usize,
    /// Takes after the first, per shot that has any.
    retakes: BTreeMap<Shot, u32>,
    retake_count: usize,
    irregular: usize,
    /// The last layer signal in range.
    pub last_event: Option<(u32, Phase)>,
    /// How many times the daemon started on this build.
    pub starts: u32,
    /// Frames stored and not processed yet, with their files: the processing backlog.
    unprocessed: BTreeMap<Shot, String>,
    /// The latest retake of each shot retaken, with its file, and the take each retaken shot's
    /// slice shows (`SliceTake`): the backlog of `[series] take = "last"`. As small as the
    /// retakes; dropped with the backlog.
    retake_files: BTreeMap<Shot, (u32, String)>,
    slice_takes: BTreeMap<Shot, u32>,
    /// Once the backlog is handed to processing ([`Progress::take_backlog`]), frames are not
    /// tracked for it any more (processing journals its results on its own).
    backlog_taken: bool,
}

/// Where a shot's flags live in [`Progress::flags`].
fn slot(shot: &Shot) -> Option<usize> {
    if shot.layer > MAX_LAYER {
        return None;
    }
    let phase = Phase::ALL.iter().position(|&p| p == shot.phase)?;
    let light = Light::ALL.iter().position(|&l| l == shot.light)?;
    Some((shot.layer as usize * Phase::ALL.len() + phase) * Light::ALL.len() + light)
}

impl Progress {
    fn flags(&self, shot: &Shot) -> u8 {
        match slot(shot) {
            Some(i) => self.flags.get(i).copied().unwrap_or(0),
            None => self.beyond.get(shot).copied().unwrap_or(0),
        }
    }

    fn set_flags(&mut self, shot: &Shot, flags: u8) {
        match slot(shot) {
            Some(i) => {
                if i >= self.flags.len() {
                    // Whole layers at a time, so a build of n layers holds about 6n bytes.
                    let per_layer = Phase::ALL.len() * Light::ALL.len();
                    self.flags.resize((i / per_layer + 1) * per_layer, 0);
                }
                self.flags[i] = flags;
            }
            None => {
                self.beyond.insert(*shot, flags);
            }
        }
    }

    pub fn apply(&mut self, record: &Record) {
        match (record, record.shot()) {
            (Record::Start { .. }, _) => self.starts += 1,
            // A layer no printer uses (flagged out of range) does not move the build on.
            (Record::Event { layer, phase, .. }, _) if (1..=MAX_LAYER).contains(layer) => {
                self.last_event = Some((*layer, *phase))
            }
            (Record::Frame { file, .. }, Some(shot)) => {
                let flags = self.flags(&shot);
                if flags & MISSING != 0 {
                    self.missing -= 1;
                }
                if flags & FRAME == 0 {
                    self.frames += 1;
                }
                if flags & PROCESSED == 0 && !self.backlog_taken {
                    self.unprocessed.insert(shot, file.clone());
                }
                self.set_flags(&shot, (flags | FRAME) & !MISSING);
            }
            (Record::Missing { .. }, Some(shot)) => {
                let flags = self.flags(&shot);
                if flags & (FRAME | MISSING) == 0 {
                    self.missing += 1;
                    self.set_flags(&shot, flags | MISSING);
                }
            }
            (Record::Processed { .. }, Some(shot)) => {
                let flags = self.flags(&shot);
                self.set_flags(&shot, flags | PROCESSED);
                self.unprocessed.remove(&shot);
            }
            (Record::Retake { take, file, .. }, Some(shot)) => {
                *self.retakes.entry(shot).or_default() += 1;
                self.retake_count += 1;
                if !self.backlog_taken && self.retake_files.get(&shot).is_none_or(|(t, _)| t < take)
                {
                    self.retake_files.insert(shot, (*take, file.clone()));
                }
            }
            (Record::SliceTake { take, .. }, Some(shot)) if !self.backlog_taken => {
                self.slice_takes.insert(shot, *take);
            }
            (Record::Irregular { .. }, _) => self.irregular += 1,
            _ => {}
        }
    }

    /// A shot that needs no capture: stored, or given up on.
    pub fn is_done(&self, shot: &Shot) -> bool {
        self.flags(shot) & (FRAME | MISSING) != 0
    }

    /// Whether the first take of `shot` is stored.
    pub fn is_stored(&self, shot: &Shot) -> bool {
        self.flags(shot) & FRAME != 0
    }

    /// How many takes of `shot` are stored (0, 1 or more).
    pub fn takes(&self, shot: &Shot) -> u32 {
        u32::from(self.is_stored(shot)) + self.retakes.get(shot).copied().unwrap_or(0)
    }

    /// Stored frames not yet processed, in build order, with their files.
    pub fn unprocessed(&self) -> impl Iterator<Item = (Shot, &str)> {
        self.unprocessed.iter().map(|(s, f)| (*s, f.as_str()))
    }

    /// Hands over the frames whose series slice does not show the take `choice` picks yet, in
    /// build order, with that take and its file (as [`Replay::unprocessed_takes`](
    /// super::Replay::unprocessed_takes)), and stops tracking them: from then on the caller's
    /// processing owns the backlog.
    pub fn take_backlog(&mut self, choice: SeriesTake) -> Vec<(Shot, u32, String)> {
        self.backlog_taken = true;
        let mut backlog: BTreeMap<Shot, (u32, String)> = std::mem::take(&mut self.unprocessed)
            .into_iter()
            .map(|(shot, file)| (shot, (1, file)))
            .collect();
        let slice_takes = std::mem::take(&mut self.slice_takes);
        for (shot, (take, file)) in std::mem::take(&mut self.retake_files) {
            let shown = slice_takes
                .get(&shot)
                .copied()
                .unwrap_or(u32::from(self.flags(&shot) & PROCESSED != 0));
            if choice == SeriesTake::Last && shown < take {
                backlog.insert(shot, (take, file));
            }
        }
        backlog
            .into_iter()
            .map(|(shot, (take, file))| (shot, take, file))
            .collect()
    }

    /// Frames stored (first takes).
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Frames recorded missing and never stored since.
    pub fn missing(&self) -> usize {
        self.missing
    }

    /// Takes after the first.
    pub fn retakes(&self) -> usize {
        self.retake_count
    }

    /// Irregular signals journaled.
    pub fn irregular(&self) -> usize {
        self.irregular
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::journal::IrregularSignal;
    use crate::build_dir::Replay;
    use chrono::{TimeZone, Utc};

    /// Records of a build with every kind of event, including an old journal's layer 0 and a
    /// layer beyond the file names' five digits.
    fn records() -> Vec<Record> {
        let at = Utc.with_ymd_and_hms(2026, 1, 1, 0, 0, 0).unwrap();
        let frame = |s: Shot| Record::Frame {
            layer: s.layer,
            phase: s.phase,
            light: s.light,
            file: format!("raw/{}.jpg", s.stem()),
            bytes: 10,
            sha256: "x".into(),
            at,
        };
        let missing = |s: Shot| Record::Missing {
            layer: s.layer,
            phase: s.phase,
            light: s.light,
            reason: "r".into(),
            at,
        };
        let processed = |s: Shot| Record::Processed {
            layer: s.layer,
            phase: s.phase,
            light: s.light,
            at,
        };
        let a = Shot::new(1, Phase::Pre, Light::Front);
        let b = Shot::new(1, Phase::Post, Light::Top);
        let c = Shot::new(2, Phase::Pre, Light::Side);
        let zero = Shot::new(0, Phase::Post, Light::Side);
        let huge = Shot::new(u32::MAX, Phase::Post, Light::Front);
        vec![
            Record::Start {
                at,
                pid: 1,
                version: "0".into(),
            },
            Record::Event {
                layer: 1,
                phase: Phase::Pre,
                at,
            },
            frame(a),
            processed(a),
            missing(b),
            missing(b),
            frame(b),
            missing(b),
            Record::Retake {
                layer: 1,
                phase: Phase::Pre,
                light: Light::Front,
                take: 2,
                file: "raw/x.r2.jpg".into(),
                bytes: 1,
                sha256: "y".into(),
                at,
            },
            Record::Irregular {
                layer: 1,
                phase: Phase::Pre,
                signal: IrregularSignal::Repeated,
                detail: "d".into(),
                at,
            },
            Record::Event {
                layer: 0,
                phase: Phase::Post,
                at,
            },
            frame(zero),
            frame(huge),
            processed(huge),
            missing(c),
            Record::Event {
                layer: 2,
                phase: Phase::Pre,
                at,
            },
        ]
    }

    #[test]
    fn answers_as_the_full_replay_does() {
        let (mut progress, mut replay) = (Progress::default(), Replay::default());
        for r in records() {
            progress.apply(&r);
            replay.apply(&r);
        }
        assert_eq!(progress.frames(), replay.frames.len());
        assert_eq!(progress.missing(), replay.missing.len());
        assert_eq!(
            progress.retakes(),
            replay.retakes.values().map(Vec::len).sum::<usize>()
        );
        assert_eq!(progress.irregular(), replay.irregular.len());
        assert_eq!(progress.last_event, replay.last_event);
        assert_eq!(progress.starts, replay.starts);
        for layer in [0, 1, 2, 3, u32::MAX] {
            for phase in Phase::ALL {
                for light in Light::ALL {
                    let s = Shot::new(layer, phase, light);
                    assert_eq!(progress.is_done(&s), replay.is_done(&s), "{s:?}");
                    assert_eq!(progress.takes(&s), replay.takes(&s), "{s:?}");
                    assert_eq!(progress.is_stored(&s), replay.frames.contains_key(&s));
                }
            }
        }
        let backlog: Vec<(Shot, String)> = progress
            .unprocessed()
            .map(|(s, f)| (s, f.to_string()))
            .collect();
        let expected: Vec<(Shot, String)> = replay
            .unprocessed()
            .into_iter()
            .map(|s| (s, replay.frames[&s].file.clone()))
            .collect();
        assert_eq!(backlog, expected);
        assert_eq!(backlog.len(), 2);
        assert_eq!(progress.take_backlog(SeriesTake::First).len(), 2);
        progress.apply(&records()[2]);
        assert_eq!(progress.unprocessed().count(), 0, "not tracked once taken");
    }

    #[test]
    fn the_backlog_of_either_take_choice_is_the_replays() {
        let at = Utc.with_ymd_and_hms(2026, 1, 1, 0, 0, 0).unwrap();
        let shown = Record::SliceTake {
            layer: 1,
            phase: Phase::Pre,
            light: Light::Front,
            take: 2,
            at,
        };
        for choice in [SeriesTake::First, SeriesTake::Last] {
            for extra in [None, Some(shown.clone())] {
                let (mut progress, mut replay) = (Progress::default(), Replay::default());
                for r in records().iter().chain(extra.as_ref()) {
                    progress.apply(r);
                    replay.apply(r);
                }
                let expected: Vec<(Shot, u32, String)> = replay
                    .unprocessed_takes(choice)
                    .into_iter()
                    .map(|(s, t)| (s, t, replay.take_entry(&s, t).unwrap().file.clone()))
                    .collect();
                let backlog = progress.take_backlog(choice);
                assert_eq!(backlog, expected, "{choice} {extra:?}");
                // The retake of layer 1 waits for its slice under "last" until it is shown.
                let retake_waits = backlog.iter().any(|(_, take, _)| *take == 2);
                assert_eq!(
                    retake_waits,
                    choice == SeriesTake::Last && extra.is_none(),
                    "{choice} {extra:?}"
                );
            }
        }
    }

    #[test]
    fn holds_a_few_bytes_per_layer() {
        let mut progress = Progress::default();
        let at = Utc.with_ymd_and_hms(2026, 1, 1, 0, 0, 0).unwrap();
        for layer in 1..=10_000 {
            for light in Light::ALL {
                let s = Shot::new(layer, Phase::Post, light);
                progress.apply(&Record::Frame {
                    layer,
                    phase: s.phase,
                    light,
                    file: format!("raw/{}.jpg", s.stem()),
                    bytes: 1,
                    sha256: String::new(),
                    at,
                });
                progress.apply(&Record::Processed {
                    layer,
                    phase: s.phase,
                    light,
                    at,
                });
            }
        }
        assert_eq!(progress.frames(), 30_000);
        assert_eq!(progress.unprocessed().count(), 0);
        assert!(progress.flags.len() <= 6 * 10_001);
    }
}
