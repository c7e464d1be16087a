//! Unit tests of the registration glue (the accuracy tests are in tests/it/registration/).

use super::pipeline::{grid_around, plate_grid, round_sig};
use super::*;
use crate::vectors::{Direction, Polyline};

#[test]
fn grid_around_covers_the_box_with_whole_pixels() {
    let g = grid_around([-3.0, 1.0, 7.0, 4.5], 2.0, 0.3).expect("small");
    assert!(g.x_min <= -5.0 && g.x_max >= 9.0 && g.y_min <= -1.0 && g.y_max >= 6.5);
    let cols = (g.x_max - g.x_min) / g.pixel_mm;
    assert!((cols - cols.round()).abs() < 1e-9);
    assert_eq!(g.columns() as f64, cols.round());
    assert!(grid_around([0.0, 0.0, 1e4, 1.0], 0.0, 0.01).is_err());
}

#[test]
fn plate_grid_uses_the_center_resolution() {
    // 0.2 mm per pixel, image center at build (0, 0).
    let h = Homography::from_matrix([[0.2, 0.0, -100.0], [0.0, -0.2, 80.0], [0.0, 0.0, 1.0]]);
    let g = plate_grid(&h).expect("regular");
    assert_eq!((g.x_min, g.x_max), (-137.5, 137.5));
    assert!((g.pixel_mm - 0.2).abs() < 1e-3, "{g:?}");
    assert_eq!(g.columns(), 1375);
}

#[test]
fn round_sig_keeps_significant_digits() {
    assert_eq!(round_sig(0.062_468_3, 4), 0.062_47);
    assert_eq!(round_sig(0.0, 4), 0.0);
}

/// A grid the raster refuses reaches the caller as that raster error, not as "no fused area".
#[test]
fn an_unrenderable_exemplar_reports_the_raster_error() {
    let mut layer = Layer::new(0, 0.03);
    layer.polylines.push(Polyline {
        part: 1,
        direction: Direction::CounterClockwise,
        points: vec![
            [0.0, 0.0],
            [10.0, 0.0],
            [10.0, 10.0],
            [0.0, 10.0],
            [0.0, 0.0],
        ],
    });
    let huge = Grid {
        x_min: -1000.0,
        x_max: 1000.0,
        y_min: -1000.0,
        y_max: 1000.0,
        pixel_mm: 0.001,
    };
    let err = render_exemplar(&layer, &huge, 11, 2, 1).unwrap_err();
    assert!(matches!(err, RegistrationError::Raster(_)), "{err}");
    assert!(err.to_string().contains("exemplar"), "{err}");
    let ok = Grid {
        x_min: -5.0,
        x_max: 15.0,
        y_min: -5.0,
        y_max: 15.0,
        pixel_mm: 0.5,
    };
    let (ex, extent) = render_exemplar(&layer, &ok, 11, 2, 1).expect("renders");
    assert_eq!((ex.width, ex.height), (40, 40));
    assert!(ex.data.iter().any(|&v| v > 0.0) && extent > 0.0);
}
