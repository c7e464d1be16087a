//! The build image's standard deviation filter, with a window that covers the same plate area
//! as the exemplar's, pixel by pixel.
//!
//! The camera sees the plate from 30° off-normal: an image pixel is about 15% longer on the
//! plate in one direction than in the other, and 25% larger on the far edge than on the near
//! one. The exemplar's square window of `n` exemplar pixels is `n·pixel_mm` wide everywhere;
//! a square window of `n` image pixels is not, and std ramps of unequal widths are concave
//! curves of unequal widths, which the registration shifts against each other (measured on the
//! mock camera: parts pulled by 0.1-0.6 px). So each image pixel gets its own box, sized in u and
//! v to the exemplar window's extent on the plate there (from H0). Box sums come from a summed
//! area table per band of rows; fractional box edges weigh the border pixels by the covered
//! fraction (the table is interpolated bilinearly, which is exact for piecewise-constant
//! pixels). For odd integer sizes this is exactly the exemplar's std filter.

use rayon::prelude::*;

/// Rows and columns `[r0, r1) x [c0, c1)` to compute; the rest of the output stays 0.
pub type Roi = [usize; 4];

/// Local standard deviation of `data` (`width` x `height`) with the box `windows(u, v)` =
/// (width, height) in pixels (real, clamped to 1..=`max_window`) centered on pixel (u, v),
/// clipped at the image borders and normalised by the covered area. Sums of I and I² in f64.
pub fn std_filter_footprint(
    data: &[f32],
    width: usize,
    height: usize,
    roi: Roi,
    max_window: f64,
    windows: impl Fn(f64, f64) -> (f64, f64) + Sync,
) -> Vec<f32> {
    let mut out = vec![0.0f32; width * height];
    let [r0, r1, c0, c1] = [
        roi[0].min(height),
        roi[1].min(height),
        roi[2].min(width),
        roi[3].min(width),
    ];
    if r0 >= r1 || c0 >= c1 || data.len() < width * height {
        return out;
    }
    let max_window = max_window.max(1.0);
    let halo = (0.5 * max_window - 0.5).ceil().max(0.0) as usize;
    // Columns the table covers: the ROI plus the widest half-window.
    let (t0, t1) = (c0.saturating_sub(halo), (c1 + halo).min(width));
    let tw = t1 - t0;
    let band = 64usize.max(2 * halo);
    out[r0 * width..r1 * width]
        .par_chunks_mut(band * width)
        .enumerate()
        .for_each(|(b, out_band)| {
            let b0 = r0 + b * band;
            let b1 = (b0 + band).min(r1);
            let s0 = b0.saturating_sub(halo);
            let s1 = (b1 + halo).min(height);
            let rows = s1 - s0;
            // Summed area tables with a zero first row and column: t[j][i] = Σ over rows
            // s0..s0+j, columns t0..t0+i.
            let stride = tw + 1;
            let mut t1v = vec![0.0f64; (rows + 1) * stride];
            let mut t2v = vec![0.0f64; (rows + 1) * stride];
            for j in 0..rows {
                let src = &data[(s0 + j) * width + t0..(s0 + j) * width + t1];
                let (mut a1, mut a2) = (0.0f64, 0.0f64);
                for (i, &v) in src.iter().enumerate() {
                    let v = f64::from(v);
                    a1 += v;
                    a2 += v * v;
                    t1v[(j + 1) * stride + i + 1] = t1v[j * stride + i + 1] + a1;
                    t2v[(j + 1) * stride + i + 1] = t2v[j * stride + i + 1] + a2;
                }
            }
            // F(x, y): the integral over [0, x] x [0, y] in table coordinates.
            let at = |t: &[f64], x: f64, y: f64| {
                let (xi, yi) = (x.floor() as usize, y.floor() as usize);
                let (xi, yi) = (xi.min(tw - 1), yi.min(rows - 1));
                let (fx, fy) = (x - xi as f64, y - yi as f64);
                let i = yi * stride + xi;
                let top = t[i] + fx * (t[i + 1] - t[i]);
                let bot = t[i + stride] + fx * (t[i + stride + 1] - t[i + stride]);
                top + fy * (bot - top)
            };
            for (k, dst) in out_band.chunks_exact_mut(width).enumerate() {
                let row = b0 + k;
                let yc = row as f64 + 0.5;
                for c in c0..c1 {
                    let (wx, wy) = windows(c as f64, row as f64);
                    let hx = 0.5 * wx.clamp(1.0, max_window);
                    let hy = 0.5 * wy.clamp(1.0, max_window);
                    let xc = c as f64 + 0.5;
                    // Clipped to the image, then into table coordinates.
                    let (xa, xb) = ((xc - hx).max(0.0), (xc + hx).min(width as f64));
                    let (ya, yb) = ((yc - hy).max(0.0), (yc + hy).min(height as f64));
                    let (xa_t, xb_t) = (xa - t0 as f64, xb - t0 as f64);
                    let (ya_t, yb_t) = (ya - s0 as f64, yb - s0 as f64);
                    let sum = |t: &[f64]| {
                        at(t, xb_t, yb_t) - at(t, xa_t, yb_t) - at(t, xb_t, ya_t)
                            + at(t, xa_t, ya_t)
                    };
                    let n = (xb - xa) * (yb - ya);
                    let mean = sum(&t1v) / n;
                    let var = sum(&t2v) / n - mean * mean;
                    dst[c] = var.max(0.0).sqrt() as f32;
                }
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::std_filter;

    fn noise(w: usize, h: usize) -> Vec<f32> {
        let mut x = 0x1234_5678_9abc_def1u64;
        (0..w * h)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (x >> 56) as f32
            })
            .collect()
    }

    #[test]
    fn odd_integer_windows_match_the_square_filter() {
        let (w, h) = (53, 149);
        let data = noise(w, h);
        for win in [1usize, 3, 11] {
            let a = std_filter(&data, w, h, win).expect("valid window");
            let wf = win as f64;
            let b = std_filter_footprint(&data, w, h, [0, h, 0, w], 64.0, |_, _| (wf, wf));
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-3, "window {win}: {x} vs {y}");
            }
        }
    }

    #[test]
    fn varying_fractional_windows_weigh_the_border_pixels() {
        let (w, h) = (40, 150);
        let data = noise(w, h);
        let windows = |u: f64, v: f64| (5.0 + 0.05 * u, 7.0 + 0.04 * v);
        let roi = [2, 140, 0, 37];
        let got = std_filter_footprint(&data, w, h, roi, 20.0, windows);
        assert_eq!(got[w + 5], 0.0, "outside the ROI");
        for &(r, c) in &[
            (2usize, 0usize),
            (45, 20),
            (139, 36),
            (3, 17),
            (70, 2),
            (100, 30),
        ] {
            let (wx, wy) = windows(c as f64, r as f64);
            let (mut n, mut s1, mut s2) = (0.0, 0.0, 0.0);
            for rr in 0..h {
                for cc in 0..w {
                    let ov = |p: usize, center: usize, half: f64| {
                        let (a, b) = (p as f64 - 0.5, p as f64 + 0.5);
                        let (lo, hi) = (center as f64 - half, center as f64 + half);
                        (b.min(hi) - a.max(lo)).max(0.0)
                    };
                    let wgt = ov(rr, r, wy / 2.0) * ov(cc, c, wx / 2.0);
                    let v = f64::from(data[rr * w + cc]);
                    n += wgt;
                    s1 += wgt * v;
                    s2 += wgt * v * v;
                }
            }
            let want = (s2 / n - (s1 / n).powi(2)).max(0.0).sqrt();
            let g = f64::from(got[r * w + c]);
            assert!((g - want).abs() < 1e-3, "({r},{c}): {g} vs {want}");
        }
    }
}
