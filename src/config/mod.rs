//! The daemon's configuration: one TOML file, unknown keys rejected, every error naming the file,
//! the key and what was expected. `layerwise check-config FILE` runs exactly this validation.

pub mod inspection;
pub mod pacs;
pub mod series;

use crate::fsutil::parse_toml;
use crate::shot::{Light, Phase, View};
use crate::vectors::{LayerMatch, LayerNumbering};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub mod web;
pub use web::WebConfig;

/// A configuration that could not be used.
pub type ConfigError = crate::fsutil::TomlFileError;

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
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildConfig {
    /// Human name of the build; becomes the DICOM PatientName.
    pub name: String,
    /// Short id of the build; becomes the DICOM PatientID. Defaults to the name.
    #[serde(default)]
    pub id: Option<String>,
    /// Where originals, the journal and the DICOM series go.
    pub output_dir: PathBuf,
    /// Layers the build will have, if known: the status command forecasts disk use from it.
    #[serde(default)]
    pub layers: Option<u32>,
    /// The build's laser scan vector file (CLI): printer layer k's z is the z of the file's
    /// layer that `layer_match` pairs with it (docs/frames.md).
    #[serde(default)]
    pub vectors: Option<PathBuf>,
    /// Without a vector file, layer k sits at z = k x this.
    #[serde(default = "default_layer_thickness")]
    pub layer_thickness_mm: f64,
    /// How printer layers pair with the vector file's layers: `geometry` (layer 1 is the first
    /// layer with geometry), `position` (layer n is the file's n-th layer) or `z`
    /// (z = n x layer_thickness_mm).
    #[serde(default)]
    pub layer_match: LayerMatch,
    /// Printer layers before the vector file's first (geometry, position): may be negative.
    #[serde(default)]
    pub layer_offset: i64,
    /// With this set, operators start and end builds with `layerwise build start|stop`: the
    /// daemon records into the folder (under this directory) of the build last started, with
    /// its name, vectors and layers; `output_dir`, `name` and `vectors` above are the
    /// defaults of a build that does not give its own. Without it, the daemon records into
    /// `output_dir`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub builds_dir: Option<PathBuf>,
}

impl BuildConfig {
    /// The numbering that pairs printer layers with the vector file's layers.
    pub fn numbering(&self) -> LayerNumbering {
        LayerNumbering {
            rule: self.layer_match,
            offset: self.layer_offset,
            thickness_mm: self.layer_thickness_mm,
        }
    }
}

/// Where layer signals come from.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum TriggerConfig {
    Serial(SerialTriggerConfig),
    Gpio(GpioTriggerConfig),
    Mock(MockTriggerConfig),
}

pub const DEFAULT_LINE_PATTERN: &str = r"^\s*LAYER\s+(?P<layer>\d+)\s+(?P<phase>PRE|POST)\s*$";

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialTriggerConfig {
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Regex with named groups `layer` (decimal) and `phase` (matched against `pre`/`post` tokens).
    #[serde(default = "default_pattern")]
    pub pattern: String,
    /// The text the printer sends for the pre-scan phase (compared case-insensitively).
    #[serde(default = "default_pre_token")]
    pub pre: String,
    #[serde(default = "default_post_token")]
    pub post: String,
    /// Backoff between attempts to reopen a vanished port: first and longest wait.
    #[serde(default = "default_reopen_ms")]
    pub reopen_backoff_ms: [u64; 2],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Edge {
    Rising,
    Falling,
    Both,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GpioMode {
    /// One line pulses before the scan, another after it.
    PerPhase,
    /// One line whose pulses alternate pre, post, pre, post …
    Alternating,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioTriggerConfig {
    #[serde(default = "default_gpio_chip")]
    pub chip: PathBuf,
    pub mode: GpioMode,
    /// Line offsets: `pre_line` and `post_line` for per-phase, `line` for alternating.
    #[serde(default)]
    pub pre_line: Option<u32>,
    #[serde(default)]
    pub post_line: Option<u32>,
    #[serde(default)]
    pub line: Option<u32>,
    #[serde(default = "default_edge")]
    pub edge: Edge,
    #[serde(default = "default_debounce")]
    pub debounce_ms: u64,
    #[serde(default)]
    pub active_low: bool,
    /// The layer number of the first pulse of a new build.
    #[serde(default = "default_first_layer")]
    pub first_layer: u32,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MockTriggerConfig {
    /// A script of lines in the serial protocol (`LAYER 1 PRE`), and `WAIT ms` lines. When absent,
    /// `layers` layers starting at `first_layer` are generated, pre then post.
    #[serde(default)]
    pub script: Option<PathBuf>,
    #[serde(default = "default_mock_layers")]
    pub layers: u32,
    #[serde(default = "default_first_layer")]
    pub first_layer: u32,
    /// Pause between events, standing in for recoating and scanning.
    #[serde(default)]
    pub interval_ms: u64,
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum LightsConfig {
    #[default]
    None,
    SerialRelay(SerialRelayConfig),
    Gpio(GpioLightsConfig),
    Mock,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialRelayConfig {
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Command strings per light, e.g. `front_on = "A1\r\n"`; Rust-style escapes \r \n \xNN work.
    pub commands: BTreeMap<String, String>,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GpioLightsConfig {
    #[serde(default = "default_gpio_chip")]
    pub chip: PathBuf,
    pub front: u32,
    pub side: u32,
    pub top: u32,
    #[serde(default)]
    pub active_low: bool,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
pub enum CameraConfig {
    Gphoto2(Gphoto2Config),
    Mock(MockCameraConfig),
}

/// How frames are taken: light settling, camera call bounds and retries.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaptureConfig {
    /// Wait after switching a light before the exposure, so the lamp is at full brightness.
    #[serde(default)]
    pub settle_ms: u64,
    /// Longest a single camera call may take; past it the daemon exits for systemd to restart it.
    #[serde(default = "default_call_timeout")]
    pub call_timeout_s: u64,
    /// How often a busy or timed-out capture is tried again before the frame is recorded missing.
    #[serde(default = "default_retries")]
    pub retries: u32,
    #[serde(default = "default_retry_backoff")]
    pub retry_backoff_ms: [u64; 2],
    /// How often to reopen a camera that dropped off USB before giving up on the frame.
    #[serde(default = "default_reopen_attempts")]
    pub reopen_attempts: u32,
}

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            settle_ms: 0,
            call_timeout_s: default_call_timeout(),
            retries: default_retries(),
            retry_backoff_ms: default_retry_backoff(),
            reopen_attempts: default_reopen_attempts(),
        }
    }
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
    pub inject: Vec<inspection::MockInjection>,
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

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewsConfig {
    /// Phases to capture, in order.
    #[serde(default = "default_phases")]
    pub phases: Vec<Phase>,
    /// Lights to switch in turn, in order, for each phase.
    #[serde(default = "default_lights")]
    pub lights: Vec<Light>,
}

impl Default for ViewsConfig {
    fn default() -> Self {
        ViewsConfig {
            phases: default_phases(),
            lights: default_lights(),
        }
    }
}

impl ViewsConfig {
    pub fn all(&self) -> Vec<View> {
        let mut out = Vec::new();
        for &phase in &self.phases {
            for &light in &self.lights {
                out.push(View { phase, light });
            }
        }
        out
    }
}

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// calibration.toml from `layerwise register images`; frames are rectified once it is set.
    #[serde(default)]
    pub file: Option<PathBuf>,
    /// bilinear (default) or bicubic.
    #[serde(default)]
    pub interpolation: crate::geometry::Interpolation,
    /// Grey level of grid pixels that fall outside the camera frame.
    #[serde(default)]
    pub fill: u16,
    /// Rectify only around this part of the vector file (build.vectors), plus `crop_margin_mm`:
    /// series stay small when one part matters.
    #[serde(default)]
    pub crop_part: Option<i64>,
    #[serde(default = "default_crop_margin")]
    pub crop_margin_mm: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StorageConfig {
    /// fsync originals, sidecars and the journal (off only for throwaway demos on slow disks).
    #[serde(default = "default_true")]
    pub fsync: bool,
    /// Frames waiting for processing held as references; beyond it they wait on disk.
    #[serde(default = "default_queue")]
    pub queue_capacity: usize,
    /// Warn when free space falls below this.
    #[serde(default = "default_min_free_gb")]
    pub min_free_gb: f64,
    /// Transfer syntax of the live DICOM series: none, deflate, or jpeg-ls (lossless).
    #[serde(default = "default_dicom_compression")]
    pub dicom: crate::dicom::Compression,
}

impl Default for StorageConfig {
    fn default() -> Self {
        StorageConfig {
            fsync: true,
            queue_capacity: default_queue(),
            min_free_gb: default_min_free_gb(),
            dicom: default_dicom_compression(),
        }
    }
}

fn default_baud() -> u32 {
    9600
}
fn default_pattern() -> String {
    DEFAULT_LINE_PATTERN.to_string()
}
fn default_pre_token() -> String {
    "PRE".into()
}
fn default_post_token() -> String {
    "POST".into()
}
fn default_reopen_ms() -> [u64; 2] {
    [250, 5000]
}
fn default_gpio_chip() -> PathBuf {
    PathBuf::from("/dev/gpiochip0")
}
fn default_edge() -> Edge {
    Edge::Rising
}
fn default_debounce() -> u64 {
    20
}
fn default_first_layer() -> u32 {
    1
}
fn default_mock_layers() -> u32 {
    10
}
fn default_call_timeout() -> u64 {
    60
}
fn default_retries() -> u32 {
    8
}
fn default_retry_backoff() -> [u64; 2] {
    [100, 3000]
}
fn default_reopen_attempts() -> u32 {
    5
}
fn default_camera_settings() -> BTreeMap<String, String> {
    BTreeMap::new()
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
fn default_phases() -> Vec<Phase> {
    Phase::ALL.to_vec()
}
fn default_lights() -> Vec<Light> {
    Light::ALL.to_vec()
}
fn default_true() -> bool {
    true
}
fn default_queue() -> usize {
    64
}
fn default_min_free_gb() -> f64 {
    20.0
}
fn default_crop_margin() -> f64 {
    5.0
}
fn default_layer_thickness() -> f64 {
    0.03
}
fn default_dicom_compression() -> crate::dicom::Compression {
    // Explicit VR little endian: what every reader and validator takes.
    crate::dicom::Compression::None
}

impl Config {
    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = crate::fsutil::read_text_bounded(path, MAX_CONFIG_BYTES).map_err(|source| {
            ConfigError::Read {
                file: path.to_path_buf(),
                source,
            }
        })?;
        Config::parse(&text, path)
    }

    /// Parses and validates configuration text; `file` names it in errors.
    pub fn parse(text: &str, file: &Path) -> Result<Config, ConfigError> {
        let config: Config = parse_toml(text, file)?;
        config.validate(file)?;
        Ok(config)
    }

    /// Whether this binary has the backends the configuration names (the daemon and
    /// `check-config` run this after [`Config::load`]; the file itself may be valid for another
    /// build of layerwise).
    pub fn check_backends(&self, file: &Path) -> Result<(), ConfigError> {
        if matches!(self.camera, CameraConfig::Gphoto2(_)) && cfg!(not(feature = "gphoto")) {
            return Err(ConfigError::Invalid {
                file: file.to_path_buf(),
                key: "camera.kind".into(),
                message: "\"gphoto2\" needs a layerwise built with the `gphoto` feature (cargo \
                          build --release --features gphoto, with libgphoto2-dev installed); this \
                          one was built without it"
                    .into(),
            });
        }
        Ok(())
    }

    /// Whether any part of the machine is the simulated one (`kind = "mock"`).
    pub fn is_simulated(&self) -> bool {
        matches!(self.trigger, TriggerConfig::Mock(_))
            || matches!(self.lights, LightsConfig::Mock)
            || matches!(self.camera, CameraConfig::Mock(_))
    }

    fn validate(&self, file: &Path) -> Result<(), ConfigError> {
        let invalid = |key: &str, message: String| ConfigError::Invalid {
            file: file.to_path_buf(),
            key: key.to_string(),
            message,
        };
        if self.build.name.trim().is_empty() {
            return Err(invalid("build.name", "must not be empty".into()));
        }
        if self.build.name.chars().any(char::is_control) {
            return Err(invalid(
                "build.name",
                "must not contain control characters (newline, NUL, …): it goes into the DICOM \
                 PatientName and the logs"
                    .into(),
            ));
        }
        if let Some(layers) = self.build.layers {
            if layers == 0 || layers > MAX_LAYER {
                return Err(invalid(
                    "build.layers",
                    format!("must be 1 to {MAX_LAYER} (file names hold 5 digits)"),
                ));
            }
        }
        if !(self.build.layer_thickness_mm > 0.0 && self.build.layer_thickness_mm <= 10.0) {
            return Err(invalid(
                "build.layer_thickness_mm",
                "must be a positive number of mm, at most 10 (a powder layer is about 0.03)".into(),
            ));
        }
        if self.build.output_dir.as_os_str().is_empty() {
            return Err(invalid("build.output_dir", "must name a directory".into()));
        }
        if self
            .build
            .builds_dir
            .as_ref()
            .is_some_and(|d| d.as_os_str().is_empty())
        {
            return Err(invalid(
                "build.builds_dir",
                "must name a directory (or leave the key out)".into(),
            ));
        }
        pacs::validate(&self.pacs, file)?;
        match &self.trigger {
            TriggerConfig::Serial(serial) => {
                let regex = regex::Regex::new(&serial.pattern).map_err(|e| {
                    invalid(
                        "trigger.pattern",
                        format!("is not a valid regular expression: {e}"),
                    )
                })?;
                for group in ["layer", "phase"] {
                    if !regex.capture_names().flatten().any(|name| name == group) {
                        return Err(invalid(
                            "trigger.pattern",
                            format!("must have a named group `(?P<{group}>…)`"),
                        ));
                    }
                }
                if serial.baud == 0 {
                    return Err(invalid(
                        "trigger.baud",
                        "must be a positive baud rate such as 9600".into(),
                    ));
                }
                check_backoff("trigger.reopen_backoff_ms", serial.reopen_backoff_ms)
                    .map_err(|m| invalid("trigger.reopen_backoff_ms", m))?;
            }
            TriggerConfig::Gpio(gpio) if gpio.first_layer == 0 || gpio.first_layer > MAX_LAYER => {
                return Err(invalid(
                    "trigger.first_layer",
                    format!("must be 1 to {MAX_LAYER}: printers count layers from 1"),
                ))
            }
            TriggerConfig::Gpio(gpio) => match gpio.mode {
                GpioMode::PerPhase if gpio.pre_line.is_none() || gpio.post_line.is_none() => {
                    return Err(invalid(
                        "trigger.pre_line",
                        "mode \"per-phase\" needs both `pre_line` and `post_line`".into(),
                    ))
                }
                GpioMode::Alternating if gpio.line.is_none() => {
                    return Err(invalid(
                        "trigger.line",
                        "mode \"alternating\" needs `line`".into(),
                    ))
                }
                _ => {}
            },
            TriggerConfig::Mock(mock) => {
                if mock.script.is_none() && mock.layers == 0 {
                    return Err(invalid(
                        "trigger.layers",
                        "must be at least 1 without a script".into(),
                    ));
                }
                let last = u64::from(mock.first_layer) + u64::from(mock.layers);
                if mock.first_layer == 0 || last > u64::from(MAX_LAYER) + 1 {
                    return Err(invalid(
                        "trigger.first_layer",
                        format!(
                            "first_layer {} and layers {} must stay within 1 to {MAX_LAYER}",
                            mock.first_layer, mock.layers
                        ),
                    ));
                }
            }
        }
        if let LightsConfig::SerialRelay(relay) = &self.lights {
            for light in &self.views.lights {
                for state in ["on", "off"] {
                    let key = format!("{light}_{state}");
                    if !relay.commands.contains_key(&key) {
                        return Err(invalid(
                            "lights.commands",
                            format!("missing `{key}`: every light in views.lights needs an on and an off command"),
                        ));
                    }
                }
            }
            for key in relay.commands.keys() {
                let known = key == "all_off"
                    || Light::ALL
                        .iter()
                        .any(|l| *key == format!("{l}_on") || *key == format!("{l}_off"));
                if !known {
                    return Err(invalid(
                        &format!("lights.commands.{key}"),
                        "unknown command: expected front_on, front_off, side_on, side_off, top_on, top_off or all_off".into(),
                    ));
                }
            }
        }
        if let CameraConfig::Mock(mock) = &self.camera {
            if mock.width < 16 || mock.height < 16 {
                return Err(invalid(
                    "camera.width",
                    "the mock sensor must be at least 16 x 16 pixels".into(),
                ));
            }
            if mock.width > MAX_MOCK_SIDE || mock.height > MAX_MOCK_SIDE {
                return Err(invalid(
                    "camera.width",
                    format!("the mock sensor is at most {MAX_MOCK_SIDE} x {MAX_MOCK_SIDE} pixels (a D810 is 7360 x 4912)"),
                ));
            }
            for (i, fault) in mock.faults.iter().enumerate() {
                if !["busy", "disconnect", "slow", "fail", "hang"].contains(&fault.fault.as_str()) {
                    return Err(invalid(
                        &format!("camera.faults[{i}].fault"),
                        format!(
                            "unknown fault '{}': expected busy, disconnect, slow, fail or hang",
                            fault.fault
                        ),
                    ));
                }
            }
        }
        if let CameraConfig::Gphoto2(camera) = &self.camera {
            // One shot must give one file: the daemon downloads the file the capture names, so
            // the second file of a RAW+JPEG shot would pile up in the camera's RAM; and a TIFF
            // frame is neither a JPEG nor a raw mosaic.
            let quality = camera
                .settings
                .iter()
                .find(|(key, _)| key.eq_ignore_ascii_case("imagequality"));
            if let Some((key, value)) = quality {
                let upper = value.to_ascii_uppercase();
                if upper.contains('+') || upper.contains("TIFF") {
                    return Err(invalid(
                        &format!("camera.settings.{key}"),
                        format!(
                            "'{value}' is not supported: layerwise takes one JPEG or one raw \
                             frame per shot; set \"JPEG Fine\" or \"NEF (Raw)\""
                        ),
                    ));
                }
            }
        }
        if self.capture.call_timeout_s == 0 {
            return Err(invalid(
                "capture.call_timeout_s",
                "must be at least 1 second".into(),
            ));
        }
        check_backoff("capture.retry_backoff_ms", self.capture.retry_backoff_ms)
            .map_err(|m| invalid("capture.retry_backoff_ms", m))?;
        if self.views.phases.is_empty() || self.views.lights.is_empty() {
            return Err(invalid(
                "views",
                "needs at least one phase and one light".into(),
            ));
        }
        for (key, twice) in [
            ("views.phases", has_duplicates(&self.views.phases)),
            ("views.lights", has_duplicates(&self.views.lights)),
        ] {
            if twice {
                return Err(invalid(key, "names an entry twice".into()));
            }
        }
        let g = &self.rectify;
        if !(g.pixel_mm > 0.0 && g.x_max > g.x_min && g.y_max > g.y_min) {
            return Err(invalid(
                "rectify",
                "needs x_min < x_max, y_min < y_max and pixel_mm > 0".into(),
            ));
        }
        g.validate().map_err(|e| {
            invalid(
                "rectify",
                format!("{e}: use a larger pixel_mm or a smaller extent"),
            )
        })?;
        if !(self.calibration.crop_margin_mm.is_finite() && self.calibration.crop_margin_mm >= 0.0)
        {
            return Err(invalid(
                "calibration.crop_margin_mm",
                "must be a finite number of mm, 0 or more".into(),
            ));
        }
        if !(self.storage.min_free_gb.is_finite() && self.storage.min_free_gb >= 0.0) {
            return Err(invalid(
                "storage.min_free_gb",
                "must be a finite number of GB, 0 or more".into(),
            ));
        }
        if self.calibration.crop_part.is_some() && self.build.vectors.is_none() {
            return Err(invalid(
                "calibration.crop_part",
                "needs build.vectors: the part's outline comes from the vector file".into(),
            ));
        }
        if let Err((key, message)) = self.inspection.check() {
            return Err(invalid(&key, message));
        }
        if self.storage.queue_capacity == 0 || self.storage.queue_capacity > MAX_QUEUE {
            return Err(invalid(
                "storage.queue_capacity",
                format!("must be 1 to {MAX_QUEUE} (frames wait on disk when the queue is full)"),
            ));
        }
        self.web
            .validate()
            .map_err(|(key, message)| invalid(key, message))?;
        Ok(())
    }

    /// The id stored as PatientID: the configured id, else the name.
    pub fn build_id(&self) -> &str {
        self.build.id.as_deref().unwrap_or(&self.build.name)
    }
}

pub use crate::shot::MAX_LAYER;
/// Largest processing queue: it holds references, but a bound keeps a typo from reserving memory.
pub const MAX_QUEUE: usize = 100_000;
/// Largest simulated sensor side.
pub const MAX_MOCK_SIDE: u32 = 16_384;
/// Largest configuration file read.
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// A back-off `[first, max]` in ms: both positive, first ≤ max (a zero back-off spins).
fn check_backoff(key: &str, [first, max]: [u64; 2]) -> Result<(), String> {
    if first == 0 || max < first {
        return Err(format!(
            "[{first}, {max}]: {key} needs 0 < first ≤ max, e.g. [250, 5000]"
        ));
    }
    Ok(())
}

fn has_duplicates<T: Ord>(items: &[T]) -> bool {
    let mut seen = std::collections::BTreeSet::new();
    !items.iter().all(|i| seen.insert(i))
}

/// The demo's configuration, embedded so `layerwise demo` runs with no files around.
pub const DEMO_CONFIG: &str = include_str!("../../config/demo.toml");

#[cfg(test)]
mod tests;
