//! Tests of the rasteriser: analytic shapes, fill rules, spot width, coverage, the grid
//! contract of docs/frames.md, the exemplar, the standard deviation filter and the real files.

use crate::common;
use crate::common::shared_cli;
use std::f64::consts::{PI, TAU};
use std::path::PathBuf;

use layerwise::raster::{
    self, coverage, exemplar, mask, rgb, std_filter, FillRule, Grid, RasterError, RasterKind,
    RasterOptions, RGB_CONTOUR, RGB_FUSED, RGB_HATCH,
};
use layerwise::vectors::{self, Direction, Hatches, Layer, Polyline};

const FILES: [&str; 4] = common::REAL_CLI_FILES;

fn circle(cx: f64, cy: f64, r: f64, n: usize, ccw: bool) -> Vec<[f64; 2]> {
    let sign = if ccw { 1.0 } else { -1.0 };
    (0..=n)
        .map(|i| {
            let a = sign * TAU * (i % n) as f64 / n as f64;
            [cx + r * a.cos(), cy + r * a.sin()]
        })
        .collect()
}

fn contour(points: Vec<[f64; 2]>, direction: Direction) -> Polyline {
    Polyline {
        part: 1,
        direction,
        points,
    }
}

fn layer_of(polylines: Vec<Polyline>, hatches: Vec<Hatches>) -> Layer {
    let mut l = Layer::new(0, 0.03);
    l.polylines = polylines;
    l.hatches = hatches;
    l
}

/// The area (mm²) a coverage image covers: the sum of its fractions times the pixel area.
fn covered_area(cov: &image::GrayImage, grid: &Grid) -> f64 {
    cov.as_raw().iter().map(|&v| v as f64 / 255.0).sum::<f64>() * grid.pixel_mm.powi(2)
}

fn count_set(img: &image::GrayImage) -> usize {
    img.as_raw().iter().filter(|&&v| v != 0).count()
}

fn diff_count(a: &image::GrayImage, b: &image::GrayImage) -> usize {
    assert_eq!(a.dimensions(), b.dimensions());
    a.as_raw()
        .iter()
        .zip(b.as_raw())
        .filter(|(x, y)| x != y)
        .count()
}

fn square(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<[f64; 2]> {
    vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
}

fn annulus() -> Layer {
    layer_of(
        vec![
            contour(
                circle(1.3, -2.1, 10.0, 4000, true),
                Direction::CounterClockwise,
            ),
            contour(circle(1.3, -2.1, 4.0, 4000, false), Direction::Clockwise),
        ],
        vec![],
    )
}

#[test]
fn annulus_area_within_half_a_percent() {
    let layer = annulus();
    let grid = Grid::on_plate_lattice([-8.7, -12.1, 11.3, 7.9], 1.0, 0.0625);
    let analytic = PI * (100.0 - 16.0);
    let px = grid.pixel_mm * grid.pixel_mm;
    let opts = RasterOptions::default();
    let m = mask(&layer, &grid, &opts).unwrap();
    let area = count_set(&m) as f64 * px;
    assert!(
        (area / analytic - 1.0).abs() < 0.005,
        "mask area {area} vs {analytic}"
    );
    // The hole is empty, the ring is full.
    let (r, c) = grid.pixel_of(1.3, -2.1);
    assert_eq!(m.get_pixel(c.round() as u32, r.round() as u32).0[0], 0);
    let (r, c) = grid.pixel_of(1.3 + 7.0, -2.1);
    assert_eq!(m.get_pixel(c.round() as u32, r.round() as u32).0[0], 255);
    // Coverage: the sum of fractions is the area, closer than the mask's.
    let cov = coverage(&layer, &grid, &opts).unwrap();
    let area_cov = covered_area(&cov, &grid);
    assert!(
        (area_cov / analytic - 1.0).abs() < 0.001,
        "coverage area {area_cov} vs {analytic}"
    );
}

#[test]
fn nonzero_and_even_odd() {
    // Two overlapping counter-clockwise squares: nonzero fills the overlap, even-odd does not.
    let layer = layer_of(
        vec![
            contour(square(0.0, 0.0, 4.0, 4.0), Direction::CounterClockwise),
            contour(square(2.0, 2.0, 6.0, 6.0), Direction::CounterClockwise),
        ],
        vec![],
    );
    let grid = Grid::on_plate_lattice([0.0, 0.0, 6.0, 6.0], 0.5, 0.125);
    let at = |img: &image::GrayImage, x: f64, y: f64| {
        let (r, c) = grid.pixel_of(x, y);
        img.get_pixel(c.round() as u32, r.round() as u32).0[0]
    };
    let nz = mask(&layer, &grid, &RasterOptions::default()).unwrap();
    let eo_opts = RasterOptions {
        fill_rule: FillRule::EvenOdd,
        ..RasterOptions::default()
    };
    let eo = mask(&layer, &grid, &eo_opts).unwrap();
    assert_eq!(at(&nz, 3.0, 3.0), 255);
    assert_eq!(at(&eo, 3.0, 3.0), 0);
    assert_eq!(at(&nz, 1.0, 1.0), 255);
    assert_eq!(at(&eo, 5.0, 5.0), 255);
    let cell = grid.pixel_mm * grid.pixel_mm;
    assert!((count_set(&nz) as f64 * cell - 28.0).abs() < 1e-9);
    assert!((count_set(&eo) as f64 * cell - 24.0).abs() < 1e-9);

    // An inner contour with the wrong (counter-clockwise) orientation: nonzero fills it,
    // even-odd still cuts the hole; the correct clockwise hole is cut by both.
    let wrong = layer_of(
        vec![
            contour(square(0.0, 0.0, 6.0, 6.0), Direction::CounterClockwise),
            contour(square(2.0, 2.0, 4.0, 4.0), Direction::Clockwise),
        ],
        vec![],
    );
    let nz = mask(&wrong, &grid, &RasterOptions::default()).unwrap();
    let eo = mask(&wrong, &grid, &eo_opts).unwrap();
    assert_eq!(at(&nz, 3.0, 3.0), 255);
    assert_eq!(at(&eo, 3.0, 3.0), 0);
    let mut right = wrong.clone();
    right.polylines[1].points.reverse();
    let nz = mask(&right, &grid, &RasterOptions::default()).unwrap();
    let eo = mask(&right, &grid, &eo_opts).unwrap();
    assert_eq!(at(&nz, 3.0, 3.0), 0);
    assert_eq!(diff_count(&nz, &eo), 0);
}

/// Distance from p to segment a–b.
fn seg_dist(p: [f64; 2], s: [f64; 4]) -> f64 {
    let (dx, dy) = (s[2] - s[0], s[3] - s[1]);
    let l2 = dx * dx + dy * dy;
    let t = if l2 > 0.0 {
        (((p[0] - s[0]) * dx + (p[1] - s[1]) * dy) / l2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    ((p[0] - s[0] - t * dx).powi(2) + (p[1] - s[1] - t * dy).powi(2)).sqrt()
}

#[test]
fn hatch_spot_width_selects_pixel_centers_within_half_width() {
    let segments = vec![
        [0.3, 0.41, 9.7, 0.41],    // horizontal
        [1.0, 2.0, 8.2, 7.77],     // diagonal
        [5.03, 1.0, 5.03, 9.0],    // vertical
        [2.0, 8.0, 2.0, 8.0],      // a point: a disc
        [9.5, 9.5, 6.123, 2.4567], // backwards
    ];
    let layer = layer_of(
        vec![],
        vec![Hatches {
            part: 1,
            segments: segments.clone(),
        }],
    );
    let grid = Grid::on_plate_lattice([0.0, 0.0, 10.0, 10.0], 0.5, 0.0625);
    for width in [0.05, 0.1, 0.3, 0.77] {
        let opts = RasterOptions {
            hatch_width_mm: width,
            ..RasterOptions::default()
        };
        let m = mask(&layer, &grid, &opts).unwrap();
        let mut set = 0;
        for r in 0..grid.rows() {
            for c in 0..grid.columns() {
                let (x, y) = grid.center_of(r as f64, c as f64);
                let d = segments
                    .iter()
                    .map(|s| seg_dist([x, y], *s))
                    .fold(f64::INFINITY, f64::min);
                let got = m.get_pixel(c as u32, r as u32).0[0] == 255;
                if (d - width / 2.0).abs() > 1e-9 {
                    assert_eq!(got, d < width / 2.0, "w {width} pixel {r},{c} d {d}");
                }
                set += got as usize;
            }
        }
        assert!(set > 0);
    }
    // Width 0 draws no hatches at all.
    let none = RasterOptions {
        hatch_width_mm: 0.0,
        ..RasterOptions::default()
    };
    assert_eq!(count_set(&mask(&layer, &grid, &none).unwrap()), 0);
    // Coverage of a long hatch: width x length (+ the caps' disc).
    let w = 0.3;
    let long = layer_of(
        vec![],
        vec![Hatches {
            part: 1,
            segments: vec![[1.0, 1.0, 9.0, 7.0]],
        }],
    );
    let opts = RasterOptions {
        hatch_width_mm: w,
        subsamples: 16,
        ..RasterOptions::default()
    };
    let cov = coverage(&long, &grid, &opts).unwrap();
    let area = covered_area(&cov, &grid);
    let analytic = 10.0 * w + PI * w * w / 4.0;
    assert!((area / analytic - 1.0).abs() < 0.01, "{area} vs {analytic}");
}

#[test]
fn open_polylines_are_stroked_like_hatches() {
    let layer = layer_of(
        vec![contour(
            vec![[1.0, 1.0], [5.0, 1.0], [5.0, 4.0]],
            Direction::Open,
        )],
        vec![],
    );
    let grid = Grid::on_plate_lattice([0.0, 0.0, 6.0, 5.0], 0.0, 0.0625);
    let opts = RasterOptions {
        hatch_width_mm: 0.25,
        ..RasterOptions::default()
    };
    let m = mask(&layer, &grid, &opts).unwrap();
    for r in 0..grid.rows() {
        for c in 0..grid.columns() {
            let (x, y) = grid.center_of(r as f64, c as f64);
            let d =
                seg_dist([x, y], [1.0, 1.0, 5.0, 1.0]).min(seg_dist([x, y], [5.0, 1.0, 5.0, 4.0]));
            if (d - 0.125).abs() > 1e-9 {
                assert_eq!(m.get_pixel(c as u32, r as u32).0[0] == 255, d < 0.125);
            }
        }
    }
    // Not filled, unless asked to and closed.
    let (r, c) = grid.pixel_of(4.0, 2.0);
    assert_eq!(m.get_pixel(c as u32, r as u32).0[0], 0);
    let closed = layer_of(
        vec![contour(square(1.0, 1.0, 5.0, 4.0), Direction::Open)],
        vec![],
    );
    let fill = RasterOptions {
        fill_closed_open: true,
        ..opts
    };
    assert_eq!(
        mask(&closed, &grid, &opts)
            .unwrap()
            .get_pixel(c as u32, r as u32)
            .0[0],
        0
    );
    assert_eq!(
        mask(&closed, &grid, &fill)
            .unwrap()
            .get_pixel(c as u32, r as u32)
            .0[0],
        255
    );
    // An open line that does not close is never filled.
    assert_eq!(diff_count(&mask(&layer, &grid, &fill).unwrap(), &m), 0);
}

#[test]
fn contours_stroked_when_asked() {
    // A 4 mm square, implicitly closed (no repeated last point), stroked 0.5 mm wide: the
    // fused area is the square grown by 0.25 mm with rounded corners.
    let layer = layer_of(
        vec![contour(
            vec![[1.0, 1.0], [5.0, 1.0], [5.0, 5.0], [1.0, 5.0]],
            Direction::CounterClockwise,
        )],
        vec![],
    );
    let grid = Grid::on_plate_lattice([1.0, 1.0, 5.0, 5.0], 1.0, 0.0625);
    let opts = RasterOptions {
        contour_width_mm: 0.5,
        subsamples: 16,
        ..RasterOptions::default()
    };
    let cov = coverage(&layer, &grid, &opts).unwrap();
    let area = covered_area(&cov, &grid);
    let r: f64 = 0.25;
    let analytic = 4.0 * 4.0 + 4.0 * 4.0 * r + PI * r * r;
    assert!(
        (area / analytic - 1.0).abs() < 0.002,
        "{area} vs {analytic}"
    );
}

#[test]
fn coverage_sums_to_area() {
    // A rotated square (side 5) and a triangle, apart.
    let a = 0.4f64;
    let (s, c) = a.sin_cos();
    let rot: Vec<[f64; 2]> = [[0.0, 0.0], [5.0, 0.0], [5.0, 5.0], [0.0, 5.0], [0.0, 0.0]]
        .iter()
        .map(|p| [2.0 + p[0] * c - p[1] * s, 1.0 + p[0] * s + p[1] * c])
        .collect();
    let tri = vec![[10.0, 1.0], [16.0, 2.5], [11.0, 6.1]];
    let layer = layer_of(
        vec![
            contour(rot, Direction::CounterClockwise),
            contour(tri, Direction::CounterClockwise),
        ],
        vec![],
    );
    let analytic = 25.0 + 0.5 * ((16.0 - 10.0) * (6.1 - 1.0) - (11.0 - 10.0) * (2.5 - 1.0));
    let grid = Grid::on_plate_lattice([-2.0, 0.0, 17.0, 8.0], 0.5, 0.1);
    for s in [1, 2, 4, 16] {
        let opts = RasterOptions {
            subsamples: s,
            ..RasterOptions::default()
        };
        let cov = coverage(&layer, &grid, &opts).unwrap();
        let area = covered_area(&cov, &grid);
        let tol = if s == 1 { 0.01 } else { 0.002 };
        assert!(
            (area / analytic - 1.0).abs() < tol,
            "s {s}: {area} vs {analytic}"
        );
        // Interior pixels are fully covered, far pixels empty, edge pixels in between.
        let at = |x: f64, y: f64| {
            let (r, c) = grid.pixel_of(x, y);
            cov.get_pixel(c.round() as u32, r.round() as u32).0[0]
        };
        assert_eq!(at(11.5, 3.0), 255);
        assert_eq!(at(8.0, 7.0), 0);
    }
}

#[test]
fn grid_contract_square_lands_where_predicted() {
    let layer = layer_of(
        vec![contour(
            square(0.0, 0.0, 10.0, 10.0),
            Direction::CounterClockwise,
        )],
        vec![],
    );
    let grid = Grid::plate();
    assert_eq!((grid.columns(), grid.rows()), (4400, 4400));
    let opts = RasterOptions::default();
    let m = mask(&layer, &grid, &opts).unwrap();
    // x = 0..10 → columns whose center x = −137.5 + (c + 0.5)/16 lies in (0, 10): 2200..=2359.
    // y = 0..10 (y up) → rows whose center y = 137.5 − (r + 0.5)/16 lies in (0, 10): 2040..=2199.
    let (mut r_lo, mut r_hi, mut c_lo, mut c_hi) = (usize::MAX, 0, usize::MAX, 0);
    for (c, r, p) in m.enumerate_pixels() {
        if p.0[0] != 0 {
            r_lo = r_lo.min(r as usize);
            r_hi = r_hi.max(r as usize);
            c_lo = c_lo.min(c as usize);
            c_hi = c_hi.max(c as usize);
        }
    }
    assert_eq!((c_lo, c_hi), (2200, 2359));
    assert_eq!((r_lo, r_hi), (2040, 2199));
    assert_eq!(count_set(&m), 160 * 160);
    assert_eq!(grid.center_of(2040.0, 2200.0), (0.03125, 9.96875));
    assert_eq!(grid.pixel_of(0.03125, 9.96875), (2040.0, 2200.0));

    // around(): snapped onto the plate lattice, covering bbox + margin.
    let g = Grid::on_plate_lattice([0.01, 0.02, 10.0, 9.99], 2.0, 0.0625);
    for v in [g.x_min, g.x_max, g.y_min, g.y_max] {
        let k = (v + 137.5) / 0.0625;
        assert!((k - k.round()).abs() < 1e-9, "{v} not on the lattice");
    }
    assert!(g.x_min <= -1.99 && g.x_max >= 12.0 && g.y_min <= -1.98 && g.y_max >= 11.99);
    assert!(g.x_min > -2.0625 && g.y_max < 12.0625);
    // The crop's pixels coincide with the plate's.
    let crop = mask(&layer, &g, &opts).unwrap();
    let (r0, c0) = grid.pixel_of(g.x_min + 0.03125, g.y_max - 0.03125);
    let (r0, c0) = (r0.round() as u32, c0.round() as u32);
    for (c, r, p) in crop.enumerate_pixels() {
        assert_eq!(p.0[0], m.get_pixel(c0 + c, r0 + r).0[0]);
    }
    // A grid of another pixel size lands on its own lattice.
    let g = Grid::on_plate_lattice([0.0, 0.0, 10.0, 10.0], 0.0, 0.1);
    assert!((((g.x_min + 137.5) / 0.1) - ((g.x_min + 137.5) / 0.1).round()).abs() < 1e-9);
    assert_eq!((g.columns(), g.rows()), (100, 100));
}

#[test]
fn exemplar_is_high_inside_and_zero_far_outside() {
    let layer = layer_of(
        vec![contour(
            circle(0.0, 0.0, 5.0, 400, true),
            Direction::CounterClockwise,
        )],
        vec![],
    );
    let grid = Grid::on_plate_lattice([-5.0, -5.0, 5.0, 5.0], 3.0, 0.0625);
    let opts = RasterOptions::default();
    let window = 11;
    let ex = exemplar(&layer, &grid, &opts, window, 7).unwrap();
    assert_eq!((ex.width, ex.height), (grid.columns(), grid.rows()));
    let (mut inside, mut ni, mut outside, mut no) = (0.0, 0, 0.0, 0);
    for r in 0..ex.height {
        for c in 0..ex.width {
            let (x, y) = grid.center_of(r as f64, c as f64);
            let rad = (x * x + y * y).sqrt();
            let v = ex.get(r, c).unwrap() as f64;
            if rad < 4.0 {
                inside += v;
                ni += 1;
            } else if rad > 6.0 {
                outside += v;
                no += 1;
            }
        }
    }
    let (inside, outside) = (inside / ni as f64, outside / no as f64);
    // Uniform bytes have a standard deviation of 256/√12 ≈ 73.9.
    assert!((inside - 73.9).abs() < 3.0, "inside {inside}");
    assert_eq!(outside, 0.0);
    // Deterministic for a seed, different for another.
    assert_eq!(ex, exemplar(&layer, &grid, &opts, window, 7).unwrap());
    assert_ne!(ex, exemplar(&layer, &grid, &opts, window, 8).unwrap());
    // The rim (noise next to zeros) is brighter than the interior, as in the paper's Fig. 7.
    let (r, c) = grid.pixel_of(5.0, 0.0);
    assert!(ex.get(r.round() as usize, c.round() as usize).unwrap() as f64 > inside);
}

/// Brute-force local (population) standard deviation with the window clipped to the image.
fn std_brute(data: &[f32], w: usize, h: usize, window: usize) -> Vec<f64> {
    let half = window / 2;
    let mut out = vec![0.0; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut vals = Vec::new();
            for rr in r.saturating_sub(half)..(r + half + 1).min(h) {
                for cc in c.saturating_sub(half)..(c + half + 1).min(w) {
                    vals.push(data[rr * w + cc] as f64);
                }
            }
            let n = vals.len() as f64;
            let mean = vals.iter().sum::<f64>() / n;
            let ss: f64 = vals.iter().map(|v| (v - mean).powi(2)).sum();
            out[r * w + c] = if n > 1.0 { (ss / n).sqrt() } else { 0.0 };
        }
    }
    out
}

/// xorshift64*: test data without a dependency.
fn random(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed | 1;
    (0..n)
        .map(|_| {
            s ^= s >> 12;
            s ^= s << 25;
            s ^= s >> 27;
            (s.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
        })
        .collect()
}

#[test]
fn std_filter_matches_brute_force() {
    for (w, h) in [(37, 23), (5, 64), (120, 90), (1, 1), (3, 2)] {
        let base = random(w * h, (w * 1000 + h) as u64);
        for (scale, offset) in [(255.0f32, 0.0f32), (10.0, 5000.0)] {
            let data: Vec<f32> = base.iter().map(|v| v * scale + offset).collect();
            for window in [1, 3, 7, 15] {
                let ours = std_filter(&data, w, h, window).unwrap();
                let want = std_brute(&data, w, h, window);
                for (i, (&a, &b)) in ours.iter().zip(&want).enumerate() {
                    assert!(
                        (a as f64 - b).abs() <= 1e-4 * (1.0 + b),
                        "{w}x{h} window {window} scale {scale} offset {offset} at {i}: {a} vs {b}"
                    );
                }
            }
        }
    }
    // Large bands in parallel agree with the brute force too.
    let (w, h) = (300, 700);
    let data: Vec<f32> = random(w * h, 99).iter().map(|v| v * 255.0).collect();
    let ours = std_filter(&data, w, h, 15).unwrap();
    let want = std_brute(&data, w, h, 15);
    let worst = ours
        .iter()
        .zip(&want)
        .map(|(&a, &b)| (a as f64 - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "worst {worst}");
    // Constant input: zero everywhere.
    assert!(std_filter(&[42.0; 100], 10, 10, 5)
        .unwrap()
        .iter()
        .all(|&v| v == 0.0));
    assert!(matches!(
        std_filter(&data, w, h, 4),
        Err(RasterError::InvalidWindow(4))
    ));
    assert!(matches!(
        std_filter(&data, w, h + 1, 3),
        Err(RasterError::SizeMismatch { .. })
    ));
}

#[test]
fn part_filter_and_rgb_colours() {
    let mut layer = layer_of(
        vec![
            contour(square(0.0, 0.0, 4.0, 4.0), Direction::CounterClockwise),
            Polyline {
                part: 2,
                direction: Direction::CounterClockwise,
                points: square(6.0, 0.0, 10.0, 4.0),
            },
        ],
        vec![
            Hatches {
                part: 1,
                segments: vec![[0.5, 2.0, 3.5, 2.0]],
            },
            Hatches {
                part: 2,
                segments: vec![[6.5, 2.0, 9.5, 2.0]],
            },
        ],
    );
    layer.index = 3;
    let grid = Grid::on_plate_lattice([0.0, 0.0, 10.0, 4.0], 1.0, 0.0625);
    let at = |x: f64, y: f64| {
        let (r, c) = grid.pixel_of(x, y);
        (c.round() as u32, r.round() as u32)
    };
    let only2 = RasterOptions {
        part: Some(2),
        ..RasterOptions::default()
    };
    let m = mask(&layer, &grid, &only2).unwrap();
    let (c, r) = at(2.0, 1.0);
    assert_eq!(m.get_pixel(c, r).0[0], 0);
    let (c, r) = at(8.0, 1.0);
    assert_eq!(m.get_pixel(c, r).0[0], 255);
    assert_eq!(count_set(&m), 64 * 64);

    let img = rgb(&layer, &grid, &RasterOptions::default()).unwrap();
    let (c, r) = at(2.0, 1.0);
    assert_eq!(*img.get_pixel(c, r), RGB_FUSED);
    let (c, r) = at(2.0, 2.0);
    assert_eq!(*img.get_pixel(c, r), RGB_HATCH);
    let (c, r) = at(2.0, 0.0);
    assert_eq!(*img.get_pixel(c, r), RGB_CONTOUR);
    let (c, r) = at(0.0, 2.0);
    assert_eq!(*img.get_pixel(c, r), RGB_CONTOUR);
    let (c, r) = at(5.0, 2.0);
    assert_eq!(img.get_pixel(c, r).0, [0, 0, 0]);
    // One pixel wide: the column through x = 2 has exactly one contour pixel near y = 0.
    let (c, _) = at(2.0, 0.0);
    let blue = (0..img.height())
        .filter(|&r| *img.get_pixel(c, r) == RGB_CONTOUR)
        .count();
    assert_eq!(blue, 2, "bottom and top edges");
}

#[test]
fn invalid_input_is_an_error_not_a_panic() {
    let layer = annulus();
    let opts = RasterOptions::default();
    for g in [
        Grid {
            pixel_mm: 0.0,
            ..Grid::plate()
        },
        Grid {
            pixel_mm: f64::NAN,
            ..Grid::plate()
        },
        Grid {
            x_max: -200.0,
            ..Grid::plate()
        },
        Grid {
            pixel_mm: 1e-6,
            ..Grid::plate()
        },
    ] {
        assert!(matches!(
            mask(&layer, &g, &opts),
            Err(RasterError::InvalidGrid(_))
        ));
    }
    // Geometry far outside the grid, NaNs and a huge spot: empty or full, no panic.
    let mut odd = layer_of(
        vec![
            contour(square(1e9, 1e9, 2e9, 2e9), Direction::CounterClockwise),
            contour(
                vec![[f64::NAN, 0.0], [1.0, 1.0], [2.0, 0.0]],
                Direction::Clockwise,
            ),
            contour(vec![[1.0, 1.0]], Direction::Open),
            contour(vec![], Direction::CounterClockwise),
        ],
        vec![Hatches {
            part: 1,
            segments: vec![[f64::INFINITY, 0.0, 1.0, 1.0], [-1e12, 0.0, 1e12, 0.0]],
        }],
    );
    let g = Grid::on_plate_lattice([0.0, 0.0, 2.0, 2.0], 0.0, 0.0625);
    let m = mask(&odd, &g, &opts).unwrap();
    assert_eq!(m.width(), 32);
    odd.hatches.clear();
    let big = RasterOptions {
        hatch_width_mm: 1e6,
        ..opts
    };
    assert_eq!(count_set(&mask(&odd, &g, &big).unwrap()), 32 * 32);
    assert!("foo".parse::<RasterKind>().is_err());
}

fn temp_png(tag: &str) -> PathBuf {
    std::env::temp_dir().join(format!("layerwise-raster-{}-{tag}.png", std::process::id()))
}

#[test]
fn real_files_rasterize_and_render() {
    for name in FILES {
        let file = vectors::read(&shared_cli(name)).unwrap();
        let grid = raster::default_grid(&file, None).unwrap();
        assert!(
            grid.columns() < 1000 && grid.rows() < 1000,
            "{name}: {grid:?}"
        );
        let eo = RasterOptions {
            fill_rule: FillRule::EvenOdd,
            ..RasterOptions::default()
        };
        let closed = RasterOptions {
            fill_closed_open: true,
            ..RasterOptions::default()
        };
        let mut fused = 0usize;
        let mut rule_diff = 0usize;
        for layer in &file.layers {
            let m = mask(layer, &grid, &RasterOptions::default()).unwrap();
            // All files seen orient their contours consistently: both rules agree.
            // Even-odd can only drop pixels (where outer contours overlap).
            let e = mask(layer, &grid, &eo).unwrap();
            assert!(m.as_raw().iter().zip(e.as_raw()).all(|(a, b)| a >= b));
            rule_diff += diff_count(&m, &e);
            let cm = mask(layer, &grid, &closed).unwrap();
            assert!(count_set(&cm) >= count_set(&m));
            fused += count_set(&m);
            coverage(layer, &grid, &RasterOptions::default()).unwrap();
        }
        assert!(fused > 0, "{name}: nothing fused");
        println!("{name}: {fused} fused pixels, {rule_diff} differ between nonzero and even-odd");
        // The colour rendering and the exemplar for a few layers.
        for k in [0, file.layers.len() / 2, file.layers.len() - 1] {
            rgb(&file.layers[k], &grid, &RasterOptions::default()).unwrap();
        }
        let k = file.layers.len() / 2;
        for kind in [
            RasterKind::Mask,
            RasterKind::Coverage,
            RasterKind::Rgb,
            RasterKind::Exemplar,
        ] {
            let out = temp_png(&format!("{name}-{kind}"));
            raster::render_to_png(&file, k, kind, &grid, None, &out).unwrap();
            let back = image::open(&out).unwrap();
            assert_eq!(
                (back.width() as usize, back.height() as usize),
                (grid.columns(), grid.rows())
            );
            if kind == RasterKind::Exemplar {
                assert_eq!(back.color(), image::ColorType::L16);
            }
            std::fs::remove_file(&out).unwrap();
        }
        assert!(matches!(
            raster::render_to_png(
                &file,
                file.layers.len(),
                RasterKind::Mask,
                &grid,
                None,
                &temp_png("none")
            ),
            Err(RasterError::NoSuchLayer { .. })
        ));
    }
}

#[test]
fn box_support_outlines_fill_when_asked() {
    // The Box file's only polylines are closed direction-2 outlines of a support block.
    let file = vectors::read(&shared_cli("Box_support_solid_ascii_with_params.cli")).unwrap();
    let grid = raster::default_grid(&file, Some(1)).unwrap();
    // Mid-height the block is about 20 x 23 mm.
    let layer = &file.layers[file.layers.len() / 2];
    assert_eq!(layer.polylines.len(), 1);
    assert_eq!(layer.polylines[0].direction, Direction::Open);
    let lines = mask(layer, &grid, &RasterOptions::default()).unwrap();
    let filled = mask(
        layer,
        &grid,
        &RasterOptions {
            fill_closed_open: true,
            ..RasterOptions::default()
        },
    )
    .unwrap();
    assert!(count_set(&filled) > 3 * count_set(&lines));
    assert!(matches!(
        raster::default_grid(&file, Some(77)),
        Err(RasterError::NoGeometry { part: Some(77) })
    ));
}
