//! The simulated lights: they record every switch (tests read the log) and light the simulated
//! plate the mock camera photographs.

use super::world::MockWorld;
use crate::hardware::lights::{Lights, LightsError};
use crate::shot::Light;
use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

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
    /// Lights that record what they were told and, given a world, light it.
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
    use crate::hardware::lights::LightsGuard;

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
