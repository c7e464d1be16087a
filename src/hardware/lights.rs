//! The front, side and top lights: a serial relay board, GPIO lines or none (the simulated ones
//! live in `sim`). Whatever happens, the lights end up off: [`LightsGuard`] switches them off when
//! it is dropped.

use crate::config::{GpioLightsConfig, LightsConfig, SerialRelayConfig};
use crate::shot::Light;
use std::collections::BTreeMap;
use std::io::Write;
use std::time::Duration;
use tracing::warn;

#[derive(Debug, thiserror::Error)]
pub enum LightsError {
    #[error("lights relay {port}: cannot open")]
    SerialOpen {
        port: String,
        #[source]
        source: serialport::Error,
    },
    #[error("lights relay {port}: cannot send the command")]
    Serial {
        port: String,
        #[source]
        source: std::io::Error,
    },
    #[error("lights GPIO {chip}")]
    Gpio {
        chip: String,
        #[source]
        source: gpiocdev::Error,
    },
    #[error("lights: bad command string {key}: {message}")]
    Command { key: String, message: String },
    #[error("lights: kind = \"mock\" belongs to the simulated machine (`layerwise demo`, tests); configure serial-relay, gpio or none")]
    Simulated,
}

pub trait Lights: Send {
    fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError>;
    fn all_off(&mut self) -> Result<(), LightsError>;
}

/// Switches all lights off when dropped, so no error path leaves a lamp burning.
pub struct LightsGuard {
    lights: Box<dyn Lights>,
}

impl LightsGuard {
    pub fn new(lights: Box<dyn Lights>) -> LightsGuard {
        LightsGuard { lights }
    }
    pub fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
        tracing::debug!(light = %light, on, "lights: switch");
        self.lights.switch(light, on)
    }
    /// All off, logging rather than failing: used on error paths.
    pub fn all_off_logged(&mut self) {
        tracing::debug!("lights: all off");
        if let Err(e) = self.lights.all_off() {
            warn!(error = %crate::logging::Chain(&e), "lights: could not switch all lights off");
        }
    }
}

impl Drop for LightsGuard {
    fn drop(&mut self) {
        self.all_off_logged();
    }
}

/// Opens the configured lights; `kind = "mock"` is the simulated machine's (see `sim`).
pub fn open(config: &LightsConfig) -> Result<Box<dyn Lights>, LightsError> {
    Ok(match config {
        LightsConfig::None => Box::new(NoLights),
        LightsConfig::SerialRelay(relay) => Box::new(SerialRelayLights::open(relay)?),
        LightsConfig::Gpio(gpio) => Box::new(GpioLights::open(gpio)?),
        LightsConfig::Mock => return Err(LightsError::Simulated),
    })
}

/// Lights that are not switched (a constant lamp, or none).
pub struct NoLights;

impl Lights for NoLights {
    fn switch(&mut self, _light: Light, _on: bool) -> Result<(), LightsError> {
        Ok(())
    }
    fn all_off(&mut self) -> Result<(), LightsError> {
        Ok(())
    }
}

/// Decodes `\r`, `\n`, `\t`, `\\` and `\xNN` in a relay command string.
pub fn decode_command(key: &str, text: &str) -> Result<Vec<u8>, LightsError> {
    let bad = |message: String| LightsError::Command {
        key: key.to_string(),
        message,
    };
    let mut out = Vec::new();
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c != '\\' {
            let mut buf = [0u8; 4];
            out.extend_from_slice(c.encode_utf8(&mut buf).as_bytes());
            continue;
        }
        match chars.next() {
            Some('r') => out.push(b'\r'),
            Some('n') => out.push(b'\n'),
            Some('t') => out.push(b'\t'),
            Some('\\') => out.push(b'\\'),
            Some('x') => {
                let hex: String = chars.by_ref().take(2).collect();
                let byte = u8::from_str_radix(&hex, 16)
                    .map_err(|_| bad(format!("`\\x{hex}` is not two hex digits")))?;
                out.push(byte);
            }
            other => {
                return Err(bad(format!(
                    "unknown escape `\\{}`",
                    other.map(String::from).unwrap_or_default()
                )))
            }
        }
    }
    Ok(out)
}

pub struct SerialRelayLights {
    port_name: String,
    port: Box<dyn serialport::SerialPort>,
    commands: BTreeMap<String, Vec<u8>>,
}

impl SerialRelayLights {
    pub fn open(config: &SerialRelayConfig) -> Result<SerialRelayLights, LightsError> {
        let mut commands = BTreeMap::new();
        for (key, text) in &config.commands {
            commands.insert(key.clone(), decode_command(key, text)?);
        }
        let port = serialport::new(&config.port, config.baud)
            .timeout(Duration::from_secs(2))
            .open()
            .map_err(|source| LightsError::SerialOpen {
                port: config.port.clone(),
                source,
            })?;
        Ok(SerialRelayLights {
            port_name: config.port.clone(),
            port,
            commands,
        })
    }

    fn send(&mut self, key: &str) -> Result<(), LightsError> {
        let Some(bytes) = self.commands.get(key) else {
            return Err(LightsError::Command {
                key: key.into(),
                message: "not configured".into(),
            });
        };
        self.port
            .write_all(bytes)
            .and_then(|_| self.port.flush())
            .map_err(|source| LightsError::Serial {
                port: self.port_name.clone(),
                source,
            })
    }
}

impl Lights for SerialRelayLights {
    fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
        self.send(&format!("{light}_{}", if on { "on" } else { "off" }))
    }
    fn all_off(&mut self) -> Result<(), LightsError> {
        if self.commands.contains_key("all_off") {
            return self.send("all_off");
        }
        let mut first_error = None;
        for light in Light::ALL {
            let key = format!("{light}_off");
            if self.commands.contains_key(&key) {
                if let Err(e) = self.send(&key) {
                    first_error.get_or_insert(e);
                }
            }
        }
        first_error.map_or(Ok(()), Err)
    }
}

pub struct GpioLights {
    chip: String,
    request: gpiocdev::Request,
    lines: [(Light, u32); 3],
}

impl GpioLights {
    pub fn open(config: &GpioLightsConfig) -> Result<GpioLights, LightsError> {
        let chip = config.chip.display().to_string();
        let lines = [
            (Light::Front, config.front),
            (Light::Side, config.side),
            (Light::Top, config.top),
        ];
        let offsets: Vec<u32> = lines.iter().map(|(_, o)| *o).collect();
        let mut builder = gpiocdev::Request::builder();
        builder
            .on_chip(&config.chip)
            .with_consumer("layerwise-lights")
            .with_lines(&offsets)
            .as_output(gpiocdev::line::Value::Inactive);
        if config.active_low {
            builder.as_active_low();
        }
        let request = builder.request().map_err(|source| LightsError::Gpio {
            chip: chip.clone(),
            source,
        })?;
        Ok(GpioLights {
            chip,
            request,
            lines,
        })
    }
}

impl Lights for GpioLights {
    fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
        let Some(&(_, offset)) = self.lines.iter().find(|(l, _)| *l == light) else {
            return Ok(());
        };
        let value = if on {
            gpiocdev::line::Value::Active
        } else {
            gpiocdev::line::Value::Inactive
        };
        self.request
            .set_value(offset, value)
            .map_err(|source| LightsError::Gpio {
                chip: self.chip.clone(),
                source,
            })
    }
    fn all_off(&mut self) -> Result<(), LightsError> {
        for light in Light::ALL {
            self.switch(light, false)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn command_escapes() {
        assert_eq!(decode_command("k", r"A1\r\n").unwrap(), b"A1\r\n");
        assert_eq!(decode_command("k", r"\xFF\x00").unwrap(), vec![0xff, 0]);
        let err = decode_command("front_on", r"\xZZ").unwrap_err().to_string();
        assert!(err.contains("front_on"), "{err}");
        assert!(decode_command("k", r"\q").is_err());
    }
}
