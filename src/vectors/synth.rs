//! Synthetic CLI content for tests and benchmarks.

use std::f64::consts::TAU;

use super::{Direction, Format, Hatches, Header, Layer, MarkingParameter, Polyline, VectorFile};

/// Generates a ring-shaped part: per layer an outer contour (counter-clockwise), an inner
/// contour (clockwise), `hatches_per_layer` hatch segments across the ring (rotated by 67° from
/// layer to layer) and CLI+ marking parameters. Units are 0.001 mm, layers 0.03 mm apart;
/// coordinates are not multiples of the unit, so writing and reading them back tests precision.
///
/// `generate(1000, 10_000, 64)` makes 1,000 layers with 10^7 hatch segments.
pub fn generate(layers: usize, hatches_per_layer: usize, points_per_contour: usize) -> VectorFile {
    let mut header = Header::new(Format::Ascii, 0.001);
    header.version = Some("200".to_string());
    header.date = Some("20240702".to_string());
    header.labels = vec![(1, "synthetic ring".to_string())];
    header.layers_declared = u32::try_from(layers).ok();
    let thickness = 0.03;
    let r_out_max = 10.5;
    header.dimension_mm = Some([
        -r_out_max,
        -r_out_max,
        thickness,
        r_out_max,
        r_out_max,
        thickness * layers as f64,
    ]);
    let n = points_per_contour.max(3);
    let out = (0..layers)
        .map(|k| {
            let kf = k as f64;
            let z = thickness * (kf + 1.0);
            let r_out = 10.0 + 0.5 * (kf * 0.1).sin();
            let r_in = 4.0 + 0.25 * (kf * 0.07).cos();
            let phase = kf * 0.013;
            let contour = |r: f64, sign: f64| -> Vec<[f64; 2]> {
                (0..=n)
                    .map(|i| {
                        let a = phase + sign * TAU * (i % n) as f64 / n as f64;
                        [r * a.cos(), r * a.sin()]
                    })
                    .collect()
            };
            let angle = (67.0 * kf).to_radians();
            let (s, c) = angle.sin_cos();
            let segments = (0..hatches_per_layer)
                .map(|i| {
                    // Lines across the outer circle, evenly spaced, alternating direction.
                    let t = (i as f64 + 0.5) / hatches_per_layer as f64;
                    let y = r_out * (2.0 * t - 1.0);
                    let half = (r_out * r_out - y * y).max(0.0).sqrt();
                    let (x0, x1) = if i % 2 == 0 {
                        (-half, half)
                    } else {
                        (half, -half)
                    };
                    let rot = |x: f64, y: f64| [x * c - y * s, x * s + y * c];
                    let [sx, sy] = rot(x0, y);
                    let [ex, ey] = rot(x1, y);
                    [sx, sy, ex, ey]
                })
                .collect();
            let mut parameters = vec![
                MarkingParameter::Power(200.0 + (k % 3) as f64 * 12.5),
                MarkingParameter::Speed(1000.0),
            ];
            if k % 10 == 0 {
                parameters.push(MarkingParameter::Focus(0.5));
            }
            Layer {
                index: k,
                z_mm: z,
                polylines: vec![
                    Polyline {
                        part: 1,
                        direction: Direction::CounterClockwise,
                        points: contour(r_out, 1.0),
                    },
                    Polyline {
                        part: 1,
                        direction: Direction::Clockwise,
                        points: contour(r_in, -1.0),
                    },
                ],
                hatches: vec![Hatches { part: 1, segments }],
                parameters,
            }
        })
        .collect();
    VectorFile {
        header,
        layers: out,
    }
}

/// A layer of closed contours only (test scenes drawn in code): per part, numbered from 1 in
/// order, its rings in mm, the outer first (written counter-clockwise) and its holes after
/// (clockwise); each ring is closed here.
pub fn contour_layer(index: usize, z_mm: f64, parts: &[&[Vec<(f64, f64)>]]) -> Layer {
    let mut layer = Layer::new(index, z_mm);
    for (k, rings) in parts.iter().enumerate() {
        for (i, ring) in rings.iter().enumerate() {
            let mut points: Vec<[f64; 2]> = ring.iter().map(|&(x, y)| [x, y]).collect();
            if let Some(&first) = points.first() {
                points.push(first);
            }
            layer.polylines.push(Polyline {
                part: k as i64 + 1,
                direction: if i == 0 {
                    Direction::CounterClockwise
                } else {
                    Direction::Clockwise
                },
                points,
            });
        }
    }
    layer
}
