//! Messages to the printer's controller (the inspection alarm's serial line): a trait, so the
//! alarm can be tested with a recorder, and its serial backend.

use crate::config::inspection::AlarmSerialConfig;
use std::io::Write;
use std::time::Duration;
use tracing::info;

#[derive(Debug, thiserror::Error)]
pub enum MessageError {
    #[error("alarm message to {port}: cannot open ({hint})")]
    Open {
        port: String,
        hint: &'static str,
        #[source]
        source: serialport::Error,
    },
    #[error("alarm message to {port}: cannot write; the port is reopened for the next message")]
    Write {
        port: String,
        #[source]
        source: std::io::Error,
    },
}

/// Where the alarm's message goes.
pub trait MessageLink: Send {
    fn send(&mut self, bytes: &[u8]) -> Result<(), MessageError>;
}

/// A serial port, opened when the first message is due and reopened after any error, so a
/// printer cable plugged in late (or replugged) still gets the next alarm.
pub struct SerialMessage {
    config: AlarmSerialConfig,
    port: Option<Box<dyn serialport::SerialPort>>,
}

impl SerialMessage {
    pub fn new(config: AlarmSerialConfig) -> SerialMessage {
        SerialMessage { config, port: None }
    }
}

impl MessageLink for SerialMessage {
    fn send(&mut self, bytes: &[u8]) -> Result<(), MessageError> {
        if self.port.is_none() {
            let port = serialport::new(&self.config.port, self.config.baud)
                .timeout(Duration::from_secs(2))
                .open()
                .map_err(|source| MessageError::Open {
                    port: self.config.port.clone(),
                    hint: super::trigger::open_hint(&source),
                    source,
                })?;
            info!(port = %self.config.port, baud = self.config.baud, "inspection alarm: serial port open");
            self.port = Some(port);
        }
        let Some(port) = self.port.as_mut() else {
            return Ok(());
        };
        let written = port.write_all(bytes).and_then(|_| port.flush());
        written.map_err(|source| {
            self.port = None;
            MessageError::Write {
                port: self.config.port.clone(),
                source,
            }
        })
    }
}

/// The configured link, if any.
pub fn open(config: Option<&AlarmSerialConfig>) -> Option<Box<dyn MessageLink>> {
    config.map(|c| Box::new(SerialMessage::new(c.clone())) as Box<dyn MessageLink>)
}
