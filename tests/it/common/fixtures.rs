//! Configurations derived from the embedded demo, and the mock camera's calibrated views.

use super::cli::layerwise;
use layerwise::config::{CameraConfig, Config, MockFaultConfig, TriggerConfig, DEMO_CONFIG};
use std::path::Path;

/// The demo configuration writing into `dir`, `layers` layers, a small sensor for speed.
pub fn demo_config(dir: &Path, layers: u32) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml"))
        .expect("the embedded demo config is valid");
    config.build.output_dir = dir.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = 320;
        mock.height = 214;
    }
    // A test's build is a few MB: it must not pause its series on a CI disk with little room
    // (tests/disk.rs sets its own limits).
    config.storage.min_free_gb = 0.0;
    config
}

pub fn add_fault(
    config: &mut Config,
    fault: &str,
    layer: u32,
    phase: &str,
    light: &str,
    times: u32,
    millis: u64,
) {
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.faults.push(MockFaultConfig {
            layer,
            phase: phase.parse().expect("phase"),
            light: light.parse().expect("light"),
            fault: fault.to_string(),
            times,
            millis,
        });
    }
}

/// Writes a configuration as TOML for the binary.
pub fn write_config(config: &Config, path: &Path) {
    let text = toml::to_string(config).expect("config serialises");
    std::fs::write(path, text).expect("config written");
}

/// The demo configuration (small, mock hardware, writing into `dir/build`) with `edit` applied
/// to its TOML, written to `dir/name`.
pub fn config_with(
    dir: &Path,
    name: &str,
    edit: impl FnOnce(&mut toml::Table),
) -> std::path::PathBuf {
    let config = demo_config(&dir.join("build"), 2);
    let path = dir.join(name);
    write_config(&config, &path);
    let mut table: toml::Table = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut table);
    std::fs::write(&path, toml::to_string(&table).unwrap()).unwrap();
    path
}

/// The table `[name]` of a configuration's TOML.
pub fn section<'a>(table: &'a mut toml::Table, name: &str) -> &'a mut toml::Table {
    table
        .get_mut(name)
        .and_then(|v| v.as_table_mut())
        .unwrap_or_else(|| panic!("[{name}]"))
}

/// check-config refuses it (naming the file and the key), and `run` refuses it before it
/// starts a build (nothing captured).
pub fn config_refused(dir: &Path, name: &str, key: &str, edit: impl FnOnce(&mut toml::Table)) {
    let path = config_with(dir, name, edit);
    super::bounded::refused(layerwise().arg("check-config").arg(&path), &[name, key]);
    super::bounded::refused(layerwise().arg("run").arg("--config").arg(&path), &[key]);
    assert!(
        super::build_dir::originals(&dir.join("build")).is_empty(),
        "{name}: frames were captured"
    );
}

/// A calibrated mock build: the mock camera's true homography as the calibration.
pub fn calibrated_config(
    dir: &Path,
    layers: u32,
    compression: layerwise::dicom::Compression,
) -> Config {
    let mut config = demo_config(dir, layers);
    config.rectify = plate_grid();
    config.storage.dicom = compression;
    let CameraConfig::Mock(mock) = &config.camera else {
        unreachable!("demo camera is the mock")
    };
    let truth = mock_camera::Homography::oblique_view(mock.width, mock.height);
    std::fs::create_dir_all(dir).unwrap();
    config.calibration.file = Some(write_true_calibration(dir, &truth));
    config
}

/// The whole 275 mm plate at 0.5 mm: 550 x 550 pixels, small enough for tests.
pub fn plate_grid() -> layerwise::rectify::Grid {
    layerwise::rectify::Grid {
        x_min: -137.5,
        x_max: 137.5,
        y_min: -137.5,
        y_max: 137.5,
        pixel_mm: 0.5,
    }
}

/// `dir/calibration.toml` holding the mock camera's true homography onto [`plate_grid`].
pub fn write_true_calibration(dir: &Path, truth: &mock_camera::Homography) -> std::path::PathBuf {
    let calibration = layerwise::rectify::Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(plate_grid()),
        fit: None,
    };
    let path = dir.join("calibration.toml");
    std::fs::write(&path, calibration.to_toml()).unwrap();
    path
}

/// A small oblique picture of the demo plate at layer 1 (top light, after the scan), a
/// calibration file holding its true homography, and a configuration whose [rectify] grid is
/// the plate at 0.5 mm: a 550×550 grid.
pub struct SmallView {
    pub renderer: mock_camera::Renderer,
    pub parts: Vec<mock_camera::Shape>,
    pub calibration: std::path::PathBuf,
    pub config: std::path::PathBuf,
}

impl SmallView {
    pub fn new(dir: &Path) -> Self {
        let (w, h) = (320, 214);
        let truth = mock_camera::Homography::oblique_view(w, h);
        let mut config = demo_config(&dir.join("build"), 1);
        config.rectify = plate_grid();
        let config_path = dir.join("small-view.toml");
        write_config(&config, &config_path);
        SmallView {
            calibration: write_true_calibration(dir, &truth),
            config: config_path,
            renderer: mock_camera::Renderer::new(w, h, truth),
            parts: mock_camera::demo_parts(1),
        }
    }

    fn scene(&self) -> mock_camera::Scene<'_> {
        mock_camera::Scene {
            layer: 1,
            fused: &self.parts,
            scanned: true,
            illumination: mock_camera::Illumination::Top,
        }
    }

    pub fn picture(&self) -> image::RgbImage {
        self.renderer.render(&self.scene())
    }

    pub fn jpeg(&self) -> Vec<u8> {
        self.renderer.render_jpeg(&self.scene(), 95)
    }

    /// `layerwise rectify` of one frame with this calibration.
    pub fn rectify(&self, image: &Path, out: &Path) -> std::process::Output {
        self.rectify_command(image, out).output().unwrap()
    }

    /// The `layerwise rectify` command of [`SmallView::rectify`], not started.
    pub fn rectify_command(&self, image: &Path, out: &Path) -> std::process::Command {
        let mut command = layerwise();
        command
            .arg("rectify")
            .arg("--calibration")
            .arg(&self.calibration)
            .arg("--config")
            .arg(&self.config)
            .arg("--image")
            .arg(image)
            .arg("--out")
            .arg(out);
        command
    }
}
