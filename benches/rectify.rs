//! Rectify and decode benches on full-size frames (7360 x 4912 → 4400 x 4400).
//!
//! `cargo bench --bench rectify`.
//! Uses all rayon threads; `RAYON_NUM_THREADS=1` for per-core figures.

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use image::{DynamicImage, GrayImage, ImageFormat, Rgb, RgbImage};
use layerwise::geometry::{homography_from_points, CameraModel, Homography};
use layerwise::rectify::{decode_jpeg, luma, Grid, Interpolation, RadialDistortion, Rectifier};

const W: u32 = 7360;
const H: u32 = 4912;

/// Deterministic textured frame: smooth colour blobs, fine noise and
/// hard-edged stripes, so neither the warp nor the JPEG coder sees a flat field.
fn frame() -> RgbImage {
    let hash = |x: u32, y: u32| {
        let mut v = x.wrapping_mul(0x9E37_79B1) ^ y.wrapping_mul(0x85EB_CA77);
        v ^= v >> 15;
        v = v.wrapping_mul(0x2C1B_3C6D);
        v ^ (v >> 12)
    };
    RgbImage::from_fn(W, H, |x, y| {
        let (fx, fy) = (x as f32, y as f32);
        let noise = (hash(x, y) & 31) as f32 - 16.0;
        let stripe = if (x / 37 + y / 53) % 2 == 0 {
            0.55
        } else {
            1.0
        };
        let c = |k: f32| {
            let s = 128.0 + 90.0 * ((fx * 0.004 + k).sin() * (fy * 0.0053 - k).cos());
            ((s + noise) * stripe).clamp(0.0, 255.0) as u8
        };
        Rgb([c(0.0), c(1.3), c(2.6)])
    })
}

/// The oblique 30° view: plate corners → image trapezoid, by DLT.
fn oblique() -> Homography {
    homography_from_points(
        [
            [1400.0, 600.0],
            [5960.0, 600.0],
            [6900.0, 4500.0],
            [460.0, 4500.0],
        ],
        [
            [-137.5, 137.5],
            [137.5, 137.5],
            [137.5, -137.5],
            [-137.5, -137.5],
        ],
    )
    .expect("bench homography")
}

fn bench_rectify(c: &mut Criterion) {
    let rgb = frame();
    let gray = luma(&rgb);
    let h = oblique();
    let plain = |interp| {
        Rectifier::new(&CameraModel::pinhole(h), Grid::plate(), interp, 0).expect("rectifier")
    };
    let lens = RadialDistortion {
        center: [3680.0, 2456.0],
        focal_px: 9000.0,
        k1: -0.05,
        k2: 0.01,
    };
    let bilinear = plain(Interpolation::Bilinear);
    let bicubic = plain(Interpolation::Bicubic);
    let camera = CameraModel::new(h, Some(lens));
    let distorted =
        Rectifier::new(&camera, Grid::plate(), Interpolation::Bilinear, 0).expect("rectifier");

    let mut g = c.benchmark_group("rectify_7360x4912_to_4400");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(4));
    g.bench_function("rgb8", |b| {
        b.iter(|| black_box(bilinear.rectify_rgb8(&rgb)))
    });
    g.bench_function("gray8", |b| {
        b.iter(|| black_box(bilinear.rectify_gray8(&gray)))
    });
    let mut rgb_out = RgbImage::new(0, 0);
    g.bench_function("rgb8_into_reused", |b| {
        b.iter(|| bilinear.rectify_rgb8_into(&rgb, &mut rgb_out))
    });
    let mut gray_out = GrayImage::new(0, 0);
    g.bench_function("gray8_into_reused", |b| {
        b.iter(|| bilinear.rectify_gray8_into(&gray, &mut gray_out))
    });
    g.bench_function("gray8_distortion", |b| {
        b.iter(|| black_box(distorted.rectify_gray8(&gray)))
    });
    g.bench_function("rgb8_distortion", |b| {
        b.iter(|| black_box(distorted.rectify_rgb8(&rgb)))
    });
    g.bench_function("gray8_bicubic", |b| {
        b.iter(|| black_box(bicubic.rectify_gray8(&gray)))
    });
    g.finish();
}

fn bench_decode(c: &mut Criterion) {
    let mut jpeg = Vec::new();
    let enc = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90);
    DynamicImage::ImageRgb8(frame())
        .write_with_encoder(enc)
        .expect("encode bench JPEG");

    let mut g = c.benchmark_group("decode_jpeg_7360x4912_q90");
    g.sample_size(10)
        .warm_up_time(Duration::from_secs(1))
        .measurement_time(Duration::from_secs(6));
    g.bench_function("zune_jpeg", |b| {
        b.iter(|| black_box(decode_jpeg(&jpeg).expect("zune")))
    });
    // libjpeg-turbo (turbojpeg crate) was measured too when the decoder was chosen: 190 ms against
    // zune-jpeg's 210 ms on this frame; zune-jpeg needs no system library.
    g.bench_function("luma_only", |b| {
        b.iter(|| black_box(layerwise::rectify::decode_jpeg_luma(&jpeg).expect("zune luma")))
    });
    g.bench_function("image_crate", |b| {
        b.iter(|| {
            black_box(image::load_from_memory_with_format(&jpeg, ImageFormat::Jpeg).expect("image"))
        })
    });
    g.finish();
}

criterion_group!(benches, bench_rectify, bench_decode);
criterion_main!(benches);
