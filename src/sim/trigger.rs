//! The simulated printer's layer signals: a script (`LAYER n PRE|POST`, `WAIT ms`), a generated
//! sequence of layers, or events a test sends itself.

use crate::clock::{SharedClock, SystemClock};
use crate::config::MockTriggerConfig;
use crate::hardware::trigger::{LayerEvent, LineProtocol, SharedHealth, Trigger, TriggerError};
use crate::shot::Phase;
use crate::shutdown::Shutdown;
use std::collections::VecDeque;
use std::path::Path;
use std::time::Duration;

/// One step of a mock script.
#[derive(Clone, Debug, PartialEq)]
pub enum ScriptStep {
    Signal(u32, Phase),
    Wait(Duration),
}

/// Events from a script, a generated sequence or an in-process channel.
pub struct MockTrigger {
    steps: VecDeque<ScriptStep>,
    interval: Duration,
    channel: Option<crossbeam_channel::Receiver<LayerEvent>>,
    clock: SharedClock,
}

impl MockTrigger {
    /// The configured script, or `layers` layers from `first_layer`, paced on `clock`.
    pub fn from_config(
        config: &MockTriggerConfig,
        clock: SharedClock,
    ) -> Result<MockTrigger, TriggerError> {
        let steps = match &config.script {
            Some(path) => parse_script(path)?,
            None => (config.first_layer..config.first_layer.saturating_add(config.layers))
                .flat_map(|layer| {
                    [
                        ScriptStep::Signal(layer, Phase::Pre),
                        ScriptStep::Signal(layer, Phase::Post),
                    ]
                })
                .collect(),
        };
        Ok(MockTrigger {
            steps,
            interval: Duration::from_millis(config.interval_ms),
            channel: None,
            clock,
        })
    }

    /// Events sent by the test itself.
    pub fn from_channel(receiver: crossbeam_channel::Receiver<LayerEvent>) -> MockTrigger {
        MockTrigger {
            steps: VecDeque::new(),
            interval: Duration::ZERO,
            channel: Some(receiver),
            clock: SystemClock::shared(),
        }
    }
}

fn parse_script(path: &Path) -> Result<VecDeque<ScriptStep>, TriggerError> {
    let text = crate::fsutil::read_text_bounded(path, 16 << 20).map_err(|source| {
        TriggerError::ScriptRead {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let protocol = LineProtocol::default_protocol();
    let mut steps = VecDeque::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(ms) = line.strip_prefix("WAIT ") {
            let ms: u64 = ms.trim().parse().map_err(|_| TriggerError::Script {
                path: path.to_path_buf(),
                line: n + 1,
                expected: "`WAIT <milliseconds>`",
                found: line.to_string(),
            })?;
            steps.push_back(ScriptStep::Wait(Duration::from_millis(ms)));
        } else if let Some((layer, phase)) = protocol.parse(line) {
            steps.push_back(ScriptStep::Signal(layer, phase));
        } else {
            return Err(TriggerError::Script {
                path: path.to_path_buf(),
                line: n + 1,
                expected: "`LAYER <n> PRE|POST` or `WAIT <ms>`",
                found: line.to_string(),
            });
        }
    }
    Ok(steps)
}

impl Trigger for MockTrigger {
    fn health(&self) -> SharedHealth {
        SharedHealth::connected("simulated printer")
    }

    fn next_event(&mut self, shutdown: &Shutdown) -> Result<Option<LayerEvent>, TriggerError> {
        if let Some(rx) = &self.channel {
            return Ok(crossbeam_channel::select! {
                recv(rx) -> event => event.ok(),
                recv(shutdown.receiver()) -> _ => None,
            });
        }
        loop {
            let stopped = match self.steps.pop_front() {
                None => return Ok(None),
                Some(ScriptStep::Wait(d)) => self.clock.sleep_unless(d, shutdown.receiver()),
                Some(ScriptStep::Signal(layer, phase)) => {
                    if self.clock.sleep_unless(self.interval, shutdown.receiver()) {
                        return Ok(None);
                    }
                    return Ok(Some(LayerEvent {
                        layer,
                        phase,
                        at: self.clock.now(),
                    }));
                }
            };
            if stopped {
                return Ok(None);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn script_errors_name_file_and_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("script.txt");
        std::fs::write(&path, "LAYER 1 PRE\nWAIT 5\nbogus\n").unwrap();
        let err = parse_script(&path).unwrap_err().to_string();
        assert!(
            err.contains("script.txt") && err.contains("line 3"),
            "{err}"
        );
    }
}
