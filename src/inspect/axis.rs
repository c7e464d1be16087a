//! The recoater axis, found from the build's own frames: the blade drags grains, scratches and
//! marks along its travel, so the fresh powder's thin structure runs along one axis and the
//! profile of line means across that axis is rougher than across the other. Each layer adds its
//! evidence (the log of the ratio of the two roughnesses, bounded, faded out near zero); the
//! streaks found add their own vote, by how much of their length runs along each axis. The axis is
//! decided once the sum reaches ±`DECIDE` after `MIN_LAYERS` layers, and kept.
//!
//! Every step is continuous in the frames' grey levels: a statistic at a tenth of a grey level
//! moves by a few hundredths between two JPEG decoders (one grey level in a few pixels per
//! thousand), so a hard cut on a layer's evidence would let the decoder decide the axis.

use super::mask::Mask;
use super::stats::{median, Lines};
use super::streak::segments;
use crate::build_dir::inspection::AxisRecord;
use crate::config::inspection::{Axis, RecoatAxis};

/// Evidence at which the axis is decided (each layer's texture adds at most 1 in size, its
/// streaks at most 1 more).
pub const DECIDE: f64 = 2.0;
/// A layer's evidence smaller than this counts as none ...
const DEAD_ZONE: f64 = 0.2;
/// ... and from there it counts more and more, fully from this size on.
const FULL: f64 = 0.3;
/// Layers seen before a decision.
const MIN_LAYERS: usize = 3;

/// Robust roughness of the line profiles of `values` along `axis`: the MAD-sigma of the
/// residuals of every segment's profile, per cell (× √ of the segment's length, so profiles of
/// lines of different lengths compare).
fn roughness(values: &[f32], bed: &Mask, axis: Axis, seg_cells: usize) -> f64 {
    let lines = Lines::new(bed.rows, bed.cols, axis);
    let mut r: Vec<f64> = segments(values, bed, &lines, seg_cells, 7)
        .into_iter()
        .flat_map(|s| {
            let scale = ((s.to - s.from) as f64).sqrt();
            s.residual.into_iter().map(move |v| v.abs() * scale)
        })
        .filter(|v| v.is_finite())
        .collect();
    if r.len() < 16 {
        return f64::NAN;
    }
    1.4826 * median(&mut r)
}

/// One layer's evidence: positive when lines run along y (the image's columns), in [-1, 1];
/// 0 when the view cannot tell. The profiles run the bed's whole length, where the grain's noise
/// is smallest against marks that run along it.
pub fn layer_evidence(values: &[f32], bed: &Mask, cell_noise: f64) -> f64 {
    let Some(b) = bed.bbox() else {
        return 0.0;
    };
    let length = (b.r1 - b.r0 + 1).max(b.c1 - b.c0 + 1);
    let along_y = roughness(values, bed, Axis::Y, length);
    let along_x = roughness(values, bed, Axis::X, length);
    if !(along_y.is_finite() && along_x.is_finite()) {
        return 0.0;
    }
    // A floor of a tenth of the cell noise: two profiles both at the rounding level tell nothing.
    let floor = 0.1 * cell_noise.max(1e-3);
    ((along_y + floor) / (along_x + floor))
        .ln()
        .clamp(-1.0, 1.0)
}

/// A layer's evidence with the little it says faded out: a layer whose marks barely lean one way
/// tells nothing (the grain's own texture, or the resampling of an oblique view, can lean a
/// little, the same way every layer: up to 0.24 on the mock camera's oblique views, which have no
/// recoating marks at all); between `DEAD_ZONE` and `FULL` it counts in proportion, so a small
/// change in the frames makes a small change in the sum.
fn faded(evidence: f64) -> f64 {
    let weight = ((evidence.abs() - DEAD_ZONE) / (FULL - DEAD_ZONE)).clamp(0.0, 1.0);
    evidence * weight
}

/// The streaks' vote, in [-1, 1]: positive when more of their length runs along y. A blade's
/// scratch and a grain it drags run along its travel, the most direct mark of the axis there is,
/// so the vote counts on every layer (the texture can lean across the travel on the same layer:
/// chatter and uneven spreading leave bands across it).
fn streak_vote(along_x: f64, along_y: f64) -> f64 {
    let total = along_x + along_y;
    if total > 0.0 {
        (along_y - along_x) / total
    } else {
        0.0
    }
}

/// The axis as configured and as the frames say.
#[derive(Clone, Debug)]
pub struct AxisFinder {
    configured: RecoatAxis,
    evidence: f64,
    layers: usize,
    found: Option<Axis>,
}

/// What changed on a layer, for its record's notes.
#[derive(Clone, Debug, PartialEq)]
pub enum AxisNews {
    Found(Axis),
    Disagrees { configured: Axis, frames: Axis },
}

impl AxisFinder {
    pub fn new(configured: RecoatAxis) -> AxisFinder {
        AxisFinder {
            configured,
            evidence: 0.0,
            layers: 0,
            found: None,
        }
    }

    /// The axes the plate-wide checks search now: the configured one, the found one, or both
    /// while the frames have not told.
    pub fn axes(&self) -> Vec<Axis> {
        match (self.configured.fixed(), self.found) {
            (Some(a), _) | (None, Some(a)) => vec![a],
            (None, None) => vec![Axis::X, Axis::Y],
        }
    }

    /// Adds a layer's evidence and the vote of its streaks (`along_x`, `along_y`: their summed
    /// lengths along each axis, in cells); returns what a log should say about it.
    pub fn push(&mut self, evidence: f64, along_x: f64, along_y: f64) -> Option<AxisNews> {
        self.layers += 1;
        let evidence = faded(evidence) + streak_vote(along_x, along_y);
        if self.found.is_none() {
            self.evidence += evidence;
            if self.layers >= MIN_LAYERS && self.evidence.abs() >= DECIDE {
                let axis = if self.evidence > 0.0 {
                    Axis::Y
                } else {
                    Axis::X
                };
                self.found = Some(axis);
                return Some(match self.configured.fixed() {
                    Some(c) if c != axis => AxisNews::Disagrees {
                        configured: c,
                        frames: axis,
                    },
                    _ => AxisNews::Found(axis),
                });
            }
        }
        None
    }

    /// Takes up an axis found before a restart (`x` or `y`).
    pub fn resume(&mut self, axis: &str) {
        self.found = match axis {
            "x" => Some(Axis::X),
            "y" => Some(Axis::Y),
            _ => self.found,
        };
        if let Some(a) = self.found {
            self.evidence = if a == Axis::Y { DECIDE } else { -DECIDE };
        }
    }

    pub fn record(&self) -> AxisRecord {
        let axes = self.axes();
        AxisRecord {
            axis: match axes.as_slice() {
                [a] => a.to_string(),
                _ => "both".into(),
            },
            source: match (self.configured.fixed(), self.found) {
                (Some(_), _) => "configured",
                (None, Some(_)) => "found",
                (None, None) => "undetermined",
            }
            .into(),
            evidence: self.evidence,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_along_y_are_found_and_a_configured_x_is_warned_about() {
        let (rows, cols) = (120, 100);
        let values: Vec<f32> = (0..rows * cols)
            .map(|i| {
                let (r, c) = (i / cols, i % cols);
                let grain = ((i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 60) as f32 * 0.3;
                let marks = if c % 9 == 0 { 4.0 } else { 0.0 };
                100.0 + grain + marks + 0.01 * r as f32
            })
            .collect();
        let bed = Mask {
            rows,
            cols,
            on: vec![true; rows * cols],
        };
        let e = layer_evidence(&values, &bed, 1.0);
        assert!(e > 0.3, "{e}");
        let mut auto = AxisFinder::new(RecoatAxis::Auto);
        assert_eq!(auto.axes(), vec![Axis::X, Axis::Y]);
        assert_eq!(auto.push(e, 0.0, 0.0), None, "not before 3 layers");
        assert_eq!(auto.push(e, 0.0, 0.0), None);
        let news = (0..20).find_map(|_| auto.push(e, 0.0, 0.0));
        assert_eq!(news, Some(AxisNews::Found(Axis::Y)));
        assert_eq!(auto.axes(), vec![Axis::Y]);
        assert_eq!(auto.record().source, "found");
        let mut set = AxisFinder::new(RecoatAxis::X);
        let news = (0..20).find_map(|_| set.push(e, 0.0, 0.0));
        assert_eq!(
            news,
            Some(AxisNews::Disagrees {
                configured: Axis::X,
                frames: Axis::Y
            })
        );
        assert_eq!(set.axes(), vec![Axis::X], "the configured axis is honoured");
    }

    /// A small change in a layer's evidence makes a small change in the sum (no cut a decoder's
    /// rounding can tip), and streaks vote by their length along each axis, on every layer.
    #[test]
    fn the_sum_moves_smoothly_and_streaks_vote_by_length() {
        let mut last = 0.0;
        for i in 0..=400 {
            let e = i as f64 * 0.001;
            let f = faded(e);
            assert!(f >= last && f - last <= 0.0041, "{e}: {last} -> {f}");
            assert_eq!(faded(-e), -f);
            last = f;
        }
        assert_eq!(faded(0.19), 0.0);
        assert_eq!(faded(0.3), 0.3);
        assert_eq!(streak_vote(0.0, 0.0), 0.0);
        assert_eq!(streak_vote(0.0, 12.0), 1.0);
        assert_eq!(streak_vote(30.0, 10.0), -0.5);
        // Texture leaning across the travel does not outvote the scratches along it.
        let mut finder = AxisFinder::new(RecoatAxis::Auto);
        let news = (0..10).find_map(|_| finder.push(-0.4, 5.0, 40.0));
        assert_eq!(news, Some(AxisNews::Found(Axis::Y)));
    }
}
