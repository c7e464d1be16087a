//! The simulated camera: `mock_camera` renders the plate through a known homography; this adapts
//! it to [`Camera`]. It photographs the layer and phase it is asked for, lit by whichever lamps
//! the simulated lights left on in the [`MockWorld`].

use super::world::MockWorld;
use crate::config::{MockCameraConfig, MockFrameFormat};
use crate::hardware::camera::{Camera, CameraError, DriverError, Frame};
use crate::shot::{Light, Phase, Shot};
use mock_camera::{
    Fault, FaultSchedule, Homography, Illumination, MockError, Renderer, Scene, ShotKey,
};
use std::collections::BTreeMap;
use std::time::Instant;

/// The schedule of faults from the configuration's plain entries.
pub fn fault_schedule(config: &MockCameraConfig) -> FaultSchedule {
    let mut schedule = FaultSchedule::new();
    for f in &config.faults {
        let fault = match f.fault.as_str() {
            "busy" => Fault::Busy { times: f.times },
            "disconnect" => Fault::Disconnect,
            "slow" => Fault::Slow { millis: f.millis },
            "hang" => Fault::Hang { millis: f.millis },
            _ => Fault::Fail,
        };
        let key = ShotKey {
            layer: f.layer,
            phase: f.phase.to_string(),
            light: f.light.to_string(),
        };
        schedule.insert(key, fault);
    }
    schedule
}

pub struct MockCameraBody {
    body: mock_camera::MockCamera,
    world: MockWorld,
    config: MockCameraConfig,
}

impl MockCameraBody {
    pub fn new(config: &MockCameraConfig, world: MockWorld) -> MockCameraBody {
        let mut renderer = Renderer::new(
            config.width,
            config.height,
            Homography::oblique_view(config.width, config.height),
        );
        renderer.seed = config.seed;
        let body =
            mock_camera::MockCamera::new(renderer, fault_schedule(config), config.jpeg_quality);
        let raw = |compression| mock_camera::nef::NefOptions {
            compression,
            ..mock_camera::nef::NefOptions::default()
        };
        let body = match config.format {
            MockFrameFormat::Jpeg => body,
            MockFrameFormat::Nef => body.with_raw(raw(mock_camera::nef::NefCompression::Lossless)),
            MockFrameFormat::NefUncompressed => {
                body.with_raw(raw(mock_camera::nef::NefCompression::Uncompressed))
            }
        };
        MockCameraBody {
            body,
            world,
            config: config.clone(),
        }
    }

    /// The ground-truth homography (image px → build mm) the frames are rendered through.
    pub fn homography(&self) -> Homography {
        self.body.renderer().homography
    }
}

fn map_error(e: MockError) -> CameraError {
    match e {
        MockError::Busy => CameraError::Busy(DriverError::said("PTP 0x2019 device busy (mock)")),
        MockError::Disconnected => {
            CameraError::Disconnected(DriverError::said("mock USB device gone"))
        }
        MockError::Timeout => CameraError::Timeout(DriverError::said("mock timeout")),
        MockError::Failed(m) => CameraError::Failed(DriverError::said(m)),
    }
}

impl Camera for MockCameraBody {
    fn capture(&mut self, shot: &Shot) -> Result<Frame, CameraError> {
        let lit = self.world.lit();
        let (layer, phase) = (shot.layer, shot.phase);
        // Exactly one lamp on is how the daemon lights a frame; anything else is rendered honestly.
        let (illumination, light_name) = match lit.iter().collect::<Vec<_>>().as_slice() {
            [] => (Illumination::Dark, "none".to_string()),
            [one] => (
                match one {
                    Light::Front => Illumination::Front,
                    Light::Side => Illumination::Side,
                    Light::Top => Illumination::Top,
                },
                one.to_string(),
            ),
            _ => (Illumination::Top, "several".to_string()),
        };
        let (fused, mut defects) = super::inject::scene(&self.config.inject, layer, phase);
        defects.extend(super::inject::unfused(&self.config.unfused, layer, phase));
        self.body.set_defects(defects);
        let scene = Scene {
            layer,
            fused: &fused,
            scanned: phase == Phase::Post,
            illumination,
        };
        let key = ShotKey {
            layer,
            phase: phase.to_string(),
            light: light_name,
        };
        let started = Instant::now();
        let data = self.body.capture(&key, &scene).map_err(map_error)?;
        Ok(Frame {
            data,
            extension: match self.config.format {
                MockFrameFormat::Jpeg => "jpg",
                MockFrameFormat::Nef | MockFrameFormat::NefUncompressed => "nef",
            }
            .into(),
            capture_ms: started.elapsed().as_secs_f64() * 1e3,
            download_ms: 0.0,
        })
    }

    fn reopen(&mut self) -> Result<(), CameraError> {
        self.body.reconnect().map_err(map_error)
    }

    fn settings(&self) -> BTreeMap<String, String> {
        let h = self.homography().m;
        BTreeMap::from([
            ("model".to_string(), "mock_camera".to_string()),
            ("width".to_string(), self.config.width.to_string()),
            ("height".to_string(), self.config.height.to_string()),
            (
                "jpeg_quality".to_string(),
                self.config.jpeg_quality.to_string(),
            ),
            ("true_homography".to_string(), format!("{h:?}")),
        ])
    }

    fn describe(&self) -> String {
        format!("mock_camera {}x{}", self.config.width, self.config.height)
    }
}
