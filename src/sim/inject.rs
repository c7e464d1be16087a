//! Anomalies the mock camera renders on purpose (`[camera] inject`, `layerwise demo --inject`),
//! so the inspection can be tested against a known truth, and the demo parts as a vector file
//! (part `k` of the vectors is `mock_camera::demo_parts(layer)[k - 1]`).

use crate::config::inspection::{InjectKind, MockInjection};
use crate::config::UnfusedSpot;
use crate::shot::Phase;
use crate::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};
use mock_camera::{demo_parts, Defect, Illumination, Shape, DEMO_LAYER_THICKNESS_MM};

const HALF: f64 = 137.5;

/// The fused shapes and the defects the camera sees on `layer` in `phase`.
pub fn scene(injections: &[MockInjection], layer: u32, phase: Phase) -> (Vec<Shape>, Vec<Defect>) {
    let mut fused = demo_parts(layer);
    let below = demo_parts(layer.saturating_sub(1));
    let mut defects = Vec::new();
    for inj in injections.iter().filter(|i| i.covers(layer)) {
        let part = |list: &[Shape]| {
            let k = inj.get("part").round().max(1.0) as usize - 1;
            list.get(k).cloned().map(|s| (k, s))
        };
        match (inj.kind, phase) {
            (InjectKind::Streak, Phase::Pre) => {
                let (y, w) = (inj.get("y"), inj.get("w").abs() / 2.0);
                defects.push(Defect {
                    region: Shape::Rect {
                        x_min: inj.get("from"),
                        x_max: inj.get("to"),
                        y_min: y - w,
                        y_max: y + w,
                    },
                    clip: None,
                    metal: false,
                    unfused: false,
                    delta: inj.get("c"),
                    light: None,
                });
            }
            (InjectKind::ShortFeed, Phase::Pre) => {
                let x = inj.get("x");
                let band = (x, -HALF, HALF, HALF);
                defects.push(Defect {
                    region: Shape::Rect {
                        x_min: x,
                        x_max: HALF,
                        y_min: -HALF,
                        y_max: HALF,
                    },
                    clip: None,
                    metal: false,
                    unfused: false,
                    delta: -inj.get("c"),
                    light: None,
                });
                // The layer below shows through.
                defects.extend(below.iter().map(|s| Defect {
                    region: s.clone(),
                    clip: Some(band),
                    metal: true,
                    unfused: false,
                    delta: 0.0,
                    light: None,
                }));
            }
            (InjectKind::Elevation, Phase::Pre) => {
                if let Some((_, s)) = part(&below) {
                    let (x0, y0, _, y1) = s.bbox();
                    defects.push(Defect {
                        region: s,
                        clip: Some((x0, y0, x0 + inj.get("w"), y1)),
                        metal: true,
                        unfused: false,
                        delta: inj.get("c"),
                        light: Some(Illumination::Side),
                    });
                }
            }
            (InjectKind::NoFusion, Phase::Post) => {
                if let Some((k, _)) = part(&fused) {
                    // Powder where the part should be: an empty polygon fuses nothing.
                    fused[k] = Shape::Polygon { rings: vec![] };
                }
            }
            (InjectKind::WideFusion, Phase::Post) => {
                if let Some((k, s)) = part(&fused) {
                    fused[k] = grown(&s, inj.get("d"));
                }
            }
            (InjectKind::Spatter, Phase::Post) => {
                let (cx, cy, r) = (inj.get("x"), inj.get("y"), inj.get("r").abs());
                for k in 0..inj.get("n").round().max(1.0) as u32 {
                    // Spread over ±8 mm, different on every layer.
                    let a = f64::from(k) * 2.399 + f64::from(layer) * 0.7;
                    let d = 3.0 + 5.0 * ((f64::from(k) * 0.618 + f64::from(layer) * 0.13) % 1.0);
                    fused.push(Shape::Circle {
                        cx: cx + d * a.cos(),
                        cy: cy + d * a.sin(),
                        r,
                    });
                }
            }
            (InjectKind::Drift, Phase::Post) => {
                if let Some((_, s)) = part(&fused) {
                    let steps = f64::from(inj.last - inj.first + 1);
                    let step = f64::from(layer - inj.first + 1);
                    defects.push(Defect {
                        region: s,
                        clip: None,
                        metal: false,
                        unfused: false,
                        delta: inj.get("c") * step / steps,
                        light: None,
                    });
                }
            }
            _ => {}
        }
    }
    (fused, defects)
}

/// Grey levels a lack-of-fusion spot is darker than fresh powder: its hollow is shadowed.
const UNFUSED_DARKER: f64 = 25.0;

/// The lack-of-fusion spots of `layer` as the camera sees them after the scan: coarse, shadowed
/// powder in an irregular outline where the layer should have fused. None before the scan: the
/// fresh powder covers the layer.
pub fn unfused(spots: &[UnfusedSpot], layer: u32, phase: Phase) -> Vec<Defect> {
    if phase != Phase::Post {
        return Vec::new();
    }
    spots
        .iter()
        .filter(|s| s.layer == layer)
        .map(|s| Defect {
            region: ragged(s),
            clip: None,
            metal: false,
            unfused: true,
            delta: -UNFUSED_DARKER,
            light: None,
        })
        .collect()
}

/// A spot's outline: within the pore's cut (the CT's void), pulled in by up to 30 % by three low
/// harmonics, their amplitudes and phases drawn from its seed (melt-pool gaps are never round).
fn ragged(spot: &UnfusedSpot) -> Shape {
    let mut rng = crate::learn::rng::Rng::new(spot.shape_seed);
    let waves: Vec<(f64, f64, f64)> = (2..=4)
        .map(|n| {
            let amplitude = rng.range(0.0, 0.05);
            (
                f64::from(n),
                amplitude,
                rng.range(0.0, std::f64::consts::TAU),
            )
        })
        .collect();
    let most: f64 = waves.iter().map(|w| w.1).sum();
    let [cx, cy] = spot.center_mm;
    let ring = (0..48)
        .map(|k| {
            let a = std::f64::consts::TAU * f64::from(k) / 48.0;
            let f: f64 = waves.iter().map(|(n, w, p)| w * (n * a + p).cos()).sum();
            let r = spot.radius_mm * (1.0 - most + f);
            (cx + r * a.cos(), cy + r * a.sin())
        })
        .collect();
    Shape::Polygon { rings: vec![ring] }
}

/// `shape` grown by `d` mm on every side.
fn grown(shape: &Shape, d: f64) -> Shape {
    match shape {
        Shape::Circle { cx, cy, r } => Shape::Circle {
            cx: *cx,
            cy: *cy,
            r: r + d,
        },
        other => {
            let (x_min, y_min, x_max, y_max) = other.bbox();
            Shape::Rect {
                x_min: x_min - d,
                y_min: y_min - d,
                x_max: x_max + d,
                y_max: y_max + d,
            }
        }
    }
}

/// A shape's outline as a counter-clockwise contour.
fn outline(shape: &Shape) -> Vec<[f64; 2]> {
    match shape {
        Shape::Circle { cx, cy, r } => (0..96)
            .map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / 96.0;
                [cx + r * a.cos(), cy + r * a.sin()]
            })
            .collect(),
        Shape::Rect {
            x_min,
            y_min,
            x_max,
            y_max,
        } => vec![
            [*x_min, *y_min],
            [*x_max, *y_min],
            [*x_max, *y_max],
            [*x_min, *y_max],
        ],
        Shape::Polygon { rings } => rings
            .first()
            .map(|r| r.iter().map(|&(x, y)| [x, y]).collect())
            .unwrap_or_default(),
    }
}

/// The demo parts of layers 1..=`layers` as a CLI vector file: contours only, part k+1 for
/// `demo_parts(layer)[k]`, layer n at z = n x 0.03 mm.
pub fn demo_vectors(layers: u32) -> VectorFile {
    let mut header = Header::new(Format::Ascii, 0.001);
    header.labels = vec![
        (1, "cylinder".into()),
        (2, "fin".into()),
        (3, "box".into()),
        (4, "wall".into()),
    ];
    header.layers_declared = Some(layers);
    let layers = (1..=layers)
        .map(|n| {
            let mut layer = Layer::new(n as usize - 1, f64::from(n) * DEMO_LAYER_THICKNESS_MM);
            for (k, shape) in demo_parts(n).iter().enumerate() {
                let mut points = outline(shape);
                if let Some(first) = points.first().copied() {
                    points.push(first);
                }
                layer.polylines.push(Polyline {
                    part: k as i64 + 1,
                    direction: Direction::CounterClockwise,
                    points,
                });
            }
            layer
        })
        .collect();
    VectorFile { header, layers }
}

/// Writes [`demo_vectors`] to `path` (ASCII CLI).
pub fn write_demo_vectors(path: &std::path::Path, layers: u32) -> std::io::Result<()> {
    let mut bytes = Vec::new();
    crate::vectors::write_ascii(&demo_vectors(layers), &mut bytes)?;
    crate::fsutil::write_atomic(path, &bytes, false)
        .map_err(|e| std::io::Error::other(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn injections_change_only_their_layers_and_phases() {
        let list = crate::config::inspection::parse_injections(
            "streak@5,no-fusion@6/part=1,wide-fusion@7,spatter@8/n=3",
        )
        .unwrap();
        let (fused, defects) = scene(&list, 4, Phase::Pre);
        assert!(defects.is_empty() && fused == demo_parts(4));
        assert_eq!(scene(&list, 5, Phase::Pre).1.len(), 1);
        assert!(scene(&list, 5, Phase::Post).1.is_empty());
        let (no, _) = scene(&list, 6, Phase::Post);
        assert!(!no[0].contains(-60.0, 40.0));
        let (wide, _) = scene(&list, 7, Phase::Post);
        assert!(wide[2].contains(39.0, 50.0) && !demo_parts(7)[2].contains(39.0, 50.0));
        assert_eq!(scene(&list, 8, Phase::Post).0.len(), 7);
        let drift = crate::config::inspection::parse_injections("drift@10..13/c=-40").unwrap();
        let ramp: Vec<f64> = (9..=14)
            .flat_map(|l| scene(&drift, l, Phase::Post).1)
            .map(|d| d.delta)
            .collect();
        assert_eq!(ramp, vec![-10.0, -20.0, -30.0, -40.0]);
        assert!(scene(&drift, 11, Phase::Pre).1.is_empty());
    }

    #[test]
    fn demo_vectors_read_back_as_the_demo_parts() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("demo.cli");
        write_demo_vectors(&path, 3).unwrap();
        let file = crate::vectors::read(&path).unwrap();
        assert_eq!(file.layers.len(), 3);
        assert!((file.layers[2].z_mm - 0.09).abs() < 1e-9);
        assert_eq!(file.layers[0].polylines.len(), 4);
        assert_eq!(file.layers[0].polylines[2].part, 3);
    }

    #[test]
    fn an_unfused_spot_shows_after_its_layer_scan_only_ragged_around_its_centre() {
        let spot = UnfusedSpot {
            layer: 12,
            center_mm: [50.0, 50.0],
            radius_mm: 0.6,
            shape_seed: 3,
        };
        let spots = [spot.clone()];
        assert!(unfused(&spots, 12, Phase::Pre).is_empty());
        assert!(unfused(&spots, 11, Phase::Post).is_empty());
        let seen = unfused(&spots, 12, Phase::Post);
        assert_eq!(seen.len(), 1);
        let d = &seen[0];
        assert!(d.unfused && !d.metal && d.delta < 0.0);
        // Inside the pore's cut, never past it.
        for k in 0..48 {
            let a = std::f64::consts::TAU * f64::from(k) / 48.0;
            let at = |r: f64| d.region.contains(50.0 + r * a.cos(), 50.0 + r * a.sin());
            assert!(at(0.0) && at(0.6 * 0.69) && !at(0.6 * 1.01), "{a}");
        }
        // Not a circle: its radius varies around it.
        let radii: Vec<f64> = (0..48)
            .filter_map(|k| {
                let a = std::f64::consts::TAU * f64::from(k) / 48.0;
                (40..80)
                    .map(|i| f64::from(i) * 0.01)
                    .find(|r| !d.region.contains(50.0 + r * a.cos(), 50.0 + r * a.sin()))
            })
            .collect();
        let (lo, hi) = radii
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), r| (a.min(*r), b.max(*r)));
        assert!(hi - lo > 0.05, "{lo}..{hi}");
    }
}
