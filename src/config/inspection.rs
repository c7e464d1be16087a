//! `[inspection]`: the per-layer inspection of the rectified views (recoater streaks, short feed,
//! super-elevation, fusion against the vectors, drift) and its alarm output. Every threshold is a
//! robust score (a z-score on median/MAD, or a ratio) with a documented default; a flag whose
//! score reaches `critical_factor` times its threshold is critical, else a warning.
//! Also the mock camera's anomaly injections (`[camera] inject = [...]`, `demo --inject`).

use super::Invalid;
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

/// `recoat_axis`: found from the build's frames (`auto`, the default: streaks and recoating marks
/// run along the blade's travel) or set (`x`, `y`: honoured, with a WARN when the frames say the
/// other).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RecoatAxis {
    #[default]
    Auto,
    X,
    Y,
}

impl RecoatAxis {
    /// The axis set by hand, `None` for `auto`.
    pub fn fixed(self) -> Option<Axis> {
        match self {
            RecoatAxis::Auto => None,
            RecoatAxis::X => Some(Axis::X),
            RecoatAxis::Y => Some(Axis::Y),
        }
    }
}

impl fmt::Display for RecoatAxis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.fixed() {
            Some(a) => a.fmt(f),
            None => f.write_str("auto"),
        }
    }
}

impl Axis {
    pub fn other(self) -> Axis {
        match self {
            Axis::X => Axis::Y,
            Axis::Y => Axis::X,
        }
    }
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

/// A key left out takes its value from [`InspectionConfig::default`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InspectionConfig {
    /// Inspect every layer in the processing worker once its views are rectified (needs
    /// calibration.file). Parts are known from build.vectors; without it only the plate-wide
    /// detectors (streaks, short feed) run.
    pub enabled: bool,
    /// Cell size of the inspection grid in mm: the series grid binned to about this.
    pub pixel_mm: f64,
    /// Axis the recoater travels along: `auto` (found from the frames), `x` or `y`.
    pub recoat_axis: RecoatAxis,
    /// Light of the pre-scan view searched for streaks and short feed.
    pub pre_light: Light,
    /// Light of the pre-scan view searched for super-elevation (raking light shows relief).
    pub elevation_light: Light,
    /// Light of the post-scan view compared with the vectors.
    pub post_light: Light,
    /// Plate border left out (the plate edge and its shadow), mm.
    pub edge_margin_mm: f64,
    /// Streak: robust z of a line mean against its neighbours across the recoating direction.
    pub streak_z: f64,
    /// Streak: the plate is cut into segments this long along the recoating direction, so a
    /// partial streak is not diluted by the whole line.
    pub streak_segment_mm: f64,
    /// Streak: wider bands than this are not streaks (short feed and lighting are).
    pub streak_max_width_mm: f64,
    /// Short feed: robust z of a band's mean or texture against the same view's reference
    /// (median of the previous `reference_layers` layers).
    pub short_feed_z: f64,
    /// Short feed: narrowest band reported, mm.
    pub short_feed_min_width_mm: f64,
    /// Layers in the short-feed reference and in the powder bed's running reference (the
    /// detectors that compare with earlier layers wait until 3 are seen).
    pub reference_layers: usize,
    /// Coverage (uneven spreading, powder too thin, the layer below showing): robust z of a
    /// region of the pre-scan view against the bed's running reference, in units of this
    /// layer's own layer-to-layer variation over the bed.
    pub coverage_z: f64,
    /// Coverage: smallest region reported, mm².
    pub coverage_min_mm2: f64,
    /// Illumination flattening: the scale of the smooth light field (vignetting, uneven light)
    /// divided out before judging the powder, mm.
    pub flatten_mm: f64,
    /// Super-elevation: robust z (3x3-smoothed) of a spot over the previous layer's footprint
    /// against the powder around the part.
    pub elevation_z: f64,
    /// Fusion: a cell is fused when its texture (local standard deviation) exceeds this many
    /// times the plate's median texture.
    pub fused_texture_factor: f64,
    /// Fusion: how far the fused edge may stray from the vectors, mm.
    pub fusion_tolerance_mm: f64,
    /// Fusion: largest unfused fraction of a part's core (its footprint less one cell).
    pub max_unfused: f64,
    /// Fusion: largest fused area beyond the tolerance around a part, as a fraction of its area
    /// (and at least `min_excess_mm2`).
    pub max_excess: f64,
    pub min_excess_mm2: f64,
    /// Spatter / stray scan: smallest fused blob away from every part, mm².
    pub spatter_min_mm2: f64,
    /// Drift: robust z of a part metric against the median/MAD of its earlier layers (a layer half
    /// this far off does not enter the baseline).
    pub drift_z: f64,
    /// Drift: layers in the running baseline; the detector waits for `drift_min_layers`.
    pub drift_window: usize,
    pub drift_min_layers: usize,
    /// Score ≥ this × threshold: critical.
    pub critical_factor: f64,
    pub alarm: AlarmConfig,
    /// A trained defect model run after the classical checks (src/config/model.rs).
    pub model: Option<super::model::ModelConfig>,
}

impl Default for InspectionConfig {
    fn default() -> Self {
        InspectionConfig {
            enabled: true,
            pixel_mm: 0.5,
            recoat_axis: RecoatAxis::Auto,
            pre_light: Light::Top,
            elevation_light: Light::Side,
            post_light: Light::Top,
            edge_margin_mm: 4.0,
            streak_z: 7.0,
            streak_segment_mm: 40.0,
            streak_max_width_mm: 5.0,
            short_feed_z: 8.0,
            short_feed_min_width_mm: 3.0,
            reference_layers: 5,
            coverage_z: 10.0,
            coverage_min_mm2: 20.0,
            flatten_mm: 30.0,
            elevation_z: 8.0,
            fused_texture_factor: 3.5,
            fusion_tolerance_mm: 0.75,
            max_unfused: 0.3,
            max_excess: 0.1,
            min_excess_mm2: 4.0,
            spatter_min_mm2: 1.5,
            drift_z: 10.0,
            drift_window: 30,
            drift_min_layers: 10,
            critical_factor: 2.0,
            alarm: AlarmConfig::default(),
            model: None,
        }
    }
}

/// The stack light switched by a flag: one channel of a relay board or GPIO line set, driven
/// through the same backends as the lights. Off by default; a key left out takes its value from
/// [`AlarmConfig::default`].
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlarmConfig {
    /// The output: kind = "none" (default), "serial-relay", "gpio" (as `[lights]`), or "mock".
    pub output: super::LightsConfig,
    /// Which channel of that output the stack light hangs on.
    pub channel: Light,
    /// Lowest severity that switches it on.
    pub severity: AlarmSeverity,
    /// Keep it on until an operator acknowledges it (`layerwise alarm ack`; it stays on across
    /// a daemon restart), or (false) switch it off after a clean layer.
    pub latch: bool,
    /// A message to the printer's controller on a serial line, sent once each time the alarm is
    /// raised (none by default), e.g.
    /// `serial = { port = "/dev/ttyUSB1", baud = 9600, message = "LAYERWISE ALARM {layer} {kind}\r\n" }`.
    pub serial: Option<AlarmSerialConfig>,
}

impl Default for AlarmConfig {
    fn default() -> Self {
        AlarmConfig {
            output: super::LightsConfig::None,
            channel: Light::Top,
            severity: AlarmSeverity::Critical,
            latch: true,
            serial: None,
        }
    }
}

/// `[inspection.alarm] serial`: the alarm's message to the printer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AlarmSerialConfig {
    /// The serial port (opened when the first message is due, reopened after an error).
    pub port: String,
    #[serde(default = "default_alarm_baud")]
    pub baud: u32,
    /// The text sent: `{layer}`, `{kind}`, `{severity}` and `{part}` are replaced by the flag
    /// that raised the alarm; TOML escapes (`\r`, `\n`) end the line as the printer expects.
    #[serde(default = "default_alarm_message")]
    pub message: String,
}

fn default_alarm_baud() -> u32 {
    9600
}
fn default_alarm_message() -> String {
    "LAYERWISE ALARM {layer} {kind} {severity}\r\n".into()
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

impl InspectionConfig {
    /// Checks the section (values serde cannot): positive sizes and thresholds, baselines of 3
    /// layers or more, an alarm message that can be sent.
    pub fn validate(&self) -> Result<(), Invalid> {
        let positive = [
            ("pixel_mm", self.pixel_mm),
            ("streak_z", self.streak_z),
            ("streak_segment_mm", self.streak_segment_mm),
            ("streak_max_width_mm", self.streak_max_width_mm),
            ("short_feed_z", self.short_feed_z),
            ("short_feed_min_width_mm", self.short_feed_min_width_mm),
            ("coverage_z", self.coverage_z),
            ("coverage_min_mm2", self.coverage_min_mm2),
            ("flatten_mm", self.flatten_mm),
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
                return Err(Invalid::new(
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
                return Err(Invalid::new(
                    format!("inspection.{key}"),
                    format!("must be a finite number, 0 or more, got {v}"),
                ));
            }
        }
        if self.reference_layers < 3 || self.drift_window < 3 || self.drift_min_layers < 3 {
            return Err(Invalid::new(
                "inspection.reference_layers / drift_window / drift_min_layers",
                "must be 3 or more (a median of fewer layers is no baseline)",
            ));
        }
        if let Some(model) = &self.model {
            model.validate()?;
            if !self.enabled {
                return Err(Invalid::new(
                    "inspection.model",
                    "runs with the inspection: set inspection.enabled = true or leave the model out",
                ));
            }
        }
        if let Some(serial) = &self.alarm.serial {
            if serial.port.trim().is_empty() || serial.message.is_empty() || serial.baud == 0 {
                return Err(Invalid::new(
                    "inspection.alarm.serial",
                    "needs a port, a baud rate above 0 and a non-empty message",
                ));
            }
        }
        Ok(())
    }
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

/// How `kind@layer[..last][/key=value…]` is written, for the errors that quote it.
const INJECTION_USAGE: &str = "expected kind@layer[..last][/key=value…], e.g. streak@40/y=12/c=6";

/// An injection (`[camera] inject`, `demo --inject`) that does not say what to render. Each names
/// the text as given.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum InjectionError {
    #[error("{text}: {}", INJECTION_USAGE)]
    NoLayer { text: String },
    #[error("{text}: unknown anomaly `{kind}` (one of {})", kind_names())]
    UnknownKind { text: String, kind: String },
    #[error("{text}: `{layer}` is not a layer number (1 to 99999)")]
    NotALayer { text: String, layer: String },
    #[error("{text}: layers {first}..{last} run backwards")]
    Backwards { text: String, first: u32, last: u32 },
    #[error("{text}: `{param}`: {}", INJECTION_USAGE)]
    NoValue { text: String, param: String },
    #[error("{text}: {} takes {}, not `{param}`", kind.name(), param_names(*kind))]
    UnknownParameter {
        text: String,
        kind: InjectKind,
        param: String,
    },
    #[error("{text}: `{value}` is not a number")]
    NotANumber { text: String, value: String },
    #[error("{text}: {param} = {value} is out of range ({min} to {max})")]
    OutOfRange {
        text: String,
        param: String,
        value: String,
        min: f64,
        max: f64,
    },
}

/// The values an injection's parameter may take: counts and part numbers are small positive
/// integers (a count sizes what the mock camera draws), the rest mm or grey levels on the plate.
fn parameter_range(param: &str) -> (f64, f64) {
    match param {
        "n" => (1.0, 1000.0),
        "part" => (1.0, 99.0),
        _ => (-1000.0, 1000.0),
    }
}

fn kind_names() -> String {
    let names: Vec<_> = InjectKind::ALL.iter().map(|k| k.name()).collect();
    names.join(", ")
}

fn param_names(kind: InjectKind) -> String {
    let keys: Vec<_> = kind.defaults().iter().map(|(k, _)| *k).collect();
    keys.join(", ")
}

impl FromStr for MockInjection {
    type Err = InjectionError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let text = || s.to_string();
        let (head, rest) = s
            .trim()
            .split_once('@')
            .ok_or_else(|| InjectionError::NoLayer { text: text() })?;
        let kind = InjectKind::ALL
            .into_iter()
            .find(|k| k.name() == head)
            .ok_or_else(|| InjectionError::UnknownKind {
                text: text(),
                kind: head.to_string(),
            })?;
        let mut parts = rest.split('/');
        let layers = parts.next().unwrap_or_default();
        let layer = |t: &str| {
            t.parse::<u32>()
                .ok()
                .filter(|l| (1..=crate::shot::MAX_LAYER).contains(l))
                .ok_or_else(|| InjectionError::NotALayer {
                    text: text(),
                    layer: t.to_string(),
                })
        };
        let (first, last) = match layers.split_once("..") {
            Some((a, b)) => (layer(a)?, layer(b)?),
            None => (layer(layers)?, layer(layers)?),
        };
        if last < first {
            return Err(InjectionError::Backwards {
                text: text(),
                first,
                last,
            });
        }
        let mut params = BTreeMap::new();
        for p in parts {
            let (k, v) = p.split_once('=').ok_or_else(|| InjectionError::NoValue {
                text: text(),
                param: p.to_string(),
            })?;
            if !kind.defaults().iter().any(|(d, _)| *d == k) {
                return Err(InjectionError::UnknownParameter {
                    text: text(),
                    kind,
                    param: k.to_string(),
                });
            }
            let given = v;
            let v: f64 = v
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| InjectionError::NotANumber {
                    text: text(),
                    value: v.to_string(),
                })?;
            let (min, max) = parameter_range(k);
            if !(min..=max).contains(&v) {
                return Err(InjectionError::OutOfRange {
                    text: text(),
                    param: k.to_string(),
                    value: given.to_string(),
                    min,
                    max,
                });
            }
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
    type Error = InjectionError;
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
pub fn parse_injections(list: &str) -> Result<Vec<MockInjection>, InjectionError> {
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
        for (bad, message) in [
            (
                "streak",
                "streak: expected kind@layer[..last][/key=value…], e.g. streak@40/y=12/c=6",
            ),
            (
                "blob@3",
                "blob@3: unknown anomaly `blob` (one of streak, short-feed, elevation, no-fusion, \
                 wide-fusion, spatter, drift)",
            ),
            (
                "streak@0",
                "streak@0: `0` is not a layer number (1 to 99999)",
            ),
            ("streak@5..2", "streak@5..2: layers 5..2 run backwards"),
            (
                "streak@4/q",
                "streak@4/q: `q`: expected kind@layer[..last][/key=value…], e.g. \
                 streak@40/y=12/c=6",
            ),
            (
                "streak@4/q=1",
                "streak@4/q=1: streak takes y, from, to, w, c, not `q`",
            ),
            ("streak@4/y=x", "streak@4/y=x: `x` is not a number"),
            (
                "spatter@1/n=4294967295",
                "spatter@1/n=4294967295: n = 4294967295 is out of range (1 to 1000)",
            ),
            (
                "streak@4/w=1e300",
                "streak@4/w=1e300: w = 1e300 is out of range (-1000 to 1000)",
            ),
        ] {
            let err = bad.parse::<MockInjection>().unwrap_err();
            assert_eq!(err.to_string(), message, "{bad}");
        }
        let err = parse_injections("streak@40, blob@3").unwrap_err();
        assert!(matches!(err, InjectionError::UnknownKind { .. }), "{err}");
        assert!(
            err.to_string()
                .starts_with(" blob@3: unknown anomaly `blob`"),
            "{err}"
        );
    }

    #[test]
    fn defaults_pass_their_own_check() {
        let c = InspectionConfig::default();
        assert!(c.enabled && c.validate().is_ok());
        assert!(matches!(c.alarm.output, super::super::LightsConfig::None));
        let mut bad = c.clone();
        bad.streak_z = 0.0;
        let refused = bad.validate().unwrap_err();
        assert_eq!(refused.key, "inspection.streak_z");
        assert_eq!(refused.message, "must be a finite number above 0, got 0");
    }
}
