//! The registration overlay (paper Fig. 11 left): the frame with the layer's contours drawn
//! through the starting mapping in red and through the refined one in blue.

use image::{DynamicImage, Rgb, RgbImage};

use crate::geometry::{BuildPoint, CameraModel, ImagePoint};
use crate::vectors::{Direction, Layer};

pub const INITIAL_COLOR: Rgb<u8> = Rgb([255, 0, 0]);
pub const FINAL_COLOR: Rgb<u8> = Rgb([0, 0, 255]);

/// The frame (as RGB) with `layer`'s contours and open polylines drawn through the `initial`
/// camera in red, then through the `refined` one in blue, about 2 px wide. Points a camera does
/// not see ([`CameraModel::image_point`]: beyond the horizon, past the lens model's fold) break
/// the lines.
pub fn draw_overlay(
    image: &DynamicImage,
    layer: &Layer,
    initial: &CameraModel,
    refined: &CameraModel,
) -> RgbImage {
    let mut out = image.to_rgb8();
    for (camera, color) in [(initial, INITIAL_COLOR), (refined, FINAL_COLOR)] {
        for p in &layer.polylines {
            let mut pts: Vec<Option<ImagePoint>> = p
                .points
                .iter()
                .map(|q| camera.image_point(BuildPoint::new(q[0], q[1])))
                .collect();
            if p.direction != Direction::Open {
                if let Some(&first) = pts.first() {
                    pts.push(first);
                }
            }
            for s in pts.windows(2) {
                if let (Some(a), Some(b)) = (s[0], s[1]) {
                    draw_segment(&mut out, a, b, color);
                }
            }
        }
    }
    out
}

/// A segment about 2 px wide: 2x2 stamps every half pixel along it.
fn draw_segment(img: &mut RgbImage, a: ImagePoint, b: ImagePoint, color: Rgb<u8>) {
    let (a, b) = ((a.u, a.v), (b.u, b.v));
    let (w, h) = (f64::from(img.width()), f64::from(img.height()));
    // Skip what is far off the frame (a wild mapping must not make this loop forever).
    let off = |p: (f64, f64)| p.0 < -w || p.0 > 2.0 * w || p.1 < -h || p.1 > 2.0 * h;
    if off(a) || off(b) {
        return;
    }
    let len = (b.0 - a.0).hypot(b.1 - a.1);
    let steps = (2.0 * len).ceil().max(1.0) as usize;
    for i in 0..=steps {
        let t = i as f64 / steps as f64;
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        let (x0, y0) = ((x - 0.5).floor(), (y - 0.5).floor());
        for (dx, dy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            let (px, py) = (x0 + dx, y0 + dy);
            if px >= 0.0 && py >= 0.0 && px < w && py < h {
                img.put_pixel(px as u32, py as u32, color);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Homography;
    use crate::vectors::Polyline;

    #[test]
    fn draws_both_mappings_in_their_colors() {
        let img = DynamicImage::ImageLuma8(image::GrayImage::new(100, 80));
        let mut layer = Layer::new(0, 0.03);
        layer.polylines.push(Polyline {
            part: 1,
            direction: Direction::CounterClockwise,
            points: vec![[10.0, 10.0], [60.0, 10.0], [60.0, 50.0], [10.0, 50.0]],
        });
        // Identity: build mm = image px; the refined one shifted by 5 px in u.
        let id = CameraModel::pinhole(Homography::IDENTITY);
        let shifted = CameraModel::pinhole(Homography::from_matrix([
            [1.0, 0.0, 5.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ]));
        let out = draw_overlay(&img, &layer, &id, &shifted);
        // The closing edge x = 10: image u = 10 (initial) and u = 5 (refined).
        assert_eq!(*out.get_pixel(10, 30), INITIAL_COLOR);
        assert_eq!(*out.get_pixel(5, 30), FINAL_COLOR);
        // The right edge x = 60: u = 60 and 55. Blue is drawn last, over red where they meet.
        assert_eq!(*out.get_pixel(60, 30), INITIAL_COLOR);
        assert_eq!(*out.get_pixel(55, 30), FINAL_COLOR);
        assert_eq!(*out.get_pixel(30, 10), FINAL_COLOR);
        assert_eq!(*out.get_pixel(40, 30), image::Rgb([0, 0, 0]));
    }
}
