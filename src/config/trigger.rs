//! `[trigger]`: where layer signals come from (a serial line, GPIO lines, or the simulation).

use super::common::{check_backoff, default_baud, default_gpio_chip};
use super::{Invalid, MAX_LAYER};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Where layer signals come from.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum TriggerConfig {
    Serial(SerialTriggerConfig),
    Gpio(GpioTriggerConfig),
    Mock(MockTriggerConfig),
}

pub const DEFAULT_LINE_PATTERN: &str = r"^\s*LAYER\s+(?P<layer>\d+)\s+(?P<phase>PRE|POST)\s*$";

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialTriggerConfig {
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Regex with named groups `layer` (decimal) and `phase` (matched against `pre`/`post` tokens).
    #[serde(default = "default_pattern")]
    pub pattern: String,
    /// The text the printer sends for the pre-scan phase (compared case-insensitively).
    #[serde(default = "default_pre_token")]
    pub pre: String,
    #[serde(default = "default_post_token")]
    pub post: String,
    /// Backoff between attempts to reopen a vanished port: first and longest wait.
    #[serde(default = "default_reopen_ms")]
    pub reopen_backoff_ms: [u64; 2],
}

fn default_pattern() -> String {
    DEFAULT_LINE_PATTERN.to_string()
}
fn default_pre_token() -> String {
    "PRE".into()
}
fn default_post_token() -> String {
    "POST".into()
}
fn default_reopen_ms() -> [u64; 2] {
    [250, 5000]
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Edge {
    Rising,
    Falling,
    Both,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpioMode {
    /// One line pulses before the scan, another after it.
    PerPhase,
    /// One line whose pulses alternate pre, post, pre, post …
    Alternating,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioTriggerConfig {
    #[serde(default = "default_gpio_chip")]
    pub chip: PathBuf,
    pub mode: GpioMode,
    /// Line offsets: `pre_line` and `post_line` for per-phase, `line` for alternating.
    #[serde(default)]
    pub pre_line: Option<u32>,
    #[serde(default)]
    pub post_line: Option<u32>,
    #[serde(default)]
    pub line: Option<u32>,
    #[serde(default = "default_edge")]
    pub edge: Edge,
    #[serde(default = "default_debounce")]
    pub debounce_ms: u64,
    #[serde(default)]
    pub active_low: bool,
    /// The layer number of the first pulse of a new build.
    #[serde(default = "default_first_layer")]
    pub first_layer: u32,
}

fn default_edge() -> Edge {
    Edge::Rising
}
fn default_debounce() -> u64 {
    20
}
/// Printers count layers from 1.
fn default_first_layer() -> u32 {
    1
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MockTriggerConfig {
    /// A script of lines in the serial protocol (`LAYER 1 PRE`), and `WAIT ms` lines. When absent,
    /// `layers` layers starting at `first_layer` are generated, pre then post.
    #[serde(default)]
    pub script: Option<PathBuf>,
    #[serde(default = "default_mock_layers")]
    pub layers: u32,
    #[serde(default = "default_first_layer")]
    pub first_layer: u32,
    /// Pause between events, standing in for recoating and scanning.
    #[serde(default)]
    pub interval_ms: u64,
}

fn default_mock_layers() -> u32 {
    10
}

impl TriggerConfig {
    /// Checks the section: a line pattern with its groups, the lines a GPIO mode needs, layer
    /// numbers within 1 to [`MAX_LAYER`].
    pub fn validate(&self) -> Result<(), Invalid> {
        match self {
            TriggerConfig::Serial(serial) => serial.validate(),
            TriggerConfig::Gpio(gpio) => gpio.validate(),
            TriggerConfig::Mock(mock) => mock.validate(),
        }
    }
}

impl SerialTriggerConfig {
    fn validate(&self) -> Result<(), Invalid> {
        let regex = regex::Regex::new(&self.pattern).map_err(|e| {
            Invalid::new("trigger.pattern", "is not a valid regular expression").because(e)
        })?;
        for group in ["layer", "phase"] {
            if !regex.capture_names().flatten().any(|name| name == group) {
                return Err(Invalid::new(
                    "trigger.pattern",
                    format!("must have a named group `(?P<{group}>…)`"),
                ));
            }
        }
        if self.baud == 0 {
            return Err(Invalid::new(
                "trigger.baud",
                "must be a positive baud rate such as 9600",
            ));
        }
        check_backoff("trigger.reopen_backoff_ms", self.reopen_backoff_ms)
    }
}

impl GpioTriggerConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.first_layer == 0 || self.first_layer > MAX_LAYER {
            return Err(Invalid::new(
                "trigger.first_layer",
                format!("must be 1 to {MAX_LAYER}: printers count layers from 1"),
            ));
        }
        match self.mode {
            GpioMode::PerPhase if self.pre_line.is_none() || self.post_line.is_none() => {
                Err(Invalid::new(
                    "trigger.pre_line",
                    "mode \"per-phase\" needs both `pre_line` and `post_line`",
                ))
            }
            GpioMode::Alternating if self.line.is_none() => Err(Invalid::new(
                "trigger.line",
                "mode \"alternating\" needs `line`",
            )),
            _ => Ok(()),
        }
    }
}

impl MockTriggerConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.script.is_none() && self.layers == 0 {
            return Err(Invalid::new(
                "trigger.layers",
                "must be at least 1 without a script",
            ));
        }
        let last = u64::from(self.first_layer) + u64::from(self.layers);
        if self.first_layer == 0 || last > u64::from(MAX_LAYER) + 1 {
            return Err(Invalid::new(
                "trigger.first_layer",
                format!(
                    "first_layer {} and layers {} must stay within 1 to {MAX_LAYER}",
                    self.first_layer, self.layers
                ),
            ));
        }
        Ok(())
    }
}
