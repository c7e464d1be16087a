//! `layerwise check`: before a build, the machine as the daemon will drive it: the camera
//! detected and its settings read, each light switched on for one test shot through the real
//! capture path (camera thread, retries, the same decoding as the series), then off again.

use super::AcquisitionError;
use crate::clock::SharedClock;
use crate::config::Config;
use crate::hardware::camera::{capture_with_retries, CameraActor, RetryPolicy};
use crate::hardware::lights::LightsGuard;
use crate::hardware::Machine;
use crate::logging::Chain;
use crate::shot::{Light, Phase, Shot};
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// One test shot.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TestShot {
    pub light: Light,
    /// What went wrong, if the shot failed (lights, camera or decoding).
    pub error: Option<String>,
    pub bytes: usize,
    pub width: u32,
    pub height: u32,
    /// Mean of the frame's luma, 0..1 of full scale: a lamp that did not light shows here.
    pub mean: f64,
    pub attempts: u32,
    pub capture_ms: f64,
    /// Where the frame was written (with `--out`).
    pub file: Option<PathBuf>,
}

/// What `layerwise check` found.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CheckReport {
    pub camera: String,
    pub settings: BTreeMap<String, String>,
    pub trigger: String,
    pub shots: Vec<TestShot>,
}

impl CheckReport {
    /// Whether every test shot worked.
    pub fn ok(&self) -> bool {
        self.shots.iter().all(|s| s.error.is_none())
    }
}

/// Opens the camera, then takes one test shot per configured light; writes them to `out` when
/// given (`check_{light}.{ext}`).
pub fn check_machine(
    config: &Config,
    machine: Machine,
    clock: SharedClock,
    out: Option<&Path>,
) -> Result<CheckReport, AcquisitionError> {
    let Machine {
        trigger,
        lights,
        camera,
        ..
    } = machine;
    let trigger = trigger.health().get().source;
    let mut lights = LightsGuard::new(lights);
    lights.all_off_logged();
    let timeout = Duration::from_secs(config.capture.call_timeout_s);
    let camera =
        CameraActor::spawn(camera, timeout, clock.clone()).map_err(AcquisitionError::CameraOpen)?;
    let policy = RetryPolicy::from_config(&config.capture);
    let settle = Duration::from_millis(config.capture.settle_ms);
    let mut shots = Vec::new();
    for &light in &config.views.lights {
        let shot = Shot {
            layer: 1,
            phase: Phase::Post,
            light,
        };
        let mut result = TestShot {
            light,
            error: None,
            bytes: 0,
            width: 0,
            height: 0,
            mean: 0.0,
            attempts: 0,
            capture_ms: 0.0,
            file: None,
        };
        if let Err(e) = lights.switch(light, true) {
            result.error = Some(format!(
                "the {light} light did not switch on: {}",
                Chain(&e)
            ));
            lights.all_off_logged();
            shots.push(result);
            continue;
        }
        clock.sleep(settle);
        let captured = capture_with_retries(&camera, &policy, &shot);
        if let Err(e) = lights.switch(light, false) {
            result.error = Some(format!(
                "the {light} light did not switch off: {}",
                Chain(&e)
            ));
            lights.all_off_logged();
        }
        match captured {
            Ok((frame, attempts)) => {
                result.bytes = frame.data.len();
                result.attempts = attempts;
                result.capture_ms = frame.capture_ms;
                match crate::rectify::decode_frame_luma(&frame.data) {
                    Ok(luma) => {
                        let picture = luma.to_display8();
                        result.width = picture.width();
                        result.height = picture.height();
                        let sum: u64 = picture.as_raw().iter().map(|&v| u64::from(v)).sum();
                        result.mean = sum as f64 / (picture.as_raw().len().max(1) as f64 * 255.0);
                    }
                    Err(e) => {
                        result.error = Some(format!("the frame does not decode: {}", Chain(&e)));
                    }
                }
                if let Some(dir) = out {
                    let path = dir.join(format!("check_{light}.{}", frame.extension));
                    crate::fsutil::write_atomic(&path, &frame.data, true)?;
                    result.file = Some(path);
                }
            }
            Err(e) => result.error = Some(crate::logging::chain(&e)),
        }
        shots.push(result);
    }
    lights.all_off_logged();
    Ok(CheckReport {
        camera: camera.describe().to_string(),
        settings: camera.settings().clone(),
        trigger,
        shots,
    })
}

impl fmt::Display for CheckReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "camera     {} ({} settings)",
            self.camera,
            self.settings.len()
        )?;
        writeln!(f, "trigger    {}", self.trigger)?;
        for s in &self.shots {
            match &s.error {
                None => writeln!(
                    f,
                    "light {:<5} ok: {} x {} px, {} bytes, mean {:.1}% of full scale, {:.0} ms, {} attempt(s){}",
                    s.light.as_str(),
                    s.width,
                    s.height,
                    s.bytes,
                    s.mean * 100.0,
                    s.capture_ms,
                    s.attempts,
                    s.file
                        .as_ref()
                        .map(|p| format!(", {}", p.display()))
                        .unwrap_or_default()
                )?,
                Some(e) => writeln!(f, "light {:<5} FAILED: {e}", s.light.as_str())?,
            }
        }
        Ok(())
    }
}
