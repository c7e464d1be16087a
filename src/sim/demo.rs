//! The files a demo build ships so that a new user can try every offline step on it: the vector
//! file of the parts the mock camera photographs (`sim::inject::demo_vectors`), and a points file
//! of four clicks (part corners in the frame, as a user would click them: a few pixels off).

use mock_camera::Homography;

/// Name of the vector file in a demo build directory.
pub const DEMO_VECTORS: &str = "demo-vectors.cli";
/// Name of the points file (`register images --init`) in a demo build directory.
pub const DEMO_POINTS: &str = "demo-points.txt";

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
