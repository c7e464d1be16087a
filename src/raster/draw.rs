//! One-pixel-wide lines for the colour rendering.

use image::{Rgb, RgbImage};

use crate::geometry::{clip_segment, Grid};

/// Draws the segment a–b (build mm) one pixel wide: one pixel per step along the major axis,
/// the pixel whose center is nearest the line, clipped to the image first so that a segment
/// far off the grid costs nothing.
pub(crate) fn line(img: &mut RgbImage, grid: &Grid, a: [f64; 2], b: [f64; 2], color: Rgb<u8>) {
    let (w, h) = (img.width() as f64, img.height() as f64);
    let (r0, c0) = grid.pixel_of(a[0], a[1]);
    let (r1, c1) = grid.pixel_of(b[0], b[1]);
    if ![r0, c0, r1, c1].iter().all(|v| v.is_finite()) {
        return;
    }
    // Clip against the pixel area [-0.5, w − 0.5] x [-0.5, h − 0.5] (c along x, r along y).
    let Some(([ca, ra], [cb, rb])) =
        clip_segment([c0, r0], [c1, r1], [-0.5, -0.5, w - 0.5, h - 0.5])
    else {
        return;
    };
    let (iw, ih) = (img.width() as i64, img.height() as i64);
    let mut put = |c: f64, r: f64| {
        let (c, r) = (c.round() as i64, r.round() as i64);
        if (0..iw).contains(&c) && (0..ih).contains(&r) {
            img.put_pixel(c as u32, r as u32, color);
        }
    };
    if (cb - ca).abs() >= (rb - ra).abs() {
        let (ca, ra, cb, rb) = if ca <= cb {
            (ca, ra, cb, rb)
        } else {
            (cb, rb, ca, ra)
        };
        let slope = if cb > ca { (rb - ra) / (cb - ca) } else { 0.0 };
        let mut c = ca.round();
        while c <= cb.round() {
            put(c, ra + (c - ca) * slope);
            c += 1.0;
        }
    } else {
        let (ca, ra, cb, rb) = if ra <= rb {
            (ca, ra, cb, rb)
        } else {
            (cb, rb, ca, ra)
        };
        let slope = (cb - ca) / (rb - ra);
        let mut r = ra.round();
        while r <= rb.round() {
            put(ca + (r - ra) * slope, r);
            r += 1.0;
        }
    }
}
