//! The training data of `learn train --data DIR`, whichever of the three kinds `DIR` is: a
//! `flaws` output (its labels.json), a build with operator verdicts, or class folders.

use super::data::{self, DataKind, Dataset, Item, Window};
use super::error::LearnError;
use super::verdicts::{latest, MIN_PER_CLASS, NORMAL, VERDICTS, WINDOW_PX};
use std::collections::BTreeMap;
use std::path::Path;

/// Reads a data folder of any of the three kinds.
pub fn open(root: &Path, normal: Option<&str>) -> Result<Dataset, LearnError> {
    if root.join(data::LABELS).is_file() {
        return data::open_flaws(root);
    }
    if root.join(crate::build_dir::VERDICTS).is_file() {
        return dataset(root);
    }
    if root.join(crate::build_dir::JOURNAL).is_file() {
        return Err(LearnError::data(
            root,
            "a build without verdicts.jsonl: confirm or dismiss its flags on the operator page first",
        ));
    }
    data::open_class_folders(root, normal)
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
