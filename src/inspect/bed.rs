//! The powder bed: which cells of a pre-scan view are powder (not the dark machine parts around
//! the plate, the plate's rim or the wedges an oblique view leaves), found from the build's own
//! first layers, and the smooth light field divided out before the powder is judged.

use super::cells::Cells;
use super::mask::Mask;
use crate::build_dir::inspection::BedRecord;
use crate::geometry::Grid;

/// Box mean of `values` over the cells of `mask` within `radius` cells (a normalised
/// convolution: cells outside the mask neither count nor dilute), by summed-area tables; NaN
/// where the window holds no masked cell.
pub fn box_mean(values: &[f32], mask: &Mask, radius: usize) -> Vec<f32> {
    let (rows, cols) = (mask.rows, mask.cols);
    let w = cols + 1;
    let mut sum = vec![0f64; (rows + 1) * w];
    let mut count = vec![0u32; (rows + 1) * w];
    for r in 0..rows {
        let (mut s, mut n) = (0f64, 0u32);
        for c in 0..cols {
            let i = r * cols + c;
            if mask.on[i] && values[i].is_finite() {
                s += f64::from(values[i]);
                n += 1;
            }
            sum[(r + 1) * w + c + 1] = sum[r * w + c + 1] + s;
            count[(r + 1) * w + c + 1] = count[r * w + c + 1] + n;
        }
    }
    let mut out = vec![f32::NAN; rows * cols];
    for r in 0..rows {
        let (r0, r1) = (r.saturating_sub(radius), (r + radius + 1).min(rows));
        for c in 0..cols {
            let (c0, c1) = (c.saturating_sub(radius), (c + radius + 1).min(cols));
            let at = |rr: usize, cc: usize| (sum[rr * w + cc], count[rr * w + cc]);
            let (a, na) = at(r1, c1);
            let (b, nb) = at(r0, c1);
            let (d, nd) = at(r1, c0);
            let (e, ne) = at(r0, c0);
            let n = na + ne - nb - nd;
            if n > 0 {
                out[r * cols + c] = ((a - b - d + e) / f64::from(n)) as f32;
            }
        }
    }
    out
}

/// The `q` quantile (0..1) of the finite values.
pub fn quantile(mut v: Vec<f32>, q: f64) -> f32 {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return f32::NAN;
    }
    let k = ((v.len() - 1) as f64 * q).round() as usize;
    let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *x
}

/// The powder of one pre-scan view within `valid` (the plate, where the camera sees): cells at
/// least half as bright as the bed around them (the 90th percentile of their row, and at least
/// a quarter of the whole view's), the largest connected region of them with its holes filled
/// (a dark defect inside the bed is bed), less `margin` cells at its border.
pub fn find(cells: &Cells, valid: &Mask, margin: usize) -> Mask {
    let (rows, cols) = (cells.rows, cells.cols);
    let smooth = box_mean(&cells.mean, valid, 2);
    let inside: Vec<f32> = (0..rows * cols)
        .filter(|&i| valid.on[i])
        .map(|i| smooth[i])
        .collect();
    let whole = quantile(inside, 0.9);
    let mut bright = Mask::new(rows, cols);
    if !whole.is_finite() || whole <= 1.0 {
        return bright;
    }
    for r in 0..rows {
        let row: Vec<f32> = (0..cols)
            .map(|c| r * cols + c)
            .filter(|&i| valid.on[i])
            .map(|i| smooth[i])
            .collect();
        let level = quantile(row, 0.9).max(0.5 * whole);
        for c in 0..cols {
            let i = r * cols + c;
            bright.on[i] = valid.on[i] && smooth[i] >= 0.5 * level;
        }
    }
    let Some(largest) = bright.largest_blob() else {
        return bright;
    };
    largest.filled().erode(margin)
}

/// The bed settled over the build's first layers: a cell is bed when it was found so in at
/// least half of them; then it stays (the bed does not move).
#[derive(Clone, Debug)]
pub struct BedFinder {
    votes: Vec<u16>,
    layers: u16,
    settle_after: u16,
    settled: Option<Mask>,
}

impl BedFinder {
    pub fn new(settle_after: usize) -> BedFinder {
        BedFinder {
            votes: Vec::new(),
            layers: 0,
            settle_after: settle_after.max(1) as u16,
            settled: None,
        }
    }

    /// The bed for this layer's view; `Some(true)` in the second place on the layer it settles.
    pub fn update(&mut self, cells: &Cells, valid: &Mask, margin: usize) -> (Mask, bool) {
        if let Some(bed) = &self.settled {
            if bed.on.len() == valid.on.len() {
                return (bed.and(valid), false);
            }
        }
        let now = find(cells, valid, margin);
        if self.votes.len() != now.on.len() {
            self.votes = vec![0; now.on.len()];
            self.layers = 0;
        }
        for (v, on) in self.votes.iter_mut().zip(&now.on) {
            *v += u16::from(*on);
        }
        self.layers += 1;
        let agreed = Mask {
            rows: now.rows,
            cols: now.cols,
            on: self.votes.iter().map(|&v| 2 * v >= self.layers).collect(),
        };
        if self.layers >= self.settle_after {
            self.settled = Some(agreed.clone());
            return (agreed.and(valid), true);
        }
        (agreed.and(&now), false)
    }
}

/// The bed as inspection.jsonl records it: its box and area, and (when `outline`) its border as
/// a polygon of at most `64` vertices (the border cells' centres in angle order about the
/// centre: the bed is one region without holes, and near-convex as plates are).
pub fn record(grid: &Grid, bed: &Mask, outline: bool) -> Option<BedRecord> {
    let b = bed.bbox()?;
    let area_mm2 = bed.count() as f64 * grid.pixel_mm * grid.pixel_mm;
    let bbox_mm = super::detect::box_mm(grid, b);
    let mut outline_mm = Vec::new();
    if outline {
        let edge = bed.minus(&bed.erode(1));
        let (cx, cy) = (
            (bbox_mm[0] + bbox_mm[2]) / 2.0,
            (bbox_mm[1] + bbox_mm[3]) / 2.0,
        );
        const SECTORS: usize = 64;
        let mut far: Vec<Option<(f64, [f64; 2])>> = vec![None; SECTORS];
        for (i, _) in edge.on.iter().enumerate().filter(|(_, on)| **on) {
            let (x, y) = grid.center_of((i / bed.cols) as f64, (i % bed.cols) as f64);
            let angle = (y - cy).atan2(x - cx);
            let s = (((angle + std::f64::consts::PI) / std::f64::consts::TAU * SECTORS as f64)
                as usize)
                .min(SECTORS - 1);
            let d = (x - cx).hypot(y - cy);
            if far[s].is_none_or(|(best, _)| d > best) {
                far[s] = Some((d, [x, y]));
            }
        }
        outline_mm = far.into_iter().flatten().map(|(_, p)| p).collect();
    }
    Some(BedRecord {
        bbox_mm,
        area_mm2,
        outline_mm,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bed_is_the_bright_region_without_the_dark_border_and_keeps_its_holes() {
        let (rows, cols) = (60, 80);
        let mut mean = vec![15f32; rows * cols];
        for r in 5..55 {
            for c in 10..70 {
                // Vignetted powder: brighter in the middle.
                mean[r * cols + c] = 100.0 - 0.02 * ((c as f32 - 40.0).powi(2));
            }
        }
        // A dark defect inside the bed is bed.
        for r in 20..25 {
            for c in 30..35 {
                mean[r * cols + c] = 20.0;
            }
        }
        let cells = Cells {
            rows,
            cols,
            texture: vec![1.0; rows * cols],
            mean,
        };
        let valid = Mask {
            rows,
            cols,
            on: vec![true; rows * cols],
        };
        let bed = find(&cells, &valid, 1);
        assert!(bed.get(22, 32), "the hole is filled");
        assert!(!bed.get(2, 40) && !bed.get(30, 5) && !bed.get(30, 75));
        assert!(bed.get(30, 12) && bed.get(30, 67) && !bed.get(30, 10));
        let mut finder = BedFinder::new(2);
        assert!(!finder.update(&cells, &valid, 1).1);
        let (settled, now) = finder.update(&cells, &valid, 1);
        assert!(now);
        assert_eq!(settled, bed);
        let grid = Grid {
            x_min: 0.0,
            x_max: 40.0,
            y_min: 0.0,
            y_max: 30.0,
            pixel_mm: 0.5,
        };
        let rec = record(&grid, &bed, true).expect("a bed");
        assert!(rec.outline_mm.len() > 16, "{rec:?}");
        assert!((rec.area_mm2 - bed.count() as f64 * 0.25).abs() < 1e-9);
    }

    #[test]
    fn box_mean_ignores_cells_outside_the_mask() {
        let mask = Mask {
            rows: 1,
            cols: 5,
            on: vec![true, true, false, true, true],
        };
        let v = [1.0, 3.0, 100.0, 5.0, 7.0];
        let m = box_mean(&v, &mask, 1);
        assert_eq!(m[2], 4.0);
        assert_eq!(m[0], 2.0);
    }
}
