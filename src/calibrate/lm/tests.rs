//! Unit tests of the IC-LM on smooth synthetic images.

use rayon::prelude::*;

use super::driver::align;
use super::pyramid::{active_spans, downsample, level_scale, warp_from_level, warp_to_level};
use super::{F32Image, LmOptions, Pair};
use crate::calibrate::RegistrationError;
use crate::geometry::mat3::{self, Mat3};
use crate::geometry::{Homography, RadialDistortion};

const BLOB_CENTERS: [(f64, f64); 4] = [(60.0, 50.0), (130.0, 70.0), (90.0, 120.0), (40.0, 130.0)];

/// A smooth blob image: sum of Gaussians, defined on continuous coordinates.
fn blobs(x: f64, y: f64) -> f64 {
    let g = |cx: f64, cy: f64, s: f64, a: f64| {
        a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
    };
    g(60.0, 50.0, 9.0, 80.0)
        + g(130.0, 70.0, 12.0, 60.0)
        + g(90.0, 120.0, 7.0, 90.0)
        + g(40.0, 130.0, 10.0, 50.0)
}

fn render(w: usize, h: usize, f: impl Fn(f64, f64) -> f64 + Sync) -> F32Image {
    let data = (0..w * h)
        .into_par_iter()
        .map(|i| f((i % w) as f64, (i / w) as f64) as f32)
        .collect();
    F32Image {
        width: w,
        height: h,
        data,
    }
}

fn apply(m: &Mat3, x: f64, y: f64) -> (f64, f64) {
    mat3::project(m, x, y).expect("in front")
}

#[test]
fn warp_level_conjugation_round_trips() {
    let m = [[1.1, 0.02, 5.0], [-0.01, 0.95, -3.0], [1e-4, -2e-4, 1.0]];
    for l in 0..4 {
        let back = warp_from_level(&warp_to_level(&m, l), l);
        for (a, b) in back.iter().flatten().zip(m.iter().flatten()) {
            assert!((a - b).abs() < 1e-12);
        }
        // A level-l point maps like its level-0 image.
        let ml = warp_to_level(&m, l);
        let s = level_scale(l);
        let (x, y) = apply(&ml, 7.0, 9.0);
        let (x0, y0) = apply(&s, 7.0, 9.0);
        let (fx, fy) = apply(&m, x0, y0);
        let (sx, sy) = apply(&s, x, y);
        assert!((fx - sx).abs() < 1e-9 && (fy - sy).abs() < 1e-9);
    }
}

#[test]
fn active_spans_dilate_the_support_by_a_square() {
    let mut img = F32Image {
        width: 20,
        height: 12,
        data: vec![0.0; 240],
    };
    img.data[5 * 20 + 7] = 3.0;
    img.data[5 * 20 + 8] = 3.0;
    let spans = active_spans(&img, 1.0, Some(2));
    for (r, row) in spans.iter().enumerate() {
        let want: Vec<(usize, usize)> = if (3..=7).contains(&r) {
            vec![(5, 11)]
        } else {
            vec![]
        };
        assert_eq!(row, &want, "row {r}");
    }
    assert_eq!(active_spans(&img, 1.0, None)[0], vec![(0, 20)]);
}

#[test]
fn downsample_averages_2x2() {
    let img = F32Image {
        width: 5,
        height: 3,
        data: (0..15).map(|v| v as f32).collect(),
    };
    let d = downsample(&img);
    assert_eq!((d.width, d.height), (2, 1));
    assert_eq!(d.data, vec![3.0, 5.0]);
}

#[test]
fn recovers_a_known_warp_on_smooth_images() {
    // Image = template seen through a known homography.
    let truth = [
        [1.03, 0.04, 12.0],
        [-0.03, 0.98, 7.0],
        [1.5e-4, -1.0e-4, 1.0],
    ];
    let inv = mat3::mat_inv(&truth).expect("invertible");
    let template = render(180, 170, blobs);
    let image = render(240, 230, |u, v| {
        let (x, y) = apply(&inv, u, v);
        blobs(x, y) * 0.5 + 7.0
    });
    let start = Homography::from_matrix([[1.0, 0.0, 9.0], [0.0, 1.0, 10.0], [0.0, 0.0, 1.0]]);
    let got = align(
        &[Pair {
            image: &image,
            exemplar: &template,
        }],
        start,
        None,
        &LmOptions::default(),
    )
    .expect("converges");
    // Where the template has structure: the blob centers.
    let mut worst = 0.0f64;
    for (u, v) in BLOB_CENTERS {
        let (a, b) = apply(&got.image_from_exemplar.matrix(), u, v);
        let (c, d) = apply(&truth, u, v);
        worst = worst.max((a - c).hypot(b - d));
    }
    assert!(worst < 0.01, "error {worst} px; {:?}", got.levels);
    let f = &got.pairs[0];
    assert!(f.correlation > 0.999, "{f:?}");
}

#[test]
fn recovers_radial_distortion_jointly() {
    let truth = [[1.0, 0.02, 20.0], [-0.01, 1.0, 15.0], [0.0, 0.0, 1.0]];
    let inv = mat3::mat_inv(&truth).expect("invertible");
    let true_d = RadialDistortion {
        center: [109.5, 104.5],
        focal_px: 150.0,
        k1: -0.08,
        k2: 0.0,
    };
    let template = render(180, 170, blobs);
    let image = render(220, 210, |u, v| {
        let (x, y) = true_d.undistort(u, v);
        let (x, y) = apply(&inv, x, y);
        blobs(x, y)
    });
    let start_d = RadialDistortion { k1: 0.0, ..true_d };
    let opts = LmOptions {
        levels: Some(2),
        ..LmOptions::default()
    };
    let pair = [Pair {
        image: &image,
        exemplar: &template,
    }];
    let got =
        align(&pair, Homography::from_matrix(truth), Some(start_d), &opts).expect("converges");
    let d = got.distortion.expect("distortion");
    assert!((d.k1 + 0.08).abs() < 0.004, "{d:?} {:?}", got.levels);
    let mut worst = 0.0f64;
    for (u, v) in BLOB_CENTERS {
        let (a, b) = apply(&got.image_from_exemplar.matrix(), u, v);
        let (a, b) = d.distort(a, b);
        let (c, e) = apply(&truth, u, v);
        let (c, e) = true_d.distort(c, e);
        worst = worst.max((a - c).hypot(b - e));
    }
    assert!(worst < 0.02, "error {worst} px; {d:?} {:?}", got.levels);
}

#[test]
fn an_unrelated_image_does_not_converge() {
    let template = render(180, 170, blobs);
    // Structure elsewhere only: the blobs moved far beyond the capture range.
    let image = render(240, 230, |u, v| blobs(u + 300.0, v - 250.0) + 5.0);
    let id = Homography::IDENTITY;
    let err = align(
        &[Pair {
            image: &image,
            exemplar: &template,
        }],
        id,
        None,
        &LmOptions::default(),
    )
    .unwrap_err();
    assert!(
        matches!(
            err,
            RegistrationError::NotConverged { .. } | RegistrationError::Diverged { .. }
        ),
        "{err}"
    );
}

#[test]
fn refuses_structureless_exemplars_and_mismatched_sizes() {
    let flat = F32Image {
        width: 64,
        height: 64,
        data: vec![0.0; 64 * 64],
    };
    let img = render(64, 64, blobs);
    let id = Homography::IDENTITY;
    let err = align(
        &[Pair {
            image: &img,
            exemplar: &flat,
        }],
        id,
        None,
        &LmOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("no structure"), "{err}");
    let small = render(32, 32, blobs);
    let err = align(
        &[
            Pair {
                image: &img,
                exemplar: &img,
            },
            Pair {
                image: &img,
                exemplar: &small,
            },
        ],
        id,
        None,
        &LmOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("pair 1"), "{err}");
}
