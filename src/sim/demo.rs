//! The files a demo build ships so that a new user can try every offline step on it: the vector
//! file of the parts the mock camera photographs, and a points file of four clicks (part corners
//! in the frame, as a user would click them: a few pixels off).

use crate::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};
use mock_camera::{Homography, Shape};
use std::f64::consts::TAU;

/// Name of the vector file in a demo build directory.
pub const DEMO_VECTORS: &str = "demo-vectors.cli";
/// Name of the points file (`register images --init`) in a demo build directory.
pub const DEMO_POINTS: &str = "demo-points.txt";

/// Polylines of one mock shape, part `part` (circles as 256-gons).
fn polylines(shape: &Shape, part: i64) -> Vec<Polyline> {
    let ring = |points: Vec<(f64, f64)>, direction| {
        let mut points: Vec<[f64; 2]> = points.into_iter().map(|(x, y)| [x, y]).collect();
        points.push(points[0]);
        Polyline {
            part,
            direction,
            points,
        }
    };
    match shape {
        Shape::Circle { cx, cy, r } => vec![ring(
            (0..256)
                .map(|i| {
                    let a = TAU * f64::from(i) / 256.0;
                    (cx + r * a.cos(), cy + r * a.sin())
                })
                .collect(),
            Direction::CounterClockwise,
        )],
        Shape::Rect {
            x_min,
            y_min,
            x_max,
            y_max,
        } => vec![ring(
            vec![
                (*x_min, *y_min),
                (*x_max, *y_min),
                (*x_max, *y_max),
                (*x_min, *y_max),
            ],
            Direction::CounterClockwise,
        )],
        Shape::Polygon { rings } => rings
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let direction = if i == 0 {
                    Direction::CounterClockwise
                } else {
                    Direction::Clockwise
                };
                ring(r.clone(), direction)
            })
            .collect(),
    }
}

/// The demo's parts (`mock_camera::demo_parts`) as a CLI file of `layers` layers, `thickness_mm`
/// apart: printer layer n is the file's n-th layer at z = n x thickness. The cylinder and its fin
/// are part 1, the box part 2, the wall part 3.
pub fn demo_vectors(layers: u32, thickness_mm: f64) -> VectorFile {
    let mut header = Header::new(Format::Ascii, 0.001);
    header.labels = vec![
        (1, "cylinder with fin".into()),
        (2, "box".into()),
        (3, "wall".into()),
    ];
    header.layers_declared = Some(layers);
    let layers = (1..=layers)
        .map(|n| {
            let mut layer = Layer::new(n as usize - 1, f64::from(n) * thickness_mm);
            for (k, shape) in mock_camera::demo_parts(n).iter().enumerate() {
                let part = [1, 1, 2, 3][k.min(3)];
                layer.polylines.extend(polylines(shape, part));
            }
            layer
        })
        .collect();
    VectorFile { header, layers }
}

/// Four clicks on part corners of the demo frame of a `width` x `height` mock camera: the true
/// image positions moved by up to 3 px, as a user's clicks are. Lines `u v x y` with a comment.
pub fn demo_points(width: u32, height: u32) -> String {
    let truth = Homography::oblique_view(width, height);
    let image_from_build = truth.inverse().expect("the mock's view is invertible");
    // Corners of the box, of the fin and of the wall (layer 1), clicked a little off.
    let clicks = [
        ((40.0, 44.0), (2.1, -1.4)),
        ((60.0, 56.0), (-1.8, 2.6)),
        ((-40.0, 40.5), (1.2, 1.9)),
        ((-9.0, -90.0), (-2.7, -0.8)),
    ];
    let mut text = String::from(
        "# Four part corners clicked in a demo frame: u v (image px) x y (build mm).\n\
         # register images --init reads this file; see the README's tutorial.\n",
    );
    // Click errors scale with the frame (a few pixels at 1472 px wide).
    let scale = f64::from(width) / 1472.0;
    for ((x, y), (du, dv)) in clicks {
        let (u, v) = image_from_build.apply(x, y).expect("in view");
        text += &format!("{:.1} {:.1} {x} {y}\n", u + scale * du, v + scale * dv);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_vectors_hold_the_mock_parts_per_layer() {
        let file = demo_vectors(5, 0.03);
        assert_eq!(file.layers.len(), 5);
        assert!((file.layers[4].z_mm - 0.15).abs() < 1e-12);
        // The wall moves by one layer thickness per layer.
        let wall_x = |k: usize| {
            file.layers[k]
                .polylines
                .iter()
                .find(|p| p.part == 3)
                .map(|p| p.points[0][0])
                .unwrap()
        };
        assert!((wall_x(1) - wall_x(0) - 0.03).abs() < 1e-9);
        let mut bytes = Vec::new();
        crate::vectors::write_ascii(&file, &mut bytes).unwrap();
        let back = crate::vectors::read_bytes(&bytes, "demo").unwrap();
        assert_eq!(back.layers.len(), 5);
    }

    #[test]
    fn demo_points_parse_and_land_near_the_truth() {
        let text = demo_points(320, 214);
        let points =
            crate::calibrate::parse_points(&text, std::path::Path::new("demo-points.txt")).unwrap();
        assert_eq!(points.len(), 4);
        let truth = Homography::oblique_view(320, 214);
        for p in points {
            let (x, y) = truth.apply(p.image.u, p.image.v).unwrap();
            assert!((x - p.build.x).hypot(y - p.build.y) < 2.0);
        }
    }
}
