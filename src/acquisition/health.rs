//! Each part's health (trigger, camera, lights, processing, disk) as status.json, `layerwise
//! status` and systemd's STATUS= show it: a state, one line on what it does, and the warning an
//! operator must act on.

use crate::build_dir::status::{CameraReport, DiskHealth, Health, HealthState, TriggerHealth};
use crate::shot::Shot;
use chrono::{DateTime, Utc};
use std::collections::BTreeMap;
use std::time::Duration;

/// What the sequencer saw of the camera and the lights this run.
#[derive(Debug, Default)]
pub(super) struct Parts {
    last_capture: Option<DateTime<Utc>>,
    retries: u64,
    failed: u64,
    /// The last capture failure, until the next frame succeeds.
    camera_error: Option<(Shot, String)>,
    /// The last switching failure, until the next switch succeeds.
    lights_error: Option<String>,
}

/// What the processing worker reports.
pub(super) struct Processing {
    pub(super) backlog: usize,
    pub(super) lag: Duration,
    pub(super) paused: bool,
    /// The processor's own fault ([`crate::series::FrameProcessor::fault`]: the inspection
    /// alarm's), shown with the lights.
    pub(super) fault: Option<String>,
}

impl Parts {
    pub(super) fn captured(&mut self, at: DateTime<Utc>, attempts: u32) {
        self.last_capture = Some(at);
        self.retries += u64::from(attempts.saturating_sub(1));
        self.camera_error = None;
    }

    pub(super) fn capture_failed(&mut self, shot: Shot, error: String) {
        self.failed += 1;
        self.camera_error = Some((shot, error));
    }

    /// The lights switched as told: a past switching failure is over.
    pub(super) fn lights_ok(&mut self) {
        self.lights_error = None;
    }

    pub(super) fn lights_failed(&mut self, error: &crate::hardware::lights::LightsError) {
        self.lights_error = Some(crate::logging::chain(error));
    }

    /// What the camera did this run, for status.json (readers make its summary when they show
    /// it).
    pub(super) fn camera_report(&self) -> CameraReport {
        CameraReport {
            last_capture_at: self.last_capture,
            retries: self.retries,
            failed: self.failed,
        }
    }

    fn camera(&self, now: DateTime<Utc>) -> Health {
        let summary = self.camera_report().summary(now);
        match &self.camera_error {
            Some((shot, error)) => Health::raise(
                HealthState::Error,
                summary,
                format!(
                    "camera failed on {}: {error}; check its power, USB cable and settings \
                     (frames are recorded as missing until it answers)",
                    shot.stem()
                ),
            ),
            None => Health::ok(summary),
        }
    }

    /// The capture lights, and the inspection alarm's stack light (`alarm`: its fault).
    fn lights(&self, alarm: Option<&str>) -> Health {
        let capture = self.lights_error.as_ref().map(|error| {
            format!("lights: {error}; check the relay board or GPIO lines and their wiring")
        });
        match (capture, alarm) {
            (None, None) => Health::ok("switching".into()),
            (Some(capture), None) => {
                Health::raise(HealthState::Error, "switching failed".into(), capture)
            }
            (None, Some(alarm)) => Health::raise(
                HealthState::Error,
                "the inspection alarm is at fault".into(),
                alarm.to_string(),
            ),
            (Some(capture), Some(alarm)) => Health::raise(
                HealthState::Error,
                "switching failed".into(),
                format!("{capture}; {alarm}"),
            ),
        }
    }

    /// Every part's health now.
    pub(super) fn health(
        &self,
        now: DateTime<Utc>,
        trigger: &TriggerHealth,
        processing: &Processing,
        disk: &DiskHealth,
    ) -> BTreeMap<String, Health> {
        BTreeMap::from([
            ("trigger".to_string(), trigger.health(now)),
            ("camera".to_string(), self.camera(now)),
            (
                "lights".to_string(),
                self.lights(processing.fault.as_deref()),
            ),
            ("processing".to_string(), processing_health(processing)),
            ("disk".to_string(), disk.health()),
        ])
    }
}

fn processing_health(p: &Processing) -> Health {
    let summary = format!(
        "backlog {} frames, lag {:.1} s",
        p.backlog,
        p.lag.as_secs_f64()
    );
    if p.paused {
        Health::raise(
            HealthState::Warning,
            summary,
            format!(
                "processing paused for disk space: {} frames wait for their DICOM series \
                 (caught up once space returns)",
                p.backlog
            ),
        )
    } else {
        Health::ok(summary)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::{Light, Phase};

    #[test]
    fn a_failed_camera_and_a_lost_trigger_raise_errors_until_they_recover() {
        let now = Utc::now();
        let mut parts = Parts::default();
        let trigger = TriggerHealth {
            source: "serial /dev/ttyUSB0".into(),
            connected: false,
            reopen_attempts: 3,
            last_error: Some("No such file or directory".into()),
            last_signal_at: Some(now - chrono::Duration::seconds(42)),
            ..TriggerHealth::default()
        };
        let processing = Processing {
            backlog: 2,
            lag: Duration::from_millis(1500),
            paused: false,
            fault: None,
        };
        let shot = Shot {
            layer: 7,
            phase: Phase::Post,
            light: Light::Top,
        };
        parts.capture_failed(shot, "busy".into());
        let health = parts.health(now, &trigger, &processing, &DiskHealth::default());
        assert_eq!(health["trigger"].state, HealthState::Error);
        assert!(health["trigger"]
            .summary
            .contains("last signal 42 s ago, 3 reopen attempts"));
        assert_eq!(health["camera"].state, HealthState::Error);
        assert!(health["camera"]
            .warning
            .as_ref()
            .unwrap()
            .contains("L00007_post_top"));
        assert_eq!(health["processing"].summary, "backlog 2 frames, lag 1.5 s");
        assert_eq!(health["disk"].state, HealthState::Ok);
        parts.captured(now, 3);
        let health = parts.health(now, &trigger, &processing, &DiskHealth::default());
        assert_eq!(health["camera"].state, HealthState::Ok);
        assert!(health["camera"].summary.contains("2 retries, 1 failed"));
    }
}
