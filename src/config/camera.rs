//! `[camera]`: the body that takes the frames (a camera libgphoto2 drives, or the simulated one).

use super::inspection::MockInjection;
use super::Invalid;
use crate::shot::{Light, Phase};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Largest simulated sensor side.
pub const MAX_MOCK_SIDE: u32 = 16_384;

/// Largest simulated sensor: 64 MP, above the largest full-frame bodies (a D850 is 45.7 MP); a
/// 16384 x 16384 frame (268 MP) takes gigabytes to render, encode and rectify per shot.
pub const MAX_MOCK_PIXELS: u64 = 64_000_000;

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum CameraConfig {
    Gphoto2(Gphoto2Config),
    Mock(MockCameraConfig),
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gphoto2Config {
    /// Model as libgphoto2 names it (`gphoto2 --auto-detect`), e.g. "Nikon DSC D810". Empty: autodetect.
    #[serde(default)]
    pub model: String,
    /// Port, e.g. "usb:002,005"; empty: the first port the model is found on.
    #[serde(default)]
    pub port: String,
    /// Camera settings applied at start, by libgphoto2 config name (`gphoto2 --list-config`).
    #[serde(default = "default_camera_settings")]
    pub settings: BTreeMap<String, String>,
}

fn default_camera_settings() -> BTreeMap<String, String> {
    BTreeMap::new()
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MockCameraConfig {
    #[serde(default = "default_mock_width")]
    pub width: u32,
    #[serde(default = "default_mock_height")]
    pub height: u32,
    #[serde(default = "default_jpeg_quality")]
    pub jpeg_quality: u8,
    /// What the body writes: `jpeg`, or a D810 raw frame `nef` (lossless compressed, the body's
    /// default) or `nef-uncompressed`.
    #[serde(default)]
    pub format: MockFrameFormat,
    #[serde(default)]
    pub seed: u64,
    /// Faults to inject, for tests and demonstrations.
    #[serde(default)]
    pub faults: Vec<MockFaultConfig>,
    /// Anomalies to render, e.g. `["streak@40", "no-fusion@120/part=1"]` (inspection tests).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inject: Vec<MockInjection>,
    /// Lack-of-fusion spots to render in the post-scan frames: `layerwise demo --pores` sets them
    /// from its CT's pores (each pore cut by each layer it spans); never read from a file.
    #[serde(skip)]
    pub unfused: Vec<UnfusedSpot>,
}

/// A pore cut by one printer layer as the camera sees it after the scan: unfused powder where
/// the layer should have fused, `radius_mm` across around `center_mm` (build x, y), its outline
/// made irregular by `shape_seed`.
#[derive(Clone, Debug, PartialEq)]
pub struct UnfusedSpot {
    pub layer: u32,
    pub center_mm: [f64; 2],
    pub radius_mm: f64,
    pub shape_seed: u64,
}

fn default_mock_width() -> u32 {
    1472
}
fn default_mock_height() -> u32 {
    982
}
fn default_jpeg_quality() -> u8 {
    90
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MockFrameFormat {
    #[default]
    Jpeg,
    Nef,
    NefUncompressed,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MockFaultConfig {
    pub layer: u32,
    pub phase: Phase,
    pub light: Light,
    /// busy | disconnect | slow | fail | hang
    pub fault: String,
    #[serde(default)]
    pub times: u32,
    #[serde(default)]
    pub millis: u64,
}

/// The faults the mock camera knows (`MockFaultConfig::fault`).
const MOCK_FAULTS: [&str; 5] = ["busy", "disconnect", "slow", "fail", "hang"];

impl CameraConfig {
    /// Checks the section: a mock sensor of a size that can be made and faults it knows; a real
    /// camera set to one file per shot.
    pub fn validate(&self) -> Result<(), Invalid> {
        match self {
            CameraConfig::Mock(mock) => mock.validate(),
            CameraConfig::Gphoto2(camera) => camera.validate(),
        }
    }

    /// Whether this binary has the backend the section names (a file valid for another build of
    /// layerwise may name one this build lacks).
    pub fn check_backend(&self) -> Result<(), Invalid> {
        if matches!(self, CameraConfig::Gphoto2(_)) && cfg!(not(feature = "gphoto")) {
            return Err(Invalid::new(
                "camera.kind",
                "\"gphoto2\" needs a layerwise built with the `gphoto` feature (cargo build \
                 --release --features gphoto, with libgphoto2-dev installed); this one was built \
                 without it",
            ));
        }
        Ok(())
    }
}

impl MockCameraConfig {
    fn validate(&self) -> Result<(), Invalid> {
        if self.width < 16 || self.height < 16 {
            return Err(Invalid::new(
                "camera.width",
                "the mock sensor must be at least 16 x 16 pixels",
            ));
        }
        if self.width > MAX_MOCK_SIDE || self.height > MAX_MOCK_SIDE {
            return Err(Invalid::new(
                "camera.width",
                format!(
                    "the mock sensor is at most {MAX_MOCK_SIDE} x {MAX_MOCK_SIDE} pixels (a D810 \
                     is 7360 x 4912)"
                ),
            ));
        }
        let pixels = u64::from(self.width) * u64::from(self.height);
        if pixels > MAX_MOCK_PIXELS {
            return Err(Invalid::new(
                "camera.width",
                format!(
                    "{} x {} is {:.0} MP; the mock sensor has at most {} MP (a D850 has 45.7)",
                    self.width,
                    self.height,
                    pixels as f64 / 1e6,
                    MAX_MOCK_PIXELS / 1_000_000
                ),
            ));
        }
        for (i, fault) in self.faults.iter().enumerate() {
            if !MOCK_FAULTS.contains(&fault.fault.as_str()) {
                return Err(Invalid::new(
                    format!("camera.faults[{i}].fault"),
                    format!(
                        "unknown fault '{}': expected busy, disconnect, slow, fail or hang",
                        fault.fault
                    ),
                ));
            }
        }
        Ok(())
    }
}

impl Gphoto2Config {
    fn validate(&self) -> Result<(), Invalid> {
        // One shot must give one file: the daemon downloads the file the capture names, so
        // the second file of a RAW+JPEG shot would pile up in the camera's RAM; and a TIFF
        // frame is neither a JPEG nor a raw mosaic.
        let quality = self
            .settings
            .iter()
            .find(|(key, _)| key.eq_ignore_ascii_case("imagequality"));
        if let Some((key, value)) = quality {
            let upper = value.to_ascii_uppercase();
            if upper.contains('+') || upper.contains("TIFF") {
                return Err(Invalid::new(
                    format!("camera.settings.{key}"),
                    format!(
                        "'{value}' is not supported: layerwise takes one JPEG or one raw frame \
                         per shot; set \"JPEG Fine\" or \"NEF (Raw)\""
                    ),
                ));
            }
        }
        Ok(())
    }
}
