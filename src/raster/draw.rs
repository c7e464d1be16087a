//! One-pixel-wide lines for the colour rendering.

use image::{Rgb, RgbImage};

use super::Grid;

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
    // Liang–Barsky against the pixel area [-0.5, w − 0.5] x [-0.5, h − 0.5].
    let (dc, dr) = (c1 - c0, r1 - r0);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dc, c0 + 0.5),
        (dc, w - 0.5 - c0),
        (-dr, r0 + 0.5),
        (dr, h - 0.5 - r0),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    if t0 > t1 {
        return;
    }
    let (ca, ra) = (c0 + t0 * dc, r0 + t0 * dr);
    let (cb, rb) = (c0 + t1 * dc, r0 + t1 * dr);
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
