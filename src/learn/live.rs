//! The model on a build's layers: each rectified view is reduced to the model's cells (at its
//! `cell_mm`), normalised, and classified tile by tile in one pass of the network; a connected
//! group of tiles whose most likely class is a defect, at `min_probability` or more, is one flag
//! (kind `model`, its class, its probability, its box in build mm). The daemon's processing
//! worker runs it after the classical checks (acquisition::inspection), `layerwise inspect` the
//! same over a stored build. It runs in a pool of its own, so it never queues behind other work.

use super::error::ModelError;
use super::file::{Model, Use};
use super::input;
use super::net;
use crate::build_dir::inspection::{Flag, FlagKind, Severity};
use crate::config::model::ModelConfig;
use crate::geometry::Grid;
use crate::rectify::FrameLuma;
use crate::shot::View;
use image::GrayImage;
use std::path::Path;

/// Where the heat maps go in a build: `model/<view>/L00042.png`, one grey pixel per tile
/// (255 = certainly a defect).
pub const HEATMAP_DIR: &str = "model";

/// At most this many model flags a view. A model that calls tiles defects all over a view says
/// so in one flag after the most probable ones, not in thousands: a layer's record must stay
/// one readable line of the inspection log (and an operator reads the first few anyway).
pub const MAX_FLAGS_PER_VIEW: usize = 32;

/// A checked model with its live settings.
pub struct LiveModel {
    pub model: Model,
    cfg: ModelConfig,
    cell_px: usize,
    views: Vec<String>,
    pool: rayon::ThreadPool,
}

/// The model's verdict on one view.
#[derive(Clone, Debug)]
pub struct ViewScan {
    pub view: View,
    /// Tile rows x columns.
    pub rows: usize,
    pub cols: usize,
    /// Per tile, the probability of not being the normal class.
    pub defect: Vec<f32>,
    /// Per tile, the most likely class and its probability.
    pub best: Vec<(usize, f32)>,
    /// Tile side, mm.
    pub tile_mm: f64,
    pub ms: f64,
}

impl LiveModel {
    /// Loads the model and checks it against views on `grid` (every check of
    /// [`Model::load`] and [`Model::check_use`]).
    pub fn open(cfg: &ModelConfig, grid: &Grid) -> Result<LiveModel, ModelError> {
        let model = Model::load(&cfg.file)?;
        model.check_use(Use::View {
            pixel_mm: grid.pixel_mm,
            w: grid.columns(),
            h: grid.rows(),
            cell_mm: cfg.cell_mm,
        })?;
        let cell_mm = model
            .header
            .input
            .cell_mm
            .or(cfg.cell_mm)
            .unwrap_or(grid.pixel_mm);
        let cell_px = ((cell_mm / grid.pixel_mm).round() as usize).max(1);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .thread_name(|i| format!("layerwise-model-{i}"))
            .build()
            .map_err(|e| ModelError::Unusable {
                path: cfg.file.clone(),
                detail: format!("cannot start its threads: {e}"),
            })?;
        Ok(LiveModel {
            model,
            cfg: cfg.clone(),
            cell_px,
            views: cfg.views.clone(),
            pool,
        })
    }

    /// Whether the model looks at `view`.
    pub fn wants(&self, view: View) -> bool {
        self.views.is_empty() || self.views.iter().any(|v| *v == view.to_string())
    }

    /// Pixels of the views per model cell (the views are reduced to cells of this many pixels,
    /// as the inspection reduces them: `inspect::cells::Cells::from_luma`).
    pub fn cell_px(&self) -> usize {
        self.cell_px
    }

    /// Runs `f` in the model's own threads.
    pub fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        self.pool.install(f)
    }

    /// Classifies every tile of a view reduced to `rows` x `cols` cells of [`LiveModel::cell_px`]
    /// pixels (cell means and textures, row-major) on `grid`.
    pub fn scan_cells(
        &self,
        view: View,
        (rows, cols): (usize, usize),
        mean: &[f32],
        texture: &[f32],
        grid: &Grid,
    ) -> Result<ViewScan, ModelError> {
        let started = std::time::Instant::now();
        self.pool.install(|| {
            let input = self
                .model
                .header
                .input
                .normalisation
                .apply(rows, cols, mean, texture);
            let x = net::tensor(&input, input::CHANNELS.len())?;
            let cam = self.model.net.cam(&x)?;
            let tiles = net::tile_probabilities(&cam)?;
            let normal = self
                .model
                .header
                .classes
                .iter()
                .position(|c| *c == self.model.header.normal_class)
                .unwrap_or(0);
            let rows = tiles.len();
            let cols = tiles.first().map_or(0, |r| r.len());
            let mut defect = Vec::with_capacity(rows * cols);
            let mut best = Vec::with_capacity(rows * cols);
            for p in tiles.iter().flatten() {
                defect.push(1.0 - p[normal]);
                let b = (0..p.len())
                    .max_by(|&a, &b| p[a].total_cmp(&p[b]))
                    .unwrap_or(0);
                best.push((b, p[b]));
            }
            Ok(ViewScan {
                view,
                rows,
                cols,
                defect,
                best,
                tile_mm: self.cell_px as f64
                    * grid.pixel_mm
                    * self.model.header.arch.stride() as f64,
                ms: started.elapsed().as_secs_f64() * 1e3,
            })
        })
    }

    /// The flags of a scan: connected groups of defect tiles (4-neighbours).
    pub fn flags(&self, scan: &ViewScan, grid: &Grid) -> Vec<Flag> {
        let h = &self.model.header;
        let normal = h
            .classes
            .iter()
            .position(|c| *c == h.normal_class)
            .unwrap_or(0);
        let hit = |i: usize| {
            let (c, p) = scan.best[i];
            c != normal && f64::from(p) >= self.cfg.min_probability
        };
        let mut seen = vec![false; scan.best.len()];
        let mut flags = Vec::new();
        let tile_px = (self.cell_px * h.arch.stride()) as u32;
        for start in 0..scan.best.len() {
            if seen[start] || !hit(start) {
                continue;
            }
            let mut stack = vec![start];
            seen[start] = true;
            let (mut r0, mut c0, mut r1, mut c1) = (usize::MAX, usize::MAX, 0, 0);
            let mut votes = vec![0f32; h.classes.len()];
            let mut top = 0f32;
            while let Some(i) = stack.pop() {
                let (r, c) = (i / scan.cols, i % scan.cols);
                (r0, c0, r1, c1) = (r0.min(r), c0.min(c), r1.max(r), c1.max(c));
                let (k, p) = scan.best[i];
                votes[k] += p;
                top = top.max(p);
                let mut next = Vec::with_capacity(4);
                if r > 0 {
                    next.push(i - scan.cols);
                }
                if r + 1 < scan.rows {
                    next.push(i + scan.cols);
                }
                if c > 0 {
                    next.push(i - 1);
                }
                if c + 1 < scan.cols {
                    next.push(i + 1);
                }
                for j in next {
                    if !seen[j] && hit(j) {
                        seen[j] = true;
                        stack.push(j);
                    }
                }
            }
            let class = (0..votes.len())
                .max_by(|&a, &b| votes[a].total_cmp(&votes[b]))
                .map(|k| h.classes[k].clone())
                .unwrap_or_default();
            let t = scan.tile_mm;
            let bbox_mm = [
                grid.x_min + c0 as f64 * t,
                grid.y_max - (r1 + 1) as f64 * t,
                grid.x_min + (c1 + 1) as f64 * t,
                grid.y_max - r0 as f64 * t,
            ];
            let p = f64::from(top);
            flags.push(Flag {
                kind: FlagKind::Model,
                class: Some(class.clone()),
                severity: if p >= self.cfg.critical_probability {
                    Severity::Critical
                } else {
                    Severity::Warning
                },
                part: None,
                view: scan.view.to_string(),
                bbox_mm,
                bbox_px: [
                    c0 as u32 * tile_px,
                    r0 as u32 * tile_px,
                    (c1 as u32 + 1) * tile_px - 1,
                    (r1 as u32 + 1) * tile_px - 1,
                ],
                score: p,
                threshold: self.cfg.min_probability,
                message: format!(
                    "model: {class} (p {p:.2}) across x = {:.1}..{:.1} mm, y = {:.1}..{:.1} mm",
                    bbox_mm[0], bbox_mm[2], bbox_mm[1], bbox_mm[3]
                ),
                since: None,
                evidence: vec![],
            });
        }
        capped(flags, MAX_FLAGS_PER_VIEW)
    }
}

/// The `max - 1` most probable of `flags` and one flag for the rest (their union box, the class
/// and probability of the most probable of them), when there are more than `max`.
fn capped(mut flags: Vec<Flag>, max: usize) -> Vec<Flag> {
    if flags.len() <= max || max == 0 {
        return flags;
    }
    flags.sort_by(|a, b| b.score.total_cmp(&a.score));
    let rest = flags.split_off(max - 1);
    let mut summary = rest[0].clone();
    for f in &rest[1..] {
        for i in 0..2 {
            summary.bbox_mm[i] = summary.bbox_mm[i].min(f.bbox_mm[i]);
            summary.bbox_px[i] = summary.bbox_px[i].min(f.bbox_px[i]);
            summary.bbox_mm[i + 2] = summary.bbox_mm[i + 2].max(f.bbox_mm[i + 2]);
            summary.bbox_px[i + 2] = summary.bbox_px[i + 2].max(f.bbox_px[i + 2]);
        }
    }
    let b = summary.bbox_mm;
    summary.message = format!(
        "model: {} more groups of defect tiles (p {:.2} or less) across x = {:.1}..{:.1} mm, y = {:.1}..{:.1} mm",
        rest.len(),
        summary.score,
        b[0],
        b[2],
        b[1],
        b[3]
    );
    flags.push(summary);
    flags
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_past_the_most_are_one_flag_over_all_of_them() {
        let flag = |i: usize| Flag {
            kind: FlagKind::Model,
            class: Some("Spots".into()),
            severity: Severity::Warning,
            part: None,
            view: "pre_top".into(),
            bbox_mm: [i as f64, 0.0, i as f64 + 1.0, 1.0],
            bbox_px: [i as u32 * 10, 0, i as u32 * 10 + 9, 9],
            score: i as f64 / 1000.0,
            threshold: 0.0,
            message: format!("tile {i}"),
            since: None,
            evidence: vec![],
        };
        let few: Vec<Flag> = (0..5).map(flag).collect();
        assert_eq!(capped(few, 8).len(), 5);
        let many = capped((0..500).map(flag).collect(), 8);
        assert_eq!(many.len(), 8);
        // The 7 most probable first, then the other 493 in one.
        assert_eq!(many[0].message, "tile 499");
        assert_eq!(many[6].message, "tile 493");
        let last = &many[7];
        assert_eq!(
            (last.bbox_mm, last.bbox_px),
            ([0.0, 0.0, 493.0, 1.0], [0, 0, 4929, 9])
        );
        assert_eq!(last.score, 0.492);
        assert!(
            last.message
                .starts_with("model: 493 more groups of defect tiles (p 0.49 or less)"),
            "{}",
            last.message
        );
    }
}

/// The heat map of a scan: one grey pixel per tile, 255 = certainly a defect.
pub fn heatmap_png(scan: &ViewScan) -> Option<Vec<u8>> {
    let px = scan
        .defect
        .iter()
        .map(|p| (p.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let img = GrayImage::from_raw(scan.cols as u32, scan.rows as u32, px)?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).ok()?;
    Some(out.into_inner())
}

/// Where a layer's heat map of `view` is kept in a build.
pub fn heatmap_path(build: &Path, view: &str, layer: u32) -> std::path::PathBuf {
    build
        .join(HEATMAP_DIR)
        .join(view)
        .join(format!("L{layer:05}.png"))
}

/// A frame the model could not look at (the rest go on).
#[derive(Debug)]
pub struct Unread {
    pub shot: crate::shot::Shot,
    pub error: super::LearnError,
}

/// Reduces a rectified view to cells of the given pixels: (rows, cols, means, textures).
pub type Reduce = dyn Fn(&FrameLuma, usize) -> (usize, usize, Vec<f32>, Vec<f32>) + Sync;

/// The model over stored frames (`layerwise inspect`): every view it looks at of each record's
/// layer is decoded, rectified as the daemon does, classified, and its flags added to the record
/// after the classical ones.
pub fn apply_offline(
    live: &LiveModel,
    rectifier: &crate::rectify::Rectifier,
    grid: &Grid,
    frames: &std::collections::BTreeMap<crate::shot::Shot, std::path::PathBuf>,
    records: &mut [crate::build_dir::inspection::InspectionRecord],
    reduce: &Reduce,
) -> Vec<Unread> {
    let mut unread = Vec::new();
    for record in records.iter_mut() {
        let (mut ms, mut views) = (0.0, 0usize);
        for (shot, path) in frames.iter().filter(|(s, _)| s.layer == record.layer) {
            if !live.wants(shot.view()) {
                continue;
            }
            let scan = crate::fsutil::read_regular(path)
                .map_err(|source| super::LearnError::Read {
                    path: path.clone(),
                    source,
                })
                .and_then(|bytes| {
                    crate::rectify::decode_frame_luma(&bytes).map_err(|source| {
                        super::LearnError::Decode {
                            path: path.clone(),
                            source,
                        }
                    })
                })
                .and_then(|luma| {
                    let (rows, cols, mean, texture) =
                        live.install(|| reduce(&luma.rectified(rectifier), live.cell_px()));
                    Ok(live.scan_cells(shot.view(), (rows, cols), &mean, &texture, grid)?)
                });
            match scan {
                Ok(scan) => {
                    ms += scan.ms;
                    views += 1;
                    record.flags.extend(live.flags(&scan, grid));
                }
                Err(error) => unread.push(Unread { shot: *shot, error }),
            }
        }
        record.plate.insert("model_ms".into(), ms);
        record.plate.insert("model_views".into(), views as f64);
    }
    unread
}
