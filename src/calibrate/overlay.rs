//! The registration overlay (paper Fig. 11 left): the frame with the layer's contours drawn
//! through the starting mapping in red and through the refined one in blue.

use image::{DynamicImage, Rgb, RgbImage};

use super::Mat3;
use crate::rectify::RadialDistortion;
use crate::vectors::{Direction, Layer};

pub const INITIAL_COLOR: Rgb<u8> = Rgb([255, 0, 0]);
pub const FINAL_COLOR: Rgb<u8> = Rgb([0, 0, 255]);

/// One mapping build mm → recorded image pixel: H⁻¹, then the lens distortion if any.
#[derive(Clone, Copy, Debug)]
pub struct Mapping<'a> {
    /// Image → build homography (docs/frames.md).
    pub homography: &'a Mat3,
    pub distortion: Option<&'a RadialDistortion>,
}

impl Mapping<'_> {
    /// Where build point (x, y) lands in the recorded image; `None` beyond the horizon or when
    /// the homography is singular.
    pub fn image_point(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let hi = super::mat_inv(self.homography)?;
        image_point_with(&hi, self.distortion, x, y)
    }
}

fn image_point_with(
    h_inv: &Mat3,
    distortion: Option<&RadialDistortion>,
    x: f64,
    y: f64,
) -> Option<(f64, f64)> {
    let w = h_inv[2][0] * x + h_inv[2][1] * y + h_inv[2][2];
    if !(w > 0.0) {
        return None;
    }
    let u = (h_inv[0][0] * x + h_inv[0][1] * y + h_inv[0][2]) / w;
    let v = (h_inv[1][0] * x + h_inv[1][1] * y + h_inv[1][2]) / w;
    Some(match distortion {
        Some(d) => d.distort(u, v),
        None => (u, v),
    })
}

/// The frame (as RGB) with `layer`'s contours and open polylines drawn through `initial` in red,
/// then through `refined` in blue, about 2 px wide.
pub fn draw_overlay(
    image: &DynamicImage,
    layer: &Layer,
    initial: Mapping,
    refined: Mapping,
) -> RgbImage {
    let mut out = image.to_rgb8();
    for (mapping, color) in [(initial, INITIAL_COLOR), (refined, FINAL_COLOR)] {
        let Some(h_inv) = super::mat_inv(mapping.homography) else {
            continue;
        };
        for p in &layer.polylines {
            let mut pts: Vec<Option<(f64, f64)>> = p
                .points
                .iter()
                .map(|q| image_point_with(&h_inv, mapping.distortion, q[0], q[1]))
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
fn draw_segment(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), color: Rgb<u8>) {
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
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let shifted = [[1.0, 0.0, 5.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let out = draw_overlay(
            &img,
            &layer,
            Mapping {
                homography: &id,
                distortion: None,
            },
            Mapping {
                homography: &shifted,
                distortion: None,
            },
        );
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
