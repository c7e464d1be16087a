//! Criterion bench of the registration: the IC-LM alignment alone (inputs prepared once) and
//! the preparation (exemplar + footprint std filter), on a 1472 x 982 mock frame with parts over
//! the plate. The side-by-side with OpenCV's ECC is bench/ecc_vs_ours.py.
//! Run: `cargo bench --bench registration`.

use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use layerwise::calibrate::{
    align, dlt_build_from_image, filter_frame, luma_f32, render_exemplar, Correspondence,
    LmOptions, Pair,
};
use layerwise::geometry::{BuildPoint, Grid, Homography, ImagePoint};
use layerwise::vectors::{Direction, Layer, Polyline};
use mock_camera::{Illumination, Renderer, Scene, Shape};

const W: u32 = 1472;
const H: u32 = 982;

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<(f64, f64)> {
    vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
}

fn setup() -> (image::DynamicImage, Layer, Homography, Grid) {
    let truth = mock_camera::Homography::oblique_view(W, H);
    let rings = [
        rect(40.0, 40.0, 70.0, 62.0),
        rect(-90.0, -30.0, -55.0, 5.0),
        rect(-15.0, -85.0, 25.0, -60.0),
        rect(60.0, -70.0, 92.0, -38.0),
        rect(-80.0, 35.0, -58.0, 70.0),
    ];
    let shapes: Vec<Shape> = rings
        .iter()
        .map(|r| Shape::Polygon {
            rings: vec![r.clone()],
        })
        .collect();
    let frame = Renderer::new(W, H, truth).render(&Scene {
        layer: 1,
        fused: &shapes,
        scanned: true,
        illumination: Illumination::Top,
    });
    let mut layer = Layer::new(0, 0.03);
    for (k, r) in rings.iter().enumerate() {
        let mut points: Vec<[f64; 2]> = r.iter().map(|&(x, y)| [x, y]).collect();
        points.push(points[0]);
        layer.polylines.push(Polyline {
            part: k as i64 + 1,
            direction: Direction::CounterClockwise,
            points,
        });
    }
    let inv = truth.inverse().expect("invertible");
    let clicks: Vec<Correspondence> = [(70.0, 62.0), (-90.0, -30.0), (25.0, -85.0), (92.0, -70.0)]
        .iter()
        .zip([(5.0, -4.0), (-6.0, 3.0), (4.0, 6.0), (-4.0, -5.0)])
        .map(|(&(x, y), (du, dv))| {
            let (u, v) = inv.apply(x, y).expect("in view");
            Correspondence {
                image: ImagePoint::new(u + du, v + dv),
                build: BuildPoint::new(x, y),
                line: 0,
            }
        })
        .collect();
    let build_from_image0 = dlt_build_from_image(&clicks, Path::new("bench")).expect("clicks");
    let grid = Grid {
        x_min: -105.0,
        x_max: 105.0,
        y_min: -100.0,
        y_max: 80.0,
        pixel_mm: 0.3,
    };
    (
        image::DynamicImage::ImageRgb8(frame),
        layer,
        build_from_image0,
        grid,
    )
}

fn bench(c: &mut Criterion) {
    let (frame, layer, build_from_image0, grid) = setup();
    let lum = luma_f32(&frame);
    let (exemplar, extent) = render_exemplar(&layer, &grid, 11, 2, 0x5EED).expect("exemplar");
    let (image, _) = filter_frame(&lum, &build_from_image0, &grid, extent, true).expect("filter");
    let start = build_from_image0
        .inverse()
        .expect("regular")
        .compose(&Homography::build_from_grid(&grid));
    let pair = [Pair {
        image: &image,
        exemplar: &exemplar,
    }];
    let opts = LmOptions::default();
    let mut g = c.benchmark_group("registration_1472x982");
    g.sample_size(10);
    g.bench_function("align_ic_lm", |b| {
        b.iter(|| align(&pair, start, None, &opts).expect("aligns"))
    });
    g.bench_function("prepare_exemplar_and_filter", |b| {
        b.iter(|| {
            let (e, extent) = render_exemplar(&layer, &grid, 11, 2, 0x5EED).expect("exemplar");
            let f = filter_frame(&lum, &build_from_image0, &grid, extent, true).expect("filter");
            (e.data.len(), f.0.data.len())
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
