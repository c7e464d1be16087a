//! The rectifier: grid pixel → build point → image point → sample.
//!
//! Work is split in two phases per run of up to [`CHUNK`] output pixels of a
//! row, so both stay in L1:
//! 1. [`map_run`]: source positions in f64, as fixed-point integer pixel +
//!    11-bit fraction (or "outside"). Straight-line code that LLVM vectorises.
//! 2. a sampling kernel: scalar generic ([`bilinear_run`], [`bicubic_run`]) or
//!    the AVX2 ones for 8-bit grey / RGB bilinear (see `simd.rs`).
//!
//! # Border rule
//! A sample is *inside* iff its (distorted) source position lies in the closed
//! rectangle spanned by the source pixel centers, `0 ≤ u ≤ W−1`, `0 ≤ v ≤ H−1`
//! (so its 2x2 bilinear neighbourhood is inside the image; at exactly `u = W−1`
//! the right-hand neighbour has weight 0). Anything else becomes `fill`, with
//! no blending. OpenCV's `BORDER_CONSTANT` instead blends with the border
//! value for positions up to one pixel outside that rectangle, so the two
//! differ only in a band of at most one source pixel around the image edge.
//! Bicubic uses the same inside test and replicates edge pixels for its outer
//! taps, so both interpolations fill exactly the same grid pixels.
//! A point whose homogeneous w ≤ 0 lies beyond the horizon (on the other side
//! of the camera) and is outside too, as is a point past the radius where the
//! distortion polynomial folds back.

use rayon::prelude::*;

use super::distortion::RadialDistortion;
use super::grid::Grid;
use super::homography::{self, Mat3};
use super::{Interpolation, RectifyError};

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

/// Largest source side: positions are i32 with 11 fraction bits.
pub const MAX_SOURCE_SIDE: usize = 1 << 19;

/// Output pixels per phase-1/phase-2 run (16 B of coordinates per pixel).
pub(crate) const CHUNK: usize = 512;
/// Output rows per rayon task.
const BAND: usize = 4;

/// A sample type: `u8` or `u16`.
pub(crate) trait Sample: Copy + Send + Sync + PartialEq + std::fmt::Debug + 'static {
    const MAX: u32;
    fn get(self) -> u32;
    /// `v` must be ≤ `MAX`.
    fn from_u32(v: u32) -> Self;
    fn zero() -> Self;
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
    fn zero() -> Self {
        0
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
    fn zero() -> Self {
        0
    }
}

/// Distortion constants in the form the inner loop wants.
#[derive(Clone, Copy, Debug)]
pub(crate) struct DistParams {
    cu: f64,
    cv: f64,
    inv_f2: f64,
    k1: f64,
    k2: f64,
    r2_max: f64,
}

impl DistParams {
    fn new(d: &RadialDistortion) -> Self {
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
    fn apply(&self, u: f64, v: f64) -> (f64, f64, bool) {
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
    fn new() -> Self {
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
    /// Grid (col, row, 1) → homogeneous undistorted image position.
    m: Mat3,
    dist: Option<DistParams>,
    /// (W−1)·2¹¹, (H−1)·2¹¹: last inside fixed-point position.
    xmax_q: i32,
    ymax_q: i32,
    wm2: i32,
    hm2: i32,
}

/// Renders one output row (`out` = one grid row, `CN` samples per pixel).
pub(crate) type RowFn<T> = fn(&Job<'_, T>, usize, &mut [T], &mut Coords);

/// Warps camera frames onto a top-down [`Grid`] of the build plate.
#[derive(Clone, Debug)]
pub struct Rectifier {
    h: Mat3,
    h_inv: Mat3,
    grid: Grid,
    distortion: Option<RadialDistortion>,
    dist: Option<DistParams>,
    interpolation: Interpolation,
    fill: u16,
    /// Grid (col, row, 1) → image, i.e. `H⁻¹ · G`.
    m: Mat3,
    /// Tests switch this off to check the SIMD kernels against the scalar ones.
    pub(crate) allow_simd: bool,
}

impl Rectifier {
    /// `homography` maps image (u, v, 1) to build (x, y, 1) in mm, up to scale;
    /// it is normalised so that H[2][2] = 1. `fill` is used for grid pixels
    /// that see no image (clamped to 255 for 8-bit output).
    pub fn new(
        homography: [[f64; 3]; 3],
        grid: Grid,
        distortion: Option<RadialDistortion>,
        interpolation: Interpolation,
        fill: u16,
    ) -> Result<Rectifier, RectifyError> {
        if homography.iter().flatten().any(|v| !v.is_finite()) {
            return Err(RectifyError::NonFiniteHomography);
        }
        let s = homography[2][2];
        if s == 0.0 {
            return Err(RectifyError::ZeroH22);
        }
        let mut h = homography;
        for v in h.iter_mut().flatten() {
            *v /= s;
        }
        let (h_inv, measure) = homography::inverse(&h);
        if !(measure > 1e-12) || h_inv.iter().flatten().any(|v| !v.is_finite()) {
            return Err(RectifyError::SingularHomography(measure));
        }
        grid.validate()?;
        if let Some(d) = &distortion {
            d.validate()?;
        }
        let p = grid.pixel_mm;
        let g = [
            [p, 0.0, grid.x_min + 0.5 * p],
            [0.0, -p, grid.y_max - 0.5 * p],
            [0.0, 0.0, 1.0],
        ];
        Ok(Rectifier {
            h,
            h_inv,
            grid,
            distortion,
            dist: distortion.as_ref().map(DistParams::new),
            interpolation,
            fill,
            m: homography::mul(&h_inv, &g),
            allow_simd: true,
        })
    }

    /// The homography (image → build), normalised to H[2][2] = 1.
    pub fn homography(&self) -> [[f64; 3]; 3] {
        self.h
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    pub fn distortion(&self) -> Option<RadialDistortion> {
        self.distortion
    }

    pub fn interpolation(&self) -> Interpolation {
        self.interpolation
    }

    pub fn fill(&self) -> u16 {
        self.fill
    }

    /// Where a build point lands in the original (recorded, distorted) image,
    /// through H⁻¹ and the distortion. `None` if it lies beyond the horizon
    /// (w ≤ 0) or past the radius where the distortion model folds back;
    /// the image size is not known here, so points off the frame still
    /// return `Some`.
    pub fn image_point(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let hi = &self.h_inv;
        let w = hi[2][0] * x + hi[2][1] * y + hi[2][2];
        if !(w > 0.0) {
            return None;
        }
        let u = (hi[0][0] * x + hi[0][1] * y + hi[0][2]) / w;
        let v = (hi[1][0] * x + hi[1][1] * y + hi[1][2]) / w;
        match &self.dist {
            None => Some((u, v)),
            Some(d) => {
                let (u, v, ok) = d.apply(u, v);
                ok.then_some((u, v))
            }
        }
    }

    /// Shared driver: splits `out` (the whole grid, `CN` samples per pixel)
    /// into row bands over rayon and runs `row_fn` on every row.
    pub(crate) fn run_into<T: Sample, const CN: usize>(
        &self,
        data: &[T],
        width: u32,
        height: u32,
        row_fn: RowFn<T>,
        out: &mut [T],
    ) {
        let row_len = self.grid.columns() * CN;
        debug_assert_eq!(out.len(), row_len * self.grid.rows());
        let fill = T::from_u32(u32::from(self.fill).min(T::MAX));
        let (w, h) = (width as usize, height as usize);
        if w < 2 || h < 2 || w > MAX_SOURCE_SIDE || h > MAX_SOURCE_SIDE || data.len() < w * h * CN {
            // No 2x2 neighbourhood, or beyond the fixed-point range: nothing is inside.
            out.par_chunks_mut(row_len.max(1))
                .for_each(|r| r.fill(fill));
            return;
        }
        let job = Job {
            src: Source {
                data: &data[..w * h * CN],
                width: w,
                height: h,
                stride: w * CN,
            },
            fill,
            m: self.m,
            dist: self.dist,
            xmax_q: ((w - 1) as i32) << FRAC_BITS,
            ymax_q: ((h - 1) as i32) << FRAC_BITS,
            wm2: (w - 2) as i32,
            hm2: (h - 2) as i32,
        };
        out.par_chunks_mut(row_len * BAND)
            .enumerate()
            .for_each_init(Coords::new, |co, (b, band)| {
                for (k, row_out) in band.chunks_mut(row_len).enumerate() {
                    row_fn(&job, b * BAND + k, row_out, co);
                }
            });
    }

    /// Picks the row kernel: `fast` (an AVX2 special case) for bilinear if
    /// given and usable, else the generic kernel, AVX2-compiled when possible.
    pub(crate) fn row_fn<T: Sample, const CN: usize>(&self, fast: Option<RowFn<T>>) -> RowFn<T> {
        #[cfg(target_arch = "x86_64")]
        if self.allow_simd && super::simd::available() {
            return match (self.interpolation, fast) {
                (Interpolation::Bilinear, Some(f)) => f,
                (Interpolation::Bilinear, None) => super::simd::row_generic::<T, CN, false>,
                (Interpolation::Bicubic, _) => super::simd::row_generic::<T, CN, true>,
            };
        }
        let _ = fast;
        match self.interpolation {
            Interpolation::Bilinear => row_plain::<T, CN, false>,
            Interpolation::Bicubic => row_plain::<T, CN, true>,
        }
    }
}

fn row_plain<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    row_generic::<T, CN, CUBIC>(job, row, out, co)
}

/// Generic row kernel; `#[inline(always)]` so the AVX2 wrapper in `simd.rs`
/// gets it compiled (and phase 1 vectorised) with AVX2.
#[inline(always)]
pub(crate) fn row_generic<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    let mut col0 = 0;
    for chunk in out.chunks_mut(CHUNK * CN) {
        let n = chunk.len() / CN;
        map_run(job, row, col0, n, co);
        if CUBIC {
            bicubic_run::<T, CN>(job, co, chunk);
        } else {
            bilinear_run::<T, CN>(job, co, chunk, 0);
        }
        col0 += n;
    }
}

/// Phase 1: fixed-point source positions of grid pixels `col0..col0 + n` of `row`.
#[inline(always)]
pub(crate) fn map_run<T>(job: &Job<'_, T>, row: usize, col0: usize, n: usize, co: &mut Coords) {
    let m = &job.m;
    let r = row as f64;
    // Along a row the homogeneous position is affine in the column: one base
    // per row plus c·step per pixel, no 3x3 product.
    let line = Line {
        bx: m[0][1] * r + m[0][2],
        by: m[1][1] * r + m[1][2],
        bw: m[2][1] * r + m[2][2],
        sx: m[0][0],
        sy: m[1][0],
        sw: m[2][0],
    };
    match &job.dist {
        Some(d) => exact_run::<T, true>(job, d, &line, col0, 0, n, co),
        None => {
            let mut j0 = 0;
            while j0 < n {
                let len = BLOCK.min(n - j0);
                fast_block(job, &line, col0, j0, len, co);
                j0 += len;
            }
        }
    }
}

/// Homogeneous source position along one grid row: `base + c·step`.
struct Line {
    bx: f64,
    by: f64,
    bw: f64,
    sx: f64,
    sy: f64,
    sw: f64,
}

impl Line {
    /// Source position in fixed-point units plus ½ (so `floor` rounds), and w.
    #[inline(always)]
    fn scaled(&self, c: f64) -> (f64, f64, f64) {
        let w = self.bw + c * self.sw;
        let rw = ONE as f64 / w;
        (
            (self.bx + c * self.sx) * rw + 0.5,
            (self.by + c * self.sy) * rw + 0.5,
            w,
        )
    }
}

/// Pixels per block of the f32 incremental path.
const BLOCK: usize = 64;
/// Largest position change (fixed-point units, 2¹⁸ = 128 px) across a block
/// for the f32 path; its rounding error stays below ~0.1 unit (5e-5 px).
const BLOCK_SPAN: f64 = (1 << 18) as f64;
/// Homogeneous w at or below this is "beyond the horizon" (keeps 1/w finite).
const W_MIN: f64 = 1e-200;

/// Phase 1 for one block of `len` pixels starting at column `col0 + j0`.
///
/// Within a block, the position relative to the block start is
/// `δ(j) = j·K / w(j)` with `K = step − U₀·sw` (one f64 setup per block),
/// evaluated in f32: δ is small, so f32 loses nothing that matters, and the
/// loop runs 8 lanes wide. Blocks where that does not hold (near the
/// horizon, steep minification) use the exact f64 path.
#[inline(always)]
fn fast_block<T>(job: &Job<'_, T>, l: &Line, col0: usize, j0: usize, len: usize, co: &mut Coords) {
    let c0 = (col0 + j0) as f64;
    let c1 = c0 + (len - 1) as f64;
    let (ux0, uy0, w0) = l.scaled(c0);
    let (ux1, uy1, w1) = l.scaled(c1);
    let (xmax, ymax) = (job.xmax_q as f64, job.ymax_q as f64);
    // w is affine in c, so positive at both ends means positive throughout,
    // and then the position is monotonic along the block.
    if w0 > W_MIN && w1 > W_MIN {
        let off_x = (ux0 < 0.0 && ux1 < 0.0) || (ux0 >= xmax + 1.0 && ux1 >= xmax + 1.0);
        let off_y = (uy0 < 0.0 && uy1 < 0.0) || (uy0 >= ymax + 1.0 && uy1 >= ymax + 1.0);
        if off_x || off_y {
            co.ix[j0..j0 + len].fill(-1);
            return;
        }
        let near = (ux1 - ux0).abs() <= BLOCK_SPAN
            && (uy1 - uy0).abs() <= BLOCK_SPAN
            && ux0.abs() < 1e9
            && uy0.abs() < 1e9
            && w1 <= 2.0 * w0
            && w0 <= 2.0 * w1;
        if near {
            let one = ONE as f64;
            let (x0i, y0i) = (ux0.floor(), uy0.floor());
            let kx = (l.sx * one + 0.5 * l.sw - ux0 * l.sw) as f32;
            let ky = (l.sy * one + 0.5 * l.sw - uy0 * l.sw) as f32;
            let (x0f, y0f) = ((ux0 - x0i) as f32, (uy0 - y0i) as f32);
            let (x0i, y0i) = (x0i as i32, y0i as i32);
            let (w0f, swf) = (w0 as f32, l.sw as f32);
            let lim = 2.0 * BLOCK_SPAN as f32;
            let ix = &mut co.ix[j0..j0 + len];
            let iy = &mut co.iy[j0..j0 + len];
            let fx = &mut co.fx[j0..j0 + len];
            let fy = &mut co.fy[j0..j0 + len];
            for j in 0..len {
                let jf = j as i32 as f32;
                let t = jf / (w0f + swf * jf);
                let dx = clamp_f32((x0f + kx * t).floor(), lim);
                let dy = clamp_f32((y0f + ky * t).floor(), lim);
                // SAFETY: clamped to ±2^19, finite (NaN became -lim).
                let (dx, dy): (i32, i32) =
                    unsafe { (dx.to_int_unchecked(), dy.to_int_unchecked()) };
                (ix[j], iy[j], fx[j], fy[j]) = finish(job, x0i + dx, y0i + dy, true);
            }
            return;
        }
    }
    exact_run::<T, false>(job, &NO_DIST, l, col0, j0, len, co);
}

/// `x` limited to [−lim, lim]; NaN gives −lim. Plain compares, so it
/// vectorises to max/min.
#[inline(always)]
fn clamp_f32(x: f32, lim: f32) -> f32 {
    let x = if x > -lim { x } else { -lim };
    if x < lim {
        x
    } else {
        lim
    }
}

/// Fixed-point position → (ix, iy, fx, fy), `ix = −1` when outside.
///
/// Inside iff the rounded position lies in [0, W−1] x [0, H−1]. On the last
/// column/row the pixel steps back by one with full weight on the far
/// neighbour, so the 2x2 block stays in the image.
#[inline(always)]
fn finish<T>(job: &Job<'_, T>, xq: i32, yq: i32, ok: bool) -> (i32, i32, i32, i32) {
    // Unsigned compare tests 0 ≤ q ≤ max in one go.
    let ok = ok & ((xq as u32) <= job.xmax_q as u32) & ((yq as u32) <= job.ymax_q as u32);
    let xi = (xq >> FRAC_BITS).min(job.wm2);
    let yi = (yq >> FRAC_BITS).min(job.hm2);
    (
        if ok { xi } else { -1 },
        yi,
        xq - (xi << FRAC_BITS),
        yq - (yi << FRAC_BITS),
    )
}

const NO_DIST: DistParams = DistParams {
    cu: 0.0,
    cv: 0.0,
    inv_f2: 0.0,
    k1: 0.0,
    k2: 0.0,
    r2_max: f64::INFINITY,
};

/// Phase 1, exact f64 per pixel (with distortion, or where the f32 block
/// path does not apply); pixels `j0..j0 + len` of the run.
#[inline(always)]
fn exact_run<T, const DIST: bool>(
    job: &Job<'_, T>,
    d: &DistParams,
    l: &Line,
    col0: usize,
    j0: usize,
    len: usize,
    co: &mut Coords,
) {
    let one = ONE as f64;
    // Clamp range for the float → int conversion (outside either way).
    let (xlim, ylim) = (job.xmax_q as f64 + 4.0, job.ymax_q as f64 + 4.0);
    let ix = &mut co.ix[j0..j0 + len];
    let iy = &mut co.iy[j0..j0 + len];
    let fx = &mut co.fx[j0..j0 + len];
    let fy = &mut co.fy[j0..j0 + len];
    for j in 0..len {
        // Grid sides are < 2^17, so the i32 round trip is exact (and i32→f64
        // converts in SIMD, usize→f64 does not).
        let c = (col0 + j0 + j) as i32 as f64;
        let w = l.bw + c * l.sw;
        let mut ok = w > W_MIN;
        let rw = 1.0 / if ok { w } else { 1.0 }; // one division per pixel
        let mut u = (l.bx + c * l.sx) * rw;
        let mut v = (l.by + c * l.sy) * rw;
        if DIST {
            let (du, dv, in_model) = d.apply(u, v);
            u = du;
            v = dv;
            ok &= in_model;
        }
        let xq = clamp_f64((u * one + 0.5).floor(), xlim);
        let yq = clamp_f64((v * one + 0.5).floor(), ylim);
        // SAFETY: clamped to [−4, max + 4] ⊂ i32, finite (NaN became −4).
        let (xq, yq): (i32, i32) = unsafe { (xq.to_int_unchecked(), yq.to_int_unchecked()) };
        (ix[j], iy[j], fx[j], fy[j]) = finish(job, xq, yq, ok);
    }
}

/// `x` limited to [−4, hi]; NaN gives −4.
#[inline(always)]
fn clamp_f64(x: f64, hi: f64) -> f64 {
    let x = if x > -4.0 { x } else { -4.0 };
    if x < hi {
        x
    } else {
        hi
    }
}

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
fn bicubic_run<T: Sample, const CN: usize>(job: &Job<'_, T>, co: &Coords, out: &mut [T]) {
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
