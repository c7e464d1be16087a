//! Operator verdicts on flags: `<build>/verdicts.jsonl`, one line per verdict (who, when, which
//! flag, confirm or false alarm), written by the operator page and read by `learn train --data
//! BUILD`: a confirmed flag teaches its class, a false alarm teaches `normal`, each as a window
//! of the flagged layer's rectified view around the flag.

use crate::build_dir::lines::LinesLog;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

pub use crate::build_dir::VERDICTS;
/// The class of a dismissed flag.
pub const NORMAL: &str = "normal";
/// Verdicts a class needs before a model is trained on them.
pub const MIN_PER_CLASS: usize = 10;
/// The side of the window cut around a flag, pixels of the rectified view.
pub const WINDOW_PX: usize = 32;

/// Confirm or dismiss.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Judgement {
    Confirm,
    FalseAlarm,
}

/// Which flag a verdict is on (as inspection.jsonl has it).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlagRef {
    /// The flag's kind (`streak`, …, or `model`).
    pub kind: String,
    /// A model flag's class.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub class: Option<String>,
    pub bbox_mm: [f64; 4],
}

impl FlagRef {
    /// The class a confirmation teaches.
    pub fn class(&self) -> &str {
        self.class.as_deref().unwrap_or(&self.kind)
    }
}

/// One verdict.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    pub layer: u32,
    pub view: String,
    pub flag: FlagRef,
    pub verdict: Judgement,
    /// Who gave it (the page's user name, or "operator").
    pub who: String,
    pub at: DateTime<Utc>,
}

pub type VerdictLog = LinesLog<Verdict>;

/// The verdicts of a build, the last one per flag winning.
pub fn latest(build: &Path) -> Result<Vec<Verdict>, crate::build_dir::JournalError> {
    let all = VerdictLog::read(&build.join(VERDICTS))?;
    let mut by_flag: BTreeMap<String, Verdict> = BTreeMap::new();
    for v in all {
        let key = format!(
            "{}/{}/{}/{:?}",
            v.layer, v.view, v.flag.kind, v.flag.bbox_mm
        );
        by_flag.insert(key, v);
    }
    Ok(by_flag.into_values().collect())
}
