//! The front, side and top lights: a serial relay board, GPIO lines, none, or a mock. Whatever
//! happens, the lights end up off: [`LightsGuard`] switches them off when it is dropped.

use crate::camera::mock::MockWorld;
use crate::config::{GpioLightsConfig, LightsConfig, SerialRelayConfig};
use crate::view::Light;
use std::collections::BTreeMap;
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tracing::warn;

#[derive(Debug, thiserror::Error)]
pub enum LightsError {
    #[error("lights relay {port}: {message}")]
    Serial { port: String, message: String },
    #[error("lights GPIO {chip}: {message}")]
    Gpio { chip: String, message: String },
    #[error("lights: bad command string {key}: {message}")]
    Command { key: String, message: String },
    #[error("lights: {0}")]
    Mock(String),
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
        self.lights.switch(light, on)
    }
    /// All off, logging rather than failing: used on error paths.
    pub fn all_off_logged(&mut self) {
        if let Err(e) = self.lights.all_off() {
            warn!(error = %e, "lights: could not switch all lights off");
        }
    }
}

impl Drop for LightsGuard {
    fn drop(&mut self) {
        self.all_off_logged();
    }
}

pub fn open(
    config: &LightsConfig,
    world: Option<MockWorld>,
) -> Result<(Box<dyn Lights>, Option<MockLightsLog>), LightsError> {
    Ok(match config {
        LightsConfig::None => (Box::new(NoLights), None),
        LightsConfig::SerialRelay(relay) => (Box::new(SerialRelayLights::open(relay)?), None),
        LightsConfig::Gpio(gpio) => (Box::new(GpioLights::open(gpio)?), None),
        LightsConfig::Mock => {
            let lights = MockLights::new(world);
            let log = lights.log();
            (Box::new(lights), Some(log))
        }
    })
}

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
            .map_err(|e| LightsError::Serial {
                port: config.port.clone(),
                message: e.to_string(),
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
            .map_err(|e| LightsError::Serial {
                port: self.port_name.clone(),
                message: e.to_string(),
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
        let request = builder.request().map_err(|e| LightsError::Gpio {
            chip: chip.clone(),
            message: e.to_string(),
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
            .map_err(|e| LightsError::Gpio {
                chip: self.chip.clone(),
                message: e.to_string(),
            })
    }
    fn all_off(&mut self) -> Result<(), LightsError> {
        for light in Light::ALL {
            self.switch(light, false)?;
        }
        Ok(())
    }
}

/// What the mock lights were told, in order; `None` light means "all off".
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LightSwitch {
    pub light: Option<Light>,
    pub on: bool,
}

/// Shared view of the mock lights' history and state, for tests.
#[derive(Clone, Default)]
pub struct MockLightsLog {
    inner: Arc<Mutex<LogState>>,
}

/// History of switches, and which lights are on now.
type LogState = (Vec<LightSwitch>, BTreeMap<Light, bool>);

impl MockLightsLog {
    pub fn history(&self) -> Vec<LightSwitch> {
        self.inner.lock().map(|g| g.0.clone()).unwrap_or_default()
    }
    /// Lights currently on.
    pub fn lit(&self) -> Vec<Light> {
        self.inner
            .lock()
            .map(|g| g.1.iter().filter(|(_, on)| **on).map(|(l, _)| *l).collect())
            .unwrap_or_default()
    }
    fn record(&self, light: Option<Light>, on: bool) {
        if let Ok(mut g) = self.inner.lock() {
            g.0.push(LightSwitch { light, on });
            match light {
                Some(l) => {
                    g.1.insert(l, on);
                }
                None => g.1.clear(),
            }
        }
    }
}

/// Lights that only record, and light the simulated plate for the mock camera.
pub struct MockLights {
    log: MockLightsLog,
    world: Option<MockWorld>,
}

impl MockLights {
    pub fn new(world: Option<MockWorld>) -> MockLights {
        MockLights {
            log: MockLightsLog::default(),
            world,
        }
    }
    pub fn log(&self) -> MockLightsLog {
        self.log.clone()
    }
}

impl Lights for MockLights {
    fn switch(&mut self, light: Light, on: bool) -> Result<(), LightsError> {
        self.log.record(Some(light), on);
        if let Some(world) = &self.world {
            world.set_light(light, on);
        }
        Ok(())
    }
    fn all_off(&mut self) -> Result<(), LightsError> {
        self.log.record(None, false);
        if let Some(world) = &self.world {
            world.all_lights_off();
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

    #[test]
    fn guard_switches_off_on_drop() {
        let lights = MockLights::new(None);
        let log = lights.log();
        {
            let mut guard = LightsGuard::new(Box::new(lights));
            guard.switch(Light::Top, true).unwrap();
            assert_eq!(log.lit(), vec![Light::Top]);
        }
        assert!(log.lit().is_empty());
        assert_eq!(
            log.history().last(),
            Some(&LightSwitch {
                light: None,
                on: false
            })
        );
    }
}
