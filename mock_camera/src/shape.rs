//! Fused regions in build mm, and the demo parts the mock build prints.

/// A region of one layer in build mm (x, y). Boundaries count as inside for circles and rects.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Disc of radius `r` centered at (`cx`, `cy`).
    Circle { cx: f64, cy: f64, r: f64 },
    /// Axis-aligned rectangle.
    Rect {
        x_min: f64,
        y_min: f64,
        x_max: f64,
        y_max: f64,
    },
    /// Closed rings in build mm, filled by the even-odd rule (so inner rings are holes).
    /// Rings are closed implicitly (last point joins the first); repeating the first point is
    /// harmless.
    Polygon { rings: Vec<Vec<(f64, f64)>> },
}

impl Shape {
    /// Whether build point (x, y) mm lies in the shape (even-odd rule for polygons).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        match self {
            Shape::Circle { cx, cy, r } => {
                let (dx, dy) = (x - cx, y - cy);
                dx * dx + dy * dy <= r * r
            }
            Shape::Rect {
                x_min,
                y_min,
                x_max,
                y_max,
            } => x >= *x_min && x <= *x_max && y >= *y_min && y <= *y_max,
            Shape::Polygon { rings } => {
                let mut inside = false;
                for ring in rings {
                    let n = ring.len();
                    if n < 3 {
                        continue;
                    }
                    let mut j = n - 1;
                    for i in 0..n {
                        let (xi, yi) = ring[i];
                        let (xj, yj) = ring[j];
                        // Half-open crossing test on the ray to +x.
                        if (yi > y) != (yj > y) && x < xj + (y - yj) * (xi - xj) / (yi - yj) {
                            inside = !inside;
                        }
                        j = i;
                    }
                }
                inside
            }
        }
    }

    /// Bounding box `(x_min, y_min, x_max, y_max)` in mm. A polygon without points gives the
    /// empty box `(inf, inf, -inf, -inf)`, which contains nothing.
    pub fn bbox(&self) -> (f64, f64, f64, f64) {
        match self {
            Shape::Circle { cx, cy, r } => {
                let r = r.abs();
                (cx - r, cy - r, cx + r, cy + r)
            }
            Shape::Rect {
                x_min,
                y_min,
                x_max,
                y_max,
            } => (*x_min, *y_min, *x_max, *y_max),
            Shape::Polygon { rings } => rings.iter().flatten().fold(
                (
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ),
                |(a, b, c, d), &(x, y)| (a.min(x), b.min(y), c.max(x), d.max(y)),
            ),
        }
    }
}

/// Layer thickness of the demo build, mm (the 45° wall shifts by this much per layer).
pub const DEMO_LAYER_THICKNESS_MM: f64 = 0.03;
/// The demo wall's offset repeats every this many layers (60 mm of travel), so it never leaves
/// its spot on the plate however high the layer number.
pub const DEMO_WALL_PERIOD_LAYERS: u32 = 2000;

/// A few simple parts for the demo and tests, varying with `layer`, all within ±100 mm:
///
/// 0. a 10 mm diameter cylinder at (−60, 40),
/// 1. its fin: a 15 x 1 mm rect attached to the cylinder's +x side,
/// 2. a 20 x 12 mm box centered at (50, 50),
/// 3. a thin (1 mm) 45° wall, 40 mm long in y, whose x position moves by the layer thickness:
///    x offset = layer · 0.03 mm (wrapping every [`DEMO_WALL_PERIOD_LAYERS`] layers).
pub fn demo_parts(layer: u32) -> Vec<Shape> {
    let offset = f64::from(layer % DEMO_WALL_PERIOD_LAYERS) * DEMO_LAYER_THICKNESS_MM;
    vec![
        Shape::Circle {
            cx: -60.0,
            cy: 40.0,
            r: 5.0,
        },
        Shape::Rect {
            x_min: -55.5,
            y_min: 39.5,
            x_max: -40.0,
            y_max: 40.5,
        },
        Shape::Rect {
            x_min: 40.0,
            y_min: 44.0,
            x_max: 60.0,
            y_max: 56.0,
        },
        Shape::Rect {
            x_min: -10.0 + offset,
            y_min: -90.0,
            x_max: -9.0 + offset,
            y_max: -50.0,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn circle_contains() {
        let c = Shape::Circle {
            cx: 10.0,
            cy: -5.0,
            r: 2.0,
        };
        assert!(c.contains(10.0, -5.0));
        assert!(c.contains(11.9, -5.0));
        assert!(c.contains(10.0, -3.0));
        assert!(!c.contains(11.5, -3.5)); // inside the bbox, outside the disc
        assert!(!c.contains(12.1, -5.0));
        assert_eq!(c.bbox(), (8.0, -7.0, 12.0, -3.0));
    }

    #[test]
    fn rect_contains() {
        let r = Shape::Rect {
            x_min: -1.0,
            y_min: 2.0,
            x_max: 3.0,
            y_max: 4.0,
        };
        assert!(r.contains(0.0, 3.0));
        assert!(r.contains(-1.0, 2.0));
        assert!(!r.contains(-1.01, 3.0));
        assert!(!r.contains(0.0, 4.01));
        assert_eq!(r.bbox(), (-1.0, 2.0, 3.0, 4.0));
    }

    #[test]
    fn polygon_with_hole_is_even_odd() {
        let outer = vec![(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)];
        let hole = vec![(3.0, 3.0), (7.0, 3.0), (7.0, 7.0), (3.0, 7.0)];
        let p = Shape::Polygon {
            rings: vec![outer, hole],
        };
        assert!(p.contains(1.0, 1.0));
        assert!(p.contains(8.5, 5.0));
        assert!(!p.contains(5.0, 5.0), "inside the hole");
        assert!(!p.contains(-1.0, 5.0));
        assert!(!p.contains(11.0, 5.0));
        assert_eq!(p.bbox(), (0.0, 0.0, 10.0, 10.0));
    }

    #[test]
    fn polygon_triangle_and_degenerate_rings() {
        let tri = Shape::Polygon {
            rings: vec![vec![(0.0, 0.0), (4.0, 0.0), (0.0, 4.0), (0.0, 0.0)]],
        };
        assert!(tri.contains(1.0, 1.0));
        assert!(!tri.contains(3.0, 3.0));
        let empty = Shape::Polygon { rings: vec![] };
        assert!(!empty.contains(0.0, 0.0));
        let (x0, y0, x1, y1) = empty.bbox();
        assert!(x0 > x1 && y0 > y1);
        let line = Shape::Polygon {
            rings: vec![vec![(0.0, 0.0), (1.0, 1.0)]],
        };
        assert!(!line.contains(0.5, 0.5));
    }

    #[test]
    fn demo_parts_move_with_layer_and_stay_on_the_plate() {
        let a = demo_parts(0);
        let b = demo_parts(100);
        assert_eq!(a.len(), 4);
        assert_eq!(a[..3], b[..3], "cylinder, fin and box do not move");
        let wall_x = |p: &[Shape]| p[3].bbox().0;
        assert!((wall_x(&b) - wall_x(&a) - 3.0).abs() < 1e-9);
        for layer in [0, 1, 1999, 2000, u32::MAX] {
            for s in demo_parts(layer) {
                let (x0, y0, x1, y1) = s.bbox();
                for v in [x0, y0, x1, y1] {
                    assert!(v.abs() <= 100.0, "layer {layer}: {s:?}");
                }
            }
        }
        // The fin touches the cylinder.
        assert!(a[0].contains(-55.2, 40.0) && a[1].contains(-55.2, 40.0));
        // The box is 20 x 12 mm.
        let (x0, y0, x1, y1) = a[2].bbox();
        assert_eq!((x1 - x0, y1 - y0), (20.0, 12.0));
    }
}
