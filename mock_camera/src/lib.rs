//! Mock camera for layerwise: renders synthetic powder-bed images of the 275 x 275 mm plate
//! through a known image → build homography (ground truth for calibration tests), and fails on
//! schedule (busy, disconnect, slow, hang, permanent failure) so capture code can be tested
//! without a Nikon on the bench.
//!
//! Frames follow docs/frames.md: build x, y in mm centered on the plate; image (u, v) =
//! (column, row) with pixel centers at integers; H maps (u, v, 1) to (x, y, 1) with H[2][2] = 1.
//! Plain types only: this crate does not depend on `layerwise`.

mod camera;
mod homography;
pub mod nef;
mod render;
mod shape;

pub use camera::{Fault, FaultSchedule, MockCamera, MockError, ShotKey};
pub use homography::Homography;
pub use render::{Defect, Illumination, Renderer, Scene};
pub use shape::{demo_parts, Shape, DEMO_LAYER_THICKNESS_MM, DEMO_WALL_PERIOD_LAYERS};
