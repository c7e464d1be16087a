//! What to draw and how: the fill rule and the options of every rasterisation.

/// Default hatch spot width in mm: a typical LPBF melt track.
pub const DEFAULT_SPOT_WIDTH_MM: f64 = 0.1;

/// How contours make an inside.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FillRule {
    /// Inside where the winding number of the contours (by their point order) is not zero:
    /// clockwise inner contours cut holes into counter-clockwise outer ones, overlapping
    /// outer contours stay filled.
    #[default]
    NonZero,
    /// Inside where a ray crosses an odd number of contour edges, whatever the orientation.
    EvenOdd,
}

/// What to draw and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RasterOptions {
    /// Only the geometry of this part id; `None` for all parts.
    pub part: Option<i64>,
    pub fill_rule: FillRule,
    /// Spot width in mm for hatches and open polylines: a pixel (sub-sample) is fused when its
    /// center is within half of it from a segment. 0 leaves hatches out.
    pub hatch_width_mm: f64,
    /// Width in mm with which contours are stroked in addition to being filled; 0 (default)
    /// leaves the fill bounded by the contour path itself.
    pub contour_width_mm: f64,
    /// Also fill direction-2 polylines whose ends meet (support outlines in Magics files).
    pub fill_closed_open: bool,
    /// Sub-samples per pixel side for [`coverage`](super::coverage) (1..=16; 4 gives 16 samples
    /// per pixel).
    pub subsamples: usize,
}

impl Default for RasterOptions {
    fn default() -> Self {
        RasterOptions {
            part: None,
            fill_rule: FillRule::NonZero,
            hatch_width_mm: DEFAULT_SPOT_WIDTH_MM,
            contour_width_mm: 0.0,
            fill_closed_open: false,
            subsamples: 4,
        }
    }
}
