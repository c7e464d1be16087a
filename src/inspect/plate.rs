//! The plate-wide checks of the pre-scan view, in turn: the powder bed (found over the first
//! layers, then kept), the view flattened against the bed's running reference and the smooth
//! light field, the recoater axis (found from the frames unless set), streaks along it, short
//! feed, and coverage; then the reference takes the layer in, less what was flagged.

use super::axis::{self, AxisFinder, AxisNews};
use super::bed::{self, BedFinder};
use super::cells::Cells;
use super::detect::{self, Profile};
use super::mask::{CellBox, Mask};
use super::powder::{self, Reference};
use super::stats::{cells_of, Found};
use crate::build_dir::inspection::{AxisRecord, BedRecord, FlagKind, InspectionRecord, Note};
use crate::config::inspection::{Axis, InspectionConfig};
use crate::geometry::Grid;
use std::collections::{BTreeMap, VecDeque};

/// What the plate-wide checks found on one layer.
pub struct PlateOutcome {
    pub found: Vec<Found>,
    pub metrics: BTreeMap<String, f64>,
    pub axis: AxisRecord,
    pub bed: Option<BedRecord>,
    pub bed_mask: Mask,
    pub notes: Vec<Note>,
}

pub struct PlateChecks {
    bed: BedFinder,
    axis: AxisFinder,
    reference: Reference,
    /// The short-feed reference profiles along x and along y.
    profiles: [VecDeque<Profile>; 2],
}

/// How many cells a box spans along `axis`.
fn length_along(b: CellBox, axis: Axis) -> f64 {
    match axis {
        Axis::X => (b.c1 - b.c0 + 1) as f64,
        Axis::Y => (b.r1 - b.r0 + 1) as f64,
    }
}

fn slot(axis: Axis) -> usize {
    match axis {
        Axis::X => 0,
        Axis::Y => 1,
    }
}

impl PlateChecks {
    pub fn new(cfg: &InspectionConfig) -> PlateChecks {
        PlateChecks {
            bed: BedFinder::new(cfg.reference_layers),
            axis: AxisFinder::new(cfg.recoat_axis),
            reference: Reference::new(cfg.reference_layers),
            profiles: [VecDeque::new(), VecDeque::new()],
        }
    }

    /// Takes the axis found before a restart from the last record that says it.
    pub fn resume(&mut self, records: &[InspectionRecord]) {
        if let Some(found) = records
            .iter()
            .rev()
            .filter_map(|r| r.axis.as_ref())
            .find(|a| a.source == "found")
        {
            self.axis.resume(&found.axis);
        }
    }

    /// Judges the pre-scan view `cells` within `valid` (the plate where the camera sees), the
    /// previous layer's parts (`parts`, grown) left out.
    pub fn inspect(
        &mut self,
        grid: &Grid,
        cfg: &InspectionConfig,
        cells: &Cells,
        valid: &Mask,
        parts: &Mask,
    ) -> PlateOutcome {
        let mut metrics = BTreeMap::new();
        let mut notes = Vec::new();
        let margin = cells_of(cfg.edge_margin_mm, grid);
        let (bed_mask, settled) = self.bed.update(cells, valid, margin);
        let bed = bed::record(grid, &bed_mask, settled);
        if settled {
            if let Some(b) = &bed {
                let [x0, y0, x1, y1] = b.bbox_mm;
                notes.push(Note {
                    level: "info".into(),
                    message: format!(
                        "the powder bed judged: {:.0} mm² within x = {x0:.0}..{x1:.0} mm, y = {y0:.0}..{y1:.0} mm (found from the first layers)",
                        b.area_mm2
                    ),
                });
            }
        }
        let powder = bed_mask.minus(parts);
        let flat = powder::flatten(cells, &powder, self.reference.get(), grid, cfg);
        metrics.insert("bed_level".into(), flat.level);
        metrics.insert("cell_noise".into(), flat.cell_noise);
        // The recoating marks persist from layer to layer, so the axis is read on the view
        // flattened by its own light field, not on its ratio to the reference.
        let own = if flat.relative {
            powder::flatten(cells, &powder, None, grid, cfg)
        } else {
            flat.clone()
        };
        let evidence = axis::layer_evidence(&own.values, &powder, own.cell_noise);
        metrics.insert("axis_evidence".into(), evidence);

        let mut found = Vec::new();
        let mut lengths = [0f64; 2];
        let mut best_streak = 0f64;
        // The first layers are the bed's baseline: what is there from the start is the bed.
        for a in self.axis.axes().into_iter().filter(|_| flat.relative) {
            let (streaks, z) = super::streak::streaks(grid, &flat.values, &powder, a, cfg);
            best_streak = best_streak.max(z);
            lengths[slot(a)] = streaks.iter().map(|s| length_along(s.cells, a)).sum();
            found.extend(streaks);
        }
        metrics.insert("streak_z".into(), best_streak);
        if let Some(news) = self.axis.push(evidence, lengths[0], lengths[1]) {
            notes.push(match news {
                AxisNews::Found(a) => Note {
                    level: "info".into(),
                    message: format!(
                        "recoater axis found from the frames: {a} (streaks and recoating marks run along it)"
                    ),
                },
                AxisNews::Disagrees { configured, frames } => Note {
                    level: "warn".into(),
                    message: format!(
                        "recoat_axis = \"{configured}\" is configured but the frames' streaks and recoating marks run along {frames}; set recoat_axis = \"{frames}\" or \"auto\""
                    ),
                },
            });
        }

        let mut best_short = None::<f64>;
        for a in self.axis.axes() {
            let refs = &mut self.profiles[slot(a)];
            let profile = detect::profile(cells, valid, a);
            let earlier: Vec<Profile> = refs.iter().cloned().collect();
            match detect::short_feed(grid, valid, &profile, &earlier, a, cfg) {
                Some((short, z)) => {
                    best_short = Some(best_short.unwrap_or(0.0).max(z));
                    if short.is_empty() {
                        refs.push_back(profile);
                    }
                    found.extend(short);
                }
                None => refs.push_back(profile),
            }
            while refs.len() > cfg.reference_layers {
                refs.pop_front();
            }
        }
        if let Some(z) = best_short {
            metrics.insert("short_feed_z".into(), z);
        }

        let mut explained = Mask::new(valid.rows, valid.cols);
        for f in found.iter().filter(|f| f.kind == FlagKind::Streak) {
            explained.set_box(f.cells.expand(1, valid.rows, valid.cols));
        }
        if flat.relative {
            let (regions, z) = powder::coverage(grid, &flat, &powder, &explained, cfg);
            metrics.insert("coverage_z".into(), z);
            found.extend(regions);
        }
        let mut flagged = explained;
        for f in &found {
            flagged.set_box(f.cells.expand(2, valid.rows, valid.cols));
        }
        self.reference.push(&cells.mean, &flagged);
        PlateOutcome {
            found,
            metrics,
            axis: self.axis.record(),
            bed,
            bed_mask,
            notes,
        }
    }
}
