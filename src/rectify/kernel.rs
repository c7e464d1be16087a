//! What the rectifier's phases share, and its sampling kernels (phase 2): the fixed-point
//! format of source positions, the sample types, one run's coordinates, the job a row kernel
//! works on, and the scalar bilinear and bicubic kernels. Phase 1 (`positions.rs`), the row
//! kernels (`row.rs`, `simd.rs`) and the driver (`warp.rs`) build on it; it uses none of them.

use crate::geometry::mat3::Mat3;
use crate::geometry::RadialDistortion;

/// Fraction bits of the fixed-point source position (and bilinear weights).
///
/// 11 bits: the position is rounded to 1/2048 px, so even across a hard
/// 0→255 edge the interpolated value moves by at most 255·2·2⁻¹² ≈ 0.12 grey
/// levels, which keeps the result within ±1 of an exact f64 bilinear (with
/// OpenCV's old INTER_BITS = 5 it could move by up to 4 levels). It is also
/// the most that fits 8-bit samples in i32 lanes: the horizontal lerp
/// (≤ 255·2¹¹) fits the i16·i16→i32 `madd`, the vertical one reaches
/// 255·2²² < 2³¹.
pub(crate) const FRAC_BITS: u32 = 11;
pub(crate) const ONE: i32 = 1 << FRAC_BITS;
/// Rounding term for the final `>> 2·FRAC_BITS`.
pub(crate) const ROUND2: u64 = 1 << (2 * FRAC_BITS - 1);

/// Output pixels per phase-1/phase-2 run (16 B of coordinates per pixel).
pub(crate) const CHUNK: usize = 512;

/// A sample type: `u8` or `u16`.
pub(crate) trait Sample: Copy + Send + Sync + PartialEq + std::fmt::Debug + 'static {
    const MAX: u32;
    fn get(self) -> u32;
    /// `v` must be ≤ `MAX`.
    fn from_u32(v: u32) -> Self;
}

impl Sample for u8 {
    const MAX: u32 = u8::MAX as u32;
    #[inline(always)]
    fn get(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn from_u32(v: u32) -> Self {
        v as u8
    }
}

impl Sample for u16 {
    const MAX: u32 = u16::MAX as u32;
    #[inline(always)]
    fn get(self) -> u32 {
        self as u32
    }
    #[inline(always)]
    fn from_u32(v: u32) -> Self {
        v as u16
    }
}

/// Distortion constants in the form the inner loop wants.
#[derive(Clone, Copy, Debug)]
pub(crate) struct DistParams {
    pub(crate) cu: f64,
    pub(crate) cv: f64,
    pub(crate) inv_f2: f64,
    pub(crate) k1: f64,
    pub(crate) k2: f64,
    pub(crate) r2_max: f64,
}

impl DistParams {
    pub(crate) fn new(d: &RadialDistortion) -> Self {
        DistParams {
            cu: d.center[0],
            cv: d.center[1],
            inv_f2: 1.0 / (d.focal_px * d.focal_px),
            k1: d.k1,
            k2: d.k2,
            r2_max: d.max_r2(),
        }
    }

    /// Undistorted → recorded position, and whether the model is valid there.
    #[inline(always)]
    pub(crate) fn apply(&self, u: f64, v: f64) -> (f64, f64, bool) {
        let (du, dv) = (u - self.cu, v - self.cv);
        let r2 = (du * du + dv * dv) * self.inv_f2;
        let k = 1.0 + r2 * (self.k1 + r2 * self.k2);
        (self.cu + du * k, self.cv + dv * k, r2 < self.r2_max)
    }
}

/// Fixed-point source positions for one run; `ix < 0` marks "outside".
pub(crate) struct Coords {
    pub(crate) ix: Vec<i32>,
    pub(crate) iy: Vec<i32>,
    pub(crate) fx: Vec<i32>,
    pub(crate) fy: Vec<i32>,
}

impl Coords {
    pub(crate) fn new() -> Self {
        Coords {
            ix: vec![0; CHUNK],
            iy: vec![0; CHUNK],
            fx: vec![0; CHUNK],
            fy: vec![0; CHUNK],
        }
    }
}

/// A source image as a flat slice (`stride` in samples, rows contiguous).
pub(crate) struct Source<'a, T> {
    pub(crate) data: &'a [T],
    pub(crate) width: usize,
    pub(crate) height: usize,
    pub(crate) stride: usize,
}

/// Everything a row kernel needs; shared by all rayon tasks.
pub(crate) struct Job<'a, T> {
    pub(crate) src: Source<'a, T>,
    pub(crate) fill: T,
    /// Grid (col, row, 1) → homogeneous undistorted image position (`image_from_grid`).
    pub(crate) m: Mat3,
    pub(crate) dist: Option<DistParams>,
    /// (W−1)·2¹¹, (H−1)·2¹¹: last inside fixed-point position.
    pub(crate) xmax_q: i32,
    pub(crate) ymax_q: i32,
    pub(crate) wm2: i32,
    pub(crate) hm2: i32,
    /// Cached positions (see `Rectifier::position_map` in `warp.rs`), grid row-major.
    pub(crate) map: Option<&'a [[i32; 2]]>,
    pub(crate) cols: usize,
}

/// Renders one output row (`out` = one grid row, `CN` samples per pixel).
pub(crate) type RowFn<T> = fn(&Job<'_, T>, usize, &mut [T], &mut Coords);

/// Phase 2, bilinear, exact fixed point; pixels `start..` of the run.
///
/// With 11-bit weights the products are exact integers, so this and the
/// AVX2 kernels give bit-identical results.
#[inline(always)]
pub(crate) fn bilinear_run<T: Sample, const CN: usize>(
    job: &Job<'_, T>,
    co: &Coords,
    out: &mut [T],
    start: usize,
) {
    let src = &job.src;
    let (data, stride) = (src.data, src.stride);
    let n = out.len() / CN;
    let one = ONE as u64;
    for i in start..n {
        let o = &mut out[i * CN..i * CN + CN];
        let x = co.ix[i];
        if x < 0 {
            o.fill(job.fill);
            continue;
        }
        let p = co.iy[i] as usize * stride + x as usize * CN;
        let (wx, wy) = (co.fx[i] as u64, co.fy[i] as u64);
        let top = &data[p..p + 2 * CN];
        let bot = &data[p + stride..p + stride + 2 * CN];
        for ch in 0..CN {
            let t = top[ch].get() as u64 * (one - wx) + top[CN + ch].get() as u64 * wx;
            let b = bot[ch].get() as u64 * (one - wx) + bot[CN + ch].get() as u64 * wx;
            let val = (t * (one - wy) + b * wy + ROUND2) >> (2 * FRAC_BITS);
            o[ch] = T::from_u32(val as u32);
        }
    }
}

/// Keys cubic convolution weights for taps at −1, 0, 1, 2 (fraction `t`).
/// A = −0.75 as in OpenCV's INTER_CUBIC, so the two can be compared.
#[inline(always)]
pub(crate) fn cubic_weights(t: f32) -> [f32; 4] {
    const A: f32 = -0.75;
    let w0 = ((A * (t + 1.0) - 5.0 * A) * (t + 1.0) + 8.0 * A) * (t + 1.0) - 4.0 * A;
    let w1 = ((A + 2.0) * t - (A + 3.0)) * t * t + 1.0;
    let s = 1.0 - t;
    let w2 = ((A + 2.0) * s - (A + 3.0)) * s * s + 1.0;
    [w0, w1, w2, 1.0 - w0 - w1 - w2]
}

/// Phase 2, bicubic (f32, result rounded and clamped to the sample range).
#[inline(always)]
pub(crate) fn bicubic_run<T: Sample, const CN: usize>(
    job: &Job<'_, T>,
    co: &Coords,
    out: &mut [T],
) {
    let src = &job.src;
    let (data, stride) = (src.data, src.stride);
    let (wmax, hmax) = (src.width - 1, src.height - 1);
    let n = out.len() / CN;
    let scale = 1.0 / ONE as f32;
    let max = T::MAX as f32;
    for i in 0..n {
        let o = &mut out[i * CN..i * CN + CN];
        let x = co.ix[i];
        if x < 0 {
            o.fill(job.fill);
            continue;
        }
        let (x, y) = (x as usize, co.iy[i] as usize);
        let wx = cubic_weights(co.fx[i] as f32 * scale);
        let wy = cubic_weights(co.fy[i] as f32 * scale);
        // Outer taps replicate the edge pixels (x, x+1 and y, y+1 are inside).
        let xs = [x.saturating_sub(1), x, x + 1, (x + 2).min(wmax)].map(|c| c * CN);
        let ys = [y.saturating_sub(1), y, y + 1, (y + 2).min(hmax)].map(|r| r * stride);
        for ch in 0..CN {
            let mut acc = 0.0f32;
            for (ry, wyk) in ys.iter().zip(wy) {
                let line = &data[*ry..*ry + stride];
                let mut h = 0.0f32;
                for (cx, wxk) in xs.iter().zip(wx) {
                    h += wxk * line[cx + ch].get() as f32;
                }
                acc += wyk * h;
            }
            o[ch] = T::from_u32((acc + 0.5).floor().clamp(0.0, max) as u32);
        }
    }
}

#[cfg(test)]
impl<'a> Job<'a, u8> {
    /// A job over a `w` x `h` grey source, positions computed (no cached map).
    pub(crate) fn for_test(
        data: &'a [u8],
        w: usize,
        h: usize,
        m: Mat3,
        dist: Option<DistParams>,
    ) -> Self {
        Job {
            src: Source {
                data,
                width: w,
                height: h,
                stride: w,
            },
            fill: 0,
            m,
            dist,
            xmax_q: ((w - 1) as i32) << FRAC_BITS,
            ymax_q: ((h - 1) as i32) << FRAC_BITS,
            wm2: (w - 2) as i32,
            hm2: (h - 2) as i32,
            map: None,
            cols: 0,
        }
    }
}
