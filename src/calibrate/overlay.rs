//! The registration overlay (paper Fig. 11 left): the frame with the layer's contours drawn
//! through the starting mapping in red and through the refined one in blue, each part's number
//! beside it; below the frame a legend and every part enlarged (a crop of the frame around it,
//! scaled up with whole pixels kept square, the contours drawn again at that scale), so that a
//! fraction of a pixel between the two mappings shows where the whole frame shows nothing.

use std::collections::BTreeMap;

use image::{DynamicImage, Rgb, RgbImage};

use crate::geometry::{BuildPoint, CameraModel, ImagePoint};
use crate::raster::sheet::draw_text;
use crate::vectors::{Direction, Layer};

pub const INITIAL_COLOR: Rgb<u8> = Rgb([255, 0, 0]);
pub const FINAL_COLOR: Rgb<u8> = Rgb([0, 0, 255]);
/// The part numbers on the frame.
pub const LABEL_COLOR: Rgb<u8> = Rgb([255, 255, 0]);
const PAPER: Rgb<u8> = Rgb([255, 255, 255]);
const INK: Rgb<u8> = Rgb([0, 0, 0]);
/// Most parts enlarged (the first by part number).
const MAX_CROPS: usize = 24;
/// Gap between the enlarged parts, pixels.
const GAP: u32 = 8;

/// The overlay: the frame (as RGB) at the top left with `layer`'s contours and open polylines
/// drawn through the `initial` camera in red, then through the `refined` one in blue, about 2
/// px wide, and each part's number in yellow; below it a legend and each part enlarged with
/// both contours (see the module doc). Points a camera does not see
/// ([`CameraModel::image_point`]: beyond the horizon, past the lens model's fold) break the
/// lines.
pub fn draw_overlay(
    image: &DynamicImage,
    layer: &Layer,
    initial: &CameraModel,
    refined: &CameraModel,
) -> RgbImage {
    let frame = image.to_rgb8();
    let (w, h) = frame.dimensions();
    let text = (w / 500).clamp(1, 6);
    let tile = (w / 5).clamp(200, 480);
    let crops = part_crops(&frame, layer, initial, refined, tile);
    let mut framed = frame;
    draw_contours(&mut framed, layer, initial, refined, |q| q);
    for (part, at) in part_labels(layer, refined) {
        let y = (at.v - 12.0 * f64::from(text)).max(0.0);
        draw_text_scaled(
            &mut framed,
            at.u.max(0.0) as u32,
            y as u32,
            &part,
            LABEL_COLOR,
            text,
        );
    }
    let scale_note = match crops.iter().map(|c| c.1).reduce(f64::min) {
        Some(s) => format!("BELOW: EACH PART ENLARGED (X{s:.1} OR MORE), SAME COLOURS"),
        None => "NO PART IN VIEW TO ENLARGE".into(),
    };
    let legend_lines: [(Option<Rgb<u8>>, String); 4] = [
        (
            Some(INITIAL_COLOR),
            "RED: CONTOURS THROUGH THE CLICKED START POINTS".into(),
        ),
        (
            Some(FINAL_COLOR),
            "BLUE: CONTOURS THROUGH THE REFINED CALIBRATION".into(),
        ),
        (
            Some(LABEL_COLOR),
            "YELLOW: PART NUMBERS (THE VECTOR FILE'S)".into(),
        ),
        (None, scale_note),
    ];
    let line_px = 11 * text;
    let legend_h = GAP + legend_lines.len() as u32 * line_px + GAP;
    let columns = ((w.saturating_sub(GAP)) / (tile + GAP)).max(1);
    let label_h = line_px;
    let rows = (crops.len() as u32).div_ceil(columns);
    let crops_h = rows * (label_h + tile + GAP);
    let mut out = RgbImage::from_pixel(w.max(tile + 2 * GAP), h + legend_h + crops_h, PAPER);
    image::imageops::replace(&mut out, &framed, 0, 0);
    for (i, (swatch, line)) in legend_lines.iter().enumerate() {
        let y = h + GAP + i as u32 * line_px;
        if let Some(c) = swatch {
            for dy in 0..7 * text {
                for dx in 0..7 * text {
                    out.put_pixel(GAP + dx, y + dy, *c);
                }
            }
        }
        draw_text_scaled(&mut out, GAP + 10 * text, y, line, INK, text);
    }
    for (k, (crop, zoom, part)) in crops.iter().enumerate() {
        let (c, r) = (k as u32 % columns, k as u32 / columns);
        let x = GAP + c * (tile + GAP);
        let y = h + legend_h + r * (label_h + tile + GAP);
        draw_text_scaled(
            &mut out,
            x,
            y,
            &format!("PART {part} X{zoom:.1}"),
            INK,
            text,
        );
        image::imageops::replace(&mut out, crop, i64::from(x), i64::from(y + label_h));
    }
    out
}

/// `text` in the sheet's 5 x 7 font, each font pixel `k` x `k` image pixels.
fn draw_text_scaled(img: &mut RgbImage, x: u32, y: u32, text: &str, color: Rgb<u8>, k: u32) {
    let mut small = RgbImage::from_pixel(6 * text.chars().count() as u32 + 1, 8, INK);
    let mark = if color == INK { PAPER } else { color };
    draw_text(&mut small, 0, 0, text, mark);
    for (sx, sy, p) in small.enumerate_pixels() {
        if *p != mark {
            continue;
        }
        for dy in 0..k {
            for dx in 0..k {
                let (px, py) = (x + sx * k + dx, y + sy * k + dy);
                if px < img.width() && py < img.height() {
                    img.put_pixel(px, py, color);
                }
            }
        }
    }
}

/// The polylines of `layer` by part number.
fn parts_of(layer: &Layer) -> BTreeMap<i64, Vec<&crate::vectors::Polyline>> {
    let mut parts: BTreeMap<i64, Vec<_>> = BTreeMap::new();
    for p in &layer.polylines {
        parts.entry(p.part).or_default().push(p);
    }
    parts
}

/// Each part's image extent through `camera`, `[u_min, v_min, u_max, v_max]`.
fn image_extent(polylines: &[&crate::vectors::Polyline], camera: &CameraModel) -> Option<[f64; 4]> {
    let mut e: Option<[f64; 4]> = None;
    for q in polylines.iter().flat_map(|p| &p.points) {
        if let Some(i) = camera.image_point(BuildPoint::new(q[0], q[1])) {
            e = Some(match e {
                None => [i.u, i.v, i.u, i.v],
                Some(a) => [a[0].min(i.u), a[1].min(i.v), a[2].max(i.u), a[3].max(i.v)],
            });
        }
    }
    e
}

/// Where each part's number goes on the frame: the top left of its image extent.
fn part_labels(layer: &Layer, camera: &CameraModel) -> Vec<(String, ImagePoint)> {
    parts_of(layer)
        .iter()
        .filter_map(|(part, lines)| {
            let e = image_extent(lines, camera)?;
            Some((part.to_string(), ImagePoint::new(e[0], e[1])))
        })
        .collect()
}

/// Per part in view (at most [`MAX_CROPS`]): a `tile` x `tile` crop of `frame` around it (its
/// image extent plus a margin), enlarged by a whole factor of at least 2 where the part is
/// smaller than the tile, with both contours drawn at that scale; and the factor.
fn part_crops(
    frame: &RgbImage,
    layer: &Layer,
    initial: &CameraModel,
    refined: &CameraModel,
    tile: u32,
) -> Vec<(RgbImage, f64, i64)> {
    let (w, h) = (f64::from(frame.width()), f64::from(frame.height()));
    let mut out = Vec::new();
    for (part, lines) in parts_of(layer).into_iter().take(MAX_CROPS) {
        let Some(e) = image_extent(&lines, refined) else {
            continue;
        };
        let side = (e[2] - e[0]).max(e[3] - e[1]);
        let span = side * 1.3 + 16.0;
        let zoom = (f64::from(tile) / span).floor().max(1.0);
        let source = f64::from(tile) / zoom;
        let (cu, cv) = (0.5 * (e[0] + e[2]), 0.5 * (e[1] + e[3]));
        let (u0, v0) = ((cu - 0.5 * source).round(), (cv - 0.5 * source).round());
        if u0 + source < 0.0 || v0 + source < 0.0 || u0 >= w || v0 >= h {
            continue;
        }
        let mut crop = RgbImage::from_pixel(tile, tile, Rgb([0, 0, 0]));
        for (x, y, p) in crop.enumerate_pixels_mut() {
            let su = u0 + (f64::from(x) / zoom).floor();
            let sv = v0 + (f64::from(y) / zoom).floor();
            if su >= 0.0 && sv >= 0.0 && su < w && sv < h {
                *p = *frame.get_pixel(su as u32, sv as u32);
            }
        }
        let single = Layer {
            polylines: lines.into_iter().cloned().collect(),
            ..Layer::new(layer.index, layer.z_mm)
        };
        // Pixel (u, v)'s centre is at crop ((u − u0 + 0.5)·zoom − 0.5).
        let place = |q: ImagePoint| {
            ImagePoint::new((q.u - u0 + 0.5) * zoom - 0.5, (q.v - v0 + 0.5) * zoom - 0.5)
        };
        draw_contours(&mut crop, &single, initial, refined, place);
        out.push((crop, zoom, part));
    }
    out
}

/// `layer`'s contours through `initial` (red) then `refined` (blue), each image point moved by
/// `place` onto `img`.
fn draw_contours(
    img: &mut RgbImage,
    layer: &Layer,
    initial: &CameraModel,
    refined: &CameraModel,
    place: impl Fn(ImagePoint) -> ImagePoint,
) {
    for (camera, color) in [(initial, INITIAL_COLOR), (refined, FINAL_COLOR)] {
        for p in &layer.polylines {
            let mut pts: Vec<Option<ImagePoint>> = p
                .points
                .iter()
                .map(|q| camera.image_point(BuildPoint::new(q[0], q[1])).map(&place))
                .collect();
            if p.direction != Direction::Open {
                if let Some(&first) = pts.first() {
                    pts.push(first);
                }
            }
            for s in pts.windows(2) {
                if let (Some(a), Some(b)) = (s[0], s[1]) {
                    draw_segment(img, a, b, color);
                }
            }
        }
    }
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
        // Below the frame: the legend and the part enlarged, both contours drawn again.
        assert!(out.height() > 80 + 200, "{:?}", out.dimensions());
        let below = |c: Rgb<u8>| {
            out.enumerate_pixels()
                .filter(|(_, y, p)| *y >= 80 && **p == c)
                .count()
        };
        // The legend's swatches are 7 x 7; the enlarged contours far more.
        assert!(below(INITIAL_COLOR) > 200 && below(FINAL_COLOR) > 200);
    }
}
