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

impl FromStr for Phase {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "pre" => Ok(Phase::Pre),
            "post" => Ok(Phase::Post),
            _ => Err(format!("unknown phase '{s}': expected pre or post")),
        }
    }
}

impl FromStr for Light {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "front" => Ok(Light::Front),
            "side" => Ok(Light::Side),
            "top" => Ok(Light::Top),
            _ => Err(format!("unknown light '{s}': expected front, side or top")),
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

impl fmt::Display for Shot {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "layer {} {} {}", self.layer, self.phase, self.light)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
