//! What phase 1's paths share (`positions.rs`, `positions/quad.rs`): a grid row's homogeneous
//! source positions, and the fixed-point position's split into pixel and weight.

use crate::geometry::mat3::Mat3;
use crate::rectify::kernel::{Job, FRAC_BITS, ONE};

/// Homogeneous source position along one grid row: `base + c·step`.
pub(crate) struct Line {
    pub(super) bx: f64,
    pub(super) by: f64,
    pub(super) bw: f64,
    pub(super) sx: f64,
    pub(super) sy: f64,
    pub(super) sw: f64,
}

impl Line {
    /// Grid row `row` under `m` (grid (col, row, 1) → homogeneous image position): along a row
    /// the position is affine in the column, one base per row plus c·step per pixel, no 3x3
    /// product.
    #[inline(always)]
    pub(crate) fn of_row(m: &Mat3, row: usize) -> Line {
        let r = row as f64;
        Line {
            bx: m[0][1] * r + m[0][2],
            by: m[1][1] * r + m[1][2],
            bw: m[2][1] * r + m[2][2],
            sx: m[0][0],
            sy: m[1][0],
            sw: m[2][0],
        }
    }

    /// Undistorted source position in pixels, and w.
    #[inline(always)]
    pub(super) fn at(&self, c: f64) -> (f64, f64, f64) {
        let w = self.bw + c * self.sw;
        ((self.bx + c * self.sx) / w, (self.by + c * self.sy) / w, w)
    }

    /// Source position in fixed-point units plus ½ (so `floor` rounds), and w.
    #[inline(always)]
    pub(crate) fn scaled(&self, c: f64) -> (f64, f64, f64) {
        let w = self.bw + c * self.sw;
        let rw = ONE as f64 / w;
        (
            (self.bx + c * self.sx) * rw + 0.5,
            (self.by + c * self.sy) * rw + 0.5,
            w,
        )
    }
}

/// Fixed-point position → (ix, iy, fx, fy), `ix = −1` when outside.
///
/// Inside iff the rounded position lies in [0, W−1] x [0, H−1]. On the last
/// column/row the pixel steps back by one with full weight on the far
/// neighbour, so the 2x2 block stays in the image.
#[inline(always)]
pub(super) fn finish<T>(job: &Job<'_, T>, xq: i32, yq: i32, ok: bool) -> (i32, i32, i32, i32) {
    // Unsigned compare tests 0 ≤ q ≤ max in one go.
    let ok = ok & ((xq as u32) <= job.xmax_q as u32) & ((yq as u32) <= job.ymax_q as u32);
    let xi = (xq >> FRAC_BITS).min(job.wm2);
    let yi = (yq >> FRAC_BITS).min(job.hm2);
    (
        if ok { xi } else { -1 },
        yi,
        xq - (xi << FRAC_BITS),
        yq - (yi << FRAC_BITS),
    )
}
