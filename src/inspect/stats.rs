//! What the detectors share: a finding, robust statistics, cell boxes in mm, and the lines along
//! the recoating axis.

use super::mask::CellBox;
use crate::build_dir::inspection::FlagKind;
use crate::config::inspection::Axis;
use crate::geometry::Grid;

/// One finding, in cells of the inspection grid.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    pub kind: FlagKind,
    pub part: Option<i64>,
    pub cells: CellBox,
    pub score: f64,
    pub threshold: f64,
    pub message: String,
}

/// MAD to standard deviation for normal noise.
const MAD_SIGMA: f64 = 1.4826;

pub(crate) fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    *m
}

/// Median and MAD-based sigma (at least `floor`) of the finite values.
pub(crate) fn robust(values: impl Iterator<Item = f64>, floor: f64) -> (f64, f64) {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    let m = median(&mut v);
    let mut dev: Vec<f64> = v.iter().map(|x| (x - m).abs()).collect();
    (m, (MAD_SIGMA * median(&mut dev)).max(floor))
}

/// Build mm `[x_min, y_min, x_max, y_max]` of a cell box.
pub fn box_mm(grid: &Grid, b: CellBox) -> [f64; 4] {
    let p = grid.pixel_mm;
    [
        grid.x_min + b.c0 as f64 * p,
        grid.y_max - (b.r1 + 1) as f64 * p,
        grid.x_min + (b.c1 + 1) as f64 * p,
        grid.y_max - b.r0 as f64 * p,
    ]
}

pub(crate) fn cells_of(mm: f64, grid: &Grid) -> usize {
    (mm / grid.pixel_mm).round().max(0.0) as usize
}

/// Lines and positions along them for the recoating axis: streaks run along it.
pub(crate) struct Lines {
    pub lines: usize,
    pub along: usize,
    pub cols: usize,
    pub axis: Axis,
}

impl Lines {
    pub fn new(rows: usize, cols: usize, axis: Axis) -> Lines {
        let (lines, along) = match axis {
            Axis::X => (rows, cols),
            Axis::Y => (cols, rows),
        };
        Lines {
            lines,
            along,
            cols,
            axis,
        }
    }
    pub fn index(&self, line: usize, pos: usize) -> usize {
        match self.axis {
            Axis::X => line * self.cols + pos,
            Axis::Y => pos * self.cols + line,
        }
    }
    pub fn cell_box(&self, l0: usize, l1: usize, p0: usize, p1: usize) -> CellBox {
        match self.axis {
            Axis::X => CellBox {
                r0: l0,
                r1: l1,
                c0: p0,
                c1: p1,
            },
            Axis::Y => CellBox {
                r0: p0,
                r1: p1,
                c0: l0,
                c1: l1,
            },
        }
    }
}

/// `x = a..b mm at y = c mm` for a line along the recoating axis.
pub(crate) fn along_text(axis: Axis, mm: [f64; 4]) -> String {
    let [x0, y0, x1, y1] = mm;
    match axis {
        Axis::X => format!(
            "across x = {x0:.0}..{x1:.0} mm at y = {:.1} mm",
            (y0 + y1) / 2.0
        ),
        Axis::Y => format!(
            "across y = {y0:.0}..{y1:.0} mm at x = {:.1} mm",
            (x0 + x1) / 2.0
        ),
    }
}
