//! The benchmarks' six views: their two sizes (D810 frames on the plate grid with `--bench`, or
//! a tenth of them on a 10x coarser grid for a quick check) and layer 1 of the demo plate
//! as each sees it in the mock camera.

use layerwise::rectify::Grid;
use layerwise::shot::{Light, Phase, View};

/// The frame size (w, h) and the rectified grid for a full (`--bench`) or a quick run.
pub fn bench_scale(full: bool) -> (u32, u32, Grid) {
    if full {
        (7360, 4912, Grid::plate())
    } else {
        (
            736,
            491,
            Grid {
                pixel_mm: 0.625,
                ..Grid::plate()
            },
        )
    }
}

/// Layer 1 of the demo plate as `view` sees it.
pub fn scene<'a>(parts: &'a [mock_camera::Shape], view: &View) -> mock_camera::Scene<'a> {
    mock_camera::Scene {
        layer: 1,
        fused: parts,
        scanned: view.phase == Phase::Post,
        illumination: match view.light {
            Light::Front => mock_camera::Illumination::Front,
            Light::Side => mock_camera::Illumination::Side,
            Light::Top => mock_camera::Illumination::Top,
        },
    }
}
