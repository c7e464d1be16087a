//! The machine's hardware behind traits: the printer's layer signal ([`trigger`]), the lights
//! ([`lights`]) and the camera ([`camera`]), each with its real backends. [`open`] builds all three
//! from a configuration; the simulated machine (`kind = "mock"`) is built by `sim`, never here.

pub mod camera;
pub mod lights;
pub mod message;
pub mod trigger;

use crate::clock::SharedClock;
use crate::config::{CameraConfig, Config, TriggerConfig};
use camera::{Camera, CameraError};
use lights::{Lights, LightsError};
use trigger::{Trigger, TriggerError};

/// Opens the camera, on the camera thread.
pub type CameraFactory = Box<dyn FnOnce() -> Result<Box<dyn Camera>, CameraError> + Send>;

/// The parts the daemon drives.
pub struct Machine {
    pub trigger: Box<dyn Trigger>,
    pub lights: Box<dyn Lights>,
    /// Called once, on the camera's own thread.
    pub camera: CameraFactory,
    /// The inspection's stack light (`inspection.alarm.output`; no output by default).
    pub alarm: Box<dyn Lights>,
    /// The inspection alarm's message to the printer (`inspection.alarm.serial`; none by default).
    pub alarm_message: Option<Box<dyn message::MessageLink>>,
}

/// A part of the machine could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum HardwareError {
    #[error(transparent)]
    Trigger(#[from] TriggerError),
    #[error(transparent)]
    Lights(#[from] LightsError),
}

/// The real trigger, lights and camera of `config`.
pub fn open(config: &Config, clock: SharedClock) -> Result<Machine, HardwareError> {
    Ok(Machine {
        trigger: open_trigger(config, clock)?,
        lights: open_lights(config)?,
        camera: camera_factory(config),
        alarm: lights::open(&config.inspection.alarm.output)?,
        alarm_message: message::open(config.inspection.alarm.serial.as_ref()),
    })
}

/// The configured trigger: a serial line or GPIO lines.
pub fn open_trigger(
    config: &Config,
    clock: SharedClock,
) -> Result<Box<dyn Trigger>, HardwareError> {
    Ok(match &config.trigger {
        TriggerConfig::Serial(serial) => {
            Box::new(trigger::SerialTrigger::new(serial.clone(), clock)?)
        }
        TriggerConfig::Gpio(gpio) => Box::new(trigger::GpioTrigger::open(gpio.clone(), clock)?),
        TriggerConfig::Mock(_) => return Err(TriggerError::Simulated.into()),
    })
}

/// The configured lights.
pub fn open_lights(config: &Config) -> Result<Box<dyn Lights>, HardwareError> {
    Ok(lights::open(&config.lights)?)
}

/// Opens the configured camera when called (on the camera thread).
pub fn camera_factory(config: &Config) -> CameraFactory {
    match &config.camera {
        #[cfg(feature = "gphoto")]
        CameraConfig::Gphoto2(real) => {
            let real = real.clone();
            Box::new(move || {
                Ok(Box::new(camera::gphoto::GphotoCamera::open(&real)?) as Box<dyn Camera>)
            })
        }
        #[cfg(not(feature = "gphoto"))]
        CameraConfig::Gphoto2(_) => Box::new(|| {
            Err(CameraError::Failed(camera::DriverError::said(
                "this layerwise was built without the `gphoto` feature; rebuild with it (needs libgphoto2-dev)",
            )))
        }),
        CameraConfig::Mock(_) => Box::new(|| {
            Err(CameraError::Failed(camera::DriverError::said(
                "kind = \"mock\" belongs to the simulated machine (`layerwise demo`, tests); configure gphoto2",
            )))
        }),
    }
}
