//! Unit tests of the registration glue (the accuracy tests are in tests/registration.rs).

use super::*;

#[test]
fn grid_matrix_follows_the_frame_contract() {
    let grid = Grid {
        x_min: -10.0,
        x_max: 10.0,
        y_min: -5.0,
        y_max: 5.0,
        pixel_mm: 0.5,
    };
    let g = grid_matrix(&grid);
    for (r, c) in [(0.0, 0.0), (3.0, 7.0), (19.0, 39.0)] {
        let (x, y) = project(&g, c, r).expect("affine");
        let (ex, ey) = grid.center_of(r, c);
        assert!((x - ex).abs() < 1e-12 && (y - ey).abs() < 1e-12);
    }
}

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
    let h = [[0.2, 0.0, -100.0], [0.0, -0.2, 80.0], [0.0, 0.0, 1.0]];
    let g = plate_grid(&h).expect("regular");
    assert_eq!((g.x_min, g.x_max), (-137.5, 137.5));
    assert!((g.pixel_mm - 0.2).abs() < 1e-3, "{g:?}");
    assert_eq!(g.columns(), 1375);
}

#[test]
fn matrix_helpers() {
    let m = [[2.0, 0.1, 3.0], [0.2, 1.5, -1.0], [1e-3, 2e-3, 1.0]];
    let inv = mat_inv(&m).expect("regular");
    let id = mat_mul(&m, &inv);
    for (i, row) in id.iter().enumerate() {
        for (j, v) in row.iter().enumerate() {
            assert!((v - if i == j { 1.0 } else { 0.0 }).abs() < 1e-12);
        }
    }
    assert!(mat_inv(&[[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]]).is_none());
    let n = normalise_h(&[[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 4.0]]).expect("ok");
    assert_eq!(n[2][2], 1.0);
    assert_eq!(n[0][0], 0.5);
    assert_eq!(round_sig(0.062_468_3, 4), 0.062_47);
}
