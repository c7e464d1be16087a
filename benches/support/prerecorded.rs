//! A camera body that returns prerecorded frames, instantly or after the time a real body takes
//! to download them, so a benchmark of the daemon measures everything but the camera; and the
//! mock camera's demo frame to give it.

use layerwise::hardware::camera::{Camera, CameraError, Frame};
use layerwise::shot::View;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

pub struct Prerecorded {
    /// Each view's frame; a view without one gets `fallback`.
    pub frames: Arc<BTreeMap<View, Vec<u8>>>,
    pub fallback: Vec<u8>,
    /// How long each frame takes to come from the body (its download over USB).
    pub download: Duration,
}

impl Prerecorded {
    /// `frame` for every view, at once.
    pub fn instant(frame: Vec<u8>) -> Prerecorded {
        Prerecorded {
            frames: Arc::default(),
            fallback: frame,
            download: Duration::ZERO,
        }
    }
}

impl Camera for Prerecorded {
    fn capture(&mut self, shot: &layerwise::shot::Shot) -> Result<Frame, CameraError> {
        let started = Instant::now();
        if !self.download.is_zero() {
            // The transfer itself: nothing to wait for but the time it takes.
            std::thread::sleep(self.download);
        }
        let data = self.frames.get(&shot.view()).unwrap_or(&self.fallback);
        Ok(Frame {
            data: data.clone(),
            extension: "jpg".into(),
            capture_ms: 0.0,
            download_ms: started.elapsed().as_secs_f64() * 1e3,
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
#[allow(dead_code)]
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
#[allow(dead_code)]
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
    run_camera(config, Prerecorded::instant(frame), options);
}

/// Runs the daemon to the end of its mock trigger with `camera` for its camera.
pub fn run_camera(
    config: &layerwise::config::Config,
    camera: Prerecorded,
    options: layerwise::acquisition::RunOptions,
) {
    let (mut machine, _simulation) =
        layerwise::sim::open(config, options.clock.clone()).expect("simulated machine");
    machine.camera = Box::new(move || Ok(Box::new(camera) as Box<dyn Camera>));
    layerwise::acquisition::run(config, machine, options).expect("mock build");
}
