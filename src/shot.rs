//! What one frame shows: a layer, a phase of that layer (before or after the laser scan) and the
//! light that was on. A view is a phase x light pair; each view is one image series.

use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Highest layer number: file names hold five digits (`L{layer:05}`).
pub const MAX_LAYER: u32 = 99_999;

/// When in the layer cycle a frame is taken.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Phase {
    /// After recoating, before the laser scans the layer.
    Pre,
    /// After the laser scan: fused metal is visible.
    Post,
}

/// Which light illuminates the plate.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Light {
    Front,
    Side,
    Top,
}

/// Which take of a shot its series slice shows when a repeated layer signal retook it
/// (`[series] take`, docs/frames.md): the first (the default) or the last one stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SeriesTake {
    #[default]
    First,
    Last,
}

impl SeriesTake {
    /// The take shown of a shot stored `takes` times (1 when stored once).
    pub fn shown(self, takes: u32) -> u32 {
        match self {
            SeriesTake::First => 1,
            SeriesTake::Last => takes.max(1),
        }
    }
}

impl fmt::Display for SeriesTake {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            SeriesTake::First => "first",
            SeriesTake::Last => "last",
        })
    }
}

impl Phase {
    pub const ALL: [Phase; 2] = [Phase::Pre, Phase::Post];
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Pre => "pre",
            Phase::Post => "post",
        }
    }
}

impl Light {
    pub const ALL: [Light; 3] = [Light::Front, Light::Side, Light::Top];
    pub fn as_str(self) -> &'static str {
        match self {
            Light::Front => "front",
            Light::Side => "side",
            Light::Top => "top",
        }
    }
}

impl fmt::Display for Phase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Display for Light {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A phase name that is neither `pre` nor `post`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown phase '{0}': expected pre or post")]
pub struct UnknownPhase(pub String);

/// A light name that is not `front`, `side` or `top`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown light '{0}': expected front, side or top")]
pub struct UnknownLight(pub String);

impl FromStr for Phase {
    type Err = UnknownPhase;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "pre" => Ok(Phase::Pre),
            "post" => Ok(Phase::Post),
            _ => Err(UnknownPhase(s.to_string())),
        }
    }
}

impl FromStr for Light {
    type Err = UnknownLight;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "front" => Ok(Light::Front),
            "side" => Ok(Light::Side),
            "top" => Ok(Light::Top),
            _ => Err(UnknownLight(s.to_string())),
        }
    }
}

/// One image series of a build: a phase under a light, named `{phase}_{light}` (e.g. `post_top`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct View {
    pub phase: Phase,
    pub light: Light,
}

impl fmt::Display for View {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}_{}", self.phase, self.light)
    }
}

/// One frame of the build: a view of one layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct Shot {
    pub layer: u32,
    pub phase: Phase,
    pub light: Light,
}

impl Shot {
    pub const fn new(layer: u32, phase: Phase, light: Light) -> Shot {
        Shot {
            layer,
            phase,
            light,
        }
    }
    pub fn view(&self) -> View {
        View {
            phase: self.phase,
            light: self.light,
        }
    }
    /// File stem of the original on disk: `L{layer:05}_{phase}_{light}` (docs/frames.md).
    pub fn stem(&self) -> String {
        format!("L{:05}_{}_{}", self.layer, self.phase, self.light)
    }
    /// Parses a stem written by [`Shot::stem`].
    pub fn from_stem(stem: &str) -> Option<Shot> {
        let rest = stem.strip_prefix('L')?;
        let mut parts = rest.splitn(3, '_');
        let layer = parts.next()?.parse().ok()?;
        let phase = parts.next()?.parse().ok()?;
        let light = parts.next()?.parse().ok()?;
        Some(Shot {
            layer,
            phase,
            light,
        })
    }
}

impl Shot {
    /// File stem of take `take` of the shot: the shot's stem, then `.r{take}` from the second
    /// take on (a retake, docs/frames.md).
    pub fn take_stem(&self, take: u32) -> String {
        if take <= 1 {
            self.stem()
        } else {
            format!("{}.r{take}", self.stem())
        }
    }

    /// The shot and take of a stored original's stem: `L00003_post_front` is take 1,
    /// `L00003_post_front.r2` take 2 (a retake, docs/frames.md).
    pub fn from_take_stem(stem: &str) -> Option<(Shot, u32)> {
        match stem.rsplit_once(".r") {
            Some((base, n)) if !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()) => {
                let take: u32 = n.parse().ok()?;
                (take > 1).then_some((Shot::from_stem(base)?, take))
            }
            _ => Some((Shot::from_stem(stem)?, 1)),
        }
    }
}

impl fmt::Display for Shot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "layer {} {} {}", self.layer, self.phase, self.light)
    }
}

/// Frames being processed, counted by a key (a layer, a layer's phase). The lanes finish frames
/// out of order, so what waits for a layer's frames (its inspection, the model's flags, its log
/// line) asks whether a key is held: at or after the first key with a frame in flight.
#[derive(Debug)]
pub struct Flights<K> {
    counts: std::collections::BTreeMap<K, usize>,
}

impl<K> Default for Flights<K> {
    fn default() -> Self {
        Flights {
            counts: Default::default(),
        }
    }
}

impl<K: Ord + Copy> Flights<K> {
    /// A frame of `key` is being processed.
    pub fn begin(&mut self, key: K) {
        *self.counts.entry(key).or_default() += 1;
    }

    /// A frame of `key` landed (or was given up).
    pub fn land(&mut self, key: K) {
        if let Some(n) = self.counts.get_mut(&key) {
            *n -= 1;
            if *n == 0 {
                self.counts.remove(&key);
            }
        }
    }

    /// Whether `key` must wait: a frame of it or of an earlier key is in flight.
    pub fn holds(&self, key: K) -> bool {
        self.counts.keys().next().is_some_and(|first| *first <= key)
    }

    /// Takes out of `open`, in key order, the entries that are done: those up to the last
    /// `complete` one (an earlier key's missing frames are not coming once a later key is
    /// complete), stopping at the first key that [`holds`](Self::holds).
    pub fn release<V>(
        &self,
        open: &mut std::collections::BTreeMap<K, V>,
        complete: impl Fn(&V) -> bool,
    ) -> Vec<(K, V)> {
        let Some(last) = open
            .iter()
            .rev()
            .find(|(_, v)| complete(v))
            .map(|(k, _)| *k)
        else {
            return Vec::new();
        };
        let keys: Vec<K> = open
            .range(..=last)
            .map(|(k, _)| *k)
            .take_while(|k| !self.holds(*k))
            .collect();
        keys.into_iter()
            .filter_map(|k| open.remove_entry(&k))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn take_stems() {
        let shot = Shot::from_stem("L00003_post_front").unwrap();
        assert_eq!(Shot::from_take_stem("L00003_post_front"), Some((shot, 1)));
        assert_eq!(
            Shot::from_take_stem("L00003_post_front.r2"),
            Some((shot, 2))
        );
        assert_eq!(
            Shot::from_take_stem("L00003_post_front.r12"),
            Some((shot, 12))
        );
        assert_eq!(Shot::from_take_stem("L00003_post_front.r1"), None);
        assert_eq!(Shot::from_take_stem("L00003_post_front.rx"), None);
        assert_eq!(SeriesTake::Last.shown(3), 3);
        assert_eq!(SeriesTake::First.shown(3), 1);
    }

    #[test]
    fn stem_round_trip() {
        let shot = Shot {
            layer: 42,
            phase: Phase::Post,
            light: Light::Top,
        };
        assert_eq!(shot.stem(), "L00042_post_top");
        assert_eq!(Shot::from_stem("L00042_post_top"), Some(shot));
        assert_eq!(Shot::from_stem("L00042_post"), None);
        assert_eq!(Shot::from_stem("X00042_post_top"), None);
        assert_eq!(shot.view().to_string(), "post_top");
    }

    #[test]
    fn unknown_names_say_what_is_expected() {
        assert_eq!("POST".parse(), Ok(Phase::Post));
        assert_eq!("Side".parse(), Ok(Light::Side));
        let e = "during".parse::<Phase>().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown phase 'during': expected pre or post"
        );
        let e = "back".parse::<Light>().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown light 'back': expected front, side or top"
        );
    }

    #[test]
    fn flights_hold_their_key_and_the_later_ones_until_every_frame_lands() {
        let mut f = Flights::default();
        assert!(!f.holds(1));
        f.begin(2);
        f.begin(2);
        assert!(!f.holds(1) && f.holds(2) && f.holds(3));
        f.land(2);
        assert!(f.holds(2));
        f.land(2);
        assert!(!f.holds(2) && !f.holds(3));
        f.land(2);
        assert!(!f.holds(2), "a landing never counted is ignored");
    }

    #[test]
    fn release_takes_up_to_the_last_complete_key_and_stops_at_a_held_one() {
        let mut f = Flights::default();
        let mut open: std::collections::BTreeMap<u32, usize> =
            [(1, 2), (2, 3), (3, 1), (4, 3), (5, 1)].into();
        let complete = |n: &usize| *n >= 3;
        f.begin(3);
        assert_eq!(f.release(&mut open, complete), vec![(1, 2), (2, 3)]);
        assert_eq!(f.release(&mut open, complete), vec![], "3 is held");
        f.land(3);
        assert_eq!(f.release(&mut open, complete), vec![(3, 1), (4, 3)]);
        assert_eq!(f.release(&mut open, complete), vec![], "5 is not complete");
        assert_eq!(open.len(), 1);
    }
}
