//! Layer inspection: classical image analysis of the rectified views against the layer's
//! vectors, per layer as the views arrive (the daemon's processing worker) or over a stored
//! build (`layerwise inspect`), with the same code and so the same flags.
//!
//! Each view is first reduced to the inspection grid ([`cells`]: mean and texture per cell of
//! about `inspection.pixel_mm`); the detectors ([`detect`]) then work on those small images:
//! recoater streaks and short feed on the pre-scan view in `pre_light`, super-elevation on the
//! pre-scan view in `elevation_light` over the previous layer's parts, fusion against the vectors
//! and spatter on the post-scan view in `post_light`, drift of each part's metrics against its
//! running baseline ([`drift`]). A layer is inspected once its views are in (or when a later
//! layer's are, with what arrived, unless a view of it is still being processed on another
//! lane: [`Inspector::begin`]), always in layer order. A trained model can join as one more
//! detector on the same cells.

pub mod axis;
pub mod bed;
pub mod cells;
pub mod check;
pub mod detect;
pub mod drift;
pub mod mask;
pub mod offline;
pub mod persist;
pub mod plate;
pub mod plot;
pub mod powder;
pub mod stats;
pub mod streak;

use crate::build_dir::inspection::{Flag, FlagKind, InspectionRecord, PartMetrics, Severity};
use crate::config::inspection::InspectionConfig;
use crate::geometry::{Grid, PLATE_HALF_MM};
use crate::raster::RasterOptions;
use crate::rectify::FrameLuma;
use crate::shot::{Phase, View};
use crate::vectors::LayerIndex;
use cells::Cells;
use check::{Check, LayerInput};
use chrono::{DateTime, Utc};
use mask::Mask;
use plate::PlateChecks;
use stats::Found;
use std::collections::{BTreeMap, BTreeSet};

/// The layers' part masks on the inspection grid, by part id.
type Parts = Vec<(i64, Mask)>;

/// How far (camera pixels) a fused edge spreads in a rectified view; see
/// [`Inspector::resolve_camera`].
const CAMERA_BLUR_PX: f64 = 1.5;

/// The largest plate footprint of one camera pixel over `grid` (5 x 5 points: an oblique camera
/// resolves the far edge worst), mm; `None` when the camera sees none of them.
pub fn camera_footprint_mm(camera: &crate::geometry::CameraModel, grid: &Grid) -> Option<f64> {
    let (rows, cols) = (grid.rows() as f64, grid.columns() as f64);
    (0..5)
        .flat_map(|i| (0..5).map(move |j| (i, j)))
        .filter_map(|(i, j)| {
            let (x, y) = grid.center_of(
                (rows - 1.0) * f64::from(i) / 4.0,
                (cols - 1.0) * f64::from(j) / 4.0,
            );
            camera.footprint_mm(crate::geometry::BuildPoint { x, y })
        })
        .reduce(f64::max)
}

/// A view of a layer being processed, which its layer's inspection waits for
/// ([`Inspector::begin`]); handed back to [`Inspector::land`] or [`Inspector::give_up`].
#[must_use = "a view in flight holds back the inspection until it lands or is given up"]
#[derive(Debug)]
pub struct InFlight {
    layer: u32,
    view: View,
}

pub struct Inspector {
    cfg: InspectionConfig,
    view_grid: Grid,
    grid: Grid,
    bin: usize,
    plate: Mask,
    vectors: Option<LayerIndex>,
    needed: BTreeSet<View>,
    pending: BTreeMap<u32, BTreeMap<View, Cells>>,
    /// Views on their way to [`Inspector::land`], per layer: no layer from the first of these on
    /// is inspected before they land (or are given up), so that a layer completed by a faster
    /// lane never takes an earlier layer's view still being processed for missing.
    in_flight: crate::shot::Flights<u32>,
    done: BTreeSet<u32>,
    plate_checks: PlateChecks,
    baseline: drift::Baseline,
    parts: BTreeMap<u32, std::sync::Arc<Parts>>,
    checks: Vec<Box<dyn Check>>,
    /// The last inspected layer and its flags (what a flag may continue).
    last: Option<(u32, Vec<Flag>)>,
}

impl Inspector {
    /// An inspector for views on `view_grid` (the series grid) of the configured `views`, with
    /// the build's vectors when known.
    pub fn new(
        cfg: &InspectionConfig,
        view_grid: Grid,
        views: &[View],
        vectors: Option<LayerIndex>,
    ) -> Inspector {
        let (grid, bin) = cells::inspection_grid(&view_grid, cfg.pixel_mm);
        let (rows, cols) = (grid.rows(), grid.columns());
        let limit = PLATE_HALF_MM - cfg.edge_margin_mm;
        let mut plate = Mask::new(rows, cols);
        for r in 0..rows {
            for c in 0..cols {
                let (x, y) = grid.center_of(r as f64, c as f64);
                plate.on[r * cols + c] = x.abs() <= limit && y.abs() <= limit;
            }
        }
        let wanted = [
            View {
                phase: Phase::Pre,
                light: cfg.pre_light,
            },
            View {
                phase: Phase::Pre,
                light: cfg.elevation_light,
            },
            View {
                phase: Phase::Post,
                light: cfg.post_light,
            },
        ];
        let needed = wanted.into_iter().filter(|v| views.contains(v)).collect();
        Inspector {
            cfg: cfg.clone(),
            view_grid,
            grid,
            bin,
            plate,
            vectors,
            needed,
            pending: BTreeMap::new(),
            in_flight: Default::default(),
            done: BTreeSet::new(),
            plate_checks: PlateChecks::new(cfg),
            baseline: drift::Baseline::new(
                cfg.drift_window,
                cfg.drift_min_layers,
                cfg.drift_z / 2.0,
            ),
            parts: BTreeMap::new(),
            checks: Vec::new(),
            last: None,
        }
    }

    /// Adds a check run after the classical ones on every layer (a trained model).
    pub fn add_check(&mut self, check: Box<dyn Check>) {
        self.checks.push(check);
    }

    /// Tells the inspector how much of the plate one camera pixel covers (the largest
    /// [`CameraModel::footprint_mm`](crate::geometry::CameraModel::footprint_mm) over the plate).
    /// A fused edge in a rectified view is only known to about 1.5 camera pixels (the lens, the
    /// demosaicing and the resampling each blur it by a fraction of one), so the fusion tolerance
    /// is at least that: a coarse camera must not read the blur around a small part as fusion
    /// beyond its vectors. Returns the tolerance in use, mm.
    pub fn resolve_camera(&mut self, footprint_mm: f64) -> f64 {
        if footprint_mm.is_finite() && footprint_mm > 0.0 {
            let floor = CAMERA_BLUR_PX * footprint_mm;
            if floor > self.cfg.fusion_tolerance_mm {
                self.cfg.fusion_tolerance_mm = floor;
            }
        }
        self.cfg.fusion_tolerance_mm
    }

    /// The inspection grid.
    pub fn grid(&self) -> Grid {
        self.grid
    }

    /// Whether the inspection looks at `view` (the others need no reduction).
    pub fn needs(&self, view: View) -> bool {
        self.needed.contains(&view)
    }

    /// What reduces views to cells, apart from the inspector (so views reduce in parallel while
    /// the inspector is locked elsewhere).
    pub fn reducer(&self) -> Reducer {
        Reducer {
            view_grid: self.view_grid,
            bin: self.bin,
            needed: self.needed.clone(),
        }
    }

    /// Whether `layer` was inspected already (in this run or before a restart).
    pub fn is_done(&self, layer: u32) -> bool {
        self.done.contains(&layer)
    }

    /// Reduces a rectified view to cells; thread-safe, so views reduce in parallel.
    pub fn cells(&self, luma: &FrameLuma) -> Cells {
        Cells::from_luma(luma, &self.view_grid, self.bin)
    }

    /// Takes up where an earlier run stopped: its layers count as done, the drift baseline is
    /// rebuilt from their metrics, the recoater axis found is kept and the last layer's flags
    /// may continue. (The bed and the powder's references warm up again over 3 layers.)
    pub fn resume(&mut self, records: &[InspectionRecord]) {
        self.plate_checks.resume(records);
        self.last = records.last().map(|r| (r.layer, r.flags.clone()));
        for r in records {
            self.done.insert(r.layer);
            for m in &r.parts {
                let flagged = r.flags.iter().any(|f| f.part == Some(m.part));
                self.baseline.push(m, flagged);
            }
        }
    }

    /// Adds a view of a layer; returns the records of the layers this completes, in order.
    /// A layer is inspected once its views are in, and one that still lacks views when a later
    /// layer's are in is inspected with what it has, unless views of it (or of a layer before
    /// it) are still in flight ([`Inspector::begin`]).
    pub fn add(
        &mut self,
        layer: u32,
        view: View,
        cells: Cells,
        at: DateTime<Utc>,
    ) -> Vec<InspectionRecord> {
        if self.done.contains(&layer) || !self.needs(view) {
            return Vec::new();
        }
        self.pending.entry(layer).or_default().insert(view, cells);
        self.ready(at)
    }

    /// Says that a view of `layer` is being processed (by one of several lanes), for
    /// [`Inspector::land`] with its cells or [`Inspector::give_up`]; `None` if the inspection
    /// will not take it.
    pub fn begin(&mut self, layer: u32, view: View) -> Option<InFlight> {
        if self.done.contains(&layer) || !self.needs(view) {
            return None;
        }
        self.in_flight.begin(layer);
        Some(InFlight { layer, view })
    }

    /// [`Inspector::add`] for a view that was in flight.
    pub fn land(
        &mut self,
        flight: InFlight,
        cells: Cells,
        at: DateTime<Utc>,
    ) -> Vec<InspectionRecord> {
        self.in_flight.land(flight.layer);
        self.add(flight.layer, flight.view, cells, at)
    }

    /// A view in flight that will not come (its processing failed): the layers it held back are
    /// inspected if they may be now.
    pub fn give_up(&mut self, flight: InFlight, at: DateTime<Utc>) -> Vec<InspectionRecord> {
        self.in_flight.land(flight.layer);
        self.ready(at)
    }

    /// Inspects, in order, every waiting layer up to the last complete one, but none from the
    /// first layer with a view in flight on.
    fn ready(&mut self, at: DateTime<Utc>) -> Vec<InspectionRecord> {
        let needed = self.needed.len();
        let ready = self
            .in_flight
            .release(&mut self.pending, |views| views.len() >= needed);
        ready
            .into_iter()
            .map(|(l, views)| self.inspect(l, &views, at))
            .collect()
    }

    /// Inspects every layer still waiting, with the views it has.
    pub fn flush(&mut self, at: DateTime<Utc>) -> Vec<InspectionRecord> {
        let pending = std::mem::take(&mut self.pending);
        pending
            .into_iter()
            .map(|(l, views)| self.inspect(l, &views, at))
            .collect()
    }

    /// The parts of `layer` (1-based) on the inspection grid; empty without vectors.
    fn parts_of(&mut self, layer: u32) -> std::sync::Arc<Parts> {
        if let Some(p) = self.parts.get(&layer) {
            return p.clone();
        }
        let mut parts = Vec::new();
        if let Some(index) = &self.vectors {
            let read = (layer >= 1)
                .then(|| index.read_layer(layer as usize - 1))
                .and_then(Result::ok);
            if let Some(vector_layer) = read {
                let ids: BTreeSet<i64> = vector_layer
                    .polylines
                    .iter()
                    .map(|p| p.part)
                    .chain(vector_layer.hatches.iter().map(|h| h.part))
                    .collect();
                for id in ids {
                    if let Some(m) = self.part_mask(&vector_layer, id) {
                        parts.push((id, m));
                    }
                }
            }
        }
        let parts = std::sync::Arc::new(parts);
        self.parts.insert(layer, parts.clone());
        while self.parts.len() > 3 {
            self.parts.pop_first();
        }
        parts
    }

    /// A part's mask on the inspection grid, rasterised only over its bounding box (the grid's
    /// own pixel centres, so the same cells as a whole-grid raster).
    fn part_mask(&self, layer: &crate::vectors::Layer, id: i64) -> Option<Mask> {
        let g = self.grid;
        let (rows, cols) = (g.rows(), g.columns());
        let [x0, y0, x1, y1] = crate::raster::layer_bbox(layer, Some(id))?;
        let (ra, ca) = g.pixel_of(x0, y1);
        let (rb, cb) = g.pixel_of(x1, y0);
        let clamp = |v: f64, n: usize| (v.max(0.0) as usize).min(n.saturating_sub(1));
        let (r0, c0) = (clamp(ra.floor() - 2.0, rows), clamp(ca.floor() - 2.0, cols));
        let (r1, c1) = (clamp(rb.ceil() + 2.0, rows), clamp(cb.ceil() + 2.0, cols));
        if rb < 0.0 || cb < 0.0 || ra > rows as f64 || ca > cols as f64 {
            return None;
        }
        let p = g.pixel_mm;
        let sub = Grid {
            x_min: g.x_min + c0 as f64 * p,
            x_max: g.x_min + (c1 + 1) as f64 * p,
            y_min: g.y_max - (r1 + 1) as f64 * p,
            y_max: g.y_max - r0 as f64 * p,
            pixel_mm: p,
        };
        let opts = RasterOptions {
            part: Some(id),
            ..RasterOptions::default()
        };
        let img = crate::raster::mask(layer, &sub, &opts).ok()?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        let mut m = Mask::new(rows, cols);
        for r in 0..h.min(rows - r0) {
            for c in 0..w.min(cols - c0) {
                m.on[(r0 + r) * cols + c0 + c] = img.as_raw()[r * w + c] > 0;
            }
        }
        (m.count() > 0).then_some(m)
    }

    fn union(&self, parts: &Parts) -> Mask {
        parts.iter().fold(
            Mask::new(self.grid.rows(), self.grid.columns()),
            |a, (_, m)| a.or(m),
        )
    }

    fn valid(&self, cells: &Cells) -> Mask {
        Mask {
            rows: cells.rows,
            cols: cells.cols,
            on: self
                .plate
                .on
                .iter()
                .zip(&cells.mean)
                .map(|(p, m)| *p && *m > 1.0)
                .collect(),
        }
    }

    /// Inspects one layer with the views it has.
    pub fn inspect(
        &mut self,
        layer: u32,
        views: &BTreeMap<View, Cells>,
        at: DateTime<Utc>,
    ) -> InspectionRecord {
        let started = std::time::Instant::now();
        let cfg = self.cfg.clone();
        let grid = self.grid;
        let mut found: Vec<(View, Found)> = Vec::new();
        let mut plate: BTreeMap<String, f64> = BTreeMap::new();
        let previous = self.parts_of(layer.saturating_sub(1));
        let current = self.parts_of(layer);
        let previous_all = self.union(&previous);
        let current_all = self.union(&current);
        let view = |phase, light| View { phase, light };

        let pre = view(Phase::Pre, cfg.pre_light);
        let mut axis = None;
        let mut bed = None;
        let mut bed_mask = None;
        let mut notes = Vec::new();
        if let Some(cells) = views.get(&pre) {
            let valid = self.valid(cells);
            let (m, _) = detect::robust(
                valid
                    .on
                    .iter()
                    .zip(&cells.mean)
                    .filter(|(v, _)| **v)
                    .map(|(_, x)| f64::from(*x)),
                0.0,
            );
            plate.insert("pre_mean".into(), m);
            let outcome =
                self.plate_checks
                    .inspect(&grid, &cfg, cells, &valid, &previous_all.dilate(2));
            plate.extend(outcome.metrics);
            found.extend(outcome.found.into_iter().map(|f| (pre, f)));
            axis = Some(outcome.axis);
            bed = outcome.bed;
            bed_mask = Some(outcome.bed_mask);
            notes = outcome.notes;
        }

        let mut pre_means = Vec::new();
        let side = view(Phase::Pre, cfg.elevation_light);
        if let Some(cells) = views.get(&side) {
            let valid = self.valid(cells);
            let (raised, means) =
                detect::elevation(&grid, cells, &valid, &previous, &previous_all, &cfg);
            pre_means = means;
            found.extend(raised.into_iter().map(|f| (side, f)));
        }

        let mut parts: Vec<PartMetrics> = Vec::new();
        let post = view(Phase::Post, cfg.post_light);
        if let (Some(cells), false) = (views.get(&post), current.is_empty()) {
            let valid = self.valid(cells);
            let fusion = detect::fusion(&grid, cells, &valid, &current, &current_all, &cfg);
            plate.insert("post_texture".into(), fusion.texture_median);
            plate.insert("fused_mm2".into(), fusion.fused_mm2);
            plate.insert("spatter_mm2".into(), fusion.spatter_mm2);
            parts = fusion.parts;
            found.extend(fusion.found.into_iter().map(|f| (post, f)));
        }
        for m in &mut parts {
            m.pre_mean = pre_means
                .iter()
                .find(|(p, _)| *p == m.part)
                .map(|(_, v)| *v);
        }
        for m in &parts {
            for d in self.baseline.check(m, cfg.drift_z) {
                let Some(b) = current
                    .iter()
                    .find(|(p, _)| *p == m.part)
                    .and_then(|(_, mask)| mask.bbox())
                else {
                    continue;
                };
                found.push((
                    post,
                    Found {
                        kind: FlagKind::Drift,
                        part: Some(m.part),
                        cells: b,
                        score: d.z.abs(),
                        threshold: cfg.drift_z,
                        message: format!(
                            "part {}: {} {:.3} drifted from its baseline {:.3} ± {:.3} (last {} layers, z = {:.1})",
                            d.part, d.metric, d.value, d.median, d.sigma, d.layers, d.z
                        ),
                    },
                ));
            }
        }
        for m in &parts {
            let flagged = found.iter().any(|(_, f)| f.part == Some(m.part));
            self.baseline.push(m, flagged);
        }
        for check in &mut self.checks {
            let more = check.check(&LayerInput {
                layer,
                grid: &grid,
                views,
                bed: bed_mask.as_ref(),
                found: &found,
            });
            found.extend(more);
        }
        self.done.insert(layer);
        let flags: Vec<Flag> = found
            .into_iter()
            .map(|(view, f)| self.flag(view, f))
            .collect();
        let mut flags = persist::group(flags);
        if let Some((before, earlier)) = &self.last {
            persist::mark_persisting(&mut flags, earlier, *before);
        }
        self.last = Some((layer, flags.clone()));
        InspectionRecord {
            layer,
            at,
            ms: started.elapsed().as_secs_f64() * 1e3,
            views: views.keys().map(|v| v.to_string()).collect(),
            plate,
            parts,
            flags,
            axis,
            bed,
            notes,
        }
    }

    fn flag(&self, view: View, f: Found) -> Flag {
        let b = f.cells;
        let bin = self.bin as u32;
        let severity = if f.score >= self.cfg.critical_factor * f.threshold {
            Severity::Critical
        } else {
            Severity::Warning
        };
        Flag {
            kind: f.kind,
            class: None,
            severity,
            part: f.part,
            view: view.to_string(),
            bbox_mm: detect::box_mm(&self.grid, b),
            bbox_px: [
                b.c0 as u32 * bin,
                b.r0 as u32 * bin,
                (b.c1 as u32 + 1) * bin - 1,
                (b.r1 as u32 + 1) * bin - 1,
            ],
            score: f.score,
            threshold: f.threshold,
            message: f.message,
            since: None,
            evidence: Vec::new(),
        }
    }
}

/// Reduces views to the inspector's cells.
#[derive(Clone, Debug)]
pub struct Reducer {
    view_grid: Grid,
    bin: usize,
    needed: BTreeSet<View>,
}

impl Reducer {
    pub fn needs(&self, view: View) -> bool {
        self.needed.contains(&view)
    }
    pub fn cells(&self, luma: &FrameLuma) -> Cells {
        Cells::from_luma(luma, &self.view_grid, self.bin)
    }
}

/// The log line of a flag: `layer 142: recoater streak across x = -40..95 mm at y = 12.3 mm
/// (score 7.1, threshold 6.0, critical)`, with `, since layer N` for a flag that persists and
/// `; also: …` for what the same cause explains.
pub fn describe(layer: u32, flag: &Flag) -> String {
    let since = flag
        .since
        .map_or(String::new(), |s| format!(", since layer {s}"));
    let also = if flag.evidence.is_empty() {
        String::new()
    } else {
        format!("; also: {}", flag.evidence.join("; "))
    };
    format!(
        "layer {layer}: {} (score {:.2}, threshold {:.2}, {}{since}){also}",
        flag.message, flag.score, flag.threshold, flag.severity
    )
}

#[cfg(test)]
mod tests;
