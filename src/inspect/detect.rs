//! The detectors, each on the cells of one view: recoater streaks and short feed (pre-scan,
//! plate-wide), super-elevation (pre-scan, over the previous layer's parts) and fusion against
//! the vectors (post-scan, per part, and spatter away from every part). Scores are robust
//! z-scores (median and MAD of the same frame or of earlier layers) or ratios; each finding
//! carries its threshold.

use super::cells::Cells;
use super::mask::{CellBox, Mask};
use crate::build_dir::inspection::{FlagKind, PartMetrics};
use crate::config::inspection::{Axis, InspectionConfig};
use crate::geometry::Grid;

pub use super::stats::{box_mm, Found};
use super::stats::{cells_of, Lines};
pub(crate) use super::stats::{median, robust};

/// Mean of the middle 60% of the values: a spot does not move it, and unlike a median of 8-bit
/// grey levels it is not quantised.
fn trimmed_mean(values: &mut [f64]) -> f64 {
    let n = values.len();
    let cut = n / 5;
    if n == 0 {
        return f64::NAN;
    }
    if cut > 0 {
        values.select_nth_unstable_by(cut, |a, b| a.total_cmp(b));
        let upper = &mut values[cut..];
        let keep = n - 2 * cut;
        upper.select_nth_unstable_by(keep, |a, b| a.total_cmp(b));
    }
    let middle = &values[cut..n - cut];
    middle.iter().sum::<f64>() / middle.len().max(1) as f64
}

/// A pre-scan view's profile along the recoating axis: per position, the trimmed mean over the
/// plate of the cell means and of the textures (trimmed, so a spot does not move it).
#[derive(Clone, Debug, PartialEq)]
pub struct Profile {
    pub mean: Vec<f64>,
    pub texture: Vec<f64>,
}

pub fn profile(cells: &Cells, valid: &Mask, axis: Axis) -> Profile {
    let lines = Lines::new(cells.rows, cells.cols, axis);
    let mut mean = Vec::with_capacity(lines.along);
    let mut texture = Vec::with_capacity(lines.along);
    for p in 0..lines.along {
        let idx: Vec<usize> = (0..lines.lines)
            .map(|l| lines.index(l, p))
            .filter(|&i| valid.on[i])
            .collect();
        if idx.len() < 10 {
            mean.push(f64::NAN);
            texture.push(f64::NAN);
            continue;
        }
        let mut m: Vec<f64> = idx.iter().map(|&i| f64::from(cells.mean[i])).collect();
        let mut t: Vec<f64> = idx.iter().map(|&i| f64::from(cells.texture[i])).collect();
        mean.push(trimmed_mean(&mut m));
        texture.push(trimmed_mean(&mut t));
    }
    Profile { mean, texture }
}

/// Short feed: the profile along the recoating axis against the median of the same view's
/// earlier profiles; a run of positions at least `short_feed_min_width_mm` wide whose mean or
/// texture departs by `short_feed_z` robust sigmas is a band the powder did not cover.
/// `None` until three earlier profiles exist.
pub fn short_feed(
    grid: &Grid,
    valid: &Mask,
    now: &Profile,
    earlier: &[Profile],
    axis: Axis,
    cfg: &InspectionConfig,
) -> Option<(Vec<Found>, f64)> {
    if earlier.len() < 3 {
        return None;
    }
    let n = now.mean.len();
    let reference = |f: fn(&Profile) -> &Vec<f64>| -> Vec<f64> {
        (0..n)
            .map(|p| {
                let mut v: Vec<f64> = earlier
                    .iter()
                    .filter_map(|e| f(e).get(p).copied())
                    .filter(|v| v.is_finite())
                    .collect();
                median(&mut v)
            })
            .collect()
    };
    let z_of = |f: fn(&Profile) -> &Vec<f64>, floor: f64| -> Vec<f64> {
        let r = reference(f);
        let d: Vec<f64> = f(now).iter().zip(&r).map(|(a, b)| a - b).collect();
        let (m, s) = robust(d.iter().copied(), floor);
        d.iter().map(|v| (v - m) / s).collect()
    };
    let zm = z_of(|p| &p.mean, 0.1);
    let zt = z_of(|p| &p.texture, 0.05);
    let z: Vec<f64> = zm
        .iter()
        .zip(&zt)
        .map(|(a, b)| {
            let v = a.abs().max(b.abs());
            if v.is_finite() {
                v
            } else {
                0.0
            }
        })
        .collect();
    let best = z.iter().copied().fold(0.0, f64::max);
    let thr = cfg.short_feed_z;
    let min_width = cells_of(cfg.short_feed_min_width_mm, grid).max(2);
    let lines = match axis {
        Axis::X => valid.bbox().map(|b| (b.r0, b.r1)),
        Axis::Y => valid.bbox().map(|b| (b.c0, b.c1)),
    }?;
    let mut found = Vec::new();
    let mut p = 0;
    while p < n {
        if z[p] < thr {
            p += 1;
            continue;
        }
        let start = p;
        while p < n && z[p] >= thr / 2.0 {
            p += 1;
        }
        if p - start < min_width {
            continue;
        }
        let mut run: Vec<f64> = z[start..p].to_vec();
        let score = median(&mut run);
        if score < thr {
            continue;
        }
        let mut shift: Vec<f64> = zm[start..p].to_vec();
        let darker = median(&mut shift) < 0.0;
        let cells = match axis {
            Axis::X => CellBox {
                r0: lines.0,
                r1: lines.1,
                c0: start,
                c1: p - 1,
            },
            Axis::Y => CellBox {
                r0: start,
                r1: p - 1,
                c0: lines.0,
                c1: lines.1,
            },
        };
        let [x0, y0, x1, y1] = box_mm(grid, cells);
        let band = match axis {
            Axis::X => format!("x = {x0:.0}..{x1:.0} mm"),
            Axis::Y => format!("y = {y0:.0}..{y1:.0} mm"),
        };
        found.push(Found {
            kind: FlagKind::ShortFeed,
            part: None,
            cells,
            score,
            threshold: thr,
            message: format!(
                "short feed: the new powder does not cover {band} across the plate ({} than the layers before)",
                if darker { "darker" } else { "brighter or rougher" }
            ),
        });
    }
    Some((found, best))
}

/// 3 x 3 mean of the valid cells' means (NaN elsewhere).
fn smoothed(cells: &Cells, valid: &Mask) -> Vec<f64> {
    let (rows, cols) = (cells.rows, cells.cols);
    let mut out = vec![f64::NAN; rows * cols];
    for r in 0..rows {
        for c in 0..cols {
            if !valid.on[r * cols + c] {
                continue;
            }
            let (mut s, mut n) = (0f64, 0usize);
            for rr in r.saturating_sub(1)..(r + 2).min(rows) {
                for cc in c.saturating_sub(1)..(c + 2).min(cols) {
                    let i = rr * cols + cc;
                    if valid.on[i] {
                        s += f64::from(cells.mean[i]);
                        n += 1;
                    }
                }
            }
            out[r * cols + c] = s / n as f64;
        }
    }
    out
}

/// Super-elevation: over each part's previous-layer footprint (grown by 1 mm), the 3x3-smoothed
/// grey level in robust z against the powder in a 5 mm ring around it (other parts left out).
/// Returns the findings and each part's mean grey level over its footprint.
pub fn elevation(
    grid: &Grid,
    cells: &Cells,
    valid: &Mask,
    footprints: &[(i64, Mask)],
    all: &Mask,
    cfg: &InspectionConfig,
) -> (Vec<Found>, Vec<(i64, f64)>) {
    let smooth = smoothed(cells, valid);
    let thr = cfg.elevation_z;
    let others = all.dilate(cells_of(2.0, grid).max(1));
    let mut found = Vec::new();
    let mut means = Vec::new();
    let (rows, cols) = (cells.rows, cells.cols);
    let ring_cells = cells_of(5.0, grid).max(3);
    for (part, whole) in footprints {
        let Some(part_box) = whole.bbox() else {
            continue;
        };
        let window = part_box.expand(ring_cells + 2, rows, cols);
        let (foot, valid, others) = (whole.crop(window), valid.crop(window), others.crop(window));
        let at = |i: usize| (window.r0 + i / valid.cols) * cols + window.c0 + i % valid.cols;
        let inside = foot.and(&valid);
        if inside.count() == 0 {
            continue;
        }
        let m = (0..inside.on.len())
            .filter(|&i| inside.on[i])
            .map(|i| f64::from(cells.mean[at(i)]))
            .sum::<f64>()
            / inside.count() as f64;
        means.push((*part, m));
        let region = foot.dilate(cells_of(1.0, grid).max(1)).and(&valid);
        let ring = foot.dilate(ring_cells).minus(&others).and(&valid);
        if ring.count() < 20 {
            continue;
        }
        let (center, sigma) = robust(
            (0..ring.on.len())
                .filter(|&i| ring.on[i])
                .map(|i| smooth[at(i)]),
            0.1,
        );
        let mut hot = Mask::new(region.rows, region.cols);
        let mut score = 0f64;
        let mut sign = 0f64;
        for (i, _) in region.on.iter().enumerate().filter(|(_, on)| **on) {
            let z = (smooth[at(i)] - center) / sigma;
            if z.abs() > score {
                score = z.abs();
                sign = z.signum();
            }
            if z.abs() >= thr {
                hot.on[i] = true;
            }
        }
        if score < thr {
            continue;
        }
        let Some(b) = hot.bbox().map(|b| b.within(window)) else {
            continue;
        };
        let [x0, y0, x1, y1] = box_mm(grid, b);
        found.push(Found {
            kind: FlagKind::Elevation,
            part: Some(*part),
            cells: b,
            score,
            threshold: thr,
            message: format!(
                "part {part} stands above the new powder at x = {x0:.0}..{x1:.0} mm, y = {y0:.0}..{y1:.0} mm (super-elevation: {} spot over the previous layer)",
                if sign > 0.0 { "bright" } else { "shadowed" }
            ),
        });
    }
    (found, means)
}

/// What the post-scan view says about fusion.
pub struct Fusion {
    pub found: Vec<Found>,
    pub parts: Vec<PartMetrics>,
    pub texture_median: f64,
    pub fused_mm2: f64,
    pub spatter_mm2: f64,
}

/// Fusion against the vectors: a cell is fused when its texture exceeds `fused_texture_factor`
/// times the plate's median texture. Per part: area ratio and IoU within `fusion_tolerance_mm`
/// of its vectors, the unfused fraction of its core (under-fusion), the fused area beyond the
/// tolerance (over-fusion); away from every part, fused blobs (spatter, stray scans).
pub fn fusion(
    grid: &Grid,
    cells: &Cells,
    valid: &Mask,
    parts: &[(i64, Mask)],
    all: &Mask,
    cfg: &InspectionConfig,
) -> Fusion {
    let cell_mm2 = grid.pixel_mm * grid.pixel_mm;
    let texture_of = |range: std::ops::Range<usize>| {
        robust(
            valid.on[range.clone()]
                .iter()
                .zip(&cells.texture[range])
                .filter(|(on, _)| **on)
                .map(|(_, t)| f64::from(*t)),
            1e-3,
        )
        .0
    };
    let texture_median = texture_of(0..cells.texture.len());
    // The camera resolves the plate differently from near to far edge: the powder's texture is
    // judged per row of cells (parts fill only a little of a row).
    let mut fused = Mask::new(cells.rows, cells.cols);
    for r in 0..cells.rows {
        let range = r * cells.cols..(r + 1) * cells.cols;
        let row = texture_of(range.clone());
        let cut = cfg.fused_texture_factor * if row.is_finite() { row } else { texture_median };
        for i in range {
            fused.on[i] = valid.on[i] && f64::from(cells.texture[i]) > cut;
        }
    }
    let tol = cells_of(cfg.fusion_tolerance_mm, grid);
    let reach = tol + cells_of(3.0, grid).max(2);
    let near_any = all.dilate(tol);
    let mut found = Vec::new();
    let mut metrics = Vec::new();
    let (rows, cols) = (cells.rows, cells.cols);
    for (part, whole) in parts {
        let area = whole.count();
        let Some(part_box) = whole.bbox() else {
            continue;
        };
        // Everything about a part happens near it: work in a window around it.
        let window = part_box.expand(reach + 2, rows, cols);
        let v = &whole.crop(window);
        let fused = fused.crop(window);
        let near_any = near_any.crop(window);
        let in_window = |data: &[f32]| -> Vec<f32> {
            (window.r0..=window.r1)
                .flat_map(|r| {
                    data[r * cols + window.c0..=r * cols + window.c1]
                        .iter()
                        .copied()
                })
                .collect()
        };
        let (mean, texture) = (in_window(&cells.mean), in_window(&cells.texture));
        let zone = v.dilate(tol);
        let fused_in = fused.and(&zone).count();
        let inter = fused.and(v).count();
        let union = area + fused_in - inter;
        let core = v.erode(1);
        let unfused =
            (core.count() >= 8).then(|| core.minus(&fused).count() as f64 / core.count() as f64);
        let excess = fused.and(&v.dilate(reach)).minus(&near_any);
        let excess_mm2 = excess.count() as f64 * cell_mm2;
        let vector_mm2 = area as f64 * cell_mm2;
        let over = |f: fn(&f32) -> f64, data: &[f32]| {
            v.on.iter()
                .zip(data)
                .filter(|(on, _)| **on)
                .map(|(_, x)| f(x))
                .sum::<f64>()
                / area as f64
        };
        metrics.push(PartMetrics {
            part: *part,
            vector_mm2,
            fused_mm2: fused_in as f64 * cell_mm2,
            area_ratio: fused_in as f64 / area as f64,
            iou: inter as f64 / union.max(1) as f64,
            unfused,
            excess_mm2,
            post_mean: over(|x| f64::from(*x), &mean),
            post_contrast: over(|x| f64::from(*x), &texture),
            fused_fraction: inter as f64 / area as f64,
            pre_mean: None,
        });
        let b = part_box;
        let [x0, y0, x1, y1] = box_mm(grid, b);
        if let Some(u) = unfused.filter(|u| *u > cfg.max_unfused) {
            found.push(Found {
                kind: FlagKind::UnderFusion,
                part: Some(*part),
                cells: b,
                score: u,
                threshold: cfg.max_unfused,
                message: format!(
                    "part {part} at x = {x0:.0}..{x1:.0} mm, y = {y0:.0}..{y1:.0} mm is {}: {:.0}% of its area shows no fused metal",
                    if u > 0.9 { "not fused" } else { "partly fused" },
                    u * 100.0
                ),
            });
        }
        let allowed = cfg.max_excess.max(cfg.min_excess_mm2 / vector_mm2);
        let ratio = excess_mm2 / vector_mm2;
        if ratio > allowed {
            if let Some(eb) = excess.bbox().map(|b| b.within(window)) {
                let [ex0, ey0, ex1, ey1] = box_mm(grid, eb);
                found.push(Found {
                    kind: FlagKind::OverFusion,
                    part: Some(*part),
                    cells: eb,
                    score: ratio,
                    threshold: allowed,
                    message: format!(
                        "part {part} fused {excess_mm2:.0} mm² beyond its vectors ({:.0}% of its area) within x = {ex0:.0}..{ex1:.0} mm, y = {ey0:.0}..{ey1:.0} mm",
                        ratio * 100.0
                    ),
                });
            }
        }
    }
    let stray = fused.minus(&all.dilate(reach));
    let min_cells = (cfg.spatter_min_mm2 / cell_mm2).ceil().max(1.0) as usize;
    let mut spatter_mm2 = 0.0;
    for (n, b) in stray.blobs() {
        if n < min_cells {
            continue;
        }
        let mm2 = n as f64 * cell_mm2;
        spatter_mm2 += mm2;
        if found.iter().filter(|f| f.kind == FlagKind::Spatter).count() >= 20 {
            continue;
        }
        let [x0, y0, x1, y1] = box_mm(grid, b);
        found.push(Found {
            kind: FlagKind::Spatter,
            part: None,
            cells: b,
            score: mm2,
            threshold: cfg.spatter_min_mm2,
            message: format!(
                "fused spot of {mm2:.1} mm² away from every part at x = {:.1}, y = {:.1} mm (spatter or a stray scan)",
                (x0 + x1) / 2.0,
                (y0 + y1) / 2.0
            ),
        });
    }
    Fusion {
        found,
        parts: metrics,
        texture_median,
        fused_mm2: fused.count() as f64 * cell_mm2,
        spatter_mm2,
    }
}
