//! The MQTT messages (docs/mqtt.md) made from the daemon's events: JSON, one topic level per
//! kind under the build's prefix. A layer's frames are gathered until its signal is done, so a
//! `layer` message tells the whole signal at once. Every queued message carries `seq`, its
//! number in the queue, by which consumers drop the duplicates at-least-once delivery allows.

use super::outbox::{Outbox, OutboxError};
use crate::build_dir::alarm::{AlarmEvent, AlarmState};
use crate::build_dir::status::health_line;
use crate::plant::event::{PlantEvent, PlantStatus};
use crate::shot::Phase;
use chrono::Utc;
use serde_json::{json, Value};
use std::collections::BTreeMap;

/// Longest topic prefix made from a build's name.
const MAX_PREFIX: usize = 128;
/// Longest text (a flag's message, a missing frame's reason) in a message.
const MAX_TEXT: usize = 1024;

/// A build name as one topic level: `/`, `+`, `#`, NUL and control characters become `_`.
pub fn topic_level(name: &str) -> String {
    let level: String = name
        .chars()
        .map(|c| {
            if matches!(c, '/' | '+' | '#') || c.is_control() {
                '_'
            } else {
                c
            }
        })
        .collect();
    let mut end = level.len().min(MAX_PREFIX);
    while !level.is_char_boundary(end) {
        end -= 1;
    }
    match &level[..end] {
        "" => "_".into(),
        cut => cut.to_string(),
    }
}

fn text(s: &str) -> String {
    if s.len() <= MAX_TEXT {
        return s.to_string();
    }
    let mut end = MAX_TEXT;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &s[..end])
}

/// The frames of the signal being captured.
#[derive(Default)]
struct OpenSignal {
    key: Option<(u32, Phase)>,
    frames: Vec<Value>,
    missing: Vec<Value>,
}

/// Turns events into queued messages and knows what the retained status says.
pub struct Messages {
    /// `[mqtt] topic_prefix`; empty: from the build's name.
    configured_prefix: String,
    build: Option<(String, String)>,
    alarm: &'static str,
    open: OpenSignal,
}

impl Messages {
    pub fn new(configured_prefix: &str) -> Messages {
        Messages {
            configured_prefix: configured_prefix.to_string(),
            build: None,
            alarm: "off",
            open: OpenSignal::default(),
        }
    }

    /// The topic prefix now (the build's, until one starts `layerwise`).
    pub fn prefix(&self) -> String {
        if !self.configured_prefix.is_empty() {
            return self.configured_prefix.clone();
        }
        let name = self.build.as_ref().map_or("layerwise", |(n, _)| n.as_str());
        format!("layerwise/{}", topic_level(name))
    }

    fn build_name(&self) -> &str {
        self.build.as_ref().map_or("", |(n, _)| n.as_str())
    }

    fn queue(&self, outbox: &mut Outbox, kind: &str, body: Value) -> Result<(), OutboxError> {
        let topic = format!("{}/{kind}", self.prefix());
        outbox
            .push(|seq| {
                let mut body = body;
                if let Value::Object(map) = &mut body {
                    map.insert("seq".into(), seq.into());
                }
                (topic, body.to_string())
            })
            .map(|_| ())
    }

    /// Queues what `event` says.
    pub fn handle(&mut self, event: &PlantEvent, outbox: &mut Outbox) -> Result<(), OutboxError> {
        match event {
            PlantEvent::BuildStarted(info) => {
                self.build = Some((info.name.clone(), info.id.clone()));
                self.alarm = alarm_word(info.alarm.as_ref());
                self.open = OpenSignal::default();
                let body = json!({
                    "event": "started", "build": info.name, "id": info.id,
                    "layers_expected": info.layers_expected, "program": info.program,
                    "dir": info.dir, "at": info.at,
                });
                self.queue(outbox, "build", body)
            }
            PlantEvent::FrameStored(frame) => {
                self.gather(frame.shot.layer, frame.shot.phase);
                self.open.frames.push(json!({
                    "view": frame.shot.view().to_string(), "take": frame.take,
                    "file": frame.file, "bytes": frame.bytes,
                    "capture_ms": round(frame.capture_ms), "download_ms": round(frame.download_ms),
                    "attempts": frame.attempts, "at": frame.at,
                }));
                Ok(())
            }
            PlantEvent::FrameMissing { shot, reason, at } => {
                self.gather(shot.layer, shot.phase);
                self.open.missing.push(json!({
                    "view": shot.view().to_string(), "reason": text(reason), "at": at,
                }));
                Ok(())
            }
            PlantEvent::PhaseDone {
                layer,
                phase,
                signal_at,
                at,
            } => {
                self.gather(*layer, *phase);
                let open = std::mem::take(&mut self.open);
                let duration = (*at - *signal_at).num_milliseconds().max(0);
                let body = json!({
                    "build": self.build_name(), "layer": layer, "phase": phase.to_string(),
                    "signal_at": signal_at, "at": at, "duration_ms": duration,
                    "frames": open.frames, "missing": open.missing,
                });
                self.queue(outbox, "layer", body)
            }
            PlantEvent::Inspected(record) => {
                for flag in &record.flags {
                    let body = json!({
                        "build": self.build_name(), "layer": record.layer,
                        "kind": flag.kind.name(), "severity": flag.severity.to_string(),
                        "part": flag.part, "view": flag.view, "bbox_mm": flag.bbox_mm,
                        "score": flag.score, "threshold": flag.threshold,
                        "message": text(&flag.message), "at": record.at,
                    });
                    self.queue(outbox, "flag", body)?;
                }
                Ok(())
            }
            PlantEvent::Alarm(alarm) => {
                let body = match alarm {
                    AlarmEvent::Raised {
                        at,
                        layer,
                        kind,
                        severity,
                        message,
                    } => {
                        self.alarm = "raised";
                        json!({
                            "event": "raised", "layer": layer, "kind": kind.name(),
                            "severity": severity.to_string(), "message": text(message), "at": at,
                        })
                    }
                    AlarmEvent::Acknowledged { at, by, note } => {
                        self.alarm = "acknowledged";
                        json!({ "event": "acknowledged", "by": text(by), "note": note.as_deref().map(text), "at": at })
                    }
                    AlarmEvent::Cleared { at, layer } => {
                        self.alarm = "off";
                        json!({ "event": "cleared", "layer": layer, "at": at })
                    }
                };
                let mut body = body;
                body["build"] = self.build_name().into();
                self.queue(outbox, "alarm", body)
            }
            PlantEvent::BuildEnded {
                reason,
                completed,
                at,
                ..
            } => {
                let body = json!({
                    "event": "ended", "build": self.build_name(),
                    "id": self.build.as_ref().map(|(_, id)| id.clone()),
                    "reason": text(reason), "completed": completed, "at": at,
                });
                self.queue(outbox, "build", body)
            }
        }
    }

    /// Starts gathering a new signal's frames when `(layer, phase)` is not the open one.
    fn gather(&mut self, layer: u32, phase: Phase) {
        if self.open.key != Some((layer, phase)) {
            self.open = OpenSignal {
                key: Some((layer, phase)),
                ..OpenSignal::default()
            };
        }
    }

    /// The retained status: online (with the daemon's latest state) or why not.
    pub fn status(&self, online: bool, reason: Option<&str>, status: &PlantStatus) -> String {
        let health: BTreeMap<&String, Value> = status
            .health
            .iter()
            .map(|(part, h)| {
                (
                    part,
                    json!({ "state": h.state.to_string().to_lowercase(), "summary": h.summary, "warning": h.warning }),
                )
            })
            .collect();
        json!({
            "online": online, "reason": reason, "build": self.build_name(),
            "layer": status.layer, "phase": status.phase.map(|p| p.to_string()),
            "state": status.state, "alarm": self.alarm, "health": health,
            "health_line": health_line(&status.health), "updated_at": status.updated_at,
            "at": Utc::now(),
        })
        .to_string()
    }
}

fn alarm_word(state: Option<&AlarmState>) -> &'static str {
    match state {
        Some(AlarmState::Raised { .. }) => "raised",
        Some(AlarmState::Acknowledged { .. }) => "acknowledged",
        _ => "off",
    }
}

fn round(ms: f64) -> f64 {
    (ms * 10.0).round() / 10.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use chrono::DateTime;

    fn stamp(s: i64) -> DateTime<Utc> {
        DateTime::from_timestamp(1_800_000_000 + s, 0).unwrap()
    }

    use crate::plant::event::{BuildInfo, FrameInfo};
    use crate::shot::{Light, Shot};

    #[test]
    fn a_signal_becomes_one_layer_message_with_its_frames_and_missing_views() {
        let dir = tempfile::tempdir().unwrap();
        let mut outbox = Outbox::open(dir.path(), 1 << 20).unwrap();
        let mut messages = Messages::new("");
        let events = [
            PlantEvent::BuildStarted(BuildInfo {
                name: "part/A #2".into(),
                id: "A2".into(),
                dir: "/b".into(),
                layers_expected: Some(3),
                program: None,
                alarm: None,
                at: stamp(0),
            }),
            PlantEvent::FrameStored(FrameInfo {
                shot: Shot {
                    layer: 1,
                    phase: Phase::Post,
                    light: Light::Top,
                },
                take: 1,
                file: "raw/L00001_post_top.jpg".into(),
                bytes: 10,
                capture_ms: 812.34,
                download_ms: 20.0,
                attempts: 1,
                at: stamp(1),
            }),
            PlantEvent::FrameMissing {
                shot: Shot {
                    layer: 1,
                    phase: Phase::Post,
                    light: Light::Side,
                },
                reason: "x".repeat(5000),
                at: stamp(2),
            },
            PlantEvent::PhaseDone {
                layer: 1,
                phase: Phase::Post,
                signal_at: stamp(0),
                at: stamp(2),
            },
        ];
        for event in &events {
            messages.handle(event, &mut outbox).unwrap();
        }
        let build = outbox.oldest().unwrap().unwrap().clone();
        assert_eq!(build.topic, "layerwise/part_A _2/build");
        outbox.ack(1);
        let layer = outbox.oldest().unwrap().unwrap().clone();
        assert_eq!(layer.topic, "layerwise/part_A _2/layer");
        let body: Value = serde_json::from_str(&layer.payload).unwrap();
        assert_eq!(body["seq"], 2);
        assert_eq!(body["layer"], 1);
        assert_eq!(body["phase"], "post");
        assert_eq!(body["duration_ms"], 2000);
        assert_eq!(body["frames"][0]["view"], "post_top");
        assert_eq!(body["frames"][0]["capture_ms"], 812.3);
        assert_eq!(body["missing"][0]["view"], "post_side");
        assert!(body["missing"][0]["reason"].as_str().unwrap().len() < 1100);
        let status = messages.status(true, None, &PlantStatus::default());
        let status: Value = serde_json::from_str(&status).unwrap();
        assert_eq!(status["online"], true);
        assert_eq!(status["alarm"], "off");
        assert_eq!(topic_level(""), "_");
        assert_eq!(topic_level(&"é".repeat(100)).len(), 128);
    }
}
