//! The daemon's configuration: one TOML file, unknown keys rejected, every error naming the file,
//! the key and what was expected. `layerwise check-config FILE` runs exactly this validation.
//!
//! One file per section holds its types, their defaults and its check (`validate`), which
//! refuses a value with an [`Invalid`] naming the key; `Config::validate` runs the sections in
//! turn and [`Config::parse`] adds the file.

mod build;
mod calibration;
mod camera;
mod capture;
mod common;
mod error;
pub mod inspection;
mod lights;
pub mod metrics;
pub mod model;
pub mod mqtt;
pub mod opcua;
pub mod pacs;
mod rectify;
pub mod series;
mod storage;
mod trigger;
mod views;
pub mod web;

pub use build::BuildConfig;
pub use calibration::CalibrationConfig;
pub use camera::{
    CameraConfig, Gphoto2Config, MockCameraConfig, MockFaultConfig, MockFrameFormat, UnfusedSpot,
    MAX_MOCK_SIDE,
};
pub use capture::CaptureConfig;
pub use error::{Cause, ConfigError, Invalid};
pub use lights::{GpioLightsConfig, LightsConfig, SerialRelayConfig};
pub use storage::{StorageConfig, MAX_QUEUE};
pub use trigger::{
    Edge, GpioMode, GpioTriggerConfig, MockTriggerConfig, SerialTriggerConfig, TriggerConfig,
    DEFAULT_LINE_PATTERN,
};
pub use views::ViewsConfig;
pub use web::WebConfig;

pub use crate::shot::MAX_LAYER;

use crate::fsutil::{parse_toml, TomlFileError};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Largest configuration file read.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// The demo's configuration, embedded so `layerwise demo` runs with no files around.
pub const DEMO_CONFIG: &str = include_str!("../../config/demo.toml");

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    pub build: BuildConfig,
    pub trigger: TriggerConfig,
    #[serde(default)]
    pub lights: LightsConfig,
    pub camera: CameraConfig,
    #[serde(default)]
    pub capture: CaptureConfig,
    #[serde(default)]
    pub views: ViewsConfig,
    /// The rectified grid of docs/frames.md.
    #[serde(default)]
    pub rectify: crate::geometry::Grid,
    #[serde(default)]
    pub calibration: CalibrationConfig,
    #[serde(default)]
    pub storage: StorageConfig,
    /// Archives every DICOM instance is pushed to (`[[pacs]]`, config/pacs.rs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pacs: Vec<pacs::PacsDestination>,
    /// The operator page (src/web).
    #[serde(default)]
    pub web: WebConfig,
    /// Per-layer inspection and its alarm (src/config/inspection.rs).
    #[serde(default)]
    pub inspection: inspection::InspectionConfig,
    /// The live series and the export (src/config/series.rs).
    #[serde(default)]
    pub series: series::SeriesConfig,
    /// Plant interfaces (src/plant, docs/plant.md), each off by default: Prometheus metrics on
    /// the page, events to an MQTT broker, an OPC UA server.
    #[serde(default)]
    pub metrics: metrics::MetricsConfig,
    #[serde(default)]
    pub mqtt: mqtt::MqttConfig,
    /// The OPC UA server (src/config/opcua.rs, docs/opcua.md).
    #[serde(default)]
    pub opcua: opcua::OpcuaConfig,
}

impl Config {
    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = crate::fsutil::read_text_bounded(path, MAX_CONFIG_BYTES).map_err(|source| {
            TomlFileError::Read {
                file: path.to_path_buf(),
                source,
            }
        })?;
        Config::parse(&text, path)
    }

    /// Parses and validates configuration text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Config, ConfigError> {
        let config: Config = parse_toml(text, file).map_err(TomlFileError::from)?;
        config
            .validate()
            .map_err(|invalid| invalid.in_text(file, text))?;
        Ok(config)
    }

    /// Whether this binary has the backends the configuration names (the daemon and
    /// `check-config` run this after [`Config::load`]; the file itself may be valid for another
    /// build of layerwise).
    pub fn check_backends(&self, file: &Path) -> Result<(), ConfigError> {
        self.camera
            .check_backend()
            .and_then(|()| self.storage.check_backend())
            .and_then(|()| self.opcua.check_backend())
            .map_err(|invalid| invalid.in_file(file))
    }

    /// Whether any part of the machine is the simulated one (`kind = "mock"`).
    pub fn is_simulated(&self) -> bool {
        matches!(self.trigger, TriggerConfig::Mock(_))
            || matches!(self.lights, LightsConfig::Mock)
            || matches!(self.camera, CameraConfig::Mock(_))
    }

    /// Checks what serde cannot, section by section; the first refusal wins.
    fn validate(&self) -> Result<(), Invalid> {
        self.build.validate()?;
        pacs::validate(&self.pacs)?;
        self.trigger.validate()?;
        self.lights.validate(&self.views)?;
        self.camera.validate()?;
        self.capture.validate()?;
        self.views.validate()?;
        rectify::validate(&self.rectify)?;
        self.calibration.validate(&self.build)?;
        self.storage.validate()?;
        self.inspection.validate()?;
        self.mqtt.validate()?;
        self.opcua.validate()?;
        self.web.validate()
    }

    /// The id stored as PatientID: the configured id, else the name.
    pub fn build_id(&self) -> &str {
        self.build.id.as_deref().unwrap_or(&self.build.name)
    }
}

#[cfg(test)]
mod tests;
