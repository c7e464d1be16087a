//! The exemplar of paper §3.1, from the raster module: the layer's fused area (hatches and open
//! polylines stroked a melt track wide) with its ones replaced by white noise, then the same
//! local standard deviation filter as the build images.

use crate::geometry::Grid;
pub use crate::raster::F32Image;
use crate::raster::{self, RasterError, RasterOptions};
use crate::vectors::Layer;

/// Spot width of hatches and open polylines in mm (a typical melt track).
pub const SPOT_WIDTH_MM: f64 = 0.1;
/// Default standard deviation window, pixels.
pub const DEFAULT_STD_WINDOW: usize = 11;
/// Default seed of the exemplar's white noise.
pub const DEFAULT_SEED: u64 = 0x5EED;

/// Bounding box `[x_min, y_min, x_max, y_max]` in mm of a layer's geometry; `None` without any.
pub fn layer_bbox(layer: &Layer) -> Option<[f64; 4]> {
    raster::layer_bbox(layer, None)
}

fn options() -> RasterOptions {
    RasterOptions {
        hatch_width_mm: SPOT_WIDTH_MM,
        ..RasterOptions::default()
    }
}

/// The exemplar of `layer` on `grid`: mask ones → white noise, zeros → 0, then the std filter.
/// Errors when the grid cannot be rasterized (too large, invalid) or the window is unusable:
/// the cause is reported as it is, not as an empty exemplar.
pub fn exemplar(
    layer: &Layer,
    grid: &Grid,
    window: usize,
    seed: u64,
) -> Result<F32Image, RasterError> {
    raster::exemplar(layer, grid, &options(), window, seed)
}
