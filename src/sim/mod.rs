//! The simulated machine: a printer that sends layer signals from a script, lights that record
//! what they are told, and a camera (`mock_camera`) that photographs the plate through a known
//! homography, lit by whatever lamps are on. `layerwise demo`, the tests and the benchmarks run
//! the daemon on it; production code never names this module (tests/it/architecture/ checks it):
//! the binary picks it when a configuration says `kind = "mock"`.

pub mod camera;
pub mod demo;
pub mod disk;
pub mod inject;
pub mod lights;
pub mod trigger;
mod world;

pub use camera::{fault_schedule, MockCameraBody};
pub use lights::{LightSwitch, MockLights, MockLightsLog};
pub use trigger::{MockTrigger, ScriptStep};
pub use world::MockWorld;

use crate::clock::SharedClock;
use crate::config::{CameraConfig, Config, LightsConfig, TriggerConfig};
use crate::hardware::camera::Camera;
use crate::hardware::{self, HardwareError, Machine};

/// What a test can see of the simulated machine while the daemon runs on it.
#[derive(Clone, Default)]
pub struct Simulation {
    pub world: MockWorld,
    /// The mock lights' log, when the lights are simulated.
    pub lights_log: Option<MockLightsLog>,
    /// The inspection alarm's log, when `inspection.alarm.output` is simulated.
    pub alarm_log: Option<MockLightsLog>,
}

/// The machine a configuration describes, with the simulated part wherever it says
/// `kind = "mock"` and the real one elsewhere (a real serial trigger can drive a mock camera).
pub fn open(config: &Config, clock: SharedClock) -> Result<(Machine, Simulation), HardwareError> {
    let world = MockWorld::new();
    let mut simulation = Simulation {
        world: world.clone(),
        lights_log: None,
        alarm_log: None,
    };
    let trigger: Box<dyn hardware::trigger::Trigger> = match &config.trigger {
        TriggerConfig::Mock(mock) => Box::new(MockTrigger::from_config(mock, clock.clone())?),
        _ => hardware::open_trigger(config, clock.clone())?,
    };
    let lights: Box<dyn hardware::lights::Lights> = match &config.lights {
        LightsConfig::Mock => {
            let lights = MockLights::new(Some(world.clone()));
            simulation.lights_log = Some(lights.log());
            Box::new(lights)
        }
        _ => hardware::open_lights(config)?,
    };
    let camera: hardware::CameraFactory = match &config.camera {
        CameraConfig::Mock(mock) => {
            let (mock, world) = (mock.clone(), world.clone());
            Box::new(move || Ok(Box::new(MockCameraBody::new(&mock, world)) as Box<dyn Camera>))
        }
        _ => hardware::camera_factory(config),
    };
    let alarm: Box<dyn hardware::lights::Lights> = match &config.inspection.alarm.output {
        LightsConfig::Mock => {
            let alarm = MockLights::new(None);
            simulation.alarm_log = Some(alarm.log());
            Box::new(alarm)
        }
        other => hardware::lights::open(other)?,
    };
    Ok((
        Machine {
            trigger,
            lights,
            camera,
            alarm,
            alarm_message: hardware::message::open(config.inspection.alarm.serial.as_ref()),
        },
        simulation,
    ))
}
