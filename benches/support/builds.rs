//! The mock builds the daemon's benchmarks run: the demo configuration on a build directory,
//! calibrated (with the demo vectors, and inspection on or off); its journal afterwards.

use layerwise::build_dir::journal::Record;
use layerwise::config::{CameraConfig, Config, TriggerConfig, DEMO_CONFIG};
use layerwise::rectify::Grid;
use std::path::Path;

pub fn config(dir: &Path, layers: u32, fsync: bool) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml")).expect("demo config");
    config.build.output_dir = dir.to_path_buf();
    config.storage.fsync = fsync;
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    config
}

pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// The journal's records of a finished build.
pub fn journal(dir: &Path) -> Vec<Record> {
    let text = std::fs::read_to_string(dir.join("journal.jsonl")).expect("journal");
    text.lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect()
}

/// A calibrated build (the mock camera's true homography onto `grid`, or the demo grid) with
/// the demo vectors, so that every frame is rectified into its series and, with `inspect`,
/// inspected.
pub fn calibrated(
    dir: &Path,
    layers: u32,
    (width, height): (u32, u32),
    grid: Option<Grid>,
    inspect: bool,
) -> Config {
    let mut config = config(dir, layers, true);
    config.rectify = grid.unwrap_or(config.rectify);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = width;
        mock.height = height;
    }
    std::fs::create_dir_all(dir).expect("build dir");
    let truth = mock_camera::Homography::oblique_view(width, height);
    let calibration = layerwise::rectify::Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(config.rectify),
        fit: None,
    };
    let path = dir.join("calibration.toml");
    std::fs::write(&path, calibration.to_toml()).expect("calibration");
    config.calibration.file = Some(path);
    let vectors = dir.join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, layers).expect("vectors");
    config.build.vectors = Some(vectors);
    config.inspection.enabled = inspect;
    // LAYERWISE_BENCH_MODEL=FILE: "on" runs that defect model too; a model trained on frames
    // of unknown scale (the pblm one) is run at 1 mm per cell, as the live bench runs it.
    if let Some(model) = std::env::var_os("LAYERWISE_BENCH_MODEL").filter(|_| inspect) {
        let mut model = layerwise::config::model::ModelConfig::for_file(model.into());
        model.cell_mm = Some(1.0);
        config.inspection.model = Some(model);
    }
    // Signals a second apart: the worker keeps up, as between the layers of a real build.
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 1000;
    }
    config
}
