//! `[rectify]`: the rectified grid of docs/frames.md (the type is [`crate::geometry::Grid`], its
//! defaults the whole plate); here its check as a section of the configuration.

use super::Invalid;
use crate::geometry::Grid;

/// Checks the section: a non-empty extent and a pixel size that gives a grid that can be made.
pub fn validate(grid: &Grid) -> Result<(), Invalid> {
    if !(grid.pixel_mm > 0.0 && grid.x_max > grid.x_min && grid.y_max > grid.y_min) {
        return Err(Invalid::new(
            "rectify",
            "needs x_min < x_max, y_min < y_max and pixel_mm > 0",
        ));
    }
    // A GridError is a message of ours with no cause: it leads, the hint follows.
    grid.validate()
        .map_err(|crate::geometry::GridError(problem)| {
            Invalid::new(
                "rectify",
                format!("{problem}: use a larger pixel_mm or a smaller extent"),
            )
        })
}
