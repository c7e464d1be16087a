//! The powder bed against its own past: a running per-cell reference of the pre-scan view (the
//! median of the last layers, where nothing was flagged), the view divided by it and by the smooth
//! light field (so vignetting, a dimmer lamp and what was there from the first layer cancel), and
//! coverage: regions of that ratio that stand out, in units of this layer's own layer-to-layer
//! variation over the bed.

use super::bed::{box_mean, quantile};
use super::cells::Cells;
use super::mask::{CellBox, Mask};
use super::stats::{box_mm, cells_of, Found};
use crate::build_dir::inspection::FlagKind;
use crate::config::inspection::InspectionConfig;
use crate::geometry::Grid;
use std::collections::VecDeque;

/// Layers the reference needs before it is used.
pub const MIN_REFERENCE: usize = 3;

/// The last layers' pre-scan means, per cell.
#[derive(Clone, Debug, Default)]
pub struct Reference {
    window: usize,
    layers: VecDeque<Vec<f32>>,
    median: Option<Vec<f32>>,
}

impl Reference {
    pub fn new(window: usize) -> Reference {
        Reference {
            window: window.max(MIN_REFERENCE),
            ..Reference::default()
        }
    }

    /// The per-cell median of the last layers, once `MIN_REFERENCE` are in.
    pub fn get(&self) -> Option<&[f32]> {
        self.median.as_deref()
    }

    /// Adds a layer: its flagged cells keep the reference's value (a defect never becomes the
    /// bed); a layer of another size restarts the reference.
    pub fn push(&mut self, mean: &[f32], flagged: &Mask) {
        if self.layers.front().is_some_and(|l| l.len() != mean.len()) {
            self.layers.clear();
            self.median = None;
        }
        let mut layer = mean.to_vec();
        if let Some(reference) = &self.median {
            for ((v, r), f) in layer.iter_mut().zip(reference).zip(&flagged.on) {
                if *f {
                    *v = *r;
                }
            }
        }
        self.layers.push_back(layer);
        while self.layers.len() > self.window {
            self.layers.pop_front();
        }
        if self.layers.len() >= MIN_REFERENCE {
            let n = self.layers.len();
            let mut column = vec![0f32; n];
            let median = (0..mean.len())
                .map(|i| {
                    for (slot, l) in column.iter_mut().zip(&self.layers) {
                        *slot = l[i];
                    }
                    let (_, m, _) = column.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b));
                    *m
                })
                .collect();
            self.median = Some(median);
        }
    }
}

/// A pre-scan view made comparable across layers and over the plate, in grey levels about the
/// bed's median (`level`): the view divided by the reference when there is one, then by the
/// smooth light field of that (a box of `flatten_mm`). NaN off the bed.
#[derive(Clone, Debug)]
pub struct Flattened {
    pub values: Vec<f32>,
    pub level: f64,
    /// Whether the values are relative to the reference (else to this view alone).
    pub relative: bool,
    /// Robust per-cell noise of the values over the bed, grey levels.
    pub cell_noise: f64,
}

pub fn flatten(
    cells: &Cells,
    bed: &Mask,
    reference: Option<&[f32]>,
    grid: &Grid,
    cfg: &InspectionConfig,
) -> Flattened {
    let n = cells.mean.len();
    let on_bed: Vec<f32> = (0..n)
        .filter(|&i| bed.on[i])
        .map(|i| cells.mean[i])
        .collect();
    let level = f64::from(quantile(on_bed, 0.5));
    let ratio: Vec<f32> = match reference {
        Some(r) => (0..n)
            .map(|i| {
                if bed.on[i] && r[i] > 1.0 {
                    cells.mean[i] / r[i]
                } else {
                    f32::NAN
                }
            })
            .collect(),
        None => (0..n)
            .map(|i| if bed.on[i] { cells.mean[i] } else { f32::NAN })
            .collect(),
    };
    let radius = cells_of(cfg.flatten_mm, grid).max(2);
    let light = box_mean(&ratio, bed, radius);
    let values: Vec<f32> = ratio
        .iter()
        .zip(&light)
        .map(|(q, l)| {
            if q.is_finite() && l.is_finite() && *l > 0.0 {
                (level as f32) * q / l
            } else {
                f32::NAN
            }
        })
        .collect();
    let local = box_mean(&values, bed, 1);
    let dev: Vec<f32> = values
        .iter()
        .zip(&local)
        .map(|(v, l)| (v - l).abs())
        .collect();
    let cell_noise = 1.4826 * f64::from(quantile(dev, 0.5));
    Flattened {
        values,
        level,
        relative: reference.is_some(),
        cell_noise,
    }
}

/// Coverage: over the bed, the flattened ratio to the reference smoothed over about 1 mm, in
/// robust z (median and MAD over the bed of this layer); regions beyond `coverage_z / 2` (those
/// within 3 mm of each other one region) whose peak reaches `coverage_z` and whose area is at
/// least `coverage_min_mm2`, each one finding, unless most of it lies on `streaks` (the lines of
/// the streaks found: a streak explains it). Returns the findings and the largest |z|.
pub fn coverage(
    grid: &Grid,
    flat: &Flattened,
    bed: &Mask,
    streaks: &Mask,
    cfg: &InspectionConfig,
) -> (Vec<Found>, f64) {
    let smooth = box_mean(&flat.values, bed, cells_of(1.0, grid).max(1));
    let inside: Vec<f64> = (0..smooth.len())
        .filter(|&i| bed.on[i] && smooth[i].is_finite())
        .map(|i| f64::from(smooth[i]))
        .collect();
    let (center, sigma) = super::stats::robust(inside.into_iter(), 1e-3 * flat.level.max(1.0));
    let z: Vec<f64> = (0..smooth.len())
        .map(|i| {
            if bed.on[i] && smooth[i].is_finite() {
                (f64::from(smooth[i]) - center) / sigma
            } else {
                0.0
            }
        })
        .collect();
    let best = z.iter().fold(0f64, |a, v| a.max(v.abs()));
    let thr = cfg.coverage_z;
    let cell_mm2 = grid.pixel_mm * grid.pixel_mm;
    let min_cells = (cfg.coverage_min_mm2 / cell_mm2).ceil().max(1.0) as usize;
    let mut found = Vec::new();
    for sign in [-1.0, 1.0] {
        let hot = Mask {
            rows: bed.rows,
            cols: bed.cols,
            on: z.iter().map(|v| v * sign >= thr / 2.0).collect(),
        };
        let near = cells_of(3.0, grid).max(1);
        for grown in hot.dilate(near).labelled() {
            let region: Vec<usize> = grown.into_iter().filter(|&i| hot.on[i]).collect();
            if region.len() < min_cells {
                continue;
            }
            let on_streaks = region.iter().filter(|&&i| streaks.on[i]).count();
            if 2 * on_streaks >= region.len() {
                continue;
            }
            let peak = region.iter().map(|&i| z[i] * sign).fold(0.0, f64::max);
            if peak < thr {
                continue;
            }
            let mut b = CellBox::cell(region[0] / bed.cols, region[0] % bed.cols);
            for &i in &region {
                b.grow(i / bed.cols, i % bed.cols);
            }
            let shift = region
                .iter()
                .map(|&i| f64::from(smooth[i]) - center)
                .sum::<f64>()
                / region.len() as f64;
            let [x0, y0, x1, y1] = box_mm(grid, b);
            let area = region.len() as f64 * cell_mm2;
            found.push(Found {
                kind: FlagKind::Coverage,
                part: None,
                cells: b,
                score: peak,
                threshold: thr,
                message: format!(
                    "uneven powder: {area:.0} mm² at x = {x0:.0}..{x1:.0} mm, y = {y0:.0}..{y1:.0} mm {:.1}% {} than {}",
                    100.0 * shift.abs() / flat.level.max(1.0),
                    if sign < 0.0 { "darker" } else { "brighter" },
                    if flat.relative { "the bed's last layers" } else { "the bed around it" }
                ),
            });
        }
    }
    (found, best)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_reference_keeps_its_value_where_a_layer_was_flagged() {
        let mut r = Reference::new(5);
        let none = Mask::new(1, 2);
        for v in [10.0, 11.0, 12.0] {
            r.push(&[v, v], &none);
        }
        assert_eq!(r.get(), Some(&[11.0f32, 11.0][..]));
        let flagged = Mask {
            rows: 1,
            cols: 2,
            on: vec![true, false],
        };
        for _ in 0..3 {
            r.push(&[50.0, 50.0], &flagged);
        }
        assert_eq!(r.get(), Some(&[11.0f32, 50.0][..]));
    }
}
