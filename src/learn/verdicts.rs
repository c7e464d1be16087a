//! Operator verdicts on flags: `<build>/verdicts.jsonl`, one line per verdict (who, when, which
//! flag, confirm or false alarm), written by the operator page and read by `learn train --data
//! BUILD`: a confirmed flag teaches its class, a false alarm teaches `normal`, each as a window
//! of the flagged layer's rectified view around the flag.

use super::data::{DataKind, Dataset, Item, Window};
use super::error::LearnError;
use super::input::Gray;
use crate::build_dir::lines::LinesLog;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

pub const VERDICTS: &str = "verdicts.jsonl";
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

/// A window of `img`, clamped inside it.
pub fn cut(img: &Gray, w: Window) -> Gray {
    let (ww, wh) = (w.w.min(img.width), w.h.min(img.height));
    let x0 = w.x0.min(img.width - ww);
    let y0 = w.y0.min(img.height - wh);
    let mut px = Vec::with_capacity(ww * wh);
    for y in y0..y0 + wh {
        px.extend_from_slice(&img.px[y * img.width + x0..y * img.width + x0 + ww]);
    }
    Gray::new(ww, wh, px)
}

/// The training set of a build's verdicts: windows of the rectified views (its DICOM series).
pub fn dataset(build: &Path) -> Result<Dataset, LearnError> {
    let path = build.join(VERDICTS);
    let verdicts = latest(build).map_err(|source| LearnError::Verdicts {
        path: path.clone(),
        source,
    })?;
    let record = crate::series::BuildRecord::open(build).map_err(|source| LearnError::Build {
        path: build.to_path_buf(),
        source: Box::new(source),
    })?;
    let grid = record.grid;
    let mut labelled: Vec<(String, Item)> = Vec::new();
    for v in &verdicts {
        let Some(view) = crate::shot::Shot::from_stem(&format!("L1_{}", v.view)).map(|s| s.view())
        else {
            continue;
        };
        let slice = crate::build_dir::series_dir(build, view).join(format!("L{:05}.dcm", v.layer));
        if !slice.is_file() {
            continue;
        }
        let [x0, y0, x1, y1] = v.flag.bbox_mm;
        let (r, c) = grid.pixel_of((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        let half = WINDOW_PX as f64 / 2.0;
        let class = match v.verdict {
            super::verdicts::Judgement::Confirm => v.flag.class().to_string(),
            super::verdicts::Judgement::FalseAlarm => NORMAL.to_string(),
        };
        labelled.push((
            class,
            Item {
                rel: slice
                    .strip_prefix(build)
                    .unwrap_or(&slice)
                    .display()
                    .to_string(),
                path: slice,
                class: 0,
                seq: String::new(),
                order: i64::from(v.layer),
                flaw: None,
                window: Some(Window {
                    x0: (c - half).max(0.0) as usize,
                    y0: (r - half).max(0.0) as usize,
                    w: WINDOW_PX,
                    h: WINDOW_PX,
                }),
            },
        ));
    }
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for (c, _) in &labelled {
        *counts.entry(c.clone()).or_default() += 1;
    }
    counts.entry(NORMAL.into()).or_default();
    if counts.len() < 2 || counts.values().any(|&n| n < MIN_PER_CLASS) {
        return Err(LearnError::data(
            &path,
            format!(
                "verdicts per class {counts:?} (with a rectified view): a model needs {MIN_PER_CLASS} or more of each, confirmed flags and false alarms; judge more flags on the operator page"
            ),
        ));
    }
    let classes: Vec<String> = counts.keys().cloned().collect();
    let items = labelled
        .into_iter()
        .map(|(c, mut item)| {
            item.class = classes.iter().position(|k| *k == c).unwrap_or(0);
            item
        })
        .collect();
    Ok(Dataset {
        kind: DataKind::Verdicts,
        root: build.to_path_buf(),
        classes,
        normal: NORMAL.into(),
        items,
        pixel_mm: Some(grid.pixel_mm),
    })
}

/// A rectified view stored as a DICOM slice, on the 8-bit scale (16-bit linear views / 257).
pub fn read_slice(path: &Path) -> Result<Gray, LearnError> {
    use dicom_pixeldata::PixelDecoder;
    let bad = |detail: String| LearnError::data(path, detail);
    let dicom = |what, source: Box<dyn std::error::Error + Send + Sync>| LearnError::Dicom {
        path: path.to_path_buf(),
        what,
        source,
    };
    let obj =
        dicom_object::open_file(path).map_err(|e| dicom("read the DICOM file", Box::new(e)))?;
    let width = obj
        .element(dicom_dictionary_std::tags::WINDOW_WIDTH)
        .ok()
        .and_then(|e| e.to_float64().ok())
        .unwrap_or(256.0);
    let px = obj
        .decode_pixel_data()
        .map_err(|e| dicom("decode the pixel data of", Box::new(e)))?;
    let (w, h) = (px.columns() as usize, px.rows() as usize);
    let bytes = px.data();
    if px.bits_allocated() != 16 || bytes.len() < 2 * w * h {
        return Err(bad(format!(
            "{w}x{h} slice of {} bits is not a layerwise view",
            px.bits_allocated()
        )));
    }
    let scale = if width > 1000.0 { 1.0 / 257.0 } else { 1.0 };
    let values = bytes[..2 * w * h]
        .chunks_exact(2)
        .map(|b| f32::from(u16::from_le_bytes([b[0], b[1]])) * scale)
        .collect();
    Ok(Gray::new(w, h, values))
}
