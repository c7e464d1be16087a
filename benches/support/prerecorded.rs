//! A camera body that returns one prerecorded frame instantly, so a benchmark of the daemon
//! measures everything but the camera; and the mock camera's demo frame to give it.

use layerwise::hardware::camera::{Camera, CameraError, Frame};
use std::collections::BTreeMap;

pub struct Prerecorded(pub Vec<u8>);

impl Camera for Prerecorded {
    fn capture(&mut self, _shot: &layerwise::shot::Shot) -> Result<Frame, CameraError> {
        Ok(Frame {
            data: self.0.clone(),
            extension: "jpg".into(),
            capture_ms: 0.0,
            download_ms: 0.0,
        })
    }
    fn reopen(&mut self) -> Result<(), CameraError> {
        Ok(())
    }
    fn settings(&self) -> BTreeMap<String, String> {
        BTreeMap::from([("model".to_string(), "prerecorded".to_string())])
    }
    fn describe(&self) -> String {
        "prerecorded".into()
    }
}

/// The demo plate at layer 1, after the scan, under the top light, as the mock camera sees it.
pub fn mock_frame(width: u32, height: u32) -> Vec<u8> {
    let renderer = mock_camera::Renderer::new(
        width,
        height,
        mock_camera::Homography::oblique_view(width, height),
    );
    let parts = mock_camera::demo_parts(1);
    let scene = mock_camera::Scene {
        layer: 1,
        fused: &parts,
        scanned: true,
        illumination: mock_camera::Illumination::Top,
    };
    renderer.render_jpeg(&scene, 90)
}

/// Runs the daemon to the end of its mock trigger with the prerecorded camera giving `frame`.
pub fn run_prerecorded(config: &layerwise::config::Config, frame: Vec<u8>) {
    run_prerecorded_with(config, frame, layerwise::acquisition::RunOptions::new());
}

/// As [`run_prerecorded`], with `options` (e.g. the plant interfaces' sink).
#[allow(dead_code)]
pub fn run_prerecorded_with(
    config: &layerwise::config::Config,
    frame: Vec<u8>,
    options: layerwise::acquisition::RunOptions,
) {
    let (mut machine, _simulation) =
        layerwise::sim::open(config, options.clock.clone()).expect("simulated machine");
    machine.camera = Box::new(move || Ok(Box::new(Prerecorded(frame)) as Box<dyn Camera>));
    layerwise::acquisition::run(config, machine, options).expect("mock build");
}
