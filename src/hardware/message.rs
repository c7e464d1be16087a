//! Messages to the printer's controller (the inspection alarm's serial line): a trait, so the
//! alarm can be tested with a recorder, and its serial backend.

use crate::config::inspection::AlarmSerialConfig;
use std::io::Write;
use std::time::Duration;
use tracing::info;

#[derive(Debug, thiserror::Error)]
#[error("alarm message to {port}: {message}")]
pub struct MessageError {
    pub port: String,
    pub message: String,
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
        let error = |message: String| MessageError {
            port: self.config.port.clone(),
            message,
        };
        if self.port.is_none() {
            let port = serialport::new(&self.config.port, self.config.baud)
                .timeout(Duration::from_secs(2))
                .open()
                .map_err(|e| {
                    error(format!(
                        "cannot open: {e}: {}",
                        super::trigger::open_hint(&e)
                    ))
                })?;
            info!(port = %self.config.port, baud = self.config.baud, "inspection alarm: serial port open");
            self.port = Some(port);
        }
        let Some(port) = self.port.as_mut() else {
            return Ok(());
        };
        let written = port.write_all(bytes).and_then(|_| port.flush());
        written.map_err(|e| {
            self.port = None;
            error(format!(
                "cannot write ({e}); the port is reopened for the next message"
            ))
        })
    }
}

/// The configured link, if any.
pub fn open(config: Option<&AlarmSerialConfig>) -> Option<Box<dyn MessageLink>> {
    config.map(|c| Box::new(SerialMessage::new(c.clone())) as Box<dyn MessageLink>)
}
