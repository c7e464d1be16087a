//! `[inspection]`: the per-layer inspection of the rectified views (recoater streaks, short feed,
//! super-elevation, fusion against the vectors, drift) and its alarm output. Every threshold is a
//! robust score (a z-score on median/MAD, or a ratio) with a documented default; a flag whose
//! score reaches `critical_factor` times its threshold is critical, else a warning.
//! Also the mock camera's anomaly injections (`[camera] inject = [...]`, `demo --inject`).

use crate::shot::Light;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::str::FromStr;

/// Along which build axis the recoater blade travels: streaks run along it, a short feed leaves
/// a band at the far end of it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    #[default]
    X,
    Y,
}

impl fmt::Display for Axis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Axis::X => "x",
            Axis::Y => "y",
        })
    }
}

/// The lowest severity of flag that switches the alarm on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AlarmSeverity {
    Warning,
    #[default]
    Critical,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InspectionConfig {
    /// Inspect every layer in the processing worker once its views are rectified (needs
    /// calibration.file). Parts are known from build.vectors; without it only the plate-wide
    /// detectors (streaks, short feed) run.
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Cell size of the inspection grid in mm: the series grid binned to about this.
    #[serde(default = "d_pixel")]
    pub pixel_mm: f64,
    /// Axis the recoater travels along.
    #[serde(default)]
    pub recoat_axis: Axis,
    /// Light of the pre-scan view searched for streaks and short feed.
    #[serde(default = "d_top")]
    pub pre_light: Light,
    /// Light of the pre-scan view searched for super-elevation (raking light shows relief).
    #[serde(default = "d_side")]
    pub elevation_light: Light,
    /// Light of the post-scan view compared with the vectors.
    #[serde(default = "d_top")]
    pub post_light: Light,
    /// Plate border left out (the plate edge and its shadow), mm.
    #[serde(default = "d_edge")]
    pub edge_margin_mm: f64,
    /// Streak: robust z of a line mean against its neighbours across the recoating direction.
    #[serde(default = "d_streak_z")]
    pub streak_z: f64,
    /// Streak: the plate is cut into segments this long along the recoating direction, so a
    /// partial streak is not diluted by the whole line.
    #[serde(default = "d_segment")]
    pub streak_segment_mm: f64,
    /// Streak: wider bands than this are not streaks (short feed and lighting are).
    #[serde(default = "d_streak_width")]
    pub streak_max_width_mm: f64,
    /// Short feed: robust z of a band's mean or texture against the same view's reference
    /// (median of the previous `reference_layers` layers).
    #[serde(default = "d_short_z")]
    pub short_feed_z: f64,
    /// Short feed: narrowest band reported, mm.
    #[serde(default = "d_short_width")]
    pub short_feed_min_width_mm: f64,
    /// Layers in the short-feed reference (the detector waits until 3 are seen).
    #[serde(default = "d_reference")]
    pub reference_layers: usize,
    /// Super-elevation: robust z (3x3-smoothed) of a spot over the previous layer's footprint
    /// against the powder around the part.
    #[serde(default = "d_elevation_z")]
    pub elevation_z: f64,
    /// Fusion: a cell is fused when its texture (local standard deviation) exceeds this many
    /// times the plate's median texture.
    #[serde(default = "d_fused_factor")]
    pub fused_texture_factor: f64,
    /// Fusion: how far the fused edge may stray from the vectors, mm.
    #[serde(default = "d_tolerance")]
    pub fusion_tolerance_mm: f64,
    /// Fusion: largest unfused fraction of a part's core (its footprint less one cell).
    #[serde(default = "d_unfused")]
    pub max_unfused: f64,
    /// Fusion: largest fused area beyond the tolerance around a part, as a fraction of its area
    /// (and at least `min_excess_mm2`).
    #[serde(default = "d_excess")]
    pub max_excess: f64,
    #[serde(default = "d_min_excess")]
    pub min_excess_mm2: f64,
    /// Spatter / stray scan: smallest fused blob away from every part, mm².
    #[serde(default = "d_spatter")]
    pub spatter_min_mm2: f64,
    /// Drift: robust z of a part metric against the median/MAD of its earlier layers (a layer half
    /// this far off does not enter the baseline).
    #[serde(default = "d_drift_z")]
    pub drift_z: f64,
    /// Drift: layers in the running baseline; the detector waits for `drift_min_layers`.
    #[serde(default = "d_drift_window")]
    pub drift_window: usize,
    #[serde(default = "d_drift_min")]
    pub drift_min_layers: usize,
    /// Score ≥ this × threshold: critical.
    #[serde(default = "d_critical")]
    pub critical_factor: f64,
    #[serde(default)]
    pub alarm: AlarmConfig,
}

/// The stack light switched by a flag: one channel of a relay board or GPIO line set, driven
/// through the same backends as the lights. Off by default.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlarmConfig {
    /// The output: kind = "none" (default), "serial-relay", "gpio" (as `[lights]`), or "mock".
    #[serde(default)]
    pub output: super::LightsConfig,
    /// Which channel of that output the stack light hangs on.
    #[serde(default = "d_top")]
    pub channel: Light,
    /// Lowest severity that switches it on.
    #[serde(default = "d_alarm_severity")]
    pub severity: AlarmSeverity,
    /// Keep it on until an operator acknowledges it (`layerwise alarm ack`; it stays on across
    /// a daemon restart), or (false) switch it off after a clean layer.
    #[serde(default = "yes")]
    pub latch: bool,
    /// A message to the printer's controller on a serial line, sent once each time the alarm is
    /// raised (none by default), e.g.
    /// `serial = { port = "/dev/ttyUSB1", baud = 9600, message = "LAYERWISE ALARM {layer} {kind}\r\n" }`.
    #[serde(default)]
    pub serial: Option<AlarmSerialConfig>,
}

/// `[inspection.alarm] serial`: the alarm's message to the printer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlarmSerialConfig {
    /// The serial port (opened when the first message is due, reopened after an error).
    pub port: String,
    #[serde(default = "d_alarm_baud")]
    pub baud: u32,
    /// The text sent: `{layer}`, `{kind}`, `{severity}` and `{part}` are replaced by the flag
    /// that raised the alarm; TOML escapes (`\r`, `\n`) end the line as the printer expects.
    #[serde(default = "d_alarm_message")]
    pub message: String,
}

impl AlarmSerialConfig {
    /// The message for a flag: its placeholders filled in.
    pub fn render(&self, layer: u32, kind: &str, severity: &str, part: Option<i64>) -> String {
        self.message
            .replace("{layer}", &layer.to_string())
            .replace("{kind}", kind)
            .replace("{severity}", severity)
            .replace("{part}", &part.map_or("-".to_string(), |p| p.to_string()))
    }
}

impl Default for AlarmConfig {
    fn default() -> Self {
        AlarmConfig {
            output: super::LightsConfig::None,
            channel: Light::Top,
            severity: d_alarm_severity(),
            latch: true,
            serial: None,
        }
    }
}

impl Default for InspectionConfig {
    fn default() -> Self {
        // The defaults of an empty table, from the one place they are declared.
        toml::from_str("").expect("every field of [inspection] has a default")
    }
}

impl InspectionConfig {
    /// Checks values serde cannot: positive sizes and thresholds.
    pub fn check(&self) -> Result<(), (String, String)> {
        let positive = [
            ("pixel_mm", self.pixel_mm),
            ("streak_z", self.streak_z),
            ("streak_segment_mm", self.streak_segment_mm),
            ("streak_max_width_mm", self.streak_max_width_mm),
            ("short_feed_z", self.short_feed_z),
            ("short_feed_min_width_mm", self.short_feed_min_width_mm),
            ("elevation_z", self.elevation_z),
            ("fused_texture_factor", self.fused_texture_factor),
            ("max_unfused", self.max_unfused),
            ("max_excess", self.max_excess),
            ("spatter_min_mm2", self.spatter_min_mm2),
            ("drift_z", self.drift_z),
            ("critical_factor", self.critical_factor),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err((
                    format!("inspection.{key}"),
                    format!("must be a finite number above 0, got {v}"),
                ));
            }
        }
        for (key, v) in [
            ("edge_margin_mm", self.edge_margin_mm),
            ("fusion_tolerance_mm", self.fusion_tolerance_mm),
            ("min_excess_mm2", self.min_excess_mm2),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((
                    format!("inspection.{key}"),
                    format!("must be a finite number, 0 or more, got {v}"),
                ));
            }
        }
        if self.reference_layers < 3 || self.drift_window < 3 || self.drift_min_layers < 3 {
            return Err((
                "inspection.reference_layers / drift_window / drift_min_layers".into(),
                "must be 3 or more (a median of fewer layers is no baseline)".into(),
            ));
        }
        if let Some(serial) = &self.alarm.serial {
            if serial.port.trim().is_empty() || serial.message.is_empty() || serial.baud == 0 {
                return Err((
                    "inspection.alarm.serial".into(),
                    "needs a port, a baud rate above 0 and a non-empty message".into(),
                ));
            }
        }
        Ok(())
    }
}

fn d_alarm_baud() -> u32 {
    9600
}
fn d_alarm_message() -> String {
    "LAYERWISE ALARM {layer} {kind} {severity}\r\n".into()
}
fn yes() -> bool {
    true
}
fn d_pixel() -> f64 {
    0.5
}
fn d_top() -> Light {
    Light::Top
}
fn d_side() -> Light {
    Light::Side
}
fn d_edge() -> f64 {
    4.0
}
fn d_streak_z() -> f64 {
    7.0
}
fn d_segment() -> f64 {
    40.0
}
fn d_streak_width() -> f64 {
    5.0
}
fn d_short_z() -> f64 {
    8.0
}
fn d_short_width() -> f64 {
    3.0
}
fn d_reference() -> usize {
    5
}
fn d_elevation_z() -> f64 {
    8.0
}
fn d_fused_factor() -> f64 {
    3.5
}
fn d_tolerance() -> f64 {
    0.75
}
fn d_unfused() -> f64 {
    0.3
}
fn d_excess() -> f64 {
    0.1
}
fn d_min_excess() -> f64 {
    4.0
}
fn d_spatter() -> f64 {
    1.5
}
fn d_drift_z() -> f64 {
    10.0
}
fn d_drift_window() -> usize {
    30
}
fn d_drift_min() -> usize {
    10
}
fn d_critical() -> f64 {
    2.0
}
fn d_alarm_severity() -> AlarmSeverity {
    AlarmSeverity::Critical
}

/// What the mock camera can get wrong on purpose.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InjectKind {
    /// A line of brighter (or darker) powder along x in the pre-scan frames.
    Streak,
    /// The powder ends short: a band at the +x end is bare (previous layer showing).
    ShortFeed,
    /// A part's −x edge stands above the powder in the pre-scan frames (bright metal, shadow).
    Elevation,
    /// A part does not fuse (post-scan: powder where the vectors are).
    NoFusion,
    /// A part fuses wider than its vectors.
    WideFusion,
    /// Fused spots away from every part.
    Spatter,
    /// A part's post-scan grey level changes slowly: a linear ramp over the injection's layers,
    /// reaching `c` grey levels on its last one (a drifting laser power or focus).
    Drift,
}

impl InjectKind {
    pub const ALL: [InjectKind; 7] = [
        InjectKind::Streak,
        InjectKind::ShortFeed,
        InjectKind::Elevation,
        InjectKind::NoFusion,
        InjectKind::WideFusion,
        InjectKind::Spatter,
        InjectKind::Drift,
    ];
    pub fn name(self) -> &'static str {
        match self {
            InjectKind::Streak => "streak",
            InjectKind::ShortFeed => "short-feed",
            InjectKind::Elevation => "elevation",
            InjectKind::NoFusion => "no-fusion",
            InjectKind::WideFusion => "wide-fusion",
            InjectKind::Spatter => "spatter",
            InjectKind::Drift => "drift",
        }
    }
    /// Parameters each kind takes (`key=value`), with their defaults.
    pub fn defaults(self) -> &'static [(&'static str, f64)] {
        match self {
            // y of the streak's center, its extent along x, width and grey-level contrast.
            InjectKind::Streak => &[
                ("y", 12.3),
                ("from", -40.0),
                ("to", 95.0),
                ("w", 1.0),
                ("c", 8.0),
            ],
            // x where the powder ends; darkening of the bare band in grey levels.
            InjectKind::ShortFeed => &[("x", 90.0), ("c", 20.0)],
            // demo part (1-based), raised strip width in mm, brightness of the raised metal.
            InjectKind::Elevation => &[("part", 3.0), ("w", 2.0), ("c", 40.0)],
            InjectKind::NoFusion => &[("part", 3.0)],
            // growth of the fused outline, mm.
            InjectKind::WideFusion => &[("part", 3.0), ("d", 1.5)],
            // spots, their radius in mm, and the center of the cloud.
            InjectKind::Spatter => &[("n", 4.0), ("r", 0.8), ("x", 0.0), ("y", 0.0)],
            // demo part, change of its post-scan grey level reached on the last layer.
            InjectKind::Drift => &[("part", 3.0), ("c", 40.0)],
        }
    }
}

/// One injected anomaly: `kind@layer[..last][/key=value…]`, e.g. `streak@40/y=-20/c=6`,
/// `short-feed@75`, `elevation@90..95`, `no-fusion@120/part=1`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct MockInjection {
    pub kind: InjectKind,
    pub first: u32,
    pub last: u32,
    pub params: BTreeMap<String, f64>,
}

impl MockInjection {
    /// A parameter, or its documented default.
    pub fn get(&self, key: &str) -> f64 {
        self.params.get(key).copied().unwrap_or_else(|| {
            self.kind
                .defaults()
                .iter()
                .find(|(k, _)| *k == key)
                .map_or(0.0, |(_, v)| *v)
        })
    }
    pub fn covers(&self, layer: u32) -> bool {
        (self.first..=self.last).contains(&layer)
    }
}

impl FromStr for MockInjection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let usage = "expected kind@layer[..last][/key=value…], e.g. streak@40/y=12/c=6";
        let (head, rest) = s.trim().split_once('@').ok_or(format!("{s}: {usage}"))?;
        let kind = InjectKind::ALL
            .into_iter()
            .find(|k| k.name() == head)
            .ok_or_else(|| {
                let names: Vec<_> = InjectKind::ALL.iter().map(|k| k.name()).collect();
                format!(
                    "{s}: unknown anomaly `{head}` (one of {})",
                    names.join(", ")
                )
            })?;
        let mut parts = rest.split('/');
        let layers = parts.next().unwrap_or_default();
        let layer = |t: &str| {
            t.parse::<u32>()
                .ok()
                .filter(|l| (1..=crate::shot::MAX_LAYER).contains(l))
                .ok_or(format!("{s}: `{t}` is not a layer number (1 to 99999)"))
        };
        let (first, last) = match layers.split_once("..") {
            Some((a, b)) => (layer(a)?, layer(b)?),
            None => (layer(layers)?, layer(layers)?),
        };
        if last < first {
            return Err(format!("{s}: layers {first}..{last} run backwards"));
        }
        let mut params = BTreeMap::new();
        for p in parts {
            let (k, v) = p.split_once('=').ok_or(format!("{s}: `{p}`: {usage}"))?;
            if !kind.defaults().iter().any(|(d, _)| *d == k) {
                let keys: Vec<_> = kind.defaults().iter().map(|(k, _)| *k).collect();
                return Err(format!(
                    "{s}: {} takes {}, not `{k}`",
                    kind.name(),
                    keys.join(", ")
                ));
            }
            let v: f64 = v
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or(format!("{s}: `{v}` is not a number"))?;
            params.insert(k.to_string(), v);
        }
        Ok(MockInjection {
            kind,
            first,
            last,
            params,
        })
    }
}

impl TryFrom<String> for MockInjection {
    type Error = String;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<MockInjection> for String {
    fn from(m: MockInjection) -> String {
        m.to_string()
    }
}

impl fmt::Display for MockInjection {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}@{}", self.kind.name(), self.first)?;
        if self.last != self.first {
            write!(f, "..{}", self.last)?;
        }
        for (k, v) in &self.params {
            write!(f, "/{k}={v}")?;
        }
        Ok(())
    }
}

/// A comma-separated list of injections (`demo --inject`).
pub fn parse_injections(list: &str) -> Result<Vec<MockInjection>, String> {
    list.split(',')
        .filter(|s| !s.trim().is_empty())
        .map(str::parse)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn injections_parse_print_and_refuse_nonsense() {
        let list = parse_injections("streak@40,short-feed@75/x=60,elevation@90..95").unwrap();
        assert_eq!(list.len(), 3);
        assert_eq!(list[0].kind, InjectKind::Streak);
        assert_eq!(list[0].get("y"), 12.3);
        assert_eq!(list[1].get("x"), 60.0);
        assert!(list[2].covers(93) && !list[2].covers(96));
        for item in &list {
            assert_eq!(&item.to_string().parse::<MockInjection>().unwrap(), item);
        }
        for bad in [
            "streak",
            "blob@3",
            "streak@0",
            "streak@5..2",
            "streak@4/q=1",
            "streak@4/y=x",
        ] {
            assert!(bad.parse::<MockInjection>().is_err(), "{bad}");
        }
    }

    #[test]
    fn defaults_pass_their_own_check() {
        let c = InspectionConfig::default();
        assert!(c.enabled && c.check().is_ok());
        assert!(matches!(c.alarm.output, super::super::LightsConfig::None));
        let mut bad = c.clone();
        bad.streak_z = 0.0;
        assert_eq!(bad.check().unwrap_err().0, "inspection.streak_z");
    }
}
