//! `[lights]`: the lamps switched in turn for each view (a serial relay board, GPIO lines, or the
//! simulation). The inspection's stack light (`[inspection.alarm] output`) takes the same kinds.

use super::common::{default_baud, default_gpio_chip};
use super::{Invalid, ViewsConfig};
use crate::shot::Light;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum LightsConfig {
    #[default]
    None,
    SerialRelay(SerialRelayConfig),
    Gpio(GpioLightsConfig),
    Mock,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialRelayConfig {
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Command strings per light, e.g. `front_on = "A1\r\n"`; Rust-style escapes \r \n \xNN work.
    pub commands: BTreeMap<String, String>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioLightsConfig {
    #[serde(default = "default_gpio_chip")]
    pub chip: PathBuf,
    pub front: u32,
    pub side: u32,
    pub top: u32,
    #[serde(default)]
    pub active_low: bool,
}

impl LightsConfig {
    /// Checks the section: a relay board has an on and an off command for every light the views
    /// switch, and no command of another name.
    pub fn validate(&self, views: &ViewsConfig) -> Result<(), Invalid> {
        match self {
            LightsConfig::SerialRelay(relay) => relay.validate(views),
            LightsConfig::None | LightsConfig::Gpio(_) | LightsConfig::Mock => Ok(()),
        }
    }
}

impl SerialRelayConfig {
    fn validate(&self, views: &ViewsConfig) -> Result<(), Invalid> {
        for light in &views.lights {
            for state in ["on", "off"] {
                let key = format!("{light}_{state}");
                if !self.commands.contains_key(&key) {
                    return Err(Invalid::new(
                        "lights.commands",
                        format!(
                            "missing `{key}`: every light in views.lights needs an on and an off \
                             command"
                        ),
                    ));
                }
            }
        }
        for key in self.commands.keys() {
            let known = key == "all_off"
                || Light::ALL
                    .iter()
                    .any(|l| *key == format!("{l}_on") || *key == format!("{l}_off"));
            if !known {
                return Err(Invalid::new(
                    format!("lights.commands.{key}"),
                    "unknown command: expected front_on, front_off, side_on, side_off, top_on, \
                     top_off or all_off",
                ));
            }
        }
        Ok(())
    }
}
