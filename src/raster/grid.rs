//! The rectified grid of docs/frames.md is [`crate::rectify::Grid`]; here are the limits and
//! constructors rasterizing needs.

use super::RasterError;
pub use crate::rectify::Grid;

/// Half the side of the build plate in mm: the plate spans −137.5..137.5 in x and y.
pub const PLATE_HALF_MM: f64 = 137.5;
/// Default pixel size in mm (the camera's resolution at the plate center).
pub const DEFAULT_PIXEL_MM: f64 = 0.0625;
/// Largest grid side accepted, in pixels: guards allocations against absurd bounding boxes.
pub const MAX_SIDE: usize = 1 << 17;
/// Largest grid accepted, in pixels (4 GiB of u8 would not be an image anyone wants).
pub const MAX_PIXELS: usize = 1 << 31;

impl Grid {
    /// The smallest grid covering `bbox` = [x_min, y_min, x_max, y_max] grown by `margin_mm`, on
    /// the plate's lattice at `pixel_mm`: its pixel centers coincide with those of the whole
    /// plate at that pixel size, so crops of different parts compare pixel for pixel.
    pub fn on_plate_lattice(bbox: [f64; 4], margin_mm: f64, pixel_mm: f64) -> Grid {
        Grid {
            pixel_mm,
            ..Grid::plate()
        }
        .around(bbox, margin_mm)
    }

    /// Checks that the grid is finite, non-empty and of a size that can be allocated.
    pub fn check_raster(&self) -> Result<(), RasterError> {
        let all = [
            self.x_min,
            self.x_max,
            self.y_min,
            self.y_max,
            self.pixel_mm,
        ];
        if all.iter().any(|v| !v.is_finite()) || self.pixel_mm <= 0.0 {
            return Err(RasterError::InvalidGrid(format!(
                "non-finite bounds or non-positive pixel size: {self:?}"
            )));
        }
        let (w, h) = (self.columns(), self.rows());
        if w == 0 || h == 0 {
            return Err(RasterError::InvalidGrid(format!("empty grid: {self:?}")));
        }
        if w > MAX_SIDE || h > MAX_SIDE || w.saturating_mul(h) > MAX_PIXELS {
            return Err(RasterError::InvalidGrid(format!(
                "{w} x {h} pixels is too large (at most {MAX_SIDE} a side, {MAX_PIXELS} in all)"
            )));
        }
        Ok(())
    }
}
