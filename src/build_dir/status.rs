//! What the daemon tells operators: `status.json`, rewritten after every frame, and the report
//! `layerwise status` makes of a build directory.

use super::health::{mb, Seen, Written as WrittenHealth};
use super::journal::Journal;
use super::manifest::BuildManifest;
use super::{JOURNAL, STATUS};
use crate::fsutil::{write_atomic, WriteError};
use crate::shot::{Phase, SeriesTake};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

pub use super::health::{
    age, health_line, when, CameraReport, DiskHealth, DiskState, Health, HealthState,
    TriggerHealth, HEALTH_PARTS,
};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LastFrame {
    pub layer: u32,
    pub file: String,
    pub at: DateTime<Utc>,
}

/// The daemon's live state, rewritten atomically after every frame.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LiveStatus {
    pub pid: u32,
    pub state: String,
    pub updated_at: Option<DateTime<Utc>>,
    pub layer: Option<u32>,
    pub phase: Option<Phase>,
    pub queue_depth: usize,
    pub last_frames: BTreeMap<String, LastFrame>,
    /// The layer signal's source (absent in status files of older versions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub trigger: Option<TriggerHealth>,
    /// The disk guard's view (absent in status files of older versions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub disk: Option<DiskHealth>,
    /// Each part's health: trigger, camera, lights, processing, disk.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub health: BTreeMap<String, Health>,
    /// What the camera did this run (absent in status files of older versions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraReport>,
}

impl LiveStatus {
    pub fn write(&self, dir: &Path) -> Result<(), WriteError> {
        let path = dir.join(STATUS);
        let json = serde_json::to_vec_pretty(self).map_err(|e| WriteError {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
        write_atomic(&path, &json, false)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum StatusError {
    #[error(transparent)]
    NotABuild(#[from] super::NotABuild),
    #[error(transparent)]
    Journal(#[from] super::journal::JournalError),
    /// status.json that is not a regular file of at most [`super::MAX_RECORD_BYTES`] (a FIFO,
    /// `/dev/zero`, a planted link) or cannot be read.
    #[error("{}: cannot be read", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a status file of a layerwise build")]
    Unreadable {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
}

#[derive(Clone, Debug, Serialize)]
pub struct StatusReport {
    pub build_dir: PathBuf,
    pub name: Option<String>,
    /// The build's study instance UID, new for every build (the manifest's): another build in
    /// the same folder has another. The page reloads when it changes.
    #[serde(default)]
    pub build_uid: Option<String>,
    pub state: String,
    /// Whether the daemon that writes this build is running now (its pid alive, its state
    /// `running`).
    pub running: bool,
    /// When status.json was last written, as shown: `last update 14:02:11 UTC (4 min ago)`.
    pub last_update: Option<String>,
    pub pid: Option<u32>,
    pub updated_at: Option<DateTime<Utc>>,
    pub layer: Option<u32>,
    pub phase: Option<Phase>,
    pub frames: usize,
    pub frames_missing: usize,
    /// Per view (`post_top`, …): frames stored and recorded missing (for `/metrics`).
    pub frames_by_view: BTreeMap<String, ViewCounts>,
    pub missing: Vec<String>,
    /// Frames taken again for repeated signals (kept beside the first takes).
    pub retakes: usize,
    /// Signals out of the expected order, oldest first: `L00003 post: repeated signal: …`.
    pub irregular: Vec<String>,
    /// Frames whose series slice does not show the take `[series] take` picks yet, those
    /// whose processing failed left out.
    pub waiting_for_processing: usize,
    /// Frames whose processing failed (`L00003_post_top: reason`), oldest layer first: their
    /// originals are kept, and the next start tries them again.
    #[serde(default)]
    pub processing_failed: Vec<String>,
    pub queue_depth: usize,
    pub last_frames: BTreeMap<String, LastFrame>,
    pub bytes_stored: u64,
    /// What the build derived from the originals so far: DICOM series, inspection records, push
    /// logs.
    pub bytes_derived: u64,
    /// Bytes on disk per kind: `originals` (raw/: originals, retakes, sidecars), `dicom`,
    /// `inspection`, `push_log`, `journal`.
    pub bytes_by_kind: BTreeMap<String, u64>,
    /// What one layer writes, all kinds together, measured on this build so far.
    pub bytes_per_layer: Option<u64>,
    pub layers_seen: usize,
    pub layers_expected: Option<u32>,
    pub free_bytes: Option<u64>,
    pub bytes_needed: Option<u64>,
    /// The layer signal's source, when the daemon reported it.
    pub trigger: Option<TriggerHealth>,
    /// Each part's health as the daemon last reported it (trigger, camera, lights, processing,
    /// disk).
    pub health: BTreeMap<String, Health>,
    /// The daemon's disk guard (free space, paused derived data, waiting for space).
    pub disk: Option<DiskHealth>,
    /// The push to each archive (`[[pacs]]`): pushed, pending, failed, last error.
    pub pacs: Vec<super::pushlog::PushSummary>,
    /// Inspection flags at warning or above, oldest first (`inspection.jsonl`).
    pub inspection_flags: Vec<String>,
    /// The inspection alarm: raised since layer N, or acknowledged by whom and when
    /// (`alarm.jsonl`; none when it was never raised).
    pub alarm: Option<super::alarm::AlarmState>,
    /// Files of the build that could not be read (status.json, build.json, inspection.jsonl,
    /// alarm.jsonl), each with where and why: the report shows what it could; `layerwise status` exits 1.
    pub damaged: Vec<String>,
    pub warning: Option<String>,
}

/// One view's frames: stored (first takes) and missing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ViewCounts {
    pub stored: usize,
    /// Missing now (a retake that stored the frame later takes it off).
    pub missing: usize,
    /// Ever recorded missing: only grows (the `/metrics` counter).
    pub recorded_missing: usize,
}

/// Frames stored and missing per view.
fn frames_by_view(replay: &super::journal::Replay) -> BTreeMap<String, ViewCounts> {
    let mut views: BTreeMap<String, ViewCounts> = BTreeMap::new();
    for shot in replay.frames.keys() {
        views.entry(shot.view().to_string()).or_default().stored += 1;
    }
    for shot in replay.missing.keys() {
        views.entry(shot.view().to_string()).or_default().missing += 1;
    }
    for shot in &replay.ever_missing {
        views
            .entry(shot.view().to_string())
            .or_default()
            .recorded_missing += 1;
    }
    views
}

/// Free bytes for an unprivileged writer on the filesystem holding `path`.
pub fn free_bytes(path: &Path) -> Option<u64> {
    use crate::fsutil::FreeSpace;
    crate::fsutil::Statvfs.free_bytes(path).ok()
}

/// Bytes of the files below `dir` (0 when it does not exist); symlinks are not followed.
fn dir_size(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .flatten()
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => dir_size(&e.path()),
            Ok(t) if t.is_file() => e.metadata().map_or(0, |m| m.len()),
            _ => 0,
        })
        .sum()
}

/// What a build has written so far, per kind of file.
struct Written {
    originals: u64,
    dicom: u64,
    inspection: u64,
    push_log: u64,
    journal: u64,
}

/// What one layer writes on average: everything, and the derived part of it.
#[derive(Clone, Copy)]
struct PerLayer {
    total: f64,
    derived: f64,
}

impl Written {
    fn measure(dir: &Path) -> Written {
        let file = |name: &str| std::fs::metadata(dir.join(name)).map_or(0, |m| m.len());
        Written {
            originals: dir_size(&dir.join(super::RAW_DIR)),
            dicom: dir_size(&dir.join(super::DICOM_DIR)),
            inspection: file(super::INSPECTION),
            push_log: dir_size(&dir.join(super::pushlog::PACS_DIR)),
            journal: file(JOURNAL),
        }
    }

    fn derived(&self) -> u64 {
        self.dicom + self.inspection + self.push_log
    }

    fn by_kind(&self) -> BTreeMap<String, u64> {
        [
            ("originals", self.originals),
            ("dicom", self.dicom),
            ("inspection", self.inspection),
            ("push_log", self.push_log),
            ("journal", self.journal),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect()
    }

    /// Originals and the journal per captured layer, derived data per processed layer.
    fn per_layer(&self, captured: usize, processed: usize) -> Option<PerLayer> {
        if captured == 0 {
            return None;
        }
        let captured_part = (self.originals + self.journal) as f64 / captured as f64;
        let derived = if processed == 0 {
            0.0
        } else {
            self.derived() as f64 / processed as f64
        };
        Some(PerLayer {
            total: captured_part + derived,
            derived,
        })
    }
}

/// What [`report`] takes from the build's configuration (its `config.toml` snapshot).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReportSettings {
    /// `storage.min_free_gb` in bytes: the free space the forecast keeps spare.
    pub min_free_bytes: u64,
    /// `[series] take`: with `last`, a retake whose slice is not written yet waits for
    /// processing as a first take does.
    pub take: SeriesTake,
}

/// Builds the report for `layerwise status` from the journal, the manifest and status.json.
pub fn report(dir: &Path, settings: ReportSettings) -> Result<StatusReport, StatusError> {
    let ReportSettings {
        min_free_bytes,
        take,
    } = settings;
    super::require_build(dir)?;
    let journal_path = dir.join(JOURNAL);
    let replay = Journal::read(&journal_path)?;
    // A damaged secondary file is shown as damaged, never a reason to show nothing (the alarm
    // and the frames must stay in view). Both are read bounded, as regular files: a FIFO or
    // `/dev/zero` in their place is damage, never a hang.
    let mut damaged = Vec::new();
    let manifest = match BuildManifest::read(dir) {
        Ok(manifest) => Some(manifest),
        Err(super::manifest::ManifestError::Read { source, .. })
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            None
        }
        Err(e) => {
            damaged.push(crate::logging::chain(&e));
            None
        }
    };
    let status_path = dir.join(STATUS);
    let live: Option<LiveStatus> = match super::read_record_file(&status_path) {
        Ok(bytes) => serde_json::from_slice(&bytes)
            .map_err(|source| {
                damaged.push(crate::logging::chain(&StatusError::Unreadable {
                    path: status_path.clone(),
                    source,
                }))
            })
            .ok(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(source) => {
            damaged.push(crate::logging::chain(&StatusError::Read {
                path: status_path.clone(),
                source,
            }));
            None
        }
    };
    let live = live.unwrap_or_default();
    let bytes_stored: u64 = replay.frames.values().map(|f| f.bytes).sum::<u64>()
        + replay
            .retakes
            .values()
            .flatten()
            .map(|f| f.bytes)
            .sum::<u64>();
    let layers: std::collections::BTreeSet<u32> = replay.frames.keys().map(|s| s.layer).collect();
    let processed_layers: std::collections::BTreeSet<u32> =
        replay.processed.iter().map(|s| s.layer).collect();
    let written = Written::measure(dir);
    let bytes_derived = written.derived();
    let layers_expected = manifest.as_ref().and_then(|m| m.layers_expected);
    let current_layer = replay.last_event.map(|(l, _)| l).or(live.layer);
    let free = free_bytes(dir);
    let per_layer = written.per_layer(layers.len(), processed_layers.len());
    let bytes_needed = match (layers_expected, current_layer, per_layer) {
        (Some(expected), Some(current), Some(per_layer)) => {
            // Everything a layer writes, for the layers still to come, and the derived data of
            // the layers captured but not processed yet.
            let to_come = expected.saturating_sub(current) as f64 * per_layer.total;
            let behind =
                layers.len().saturating_sub(processed_layers.len()) as f64 * per_layer.derived;
            Some((to_come + behind).ceil() as u64)
        }
        _ => None,
    };
    let forecast_warning = match (free, bytes_needed) {
        (Some(free), Some(needed)) if needed.saturating_add(min_free_bytes) > free => Some(format!(
            "the rest of the build needs about {:.1} GB but only {:.1} GB are free (keeping {:.1} GB spare): free space before it runs out",
            needed as f64 / 1e9,
            free as f64 / 1e9,
            min_free_bytes as f64 / 1e9
        )),
        (Some(free), _) if free < min_free_bytes => Some(format!("only {:.1} GB free", free as f64 / 1e9)),
        _ => None,
    };
    let now = Utc::now();
    let alive = live.pid != 0 && Path::new(&format!("/proc/{}", live.pid)).exists();
    let running = live.state == "running" && alive;
    // A frame whose processing failed is a failure, not backlog.
    let unprocessed = replay.unprocessed_takes(take);
    let processing_failed: Vec<String> = unprocessed
        .iter()
        .filter_map(|(shot, take)| {
            let reason = replay.failure(shot, *take)?;
            Some(format!("{}: {reason}", shot.take_stem(*take)))
        })
        .collect();
    let waiting_for_processing = unprocessed.len() - processing_failed.len();
    let health = super::health::shown(
        WrittenHealth {
            health: &live.health,
            trigger: live.trigger.as_ref(),
            camera: live.camera.as_ref(),
            disk: live.disk.as_ref(),
        },
        &Seen {
            now,
            running,
            free_bytes: free,
            min_free_bytes,
            waiting_for_processing,
        },
    );
    let last_update = live
        .updated_at
        .map(|at| format!("last update {}", super::health::when(now, at)));
    let state = match live.state.as_str() {
        "running" if !alive => {
            "not running (the daemon stopped without a clean shutdown)".to_string()
        }
        "" => "unknown".to_string(),
        s => s.to_string(),
    };
    let alarm = super::alarm::state(dir);
    let (inspection_flags, inspection_damage) = match super::inspection::open_flags(dir) {
        Ok(flags) => (flags, None),
        Err(e) => (Vec::new(), Some(crate::logging::chain(&e))),
    };
    damaged.extend(inspection_damage);
    if let Some(super::alarm::AlarmState::Unreadable { reason }) = &alarm {
        damaged.push(reason.clone());
    }
    // What must be acted on first: the alarm, a daemon that died, the parts, then the forecast.
    let mut warnings: Vec<String> = Vec::new();
    if alarm.as_ref().is_some_and(|a| a.needs_attention()) {
        warnings.push("the inspection alarm needs an operator (see alarm)".into());
    }
    if live.state == "running" && !alive {
        warnings.push(format!(
            "the daemon is not running ({}): nothing is captured; start it again \
             (systemctl start layerwise)",
            last_update.as_deref().unwrap_or("it never reported")
        ));
    }
    if health.is_empty() {
        warnings.extend(live.trigger.iter().filter_map(TriggerHealth::warning));
    } else {
        warnings.extend(
            HEALTH_PARTS
                .iter()
                .filter_map(|p| health.get(*p).and_then(|h| h.warning.clone())),
        );
    }
    warnings.extend(forecast_warning);
    let warning = (!warnings.is_empty()).then(|| warnings.join("; "));
    Ok(StatusReport {
        build_dir: dir.to_path_buf(),
        build_uid: manifest.as_ref().map(|m| m.study_instance_uid.clone()),
        name: manifest.map(|m| m.name),
        state,
        running,
        last_update,
        pid: (live.pid != 0).then_some(live.pid),
        updated_at: live.updated_at,
        layer: current_layer,
        phase: replay.last_event.map(|(_, p)| p).or(live.phase),
        frames: replay.frames.len(),
        frames_missing: replay.missing.len(),
        frames_by_view: frames_by_view(&replay),
        missing: replay
            .missing
            .iter()
            .map(|(shot, reason)| format!("{}: {reason}", shot.stem()))
            .collect(),
        retakes: replay.retakes.values().map(Vec::len).sum(),
        irregular: replay
            .irregular
            .iter()
            .map(|i| format!("L{:05} {}: {}: {}", i.layer, i.phase, i.signal, i.detail))
            .collect(),
        waiting_for_processing,
        processing_failed,
        queue_depth: live.queue_depth,
        last_frames: live.last_frames,
        bytes_stored,
        bytes_derived,
        bytes_by_kind: written.by_kind(),
        bytes_per_layer: per_layer.map(|p| p.total.ceil() as u64),
        layers_seen: layers.len(),
        layers_expected,
        free_bytes: free,
        bytes_needed,
        trigger: live.trigger.clone(),
        health,
        disk: live.disk.clone(),
        pacs: super::pushlog::summaries(dir),
        inspection_flags,
        alarm,
        damaged,
        warning,
    })
}

/// The last ten lines of a list, indented, after a count of the earlier ones.
fn last_ten(f: &mut fmt::Formatter<'_>, lines: &[String]) -> fmt::Result {
    let skip = lines.len().saturating_sub(10);
    if skip > 0 {
        writeln!(f, "  … {skip} earlier ones")?;
    }
    for line in &lines[skip..] {
        writeln!(f, "  {line}")?;
    }
    Ok(())
}

fn gb(bytes: u64) -> String {
    format!("{:.2} GB", bytes as f64 / 1e9)
}

impl fmt::Display for StatusReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "build      {} ({})",
            self.name.as_deref().unwrap_or("?"),
            self.build_dir.display()
        )?;
        writeln!(
            f,
            "daemon     {}{}{}",
            self.state,
            self.pid.map(|p| format!(", pid {p}")).unwrap_or_default(),
            match (&self.last_update, self.running) {
                (Some(update), false) => format!(", {update}"),
                _ => String::new(),
            }
        )?;
        if let Some(alarm) = &self.alarm {
            writeln!(f, "alarm      {alarm}")?;
        }
        match (self.layer, self.phase) {
            (Some(l), Some(p)) => writeln!(
                f,
                "layer      {l} {p}{}",
                self.layers_expected
                    .map(|e| format!(" of {e}"))
                    .unwrap_or_default()
            )?,
            _ => writeln!(f, "layer      none yet")?,
        }
        writeln!(
            f,
            "frames     {} stored ({}, series {}), {} missing",
            self.frames,
            gb(self.bytes_stored),
            gb(self.bytes_derived),
            self.frames_missing
        )?;
        for m in self.missing.iter().take(10) {
            writeln!(f, "  missing  {m}")?;
        }
        if self.missing.len() > 10 {
            writeln!(f, "  … and {} more", self.missing.len() - 10)?;
        }
        if self.retakes > 0 {
            writeln!(
                f,
                "retakes    {} (kept beside the first takes)",
                self.retakes
            )?;
        }
        if !self.irregular.is_empty() {
            writeln!(f, "signals    {} irregular", self.irregular.len())?;
            last_ten(f, &self.irregular)?;
        }
        writeln!(
            f,
            "processing {} waiting (queue depth {})",
            self.waiting_for_processing, self.queue_depth
        )?;
        if !self.processing_failed.is_empty() {
            writeln!(
                f,
                "failed     {} frames' processing (originals kept; the next start tries again)",
                self.processing_failed.len()
            )?;
            last_ten(f, &self.processing_failed)?;
        }
        if let Some(t) = &self.trigger {
            let last = t
                .last_signal_at
                .map(|at| format!(", last signal {}", at.format("%Y-%m-%d %H:%M:%S")))
                .unwrap_or_default();
            let state = if t.connected {
                "connected"
            } else {
                "NOT CONNECTED"
            };
            writeln!(f, "trigger    {} {state}{last}", t.source)?;
        }
        for (view, last) in &self.last_frames {
            writeln!(
                f,
                "  last {view:<10} layer {:>5}  {}  {}",
                last.layer,
                last.at.format("%Y-%m-%d %H:%M:%S"),
                last.file
            )?;
        }
        if let Some(free) = self.free_bytes {
            write!(f, "disk       {} free", gb(free))?;
            if let Some(needed) = self.bytes_needed {
                write!(f, ", the rest of the build needs about {}", gb(needed))?;
            }
            if let Some(per_layer) = self.bytes_per_layer {
                let kinds: Vec<String> = self
                    .bytes_by_kind
                    .iter()
                    .filter(|(_, &b)| b > 0)
                    .map(|(k, &b)| format!("{k} {}", mb(b)))
                    .collect();
                write!(
                    f,
                    " ({} per layer; written so far: {})",
                    mb(per_layer),
                    kinds.join(", ")
                )?;
            }
            writeln!(f)?;
        }
        for part in HEALTH_PARTS {
            if let Some(h) = self.health.get(part) {
                writeln!(f, "  {part:<10} {:<7} {}", h.state, h.summary)?;
            }
        }
        for push in &self.pacs {
            write!(f, "{push}")?;
        }
        if !self.inspection_flags.is_empty() {
            writeln!(f, "inspection {} flags", self.inspection_flags.len())?;
            last_ten(f, &self.inspection_flags)?;
        }
        for d in &self.damaged {
            writeln!(f, "DAMAGED    {d}")?;
        }
        if let Some(w) = &self.warning {
            writeln!(f, "WARNING    {w}")?;
        }
        Ok(())
    }
}
