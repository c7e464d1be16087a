//! `inspection.jsonl`: one record per inspected layer (its metrics, its flags, the time it took),
//! appended and fsynced per record like the journal, a torn last record cut on reopening. The
//! daemon and `layerwise inspect` write it; `layerwise status` reads its open flags.

use super::lines::LinesLog;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

/// How bad a flag is.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Recorded only.
    Info,
    /// Logged at WARN, listed by `layerwise status`.
    #[default]
    Warning,
    /// Worth stopping the build for; switches the alarm at its default setting.
    Critical,
}

impl fmt::Display for Severity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Severity::Info => "info",
            Severity::Warning => "warning",
            Severity::Critical => "critical",
        })
    }
}

/// What was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FlagKind {
    /// A line along the recoating direction in the fresh powder.
    Streak,
    /// A band the new powder did not cover.
    ShortFeed,
    /// A region of the fresh powder unlike the bed's running reference: uneven spreading,
    /// powder too thin, the layer below showing through, something standing above it.
    Coverage,
    /// A part standing above the fresh powder (super-elevation, swelling).
    Elevation,
    /// Less fused than the vectors say (part not or partly fused).
    UnderFusion,
    /// Fused beyond the vectors' outline.
    OverFusion,
    /// Fused spots away from every part (spatter, a stray scan).
    Spatter,
    /// A part metric moved away from its running baseline.
    Drift,
    /// A trained model's defect class (the flag's `class`), `[inspection.model]`.
    Model,
}

impl FlagKind {
    pub const ALL: [FlagKind; 9] = [
        FlagKind::Streak,
        FlagKind::ShortFeed,
        FlagKind::Coverage,
        FlagKind::Elevation,
        FlagKind::UnderFusion,
        FlagKind::OverFusion,
        FlagKind::Spatter,
        FlagKind::Drift,
        FlagKind::Model,
    ];
    pub fn name(self) -> &'static str {
        match self {
            FlagKind::Streak => "streak",
            FlagKind::ShortFeed => "short_feed",
            FlagKind::Coverage => "coverage",
            FlagKind::Elevation => "elevation",
            FlagKind::UnderFusion => "under_fusion",
            FlagKind::OverFusion => "over_fusion",
            FlagKind::Spatter => "spatter",
            FlagKind::Drift => "drift",
            FlagKind::Model => "model",
        }
    }
}

impl fmt::Display for FlagKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One anomaly on one layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Flag {
    pub kind: FlagKind,
    /// A model flag's class (the model's class name); absent for the classical checks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub class: Option<String>,
    pub severity: Severity,
    /// The vector file's part id, `None` for plate-wide findings.
    pub part: Option<i64>,
    /// The view it was seen in (`pre_top`, …).
    pub view: String,
    /// `[x_min, y_min, x_max, y_max]` in build mm.
    pub bbox_mm: [f64; 4],
    /// `[column_min, row_min, column_max, row_max]` (inclusive) on the series grid.
    pub bbox_px: [u32; 4],
    pub score: f64,
    pub threshold: f64,
    /// What an operator reads: "recoater streak across x = -40..95 mm at y = 12.3 mm".
    pub message: String,
    /// The first layer of a flag that continues one of the layer before (the same cause in the
    /// same place): a persisting flag, reported on every layer it is seen but raising no new
    /// alarm. Absent on a new flag (and in records written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub since: Option<u32>,
    /// What else the same cause explains, folded into this flag (a part's drifts beside its
    /// fusion flag, the coverage regions of a short feed): one line each.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub evidence: Vec<String>,
}

/// How the recoater axis of a layer's plate-wide checks was chosen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AxisRecord {
    /// `x`, `y`, or `both` while the frames have not told yet (both are searched).
    pub axis: String,
    /// `configured`, `found` (from the frames), or `undetermined`.
    pub source: String,
    /// The frames' evidence so far: positive for y (lines run along the image's columns),
    /// negative for x; a decision at ±2 (±3 before 2026-12-04).
    pub evidence: f64,
}

/// The powder bed the plate-wide checks judge, as found from the frames within the plate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BedRecord {
    /// `[x_min, y_min, x_max, y_max]` in build mm.
    pub bbox_mm: [f64; 4],
    pub area_mm2: f64,
    /// The outline, build mm (a closed polygon, at most a few dozen vertices); written on the
    /// layer where the bed was settled, empty on the others.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub outline_mm: Vec<[f64; 2]>,
}

/// Something about the inspection itself worth a line in the log (`warn` or `info`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Note {
    pub level: String,
    pub message: String,
}

/// Per-part measurements of one layer.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartMetrics {
    pub part: i64,
    /// Area of the part's vectors on the inspection grid, mm².
    pub vector_mm2: f64,
    /// Fused area within the tolerance around the part, mm².
    pub fused_mm2: f64,
    /// fused / vector area.
    pub area_ratio: f64,
    /// Intersection over union of fused and vector areas.
    pub iou: f64,
    /// Unfused fraction of the part's core (`None` when the part is too thin to judge).
    pub unfused: Option<f64>,
    /// Fused area beyond the tolerance around the part, mm².
    pub excess_mm2: f64,
    /// Mean grey level over the part after the scan, and its texture (local standard deviation).
    pub post_mean: f64,
    pub post_contrast: f64,
    /// Fused fraction of the part's vector area.
    pub fused_fraction: f64,
    /// Mean grey level over the previous layer's footprint before the scan.
    pub pre_mean: Option<f64>,
}

/// One inspected layer.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InspectionRecord {
    pub layer: u32,
    pub at: DateTime<Utc>,
    /// Wall time the inspection of the layer took, ms.
    pub ms: f64,
    /// Views that were inspected.
    pub views: Vec<String>,
    /// Plate-wide metrics (`pre_mean`, `pre_texture`, `post_texture`, best scores …).
    pub plate: BTreeMap<String, f64>,
    pub parts: Vec<PartMetrics>,
    pub flags: Vec<Flag>,
    /// The recoater axis the plate-wide checks used.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<AxisRecord>,
    /// The powder bed judged.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bed: Option<BedRecord>,
    /// What the inspection says about itself on this layer (the axis found, a configured axis
    /// the frames disagree with).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<Note>,
}

/// The inspection log of a build, open for appending.
pub type InspectionLog = LinesLog<InspectionRecord>;

/// Flags at warning or above of a build, oldest first: `L00142 streak (warning): …`; a flag that
/// persists over layers is listed once, on its first layer, with the last layer it was seen on.
/// A log that cannot be read is an error, never "no flags".
pub fn open_flags(dir: &Path) -> Result<Vec<String>, super::lines::JournalError> {
    let records = InspectionLog::read(&dir.join(super::INSPECTION))?;
    // (first layer, kind, view, message) → the last layer it was seen on.
    let mut flags: Vec<(u32, &Flag, u32)> = Vec::new();
    for r in &records {
        for f in r.flags.iter().filter(|f| f.severity >= Severity::Warning) {
            let first = f.since.and_then(|since| {
                flags
                    .iter_mut()
                    .rev()
                    .find(|(layer, g, _)| *layer == since && g.kind == f.kind && g.view == f.view)
            });
            match first {
                Some((_, _, last)) => *last = r.layer,
                None => flags.push((r.layer, f, r.layer)),
            }
        }
    }
    Ok(flags
        .into_iter()
        .map(|(layer, f, last)| {
            let span = if last > layer {
                format!(" (persists to layer {last})")
            } else {
                String::new()
            };
            format!(
                "L{layer:05} {} ({}): {}{span}",
                f.kind, f.severity, f.message
            )
        })
        .collect())
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::io::Write;

    /// A recoater streak on `pre_top` (also the web timeline's fixture).
    pub(crate) fn streak(severity: Severity) -> Flag {
        Flag {
            kind: FlagKind::Streak,
            class: None,
            severity,
            part: None,
            view: "pre_top".into(),
            bbox_mm: [-40.0, 12.0, 95.0, 13.0],
            bbox_px: [195, 249, 465, 251],
            score: 9.0,
            threshold: 7.0,
            message: "recoater streak".into(),
            since: None,
            evidence: vec![],
        }
    }

    /// Layer `layer`'s record with `flags`.
    pub(crate) fn record_with(layer: u32, flags: Vec<Flag>) -> InspectionRecord {
        InspectionRecord {
            layer,
            at: chrono::DateTime::from_timestamp(1_700_000_000, 0).unwrap(),
            ms: 1.0,
            views: vec!["pre_top".into()],
            plate: BTreeMap::new(),
            parts: vec![],
            flags,
            axis: None,
            bed: None,
            notes: vec![],
        }
    }

    fn record(layer: u32) -> InspectionRecord {
        record_with(layer, vec![streak(Severity::Warning)])
    }

    #[test]
    fn appends_reopens_and_cuts_a_torn_tail() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(crate::build_dir::INSPECTION);
        let (mut log, old) = InspectionLog::open(&path, false).unwrap();
        assert!(old.is_empty());
        log.append(&record(1)).unwrap();
        log.append(&record(2)).unwrap();
        drop(log);
        std::fs::OpenOptions::new()
            .append(true)
            .open(&path)
            .unwrap()
            .write_all(b"{\"layer\":3,\"at")
            .unwrap();
        assert_eq!(InspectionLog::read(&path).unwrap().len(), 2);
        let (_, back) = InspectionLog::open(&path, false).unwrap();
        assert_eq!(back, vec![record(1), record(2)]);
        assert!(std::fs::read_to_string(&path).unwrap().ends_with("}\n"));
        let flags = open_flags(dir.path()).unwrap();
        assert_eq!(flags.len(), 2);
        assert!(flags[1].starts_with("L00002 streak (warning)"), "{flags:?}");
    }
}
