//! The rectified (top-down) grid of docs/frames.md, in build-plate millimetres: one type for the
//! rectifier, the rasterizer, the distance fields, the series and the configuration.

/// Half the side of the build plate in mm: the plate spans −137.5..137.5 in x and y.
pub const PLATE_HALF_MM: f64 = 137.5;
/// Default pixel size in mm (the camera's resolution at the plate center).
pub const DEFAULT_PIXEL_MM: f64 = 0.0625;
/// Largest grid side accepted, in pixels: guards allocations against absurd bounding boxes.
pub const MAX_SIDE: usize = 1 << 17;
/// Largest grid accepted, in pixels (4 GiB of u8 would not be an image anyone wants).
pub const MAX_PIXELS: usize = 1 << 31;

/// Resampling kernel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interpolation {
    #[default]
    /// 2x2 bilinear, exact fixed point with 11-bit position fractions.
    Bilinear,
    /// 4x4 Keys cubic convolution with A = −0.75 (OpenCV's INTER_CUBIC),
    /// rounded and clamped to the sample range.
    Bicubic,
}

/// A grid that describes no raster that can be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct GridError(pub String);

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
            x_min: -PLATE_HALF_MM,
            x_max: PLATE_HALF_MM,
            y_min: -PLATE_HALF_MM,
            y_max: PLATE_HALF_MM,
            pixel_mm: DEFAULT_PIXEL_MM,
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

    /// The `px` x `px` grid on this grid's lattice whose centre pixel holds `center` (build mm):
    /// a patch or crop of the same pixels (docs/frames.md).
    pub fn patch_around(&self, center: [f64; 2], px: usize) -> Grid {
        let p = self.pixel_mm;
        let (r, c) = self.pixel_of(center[0], center[1]);
        let half = (px / 2) as f64;
        let x_min = self.x_min + (c.round() - half) * p;
        let y_max = self.y_max - (r.round() - half) * p;
        Grid {
            x_min,
            x_max: x_min + px as f64 * p,
            y_min: y_max - px as f64 * p,
            y_max,
            pixel_mm: p,
        }
    }

    /// Checks that the grid is finite, non-empty and of a size that can be allocated: at most
    /// [`MAX_SIDE`] pixels a side and [`MAX_PIXELS`] in all. Every user of a grid (rectifier,
    /// rasterizer, distance fields, configuration) runs this one check.
    pub fn validate(&self) -> Result<(), GridError> {
        let all = [
            self.x_min,
            self.x_max,
            self.y_min,
            self.y_max,
            self.pixel_mm,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(GridError(format!("non-finite value in {self:?}")));
        }
        if self.pixel_mm <= 0.0 {
            return Err(GridError(format!(
                "pixel_mm must be > 0, got {}",
                self.pixel_mm
            )));
        }
        if self.x_max <= self.x_min || self.y_max <= self.y_min {
            return Err(GridError(format!(
                "empty extent: x {}..{}, y {}..{}",
                self.x_min, self.x_max, self.y_min, self.y_max
            )));
        }
        let (w, h) = (
            (self.x_max - self.x_min) / self.pixel_mm,
            (self.y_max - self.y_min) / self.pixel_mm,
        );
        if !(0.5..=MAX_SIDE as f64).contains(&w) || !(0.5..=MAX_SIDE as f64).contains(&h) {
            return Err(GridError(format!(
                "grid would be {w:.1} x {h:.1} pixels; each side must be 1..={MAX_SIDE}"
            )));
        }
        let (cols, rows) = (self.columns(), self.rows());
        if cols == 0 || rows == 0 {
            return Err(GridError(format!("empty grid: {self:?}")));
        }
        if cols.saturating_mul(rows) > MAX_PIXELS {
            return Err(GridError(format!(
                "{cols} x {rows} pixels is too large (at most {MAX_SIDE} a side, {MAX_PIXELS} in all)"
            )));
        }
        Ok(())
    }

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

    /// The smallest grid on this grid's pixel lattice that covers `bbox` ([x_min, y_min, x_max,
    /// y_max] mm) plus `margin_mm`, clipped to this grid. Pixels keep their centers, so a crop's
    /// pixel is exactly a pixel of the full view.
    pub fn around(&self, bbox: [f64; 4], margin_mm: f64) -> Grid {
        let p = self.pixel_mm;
        // The tolerance keeps an edge already on the lattice from moving a whole pixel because of
        // rounding in the division.
        let eps = 1e-9;
        let snap_down = |v: f64, origin: f64| origin + ((v - origin) / p + eps).floor() * p;
        let snap_up = |v: f64, origin: f64| origin + ((v - origin) / p - eps).ceil() * p;
        let x_min = snap_down(bbox[0] - margin_mm, self.x_min).max(self.x_min);
        let x_max = snap_up(bbox[2] + margin_mm, self.x_min).min(self.x_max);
        let y_min = snap_down(bbox[1] - margin_mm, self.y_max).max(self.y_min);
        let y_max = snap_up(bbox[3] + margin_mm, self.y_max).min(self.y_max);
        Grid {
            x_min,
            x_max: x_max.max(x_min + p),
            y_min,
            y_max: y_max.max(y_min + p),
            pixel_mm: p,
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_keep_pixel_centers_on_the_plate_lattice() {
        let plate = Grid::plate();
        let crop = plate.around([-65.03, 34.97, -39.98, 45.01], 2.0);
        for v in [crop.x_min - plate.x_min, plate.y_max - crop.y_max] {
            let steps = v / plate.pixel_mm;
            assert!((steps - steps.round()).abs() < 1e-9, "{crop:?}");
        }
        assert!(
            crop.x_min <= -67.03
                && crop.x_max >= -37.98
                && crop.y_min <= 32.97
                && crop.y_max >= 47.01
        );
        assert!(crop.x_min > -67.03 - plate.pixel_mm && crop.y_max < 47.01 + plate.pixel_mm);
        let (r, c) = crop.pixel_of(-60.0, 40.0);
        let (x, y) = crop.center_of(r.round(), c.round());
        let (pr, pc) = plate.pixel_of(x, y);
        assert!((pr - pr.round()).abs() < 1e-9 && (pc - pc.round()).abs() < 1e-9);
        let clipped = plate.around([100.0, 100.0, 200.0, 200.0], 5.0);
        assert_eq!((clipped.x_max, clipped.y_max), (137.5, 137.5));
    }
}
