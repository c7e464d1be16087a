//! What exposes a frame: the light on, the settle time, the camera (with its retries), the light
//! off; and what the camera and the lights did, for their health. It records nothing: the
//! [`super::recorder::Recorder`] does that with what it returns.

use super::health::Parts;
use crate::clock::SharedClock;
use crate::hardware::camera::{
    capture_with_retries, CameraActor, CameraError, CaptureFailure, Frame, RetryPolicy,
};
use crate::hardware::lights::LightsGuard;
use crate::logging::Chain;
use crate::shot::Shot;
use std::collections::BTreeMap;
use std::time::Duration;
use tracing::warn;

/// What one exposure gave.
pub(super) enum Exposed {
    /// The frame, downloaded after `attempts` captures.
    Frame { frame: Frame, attempts: u32 },
    /// No frame, and why (the journal's words).
    Missing(String),
    /// The camera hung in its driver: the process must restart (systemd does it).
    Hung(CameraError),
}

pub(super) struct Exposure {
    lights: LightsGuard,
    camera: CameraActor,
    policy: RetryPolicy,
    settle: Duration,
    clock: SharedClock,
    /// What the camera and the lights did this run.
    parts: Parts,
}

impl Exposure {
    /// Switches every light off first: a restart after a crash finds them as they were left.
    pub(super) fn new(
        mut lights: LightsGuard,
        camera: CameraActor,
        policy: RetryPolicy,
        settle: Duration,
        clock: SharedClock,
    ) -> Exposure {
        lights.all_off_logged();
        Exposure {
            lights,
            camera,
            policy,
            settle,
            clock,
            parts: Parts::default(),
        }
    }

    /// The light of `shot` on, the settle time, the capture (retried as the policy says), the
    /// light off. A light that does not switch off switches every light off.
    pub(super) fn expose(&mut self, shot: Shot) -> Exposed {
        if let Err(e) = self.lights.switch(shot.light, true) {
            self.parts.lights_failed(&e);
            self.lights.all_off_logged();
            return Exposed::Missing(format!(
                "the {} light did not switch on: {}",
                shot.light,
                Chain(&e)
            ));
        }
        self.clock.sleep(self.settle);
        let result = capture_with_retries(&self.camera, &self.policy, &shot);
        match self.lights.switch(shot.light, false) {
            Ok(()) => self.parts.lights_ok(),
            Err(e) => {
                warn!(light = %shot.light, error = %Chain(&e), "lights: could not switch off; switching all off");
                self.parts.lights_failed(&e);
                self.lights.all_off_logged();
            }
        }
        match result {
            Ok((frame, attempts)) => {
                self.parts.captured(self.clock.now(), attempts);
                Exposed::Frame { frame, attempts }
            }
            Err(CaptureFailure::Missing { attempts, last }) => {
                let reason = format!("camera failed after {attempts} attempts: {}", Chain(&last));
                self.parts.capture_failed(shot, reason.clone());
                Exposed::Missing(reason)
            }
            Err(CaptureFailure::Hung(e)) => {
                self.parts.capture_failed(shot, e.fatal_reason());
                self.lights.all_off_logged();
                Exposed::Hung(e)
            }
        }
    }

    /// The camera's settings in force, for the sidecars.
    pub(super) fn camera_settings(&self) -> &BTreeMap<String, String> {
        self.camera.settings()
    }

    /// What the camera and the lights did, for status.json.
    pub(super) fn parts(&self) -> &Parts {
        &self.parts
    }

    /// Every light off (at the end of a run, and on its error paths).
    pub(super) fn all_off(&mut self) {
        self.lights.all_off_logged();
    }
}
