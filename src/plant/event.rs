//! What the daemon tells the plant interfaces: the events, in the order it saw them, and its
//! latest status (the hand-off is [`super::sink`]).

use crate::build_dir::alarm::{AlarmEvent, AlarmState};
use crate::build_dir::inspection::InspectionRecord;
use crate::build_dir::status::Health;
use crate::shot::{Phase, Shot};
use chrono::{DateTime, Utc};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

/// One thing that happened, in the order the daemon saw it.
#[derive(Clone, Debug)]
pub enum PlantEvent {
    /// A run of a build began (the daemon started, or the next build of `builds_dir`).
    BuildStarted(BuildInfo),
    /// A frame was stored.
    FrameStored(FrameInfo),
    /// A frame was recorded as missing.
    FrameMissing {
        shot: Shot,
        reason: String,
        at: DateTime<Utc>,
    },
    /// Every light of a layer signal is done (stored, missing or skipped).
    PhaseDone {
        layer: u32,
        phase: Phase,
        /// When the signal came.
        signal_at: DateTime<Utc>,
        at: DateTime<Utc>,
    },
    /// A layer's inspection record (its metrics and flags).
    Inspected(Arc<InspectionRecord>),
    /// The inspection alarm changed (`alarm.jsonl`'s record).
    Alarm(AlarmEvent),
    /// The run ended, and why; `completed`: the build ended (its trigger ended or the operator
    /// ended it), not a stop in its middle (a signal, a failure).
    BuildEnded {
        reason: String,
        completed: bool,
        /// An error stopped it (`reason` is the error).
        failed: bool,
        at: DateTime<Utc>,
    },
}

/// What is known of a build when its run starts.
#[derive(Clone, Debug)]
pub struct BuildInfo {
    pub name: String,
    pub id: String,
    pub dir: PathBuf,
    pub layers_expected: Option<u32>,
    /// The vector file's name (the job's program).
    pub program: Option<String>,
    /// Where alarm.jsonl leaves the alarm (a restart in the middle of a raise).
    pub alarm: Option<AlarmState>,
    pub at: DateTime<Utc>,
}

/// A stored frame.
#[derive(Clone, Debug)]
pub struct FrameInfo {
    pub shot: Shot,
    /// 1: the frame; more: a retake.
    pub take: u32,
    /// Relative to the build directory.
    pub file: String,
    pub bytes: u64,
    pub capture_ms: f64,
    pub download_ms: f64,
    pub attempts: u32,
    pub at: DateTime<Utc>,
}

/// The daemon's state as it last wrote status.json: latest value only.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlantStatus {
    pub layer: Option<u32>,
    pub phase: Option<Phase>,
    /// "running", "stopped", "failed".
    pub state: String,
    pub health: BTreeMap<String, Health>,
    pub updated_at: Option<DateTime<Utc>>,
}
