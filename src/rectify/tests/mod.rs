//! Unit tests for the rectify module; decoding and dispatch by pixel format in `decode.rs`.

use image::{DynamicImage, GrayImage, ImageBuffer, Luma, Rgb, RgbImage};

use super::*;
use crate::geometry::{homography_from_points, BuildPoint, Homography};

mod decode;

fn camera_of(h: [[f64; 3]; 3], distortion: Option<RadialDistortion>) -> CameraModel {
    CameraModel::new(Homography::from_matrix(h), distortion)
}

/// [`Rectifier::image_point`] as (u, v).
fn image_uv(r: &Rectifier, x: f64, y: f64) -> Option<(f64, f64)> {
    r.image_point(BuildPoint::new(x, y)).map(|p| (p.u, p.v))
}

/// Small deterministic PRNG (xorshift64*), so tests need no extra crate.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.unit()
    }
}

fn grid_1mm(w: f64, h: f64) -> Grid {
    Grid {
        x_min: 0.0,
        x_max: w,
        y_min: 0.0,
        y_max: h,
        pixel_mm: 1.0,
    }
}

fn both_paths(r: &Rectifier) -> [Rectifier; 2] {
    let mut scalar = r.clone();
    scalar.allow_simd = false;
    [r.clone(), scalar]
}

// ---------------------------------------------------------------- Grid

#[test]
fn plate_grid_is_4400_square() {
    let g = Grid::plate();
    assert_eq!((g.columns(), g.rows()), (4400, 4400));
    let (x, y) = g.center_of(0.0, 0.0);
    assert_eq!(
        (x, y),
        (g.x_min + g.pixel_mm / 2.0, g.y_max - g.pixel_mm / 2.0)
    );
    assert_eq!((x, y), (-137.46875, 137.46875));
    // Last pixel center is half a pixel inside the opposite corner.
    assert_eq!(g.center_of(4399.0, 4399.0), (137.46875, -137.46875));
}

#[test]
fn grid_round_trip() {
    let g = Grid {
        x_min: -20.0,
        x_max: 35.0,
        y_min: -7.5,
        y_max: 12.25,
        pixel_mm: 0.25,
    };
    assert_eq!((g.columns(), g.rows()), (220, 79));
    for (r, c) in [
        (0.0, 0.0),
        (3.25, 17.5),
        (78.0, 219.0),
        (-0.5, -0.5),
        (40.1, 100.9),
    ] {
        let (x, y) = g.center_of(r, c);
        let (r2, c2) = g.pixel_of(x, y);
        assert!(
            (r2 - r).abs() < 1e-9 && (c2 - c).abs() < 1e-9,
            "{r},{c} -> {r2},{c2}"
        );
    }
    // y up: a larger row is lower on the plate.
    assert!(g.center_of(10.0, 0.0).1 < g.center_of(9.0, 0.0).1);
}

#[test]
fn bad_grids_are_rejected() {
    let h = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for g in [
        Grid {
            pixel_mm: 0.0,
            ..Grid::plate()
        },
        Grid {
            pixel_mm: -1.0,
            ..Grid::plate()
        },
        Grid {
            x_max: -200.0,
            ..Grid::plate()
        },
        Grid {
            y_min: f64::NAN,
            ..Grid::plate()
        },
        Grid {
            pixel_mm: 1e-9,
            ..Grid::plate()
        },
    ] {
        let e = Rectifier::new(&camera_of(h, None), g, Interpolation::Bilinear, 0);
        assert!(matches!(e, Err(RectifyError::InvalidGrid(_))), "{g:?}");
    }
}

// ------------------------------------------------------ exact mappings

/// H such that grid pixel (r, c) of `grid_1mm(w, h)` samples image (c, r).
fn identity_h(h: f64) -> [[f64; 3]; 3] {
    // x = u + 0.5, y = (h − 0.5) − v
    [[1.0, 0.0, 0.5], [0.0, -1.0, h - 0.5], [0.0, 0.0, 1.0]]
}

fn pattern(x: u32, y: u32, ch: u32) -> u32 {
    (x * 37 + y * 101 + ch * 59 + (x * y) % 13) % 256
}

#[test]
fn identity_mapping_reproduces_the_image() {
    let (w, h) = (67u32, 45u32);
    let gray = GrayImage::from_fn(w, h, |x, y| Luma([pattern(x, y, 0) as u8]));
    let rgb = RgbImage::from_fn(w, h, |x, y| Rgb([0, 1, 2].map(|c| pattern(x, y, c) as u8)));
    let g16: Gray16Image =
        ImageBuffer::from_fn(w, h, |x, y| Luma([(pattern(x, y, 0) * 257 + x) as u16]));
    let rgb16: Rgb16Image = ImageBuffer::from_fn(w, h, |x, y| {
        Rgb([0, 1, 2].map(|c| (pattern(x, y, c) * 255 + y) as u16))
    });
    for interp in [Interpolation::Bilinear, Interpolation::Bicubic] {
        let r = Rectifier::new(
            &camera_of(identity_h(h as f64), None),
            grid_1mm(w as f64, h as f64),
            interp,
            0,
        )
        .unwrap();
        for r in both_paths(&r) {
            assert_eq!(r.rectify_gray8(&gray), gray, "{interp:?}");
            assert_eq!(r.rectify_rgb8(&rgb), rgb, "{interp:?}");
            assert_eq!(r.rectify_gray16(&g16), g16, "{interp:?}");
            assert_eq!(r.rectify_rgb16(&rgb16), rgb16, "{interp:?}");
        }
    }
}

#[test]
fn scale_translate_gives_known_values() {
    // x = 2u + 0.5, y = (2·h − 0.5) − 2v: grid pixel (r, c) samples
    // (u, v) = (c/2, r/2), so even indices hit pixel centers and odd ones lie
    // half way between; the last row/column (u = w − 0.5) is outside.
    let (w, h) = (40u32, 30u32);
    let hm = [
        [2.0, 0.0, 0.5],
        [0.0, -2.0, 2.0 * h as f64 - 0.5],
        [0.0, 0.0, 1.0],
    ];
    let grid = grid_1mm(2.0 * w as f64, 2.0 * h as f64);
    let img = GrayImage::from_fn(w, h, |x, y| Luma([pattern(x, y, 0) as u8]));
    let p = |x: u32, y: u32| pattern(x, y, 0);
    let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 7).unwrap();
    let mut checked = 0;
    for r in both_paths(&r) {
        let out = r.rectify_gray8(&img);
        assert_eq!(out.dimensions(), (2 * w, 2 * h));
        for row in 0..2 * h {
            for col in 0..2 * w {
                let got = u32::from(out.get_pixel(col, row)[0]);
                let (x, y) = (col / 2, row / 2);
                let expected = if col == 2 * w - 1 || row == 2 * h - 1 {
                    7
                } else {
                    match (col % 2 == 1, row % 2 == 1) {
                        (false, false) => p(x, y),
                        // half way between two pixels: rounds half up
                        (true, false) => (p(x, y) + p(x + 1, y)).div_ceil(2),
                        (false, true) => (p(x, y) + p(x, y + 1)).div_ceil(2),
                        (true, true) => {
                            (p(x, y) + p(x + 1, y) + p(x, y + 1) + p(x + 1, y + 1) + 2) / 4
                        }
                    }
                };
                assert_eq!(got, expected, "row {row} col {col}");
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 2 * 4 * w * h);
}

// --------------------------------------------- f64 reference bilinear

/// Plain f64 bilinear at the position `image_point` gives, with the same
/// inside rule; `None` for outside.
fn reference<F: Fn(usize, usize, usize) -> f64>(
    r: &Rectifier,
    w: usize,
    h: usize,
    cn: usize,
    at: F,
    row: usize,
    col: usize,
) -> Option<Vec<f64>> {
    let (x, y) = r.grid().center_of(row as f64, col as f64);
    let (u, v) = image_uv(r, x, y)?;
    if !(u >= 0.0 && u <= (w - 1) as f64 && v >= 0.0 && v <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (
        (u.floor() as usize).min(w - 2),
        (v.floor() as usize).min(h - 2),
    );
    let (a, b) = (u - x0 as f64, v - y0 as f64);
    Some(
        (0..cn)
            .map(|ch| {
                (1.0 - b) * ((1.0 - a) * at(x0, y0, ch) + a * at(x0 + 1, y0, ch))
                    + b * ((1.0 - a) * at(x0, y0 + 1, ch) + a * at(x0 + 1, y0 + 1, ch))
            })
            .collect(),
    )
}

/// Distance of the sample position from the inside-rectangle boundary, to
/// skip pixels whose inside/outside verdict hinges on the last ulp.
fn near_boundary(r: &Rectifier, w: usize, h: usize, row: usize, col: usize) -> bool {
    let (x, y) = r.grid().center_of(row as f64, col as f64);
    match image_uv(r, x, y) {
        None => false,
        Some((u, v)) => {
            let d = [u, (w - 1) as f64 - u, v, (h - 1) as f64 - v]
                .into_iter()
                .map(f64::abs)
                .fold(f64::INFINITY, f64::min);
            d < 1e-3
        }
    }
}

fn random_oblique(rng: &mut Rng, w: f64, h: f64) -> ([[f64; 3]; 3], Grid) {
    // A trapezoid-ish quad inside the image mapped to a 100 x 80 mm rectangle;
    // the grid overhangs it so part of the output is outside the image.
    let img = [
        [rng.range(0.05, 0.3) * w, rng.range(0.05, 0.25) * h],
        [rng.range(0.7, 0.95) * w, rng.range(0.05, 0.25) * h],
        [rng.range(0.75, 1.0) * w, rng.range(0.75, 0.95) * h],
        [rng.range(0.0, 0.25) * w, rng.range(0.75, 0.95) * h],
    ];
    let build = [[0.0, 80.0], [100.0, 80.0], [100.0, 0.0], [0.0, 0.0]];
    let hm = homography_from_points(img, build).unwrap().matrix();
    let grid = Grid {
        x_min: -15.0,
        x_max: 115.0,
        y_min: -12.0,
        y_max: 93.0,
        pixel_mm: 0.37,
    };
    (hm, grid)
}

fn smooth(x: usize, y: usize, ch: usize) -> f64 {
    let (x, y) = (x as f64, y as f64);
    0.5 + 0.45 * ((x * 0.071 + ch as f64).sin() * (y * 0.053 - ch as f64 * 0.7).cos())
}

/// Checks every grid pixel against the f64 reference (±1, exact fill
/// outside); returns the number of inside pixels compared.
fn check_against_reference<F: Fn(usize, usize, usize) -> f64>(
    r: &Rectifier,
    w: usize,
    h: usize,
    cn: usize,
    at: F,
    got: &[u32],
    fill: u32,
) -> usize {
    let tol = 1.0;
    let cols = r.grid().columns();
    let mut inside = 0;
    let mut worst: f64 = 0.0;
    for row in 0..r.grid().rows() {
        for col in 0..cols {
            if near_boundary(r, w, h, row, col) {
                continue;
            }
            let px = &got[(row * cols + col) * cn..][..cn];
            match reference(r, w, h, cn, &at, row, col) {
                None => assert!(
                    px.iter().all(|&v| v == fill),
                    "row {row} col {col}: {px:?} should be fill"
                ),
                Some(want) => {
                    inside += 1;
                    for (g, want) in px.iter().zip(want) {
                        let d = (f64::from(*g) - (want + 0.5).floor()).abs();
                        worst = worst.max(d);
                        assert!(d <= tol, "row {row} col {col}: got {g}, want {want}");
                    }
                }
            }
        }
    }
    assert!(worst <= tol);
    inside
}

#[test]
fn fixed_point_matches_f64_reference_gray8() {
    let mut rng = Rng(0x5EED_1234);
    let (w, h) = (211usize, 157usize);
    // Smooth and hard-edged (noise) content: the 11-bit positions keep both
    // within ±1 grey level.
    let smooth_img = GrayImage::from_fn(w as u32, h as u32, |x, y| {
        Luma([(smooth(x as usize, y as usize, 0) * 255.0).round() as u8])
    });
    let mut nrng = Rng(99);
    let noise_img =
        GrayImage::from_fn(w as u32, h as u32, |_, _| Luma([(nrng.next() >> 56) as u8]));
    for trial in 0..4 {
        let (hm, grid) = random_oblique(&mut rng, w as f64, h as f64);
        let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 3).unwrap();
        for img in [&smooth_img, &noise_img] {
            let [simd, scalar] = both_paths(&r);
            let out = simd.rectify_gray8(img);
            assert_eq!(
                out,
                scalar.rectify_gray8(img),
                "SIMD and scalar differ (trial {trial})"
            );
            let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
            let at = |x: usize, y: usize, _| f64::from(img.get_pixel(x as u32, y as u32)[0]);
            let n = check_against_reference(&r, w, h, 1, at, &got, 3);
            assert!(n > 20_000, "only {n} inside pixels");
        }
    }
}

#[test]
fn fixed_point_matches_f64_reference_rgb8_and_16bit() {
    let mut rng = Rng(0xC0FFEE);
    let (w, h) = (180usize, 131usize);
    let rgb = RgbImage::from_fn(w as u32, h as u32, |x, y| {
        Rgb([0, 1, 2].map(|c| (smooth(x as usize, y as usize, c) * 255.0).round() as u8))
    });
    let g16: Gray16Image = ImageBuffer::from_fn(w as u32, h as u32, |x, y| {
        Luma([(smooth(x as usize, y as usize, 1) * 65535.0).round() as u16])
    });
    let rgb16: Rgb16Image = ImageBuffer::from_fn(w as u32, h as u32, |x, y| {
        Rgb([0, 1, 2].map(|c| (smooth(x as usize, y as usize, c) * 65535.0).round() as u16))
    });
    for _ in 0..3 {
        let (hm, grid) = random_oblique(&mut rng, w as f64, h as f64);
        let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 1000).unwrap();
        let [simd, scalar] = both_paths(&r);

        let out = simd.rectify_rgb8(&rgb);
        assert_eq!(out, scalar.rectify_rgb8(&rgb), "SIMD and scalar differ");
        let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
        let at = |x: usize, y: usize, c: usize| f64::from(rgb.get_pixel(x as u32, y as u32)[c]);
        assert!(check_against_reference(&r, w, h, 3, at, &got, 255) > 10_000);

        let out = simd.rectify_gray16(&g16);
        let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
        let at = |x: usize, y: usize, _| f64::from(g16.get_pixel(x as u32, y as u32)[0]);
        assert!(check_against_reference(&r, w, h, 1, at, &got, 1000) > 10_000);

        let out = simd.rectify_rgb16(&rgb16);
        let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
        let at = |x: usize, y: usize, c: usize| f64::from(rgb16.get_pixel(x as u32, y as u32)[c]);
        assert!(check_against_reference(&r, w, h, 3, at, &got, 1000) > 10_000);
    }
}

#[test]
fn bicubic_is_close_to_bilinear_on_smooth_content() {
    let mut rng = Rng(7);
    let (w, h) = (150usize, 120usize);
    let img = GrayImage::from_fn(w as u32, h as u32, |x, y| {
        Luma([(smooth(x as usize, y as usize, 0) * 255.0).round() as u8])
    });
    let (hm, grid) = random_oblique(&mut rng, w as f64, h as f64);
    let lin = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 0).unwrap();
    let cub = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bicubic, 0).unwrap();
    let (a, b) = (lin.rectify_gray8(&img), cub.rectify_gray8(&img));
    let worst = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| x.abs_diff(*y))
        .max()
        .unwrap();
    // Same inside set (both fill with 0 where the other does) and close values.
    assert!(worst <= 3, "bicubic vs bilinear differ by {worst}");
    let [simd, scalar] = both_paths(&cub);
    assert_eq!(
        simd.rectify_rgb8(&DynamicImage::ImageLuma8(img.clone()).to_rgb8()),
        scalar.rectify_rgb8(&DynamicImage::ImageLuma8(img).to_rgb8())
    );
}

// ------------------------------------------- projective ground truth

const LIGHT: u8 = 220;
const DARK: u8 = 30;

/// 8 mm checkerboard in build coordinates.
fn checker(x: f64, y: f64) -> u8 {
    if ((x / 8.0).floor() as i64 + (y / 8.0).floor() as i64).rem_euclid(2) == 0 {
        LIGHT
    } else {
        DARK
    }
}

fn checker_margin(x: f64, y: f64) -> f64 {
    let m = |t: f64| {
        let f = (t / 8.0).rem_euclid(1.0) * 8.0;
        f.min(8.0 - f)
    };
    m(x).min(m(y))
}

/// The camera view of the board: each recorded pixel → (undistort) → H → build.
fn render_camera(
    h: &[[f64; 3]; 3],
    w: u32,
    hgt: u32,
    dist: Option<&RadialDistortion>,
) -> GrayImage {
    GrayImage::from_fn(w, hgt, |u, v| {
        let (u, v) = match dist {
            Some(d) => d.undistort(u as f64, v as f64),
            None => (u as f64, v as f64),
        };
        let s = h[2][0] * u + h[2][1] * v + h[2][2];
        let x = (h[0][0] * u + h[0][1] * v + h[0][2]) / s;
        let y = (h[1][0] * u + h[1][1] * v + h[1][2]) / s;
        Luma([checker(x, y)])
    })
}

/// Share of grid pixels (inside the plate square, ≥ 2 px from a square edge)
/// whose class (light/dark) is right.
fn checker_accuracy(r: &Rectifier, out: &GrayImage) -> f64 {
    let g = r.grid();
    let (mut good, mut total) = (0usize, 0usize);
    for (col, row, px) in out.enumerate_pixels() {
        let (x, y) = g.center_of(row as f64, col as f64);
        let edge = (x + 100.0).min(100.0 - x).min(y + 100.0).min(100.0 - y);
        if edge < 2.0 * g.pixel_mm || checker_margin(x, y) < 2.0 * g.pixel_mm {
            continue;
        }
        total += 1;
        let want = checker(x, y);
        let got = if px[0] > (LIGHT + DARK) / 2 {
            LIGHT
        } else {
            DARK
        };
        good += usize::from(got == want);
    }
    assert!(total > 10_000, "only {total} pixels checked");
    good as f64 / total as f64
}

fn oblique_camera() -> [[f64; 3]; 3] {
    // Plate square ±100 mm seen as a trapezoid, as the real 30° camera does.
    homography_from_points(
        [[180.0, 70.0], [620.0, 70.0], [760.0, 520.0], [40.0, 520.0]],
        [
            [-100.0, 100.0],
            [100.0, 100.0],
            [100.0, -100.0],
            [-100.0, -100.0],
        ],
    )
    .unwrap()
    .matrix()
}

fn board_grid() -> Grid {
    Grid {
        x_min: -110.0,
        x_max: 110.0,
        y_min: -110.0,
        y_max: 110.0,
        pixel_mm: 0.5,
    }
}

#[test]
fn projective_checkerboard_is_recovered() {
    let hm = oblique_camera();
    let cam = render_camera(&hm, 800, 600, None);
    for interp in [Interpolation::Bilinear, Interpolation::Bicubic] {
        let r = Rectifier::new(&camera_of(hm, None), board_grid(), interp, 0).unwrap();
        let acc = checker_accuracy(&r, &r.rectify_gray8(&cam));
        assert!(acc >= 0.99, "{interp:?}: accuracy {acc}");
    }
    // A wrong homography must fail the same check (the test can fail).
    let mut wrong = hm;
    wrong[0][2] += 6.0;
    let r = Rectifier::new(
        &camera_of(wrong, None),
        board_grid(),
        Interpolation::Bilinear,
        0,
    )
    .unwrap();
    assert!(checker_accuracy(&r, &r.rectify_gray8(&cam)) < 0.9);
}

// --------------------------------------------------------- distortion

fn lens() -> RadialDistortion {
    RadialDistortion {
        center: [410.0, 290.0],
        focal_px: 700.0,
        k1: -0.12,
        k2: 0.03,
    }
}

#[test]
fn distorted_camera_is_recovered() {
    let hm = oblique_camera();
    let d = lens();
    let cam = render_camera(&hm, 800, 600, Some(&d));
    let r = Rectifier::new(
        &camera_of(hm, Some(d)),
        board_grid(),
        Interpolation::Bilinear,
        0,
    )
    .unwrap();
    for r in both_paths(&r) {
        let acc = checker_accuracy(&r, &r.rectify_gray8(&cam));
        assert!(acc >= 0.99, "accuracy {acc}");
        let acc = checker_accuracy(
            &r,
            &luma(&r.rectify_rgb8(&DynamicImage::ImageLuma8(cam.clone()).to_rgb8())),
        );
        assert!(acc >= 0.99, "rgb accuracy {acc}");
    }
    // Ignoring the distortion must visibly fail.
    let plain = Rectifier::new(
        &camera_of(hm, None),
        board_grid(),
        Interpolation::Bilinear,
        0,
    )
    .unwrap();
    assert!(checker_accuracy(&plain, &plain.rectify_gray8(&cam)) < 0.95);
    // image_point goes through the distortion.
    let (u, v) = image_uv(&r, 100.0, 100.0).unwrap();
    let (uu, vu) = d.undistort(u, v);
    assert!((uu - 620.0).abs() < 1e-6 && (vu - 70.0).abs() < 1e-6);
}

// ------------------------------------------------ fill, errors, decode

#[test]
fn fill_outside_the_image() {
    let img = GrayImage::from_pixel(50, 40, Luma([200]));
    // Grid twice the image: the right and bottom halves see nothing.
    let r = Rectifier::new(
        &camera_of(identity_h(80.0), None),
        grid_1mm(100.0, 80.0),
        Interpolation::Bilinear,
        77,
    )
    .unwrap();
    for r in both_paths(&r) {
        let out = r.rectify_gray8(&img);
        for (c, row, px) in out.enumerate_pixels() {
            // Grid (row, col) samples image (col, row).
            let inside = c <= 49 && row <= 39;
            assert_eq!(px[0], if inside { 200 } else { 77 }, "row {row} col {c}");
        }
        let rgb = r.rectify_rgb8(&DynamicImage::ImageLuma8(img.clone()).to_rgb8());
        assert_eq!(rgb.get_pixel(99, 0).0, [77, 77, 77]);
        assert_eq!(rgb.get_pixel(10, 30).0, [200, 200, 200]);
        assert_eq!(rgb.get_pixel(10, 50).0, [77, 77, 77]);
    }
    // 8-bit output clamps the fill; 16-bit keeps it.
    let r = Rectifier::new(
        &camera_of(identity_h(80.0), None),
        grid_1mm(100.0, 80.0),
        Interpolation::Bicubic,
        4000,
    )
    .unwrap();
    assert_eq!(r.rectify_gray8(&img).get_pixel(99, 0)[0], 255);
    let g16: Gray16Image = ImageBuffer::from_pixel(50, 40, Luma([9]));
    assert_eq!(r.rectify_gray16(&g16).get_pixel(99, 0)[0], 4000);
    // A 1-pixel-wide image has no 2x2 neighbourhood: all fill.
    let thin = GrayImage::from_pixel(1, 40, Luma([5]));
    assert!(r.rectify_gray8(&thin).pixels().all(|p| p[0] == 255));
}

#[test]
fn beyond_the_horizon_is_outside() {
    // Strong perspective: part of the grid maps behind the camera (w ≤ 0).
    let hm = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.02, 1.0]];
    let grid = Grid {
        x_min: -50.0,
        x_max: 50.0,
        y_min: -300.0,
        y_max: 300.0,
        pixel_mm: 1.0,
    };
    let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 9).unwrap();
    // H maps v → y = v/(1 + 0.02 v): y ≥ 50 is beyond the horizon.
    assert!(image_uv(&r, 0.0, 60.0).is_none());
    assert!(image_uv(&r, 0.0, 10.0).is_some());
    let img = GrayImage::from_pixel(400, 400, Luma([100]));
    for r in both_paths(&r) {
        let out = r.rectify_gray8(&img);
        let (row, _) = grid.pixel_of(0.0, 60.0);
        assert_eq!(out.get_pixel(50, row as u32)[0], 9);
    }
}

#[test]
fn bad_homographies_are_errors() {
    let g = Grid::plate();
    let bi = Interpolation::Bilinear;
    let singular = [[1.0, 2.0, 3.0], [2.0, 4.0, 6.0], [0.0, 0.0, 1.0]];
    assert!(matches!(
        Rectifier::new(&camera_of(singular, None), g, bi, 0),
        Err(RectifyError::SingularHomography(_))
    ));
    let zero = [[0.0; 3]; 3];
    assert!(matches!(
        Rectifier::new(&camera_of(zero, None), g, bi, 0),
        Err(RectifyError::ZeroH22)
    ));
    let h22 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
    assert!(matches!(
        Rectifier::new(&camera_of(h22, None), g, bi, 0),
        Err(RectifyError::ZeroH22)
    ));
    let nan = [[f64::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    assert!(matches!(
        Rectifier::new(&camera_of(nan, None), g, bi, 0),
        Err(RectifyError::NonFiniteHomography)
    ));
    // Scale does not matter: a mm-scale homography is fine, and H is normalised.
    let scaled = [[0.04, 0.0, -137.5], [0.0, -0.04, 137.5], [0.0, 0.0, 2.0]];
    let r = Rectifier::new(&camera_of(scaled, None), g, bi, 0).unwrap();
    assert_eq!(r.camera().build_from_image().matrix()[2][2], 1.0);
    let bad_lens = RadialDistortion {
        focal_px: 0.0,
        ..lens()
    };
    assert!(matches!(
        Rectifier::new(&camera_of(scaled, Some(bad_lens)), g, bi, 0),
        Err(RectifyError::InvalidDistortion(_))
    ));
    let e = Rectifier::new(&camera_of(singular, None), g, bi, 0)
        .err()
        .unwrap();
    assert!(e.to_string().contains("singular"));
}

#[test]
fn dlt_maps_the_corners() {
    let img = [
        [1400.0, 600.0],
        [5960.0, 600.0],
        [6900.0, 4500.0],
        [460.0, 4500.0],
    ];
    let build = [
        [-137.5, 137.5],
        [137.5, 137.5],
        [137.5, -137.5],
        [-137.5, -137.5],
    ];
    let h = homography_from_points(img, build).unwrap().matrix();
    assert_eq!(h[2][2], 1.0);
    let r = Rectifier::new(
        &camera_of(h, None),
        Grid::plate(),
        Interpolation::Bilinear,
        0,
    )
    .unwrap();
    for (p, q) in img.iter().zip(build) {
        let (u, v) = image_uv(&r, q[0], q[1]).unwrap();
        assert!((u - p[0]).abs() < 1e-6 && (v - p[1]).abs() < 1e-6);
    }
    let collinear = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 0.0]];
    assert!(homography_from_points(collinear, build).is_err());
}

#[test]
fn simd_gather_paths_match_scalar_and_reference() {
    // Minified (8 grid pixels span > 15 source columns) and steeply rotated
    // views (source rows change within 8 pixels) take the gather paths.
    let (w, h) = (300usize, 220usize);
    let mut nrng = Rng(5);
    let gray = GrayImage::from_fn(w as u32, h as u32, |_, _| Luma([(nrng.next() >> 56) as u8]));
    let rgb = RgbImage::from_fn(w as u32, h as u32, |_, _| {
        Rgb([0, 1, 2].map(|_| (nrng.next() >> 56) as u8))
    });
    let build = [[0.0, 80.0], [100.0, 80.0], [100.0, 0.0], [0.0, 0.0]];
    let (s, c) = 40f64.to_radians().sin_cos();
    let rot = |u: f64, v: f64| {
        [
            150.0 + c * (u - 150.0) - s * (v - 110.0),
            110.0 + s * (u - 150.0) + c * (v - 110.0),
        ]
    };
    let views = [
        (
            [[10.0, 10.0], [290.0, 15.0], [295.0, 210.0], [5.0, 205.0]],
            2.5,
        ),
        (
            [
                rot(70.0, 60.0),
                rot(230.0, 60.0),
                rot(240.0, 170.0),
                rot(60.0, 170.0),
            ],
            0.3,
        ),
    ];
    for (img, pixel_mm) in views {
        let hm = homography_from_points(img, build).unwrap().matrix();
        let grid = Grid {
            x_min: -10.0,
            x_max: 110.0,
            y_min: -10.0,
            y_max: 90.0,
            pixel_mm,
        };
        let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 17).unwrap();
        let [simd, scalar] = both_paths(&r);
        let out = simd.rectify_gray8(&gray);
        assert_eq!(out, scalar.rectify_gray8(&gray));
        let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
        let at = |x: usize, y: usize, _| f64::from(gray.get_pixel(x as u32, y as u32)[0]);
        assert!(check_against_reference(&r, w, h, 1, at, &got, 17) > 1000);
        let out = simd.rectify_rgb8(&rgb);
        assert_eq!(out, scalar.rectify_rgb8(&rgb));
        let got: Vec<u32> = out.as_raw().iter().map(|&v| v.into()).collect();
        let at = |x: usize, y: usize, ch: usize| f64::from(rgb.get_pixel(x as u32, y as u32)[ch]);
        assert!(check_against_reference(&r, w, h, 3, at, &got, 17) > 1000);
    }
}

#[test]
fn into_variants_reuse_or_resize_the_buffer() {
    let mut rng = Rng(11);
    let (w, h) = (120usize, 90usize);
    let img = RgbImage::from_fn(w as u32, h as u32, |x, y| {
        Rgb([0, 1, 2].map(|c| (smooth(x as usize, y as usize, c) * 255.0) as u8))
    });
    let (hm, grid) = random_oblique(&mut rng, w as f64, h as f64);
    let r = Rectifier::new(&camera_of(hm, None), grid, Interpolation::Bilinear, 0).unwrap();
    let want = r.rectify_rgb8(&img);
    let mut dst = RgbImage::new(3, 3); // wrong size: replaced
    r.rectify_rgb8_into(&img, &mut dst);
    assert_eq!(dst, want);
    // Stale contents are fully overwritten, fill included.
    for p in dst.pixels_mut() {
        *p = Rgb([1, 2, 3]);
    }
    let ptr = dst.as_ptr();
    r.rectify_rgb8_into(&img, &mut dst);
    assert_eq!(dst, want);
    assert_eq!(dst.as_ptr(), ptr, "right-sized buffer is reused");
    let gray = luma(&img);
    let mut g = GrayImage::new(0, 0);
    r.rectify_gray8_into(&gray, &mut g);
    assert_eq!(g, r.rectify_gray8(&gray));
}
