//! The rectified (top-down) output grid, in build-plate millimetres.

use super::RectifyError;

/// Largest accepted grid side, in pixels. Far above any real plate view; it
/// keeps row/column indices and buffer sizes comfortably in range.
const MAX_SIDE: usize = 1 << 17;

/// A top-down raster over the build plate.
///
/// Pixel (row r, column c) has its center at
/// `x = x_min + (c + 0.5)·pixel_mm`, `y = y_max − (r + 0.5)·pixel_mm`:
/// x grows to the right, y grows upwards (row 0 is the far, +y edge).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grid {
    pub x_min: f64,
    pub x_max: f64,
    pub y_min: f64,
    pub y_max: f64,
    pub pixel_mm: f64,
}

impl Default for Grid {
    fn default() -> Self {
        Grid::plate()
    }
}

impl Grid {
    /// The whole 275 x 275 mm plate at 0.0625 mm/px: 4400 x 4400 pixels.
    pub fn plate() -> Grid {
        Grid {
            x_min: -137.5,
            x_max: 137.5,
            y_min: -137.5,
            y_max: 137.5,
            pixel_mm: 0.0625,
        }
    }

    /// Number of columns: `((x_max − x_min) / pixel_mm).round()`.
    pub fn columns(&self) -> usize {
        side(self.x_max - self.x_min, self.pixel_mm)
    }

    /// Number of rows: `((y_max − y_min) / pixel_mm).round()`.
    pub fn rows(&self) -> usize {
        side(self.y_max - self.y_min, self.pixel_mm)
    }

    /// Build coordinates (x, y) in mm of the point at fractional pixel
    /// position (row, col); integer positions are pixel centers.
    pub fn center_of(&self, row: f64, col: f64) -> (f64, f64) {
        (
            self.x_min + (col + 0.5) * self.pixel_mm,
            self.y_max - (row + 0.5) * self.pixel_mm,
        )
    }

    /// Inverse of [`Grid::center_of`]: fractional (row, col) of build point (x, y).
    pub fn pixel_of(&self, x: f64, y: f64) -> (f64, f64) {
        (
            (self.y_max - y) / self.pixel_mm - 0.5,
            (x - self.x_min) / self.pixel_mm - 0.5,
        )
    }

    /// Checks that the grid describes a non-empty raster of sane size.
    pub(crate) fn validate(&self) -> Result<(), RectifyError> {
        let all = [
            self.x_min,
            self.x_max,
            self.y_min,
            self.y_max,
            self.pixel_mm,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(RectifyError::InvalidGrid(format!(
                "non-finite value in {self:?}"
            )));
        }
        if self.pixel_mm <= 0.0 {
            return Err(RectifyError::InvalidGrid(format!(
                "pixel_mm must be > 0, got {}",
                self.pixel_mm
            )));
        }
        if self.x_max <= self.x_min || self.y_max <= self.y_min {
            return Err(RectifyError::InvalidGrid(format!(
                "empty extent: x {}..{}, y {}..{}",
                self.x_min, self.x_max, self.y_min, self.y_max
            )));
        }
        let (w, h) = (
            (self.x_max - self.x_min) / self.pixel_mm,
            (self.y_max - self.y_min) / self.pixel_mm,
        );
        if !(0.5..=MAX_SIDE as f64).contains(&w) || !(0.5..=MAX_SIDE as f64).contains(&h) {
            return Err(RectifyError::InvalidGrid(format!(
                "grid would be {w:.1} x {h:.1} pixels; each side must be 1..={MAX_SIDE}"
            )));
        }
        Ok(())
    }
}

fn side(extent: f64, pixel_mm: f64) -> usize {
    let n = (extent / pixel_mm).round();
    // Saturating cast: garbage grids give 0 (or a huge value that
    // `validate` rejects before any buffer is sized from it).
    if n.is_finite() && n > 0.0 {
        n as usize
    } else {
        0
    }
}
