//! Recoater streaks: thin lines along the recoating axis in the fresh powder.

use super::mask::Mask;
use super::stats::{along_text, box_mm, cells_of, median, robust, Found, Lines};
use crate::build_dir::inspection::FlagKind;
use crate::config::inspection::{Axis, InspectionConfig};
use crate::geometry::Grid;

/// Lines of one segment above the threshold (a streak candidate).
struct Run {
    segment: usize,
    first: usize,
    last: usize,
    score: f64,
    sign: f64,
    /// Positions along the lines the segment covers.
    from: usize,
    to: usize,
}

/// The line profiles of one segment along the recoating axis: per line, the mean of `values`
/// over the segment's cells in `valid` less the running median of its neighbours, weighed by the
/// square root of its cell count (a line with fewer cells, a part's footprint left out, has a
/// noisier mean; so one scale fits all lines). NaN for a line with fewer than half its cells.
pub(crate) struct Segment {
    pub from: usize,
    pub to: usize,
    pub residual: Vec<f64>,
}

/// The segments (about `seg_cells` long) of `lines` and their residual profiles.
pub(crate) fn segments(
    values: &[f32],
    valid: &Mask,
    lines: &Lines,
    seg_cells: usize,
    half: usize,
) -> Vec<Segment> {
    let nseg = ((lines.along as f64 / seg_cells.max(1) as f64).round() as usize).max(1);
    (0..nseg)
        .map(|s| {
            let (p0, p1) = (s * lines.along / nseg, (s + 1) * lines.along / nseg);
            let mut counts = vec![0usize; lines.lines];
            let profile: Vec<f64> = (0..lines.lines)
                .map(|l| {
                    let (mut sum, mut n) = (0f64, 0usize);
                    for p in p0..p1 {
                        let i = lines.index(l, p);
                        if valid.on[i] {
                            sum += f64::from(values[i]);
                            n += 1;
                        }
                    }
                    counts[l] = n;
                    if n >= 3 && 2 * n >= p1 - p0 {
                        sum / n as f64
                    } else {
                        f64::NAN
                    }
                })
                .collect();
            let mut n: Vec<f64> = counts.iter().map(|&c| c as f64).collect();
            let n_ref = median(&mut n).max(1.0);
            let residual = (0..lines.lines)
                .map(|l| {
                    // A window centred on the line (shrinking toward the ends, so a slope in
                    // the lighting does not bias it); lines too near an end are not judged.
                    let h = half.min(l).min(lines.lines - 1 - l);
                    if !profile[l].is_finite() || h < 3 {
                        return f64::NAN;
                    }
                    let mut window: Vec<f64> = profile[l - h..l + h + 1]
                        .iter()
                        .copied()
                        .filter(|v| v.is_finite())
                        .collect();
                    (profile[l] - median(&mut window)) * (counts[l] as f64 / n_ref).sqrt()
                })
                .collect();
            Segment {
                from: p0,
                to: p1,
                residual,
            }
        })
        .collect()
}

/// Recoater streaks along `axis`: in segments along it, the profile of line means of `values`
/// (the flattened view, or its ratio to the bed's reference, in grey levels) across it, less its
/// running median, in robust z. Runs of lines above the threshold no wider than
/// `streak_max_width_mm` are streaks; runs in neighbouring segments on the same lines merge.
/// Returns the streaks and the largest |z| seen.
pub fn streaks(
    grid: &Grid,
    values: &[f32],
    valid: &Mask,
    axis: Axis,
    cfg: &InspectionConfig,
) -> (Vec<Found>, f64) {
    let lines = Lines::new(valid.rows, valid.cols, axis);
    let thr = cfg.streak_z;
    let seg_cells = cells_of(cfg.streak_segment_mm, grid).max(4);
    let max_width = cells_of(cfg.streak_max_width_mm, grid).max(1);
    let half = (3 * max_width).max(7);
    let mut best = 0f64;
    let mut runs: Vec<Run> = Vec::new();
    for (s, seg) in segments(values, valid, &lines, seg_cells, half)
        .into_iter()
        .enumerate()
    {
        let (p0, p1) = (seg.from, seg.to);
        let residual = seg.residual;
        let (m, sigma) = robust(residual.iter().copied(), 0.05);
        let z: Vec<f64> = residual.iter().map(|r| (r - m) / sigma).collect();
        let mut l = 0;
        while l < lines.lines {
            if z[l].is_nan() || z[l].abs() < thr {
                l += 1;
                continue;
            }
            let sign = z[l].signum();
            let (mut a, mut b) = (l, l);
            // Grow over the run's shoulders (same sign, half the threshold).
            while a > 0 && z[a - 1] * sign >= thr / 2.0 {
                a -= 1;
            }
            while b + 1 < lines.lines && z[b + 1] * sign >= thr / 2.0 {
                b += 1;
            }
            let score = z[a..=b].iter().map(|v| v * sign).fold(0.0, f64::max);
            if b - a < max_width {
                runs.push(Run {
                    segment: s,
                    first: a,
                    last: b,
                    score,
                    sign,
                    from: p0,
                    to: p1 - 1,
                });
            }
            l = b + 1;
        }
        best = best.max(
            z.iter()
                .filter(|v| v.is_finite())
                .fold(0.0, |a, v| a.max(v.abs())),
        );
    }
    // Merge runs on overlapping lines in neighbouring segments.
    runs.sort_by_key(|r| (r.first, r.segment));
    let mut merged: Vec<Run> = Vec::new();
    for r in runs {
        let joined = merged.iter_mut().find(|m| {
            m.sign == r.sign
                && r.first <= m.last + 1
                && m.first <= r.last + 1
                && (r.segment == m.segment + 1 || m.segment == r.segment + 1)
        });
        match joined {
            Some(m) => {
                m.segment = m.segment.max(r.segment);
                m.first = m.first.min(r.first);
                m.last = m.last.max(r.last);
                m.score = m.score.max(r.score);
                m.from = m.from.min(r.from);
                m.to = m.to.max(r.to);
            }
            None => merged.push(r),
        }
    }
    let found = merged
        .into_iter()
        .map(|r| {
            let cells = lines.cell_box(r.first, r.last, r.from, r.to);
            let mm = box_mm(grid, cells);
            let width = (r.last - r.first + 1) as f64 * grid.pixel_mm;
            Found {
                kind: FlagKind::Streak,
                part: None,
                cells,
                score: r.score,
                threshold: thr,
                message: format!(
                    "recoater streak {} ({width:.1} mm wide, {})",
                    along_text(axis, mm),
                    if r.sign > 0.0 { "brighter" } else { "darker" }
                ),
            }
        })
        .collect();
    (found, best)
}
