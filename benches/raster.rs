//! Rasteriser benchmarks (`cargo bench --bench raster`): one full-plate 4400 x 4400 layer,
//! dense with parts: 10 x 10 rings (outer contour counter-clockwise, inner clockwise, 512
//! points each) and hatches 0.1 mm apart across every ring (about 20,000 segments), as mask,
//! 4 x 4 coverage, colour, and the exemplar (mask → noise → 11 x 11 standard deviation).
//! Peak RSS (VmHWM) is printed at the end.

use std::f64::consts::TAU;
use std::hint::black_box;
use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use layerwise::raster::{self, Grid, RasterOptions};
use layerwise::vectors::{Direction, Hatches, Layer, Polyline};

/// A plate full of rings with hatches: 100 parts on a 27 mm pitch.
fn dense_layer() -> Layer {
    let mut layer = Layer::new(0, 0.03);
    let n = 512;
    for i in 0..10 {
        for j in 0..10 {
            let part = (i * 10 + j) as i64;
            let (cx, cy) = (-121.5 + 27.0 * i as f64, -121.5 + 27.0 * j as f64);
            let (ro, ri) = (12.0, 4.0 + 0.3 * (i as f64));
            let ring = |r: f64, sign: f64| -> Vec<[f64; 2]> {
                (0..=n)
                    .map(|k| {
                        let a = sign * TAU * (k % n) as f64 / n as f64;
                        [cx + r * a.cos(), cy + r * a.sin()]
                    })
                    .collect()
            };
            layer.polylines.push(Polyline {
                part,
                direction: Direction::CounterClockwise,
                points: ring(ro, 1.0),
            });
            layer.polylines.push(Polyline {
                part,
                direction: Direction::Clockwise,
                points: ring(ri, -1.0),
            });
            // Hatches across the outer circle at 67° · part, 0.1 mm apart.
            let (s, c) = (67.0f64 * part as f64).to_radians().sin_cos();
            let segments = (0..240)
                .map(|k| {
                    let y = -ro + 0.1 * (k as f64 + 0.5);
                    let h = (ro * ro - y * y).max(0.0).sqrt();
                    let rot = |x: f64, y: f64| [cx + x * c - y * s, cy + x * s + y * c];
                    let (a, b) = (rot(-h, y), rot(h, y));
                    [a[0], a[1], b[0], b[1]]
                })
                .collect();
            layer.hatches.push(Hatches { part, segments });
        }
    }
    layer
}

fn vm_hwm() -> String {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM"))
                .map(str::to_string)
        })
        .unwrap_or_else(|| "VmHWM unknown".to_string())
}

fn bench(c: &mut Criterion) {
    let layer = dense_layer();
    let grid = Grid::plate();
    let opts = RasterOptions::default();
    let mut g = c.benchmark_group("raster_4400");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    g.bench_function("mask", |b| {
        b.iter(|| black_box(raster::mask(&layer, &grid, &opts).expect("mask")))
    });
    g.bench_function("coverage_4x4", |b| {
        b.iter(|| black_box(raster::coverage(&layer, &grid, &opts).expect("coverage")))
    });
    g.bench_function("rgb", |b| {
        b.iter(|| black_box(raster::rgb(&layer, &grid, &opts).expect("rgb")))
    });
    g.bench_function("exemplar_w11", |b| {
        b.iter(|| black_box(raster::exemplar(&layer, &grid, &opts, 11, 1).expect("exemplar")))
    });
    let img: Vec<f32> = (0..grid.columns() * grid.rows())
        .map(|i| (i % 251) as f32)
        .collect();
    for w in [5, 31] {
        g.bench_function(format!("std_filter_w{w}"), |b| {
            b.iter(|| {
                black_box(raster::std_filter(&img, grid.columns(), grid.rows(), w).expect("filter"))
            })
        });
    }
    g.finish();
    println!("peak RSS: {}", vm_hwm());
}

criterion_group!(benches, bench);
criterion_main!(benches);
