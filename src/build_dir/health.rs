//! Each part's health (trigger, camera, lights, processing, disk) as the daemon reports it in
//! status.json, and as a reader shows it later: ages counted from the moment it is shown, the
//! disk's free space measured then, and no part green for a daemon that is not running.

use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;

/// How long ago `at` was, as an operator reads it: `42 s ago`, `4 min ago`, `3 h ago`.
pub fn age(now: DateTime<Utc>, at: DateTime<Utc>) -> String {
    let seconds = (now - at).num_seconds().max(0);
    match seconds {
        0..=119 => format!("{seconds} s ago"),
        120..=7199 => format!("{} min ago", seconds / 60),
        7200..=172_799 => format!("{} h ago", seconds / 3600),
        _ => format!("{} days ago", seconds / 86_400),
    }
}

/// A moment with its age: `14:02:11 UTC (4 min ago)`; the date too when it was not today.
pub fn when(now: DateTime<Utc>, at: DateTime<Utc>) -> String {
    let format = if now.date_naive() == at.date_naive() {
        "%H:%M:%S UTC"
    } else {
        "%Y-%m-%d %H:%M:%S UTC"
    };
    format!("{} ({})", at.format(format), age(now, at))
}

/// How the printer's layer signal reaches the daemon, as status.json reports it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TriggerHealth {
    /// What the signal comes from, e.g. `serial /dev/ttyUSB0`.
    pub source: String,
    pub connected: bool,
    /// When `connected` last changed.
    pub since: Option<DateTime<Utc>>,
    /// Failed attempts to open the source since it was last connected.
    pub reopen_attempts: u64,
    /// The last failure, with what to check.
    pub last_error: Option<String>,
    /// When the last layer signal arrived.
    pub last_signal_at: Option<DateTime<Utc>>,
}

impl TriggerHealth {
    /// What an operator must act on, if anything.
    pub fn warning(&self) -> Option<String> {
        (!self.connected).then(|| {
            format!(
                "trigger {} not connected{}{}: {}",
                self.source,
                self.since
                    .map(|t| format!(" since {}", t.format("%Y-%m-%d %H:%M:%S UTC")))
                    .unwrap_or_default(),
                if self.reopen_attempts > 0 {
                    format!(" ({} attempts to reopen)", self.reopen_attempts)
                } else {
                    String::new()
                },
                self.last_error.as_deref().unwrap_or("no signal can arrive")
            )
        })
    }

    /// One line on the signal's source at `now`: `serial /dev/ttyUSB0 connected, last signal
    /// 42 s ago`.
    pub fn summary(&self, now: DateTime<Utc>) -> String {
        format!(
            "{} {}, last signal {}{}",
            self.source,
            if self.connected {
                "connected"
            } else {
                "NOT CONNECTED"
            },
            self.last_signal_at
                .map_or_else(|| "none yet".into(), |at| age(now, at)),
            if self.reopen_attempts > 0 {
                format!(", {} reopen attempts", self.reopen_attempts)
            } else {
                String::new()
            }
        )
    }

    /// The trigger's health at `now`: an error while it is not connected.
    pub fn health(&self, now: DateTime<Utc>) -> Health {
        let summary = self.summary(now);
        match self.warning() {
            Some(warning) => Health::raise(HealthState::Error, summary, warning),
            None => Health::ok(summary),
        }
    }
}

/// What the camera did this run, as status.json keeps it (the camera's summary is made from it
/// when it is shown, so its age is never stale).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CameraReport {
    pub last_capture_at: Option<DateTime<Utc>>,
    pub retries: u64,
    pub failed: u64,
}

impl CameraReport {
    /// `last capture 4 min ago, 0 retries, 1 failed this run`.
    pub fn summary(&self, now: DateTime<Utc>) -> String {
        format!(
            "last capture {}, {} retries, {} failed this run",
            self.last_capture_at
                .map_or_else(|| "none yet".into(), |at| age(now, at)),
            self.retries,
            self.failed
        )
    }
}

/// How a part of the machine is doing, as status.json, `layerwise status` and systemd show it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HealthState {
    #[default]
    Ok,
    /// The daemon is not running: the part did nothing since (shown, never written by the
    /// daemon).
    Stopped,
    Warning,
    Error,
}

impl fmt::Display for HealthState {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            HealthState::Ok => "ok",
            HealthState::Stopped => "stopped",
            HealthState::Warning => "WARNING",
            HealthState::Error => "ERROR",
        })
    }
}

/// One part's health: its state, one line on what it does, and what an operator must act on.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Health {
    pub state: HealthState,
    pub summary: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warning: Option<String>,
}

impl Health {
    pub fn ok(summary: String) -> Health {
        Health {
            state: HealthState::Ok,
            summary,
            warning: None,
        }
    }

    /// A state other than ok, with the warning that goes with it.
    pub fn raise(state: HealthState, summary: String, warning: String) -> Health {
        Health {
            state,
            summary,
            warning: Some(warning),
        }
    }
}

/// The parts in the order an operator reads them.
pub const HEALTH_PARTS: [&str; 5] = ["trigger", "camera", "lights", "processing", "disk"];

/// One line for systemd's STATUS= and the log: the parts not ok with their warnings, or that all
/// are ok.
pub fn health_line(health: &BTreeMap<String, Health>) -> String {
    let raised: Vec<String> = HEALTH_PARTS
        .iter()
        .filter_map(|part| health.get(*part).map(|h| (part, h)))
        .filter(|(_, h)| h.state != HealthState::Ok)
        .map(|(part, h)| {
            format!(
                "{part} {}: {}",
                h.state,
                h.warning.as_deref().unwrap_or(&h.summary)
            )
        })
        .collect();
    if raised.is_empty() {
        "all parts ok".to_string()
    } else {
        raised.join("; ")
    }
}

/// Where the build directory's disk stands for the daemon.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DiskState {
    /// Above `storage.min_free_gb`: everything is written.
    #[default]
    Ok,
    /// Below `storage.min_free_gb`: originals are captured, derived data (DICOM series,
    /// inspection) waits and is caught up once space returns.
    Low,
    /// An original could not be written: frames are recorded as missing until space returns.
    Full,
}

/// The disk as the daemon sees it (status.json `disk`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DiskHealth {
    pub state: DiskState,
    pub free_bytes: Option<u64>,
    /// `storage.min_free_gb` in bytes.
    pub min_free_bytes: u64,
    /// Free space the daemon waits for after the disk filled.
    pub need_bytes: u64,
    /// When the state last changed.
    pub since: Option<DateTime<Utc>>,
    /// Frames not captured because the disk was full (this run).
    pub frames_missed: u64,
    /// Whether the derived data (DICOM series, inspection) waits for space.
    pub derived_paused: bool,
    /// Journal records held in memory until space returns.
    pub journal_held: usize,
}

/// A size as an operator reads it: MB below 10 GB, GB above.
pub fn mb(bytes: u64) -> String {
    if bytes >= 10_000_000_000 {
        format!("{:.1} GB", bytes as f64 / 1e9)
    } else {
        format!("{:.1} MB", bytes as f64 / 1e6)
    }
}

impl DiskHealth {
    pub fn health(&self) -> Health {
        let free = self.free_bytes.map_or_else(|| "? MB".into(), mb);
        match self.state {
            // A slice found the disk full while the free space looked enough (a quota, or a
            // slice larger than the room left): the derived data waits for it to grow.
            DiskState::Ok if self.derived_paused => Health::raise(
                HealthState::Warning,
                format!("{free} free, a slice found it full"),
                format!(
                    "disk: a slice found the disk full ({free} free): DICOM series and \
                     inspection paused until the free space grows (caught up then), originals \
                     still captured; free space on the build disk"
                ),
            ),
            DiskState::Ok => Health::ok(format!("{free} free")),
            DiskState::Low => Health::raise(
                HealthState::Warning,
                format!("{free} free, below storage.min_free_gb"),
                format!(
                    "disk low: {free} free, below storage.min_free_gb ({}): DICOM series and \
                     inspection paused (caught up once space returns), originals still \
                     captured; free space on the build disk",
                    mb(self.min_free_bytes)
                ),
            ),
            DiskState::Full => Health::raise(
                HealthState::Error,
                format!("full, {} frames missed", self.frames_missed),
                format!(
                    "waiting for disk space: {free} free, need {}; {} frames missed so far; \
                     free space on the build disk now",
                    mb(self.need_bytes),
                    self.frames_missed
                ),
            ),
        }
    }
}

/// What a reader knows, beside status.json, at the moment it shows the health.
#[derive(Clone, Copy, Debug)]
pub struct Seen {
    pub now: DateTime<Utc>,
    /// Whether the daemon that wrote status.json is running.
    pub running: bool,
    /// The build disk's free space, measured now.
    pub free_bytes: Option<u64>,
    /// `storage.min_free_gb` in bytes.
    pub min_free_bytes: u64,
    /// Frames the journal says wait for processing.
    pub waiting_for_processing: usize,
}

/// What the daemon last wrote into status.json about its parts.
#[derive(Clone, Copy, Debug)]
pub struct Written<'a> {
    pub health: &'a BTreeMap<String, Health>,
    pub trigger: Option<&'a TriggerHealth>,
    pub camera: Option<&'a CameraReport>,
    pub disk: Option<&'a DiskHealth>,
}

/// Each part's health as it stands when shown: the trigger's and the camera's ages counted to
/// `seen.now`, the disk from the free space measured now; with the daemon not running every part
/// says so (none is ok), a fault it had when it stopped stays with "before the daemon stopped".
/// A status.json of a version without health reports stays empty.
pub fn shown(written: Written<'_>, seen: &Seen) -> BTreeMap<String, Health> {
    let mut health = written.health.clone();
    if health.is_empty() {
        return health;
    }
    if let Some(trigger) = written.trigger {
        health.insert("trigger".into(), trigger.health(seen.now));
    }
    if let (Some(camera), Some(h)) = (written.camera, health.get_mut("camera")) {
        h.summary = camera.summary(seen.now);
    }
    if seen.running {
        if let Some(disk) = written.disk {
            let mut disk = disk.clone();
            disk.free_bytes = seen.free_bytes.or(disk.free_bytes);
            health.insert("disk".into(), disk.health());
        }
        return health;
    }
    if let Some(h) = health.get_mut("processing") {
        *h = Health::ok(match seen.waiting_for_processing {
            0 => "nothing waits".into(),
            n => format!("{n} frames wait for their series (the next start processes them)"),
        });
    }
    for (part, h) in health.iter_mut().filter(|(p, _)| p.as_str() != "disk") {
        h.summary.push_str(", daemon stopped");
        match h.state {
            HealthState::Ok => h.state = HealthState::Stopped,
            _ => {
                if let Some(w) = &mut h.warning {
                    *w = format!("{part} before the daemon stopped: {w}");
                }
            }
        }
    }
    if let Some(free) = seen.free_bytes {
        let disk = if free < seen.min_free_bytes {
            Health::raise(
                HealthState::Warning,
                format!("{} free now, below storage.min_free_gb", mb(free)),
                format!(
                    "disk low: {} free now, below storage.min_free_gb ({}): free space on the \
                     build disk before the daemon starts again",
                    mb(free),
                    mb(seen.min_free_bytes)
                ),
            )
        } else {
            Health::ok(format!("{} free now", mb(free)))
        };
        health.insert("disk".into(), disk);
    }
    health
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(s: i64) -> DateTime<Utc> {
        DateTime::from_timestamp(1_800_000_000 + s, 0).unwrap()
    }

    fn written_health() -> BTreeMap<String, Health> {
        HEALTH_PARTS
            .iter()
            .map(|p| (p.to_string(), Health::ok(format!("{p} as written"))))
            .collect()
    }

    #[test]
    fn ages_count_to_the_moment_shown_and_a_stopped_daemon_is_never_ok() {
        let trigger = TriggerHealth {
            source: "simulated printer".into(),
            connected: true,
            last_signal_at: Some(at(0)),
            ..TriggerHealth::default()
        };
        let camera = CameraReport {
            last_capture_at: Some(at(1)),
            retries: 0,
            failed: 0,
        };
        let full = DiskHealth {
            state: DiskState::Full,
            free_bytes: Some(1_200_000),
            need_bytes: 500_000_000,
            ..DiskHealth::default()
        };
        let mut health = written_health();
        health.insert("disk".into(), full.health());
        health.insert(
            "lights".into(),
            Health::raise(
                HealthState::Error,
                "switching failed".into(),
                "relay".into(),
            ),
        );
        let written = Written {
            health: &health,
            trigger: Some(&trigger),
            camera: Some(&camera),
            disk: Some(&full),
        };
        let mut seen = Seen {
            now: at(241),
            running: true,
            free_bytes: Some(2_000_000_000),
            min_free_bytes: 1_000_000_000,
            waiting_for_processing: 2,
        };
        let running = shown(written, &seen);
        assert_eq!(
            running["trigger"].summary,
            "simulated printer connected, last signal 4 min ago"
        );
        assert!(running["camera"]
            .summary
            .starts_with("last capture 4 min ago"));
        assert_eq!(running["camera"].state, HealthState::Ok);
        // The daemon still waits for space it has not seen yet: its state, today's free space.
        assert_eq!(running["disk"].state, HealthState::Error);
        assert!(running["disk"]
            .warning
            .as_ref()
            .unwrap()
            .contains("2000.0 MB free"));

        seen.running = false;
        let stopped = shown(written, &seen);
        for part in ["trigger", "camera", "processing"] {
            assert_eq!(stopped[part].state, HealthState::Stopped, "{part}");
            assert!(
                stopped[part].summary.ends_with(", daemon stopped"),
                "{part}"
            );
        }
        assert_eq!(
            stopped["camera"].summary,
            "last capture 4 min ago, 0 retries, 0 failed this run, daemon stopped"
        );
        assert!(stopped["processing"].summary.starts_with("2 frames wait"));
        assert_eq!(stopped["lights"].state, HealthState::Error);
        assert_eq!(
            stopped["lights"].warning.as_deref(),
            Some("lights before the daemon stopped: relay")
        );
        // The disk freed while the daemon was stopped: no "full" any more.
        assert_eq!(stopped["disk"], Health::ok("2000.0 MB free now".into()));
        seen.free_bytes = Some(10_000_000);
        assert_eq!(shown(written, &seen)["disk"].state, HealthState::Warning);
        assert!(!health_line(&stopped).contains("all parts ok"));
    }

    #[test]
    fn ages_read_as_an_operator_says_them() {
        assert_eq!(age(at(100), at(58)), "42 s ago");
        assert_eq!(age(at(1000), at(0)), "16 min ago");
        assert_eq!(age(at(4 * 3600), at(0)), "4 h ago");
        assert_eq!(age(at(3 * 86_400), at(0)), "3 days ago");
        assert_eq!(age(at(0), at(10)), "0 s ago", "a clock behind is now");
        assert_eq!(when(at(61), at(1)), "08:00:01 UTC (60 s ago)");
    }
}
