//! Local standard deviation filter and the f32 image it works on.

use image::{GrayImage, ImageBuffer, Luma};
use rayon::prelude::*;

use super::error::RasterError;

/// A row-major single-channel f32 image (luminance, exemplar, filter output).
#[derive(Debug, Clone, PartialEq)]
pub struct F32Image {
    pub width: usize,
    pub height: usize,
    /// `width * height` values, row 0 first.
    pub data: Vec<f32>,
}

impl F32Image {
    /// The value at (row, col); `None` outside.
    pub fn get(&self, row: usize, col: usize) -> Option<f32> {
        (row < self.height && col < self.width).then(|| self.data[row * self.width + col])
    }

    /// Largest value (0 for an empty or all-negative image).
    pub fn max(&self) -> f32 {
        self.data.iter().copied().fold(0.0, f32::max)
    }

    /// From an 8-bit image, values 0..255.
    pub fn from_gray(img: &GrayImage) -> F32Image {
        F32Image {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.as_raw().iter().map(|&v| v as f32).collect(),
        }
    }

    /// 8-bit, scaled so that the maximum maps to 255 (all zero stays zero).
    pub fn to_gray8_scaled(&self) -> GrayImage {
        let scale = scale_to(self.max(), 255.0);
        let data = self
            .data
            .iter()
            .map(|&v| (v * scale).round().clamp(0.0, 255.0) as u8);
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data.collect())
            .unwrap_or_default()
    }

    /// 16-bit, scaled so that the maximum maps to 65535 (all zero stays zero).
    pub fn to_gray16_scaled(&self) -> ImageBuffer<Luma<u16>, Vec<u16>> {
        let scale = scale_to(self.max(), 65535.0);
        let data = self
            .data
            .iter()
            .map(|&v| (v * scale).round().clamp(0.0, 65535.0) as u16);
        ImageBuffer::from_raw(self.width as u32, self.height as u32, data.collect())
            .unwrap_or_default()
    }
}

fn scale_to(max: f32, top: f32) -> f32 {
    if max > 0.0 && max.is_finite() {
        top / max
    } else {
        0.0
    }
}

/// Local standard deviation over a `window` x `window` neighbourhood (odd window), the same
/// filter for build images and for the exemplar so that both dilate the part alike.
///
/// The population standard deviation (divisor n; 0 when n = 1), as the registration filters the
/// build images, so exemplar and frames are the same filter.
/// At the borders the window is clipped to the image and n is the number of pixels actually
/// covered. Box sums of I and I² come from running sums in f64 (columns slid down, then a row
/// slid across), so the cost per pixel does not depend on the window; values are taken
/// relative to the image mean first, which keeps Σ(I²) − (ΣI)²/n from cancelling when the
/// mean is large. Parallel over bands of rows.
pub fn std_filter(
    data: &[f32],
    width: usize,
    height: usize,
    window: usize,
) -> Result<Vec<f32>, RasterError> {
    if window == 0 || window.is_multiple_of(2) {
        return Err(RasterError::InvalidWindow(window));
    }
    if data.len() != width.saturating_mul(height) {
        return Err(RasterError::SizeMismatch {
            len: data.len(),
            width,
            height,
        });
    }
    let mut out = vec![0f32; data.len()];
    if data.is_empty() {
        return Ok(out);
    }
    let n_all = data.len() as f64;
    let mean = data.iter().map(|&v| v as f64).sum::<f64>() / n_all;
    let half = window / 2;
    let threads = rayon::current_num_threads().max(1);
    // Bands much taller than the window so that priming the column sums is cheap.
    let band = height.div_ceil(threads * 4).max(4 * window).max(16);
    out.par_chunks_mut(band * width)
        .enumerate()
        .for_each(|(bi, rows)| {
            band_std(data, width, height, half, mean, bi * band, rows);
        });
    Ok(out)
}

/// One band of output rows starting at `row0`.
fn band_std(
    data: &[f32],
    width: usize,
    height: usize,
    half: usize,
    mean: f64,
    row0: usize,
    out: &mut [f32],
) {
    let nrows = out.len() / width;
    // Column sums over the rows currently in the window.
    let mut s1 = vec![0f64; width];
    let mut s2 = vec![0f64; width];
    let add_row = |s1: &mut [f64], s2: &mut [f64], r: usize, sign: f64| {
        let row = &data[r * width..(r + 1) * width];
        for ((a, b), &v) in s1.iter_mut().zip(s2.iter_mut()).zip(row) {
            let d = v as f64 - mean;
            *a += sign * d;
            *b += sign * d * d;
        }
    };
    let mut lo = row0.saturating_sub(half);
    let mut hi = lo; // rows lo..hi are in the column sums
    for (ri, out_row) in out.chunks_mut(width).enumerate() {
        let r = row0 + ri;
        let want_lo = r.saturating_sub(half);
        let want_hi = (r + half + 1).min(height);
        while hi < want_hi {
            add_row(&mut s1, &mut s2, hi, 1.0);
            hi += 1;
        }
        while lo < want_lo {
            add_row(&mut s1, &mut s2, lo, -1.0);
            lo += 1;
        }
        let rows_in = (hi - lo) as f64;
        // Slide across the row.
        let (mut a, mut b) = (0f64, 0f64);
        let (mut cl, mut ch) = (0usize, 0usize);
        for (c, o) in out_row.iter_mut().enumerate() {
            let want_hi = (c + half + 1).min(width);
            let want_lo = c.saturating_sub(half);
            while ch < want_hi {
                a += s1[ch];
                b += s2[ch];
                ch += 1;
            }
            while cl < want_lo {
                a -= s1[cl];
                b -= s2[cl];
                cl += 1;
            }
            let n = rows_in * (ch - cl) as f64;
            // Population standard deviation (divide by n), as the registration's per-pixel
            // footprint filter of the build images computes it: exemplar and frames must match.
            *o = if n > 1.0 {
                ((b - a * a / n) / n).max(0.0).sqrt() as f32
            } else {
                0.0
            };
        }
        debug_assert!(nrows > 0);
    }
}

/// Deterministic white noise: a uniform byte for pixel `index` under `seed`, independent of
/// the order pixels are visited in (so parallel and serial runs agree).
pub(crate) fn noise_byte(seed: u64, index: u64) -> u8 {
    // SplitMix64: a Weyl sequence started at the mixed seed, then the finaliser.
    let z = mix(seed).wrapping_add(index.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    (mix(z) >> 56) as u8
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
