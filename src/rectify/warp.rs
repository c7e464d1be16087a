//! The rectifier: grid pixel → build point → image point → sample.
//!
//! Work is split in two phases per run of up to [`CHUNK`] output pixels of a
//! row, so both stay in L1:
//! 1. [`map_run`]: source positions as fixed-point integers (pixel + 11-bit
//!    fraction), or "outside". Along a grid row the homogeneous position is
//!    affine in the column, so each pixel costs a few adds/multiplies and
//!    one division. Blocks of 64 pixels are evaluated relative to the block
//!    start in f32, 8 lanes with AVX2 ([`fast_block`],
//!    [`fast_block_distorted`]); near the horizon each pixel is evaluated
//!    in f64 ([`exact_run`]). With lens distortion the positions are instead
//!    computed once per `Rectifier` into a cached map (8 bytes per grid
//!    pixel), which measured ~2x faster per frame than re-evaluating the
//!    lens model (see `Rectifier::position_map`).
//! 2. a sampling kernel: scalar generic ([`bilinear_run`], [`bicubic_run`]) or
//!    the AVX2 ones for 8-bit grey / RGB bilinear (see `simd.rs`).
//!
//! # Border rule
//! The source position is first rounded to 1/2048 px. A sample is *inside*
//! iff that position lies in the closed rectangle spanned by the source pixel
//! centers, `0 ≤ u ≤ W−1`, `0 ≤ v ≤ H−1`, so its whole 2x2 bilinear
//! neighbourhood is in the image (at exactly `u = W−1` the right-hand
//! neighbour has weight 0). Anything else becomes `fill`, with no blending.
//! OpenCV's `BORDER_CONSTANT` instead blends with the border value for
//! positions up to one pixel outside that rectangle, so the two differ only
//! in a band of at most one source pixel around the image edge.
//! Bicubic uses the same inside test and replicates edge pixels for its outer
//! taps, so both interpolations fill exactly the same grid pixels.
//! A point whose homogeneous w ≤ 0 lies beyond the horizon (on the other side
//! of the camera) and is outside too, as is a point past the radius where the
//! distortion polynomial folds back.

use std::sync::{Arc, OnceLock};

use rayon::prelude::*;

use super::{Interpolation, RectifyError};
use crate::geometry::mat3::{self as homography, Mat3};
use crate::geometry::{Grid, RadialDistortion};

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

/// Largest source image side (pixels) the rectifier samples; larger sources
/// give an all-fill result. Positions are i32 with 11 fraction bits.
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
    /// Cached positions (see [`Rectifier::position_map`]), grid row-major.
    map: Option<&'a [[i32; 2]]>,
    cols: usize,
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
    /// With distortion: cached fixed-point source positions of every grid
    /// pixel, built on first use and shared by clones.
    map: PositionMap,
}

/// Row-major `[X, Y]` fixed-point source position per grid pixel
/// (`X = i32::MIN`: outside whatever the image size).
#[derive(Clone, Default)]
struct PositionMap(Arc<OnceLock<Vec<[i32; 2]>>>);

impl std::fmt::Debug for PositionMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0.get() {
            Some(m) => write!(f, "PositionMap({} pixels)", m.len()),
            None => f.write_str("PositionMap(not built)"),
        }
    }
}

impl Rectifier {
    /// `homography` maps image (u, v, 1) to build (x, y, 1) in mm, up to scale;
    /// it is normalised so that `H[2][2]` = 1. `fill` is used for grid pixels
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
        if measure.is_nan() || measure <= 1e-12 || h_inv.iter().flatten().any(|v| !v.is_finite()) {
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
            map: Default::default(),
        })
    }

    /// The homography (image → build), normalised to `H[2][2]` = 1.
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
        // Beyond the horizon (or NaN): not a point the camera sees.
        if w.is_nan() || w <= 0.0 {
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
            map: self.dist.is_some().then(|| self.position_map()),
            cols: self.grid.columns(),
        };
        out.par_chunks_mut(row_len * BAND)
            .enumerate()
            .for_each_init(Coords::new, |co, (b, band)| {
                for (k, row_out) in band.chunks_mut(row_len).enumerate() {
                    row_fn(&job, b * BAND + k, row_out, co);
                }
            });
    }

    /// The cached position map (built on first call; see [`PositionMap`]).
    ///
    /// Used with distortion, where evaluating the lens model per pixel per
    /// frame costs more than streaming 8 bytes per pixel: measured on the
    /// 7360x4912 → 4400² bench, single thread, grey: ~45 ms per frame
    /// evaluating per pixel (f32 block path) vs ~23 ms from the map (no
    /// distortion, computed: ~25 ms). The map costs 8 bytes per grid pixel
    /// (155 MB for the plate grid) and one warp's worth of time to build.
    /// Without distortion the incremental per-row computation is kept: no
    /// memory, no warm-up.
    fn position_map(&self) -> &[[i32; 2]] {
        self.map.0.get_or_init(|| {
            let cols = self.grid.columns();
            // Image-independent positions: map_run with bounds no real source
            // reaches (sides ≤ 2^19 px, so positions ≤ 2^30 units).
            let big = 1i32 << 30;
            let job: Job<'_, u8> = Job {
                src: Source {
                    data: &[],
                    width: 0,
                    height: 0,
                    stride: 0,
                },
                fill: 0,
                m: self.m,
                dist: self.dist,
                xmax_q: big,
                ymax_q: big,
                wm2: big >> FRAC_BITS,
                hm2: big >> FRAC_BITS,
                map: None,
                cols,
            };
            let mut map = vec![[0i32; 2]; cols * self.grid.rows()];
            map.par_chunks_mut(cols)
                .enumerate()
                .for_each_init(Coords::new, |co, (row, out)| {
                    for (k, chunk) in out.chunks_mut(CHUNK).enumerate() {
                        map_run(&job, row, k * CHUNK, chunk.len(), co);
                        for (i, p) in chunk.iter_mut().enumerate() {
                            *p = if co.ix[i] < 0 {
                                [i32::MIN, 0]
                            } else {
                                [
                                    (co.ix[i] << FRAC_BITS) + co.fx[i],
                                    (co.iy[i] << FRAC_BITS) + co.fy[i],
                                ]
                            };
                        }
                    }
                });
            map
        })
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
    if let Some(map) = job.map {
        // Cached positions (distortion): only the image bounds are applied.
        // i32::MIN fails finish's unsigned range test, so it stays outside.
        let src = &map[row * job.cols + col0..][..n];
        let ix = &mut co.ix[..n];
        let iy = &mut co.iy[..n];
        let fx = &mut co.fx[..n];
        let fy = &mut co.fy[..n];
        for j in 0..n {
            let [x, y] = src[j];
            (ix[j], iy[j], fx[j], fy[j]) = finish(job, x, y, true);
        }
        return;
    }
    let mut j0 = 0;
    while j0 < n {
        let len = BLOCK.min(n - j0);
        match &job.dist {
            Some(d) => fast_block_distorted(job, d, &line, col0, j0, len, co),
            None => fast_block(job, &line, col0, j0, len, co),
        }
        j0 += len;
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
    /// Undistorted source position in pixels, and w.
    #[inline(always)]
    fn at(&self, c: f64) -> (f64, f64, f64) {
        let w = self.bw + c * self.sw;
        ((self.bx + c * self.sx) / w, (self.by + c * self.sy) / w, w)
    }

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

/// [`fast_block`] with lens distortion.
///
/// The undistorted offset from the block start, (δu, δv) = j·(Ku, Kv)/w(j),
/// is pushed through the distortion as a difference from the block start:
/// with e = Δr² and κ = Δk = e·(k1 + k2·(2r₀² + e)),
/// `Δu_d = δu·(k₀ + κ) + du₀·κ` (and likewise for v). Every f32 term is a
/// small difference, so the result keeps the block path's precision.
#[inline(always)]
fn fast_block_distorted<T>(
    job: &Job<'_, T>,
    d: &DistParams,
    l: &Line,
    col0: usize,
    j0: usize,
    len: usize,
    co: &mut Coords,
) {
    let c0 = (col0 + j0) as f64;
    let c1 = c0 + (len - 1) as f64;
    let (u0, v0, w0) = l.at(c0);
    let (u1, v1, w1) = l.at(c1);
    let one = ONE as f64;
    if w0 > W_MIN && w1 > W_MIN && w1 <= 2.0 * w0 && w0 <= 2.0 * w1 {
        let (ud0, vd0, in0) = d.apply(u0, v0);
        let (ud1, vd1, in1) = d.apply(u1, v1);
        let span = BLOCK_SPAN / one;
        let near = in0
            && in1
            && (u1 - u0).abs() <= span
            && (v1 - v0).abs() <= span
            && (ud1 - ud0).abs() <= span
            && (vd1 - vd0).abs() <= span
            && ud0.abs() < 1e5
            && vd0.abs() < 1e5;
        if near {
            let (du0, dv0) = (u0 - d.cu, v0 - d.cv);
            let r20 = (du0 * du0 + dv0 * dv0) * d.inv_f2;
            let k0 = 1.0 + r20 * (d.k1 + r20 * d.k2);
            let (xs, ys) = (ud0 * one + 0.5, vd0 * one + 0.5);
            let (x0i, y0i) = (xs.floor(), ys.floor());
            let (x0f, y0f) = ((xs - x0i) as f32, (ys - y0i) as f32);
            let (x0i, y0i) = (x0i as i32, y0i as i32);
            let ku = (l.sx - u0 * l.sw) as f32;
            let kv = (l.sy - v0 * l.sw) as f32;
            let (w0f, swf) = (w0 as f32, l.sw as f32);
            let (du0f, dv0f, k0f) = (du0 as f32, dv0 as f32, k0 as f32);
            let (au, av, s) = (
                (2.0 * du0 * d.inv_f2) as f32,
                (2.0 * dv0 * d.inv_f2) as f32,
                d.inv_f2 as f32,
            );
            let (k1, k2, r20f) = (d.k1 as f32, d.k2 as f32, r20 as f32);
            // Room left below the fold, as a limit on Δr².
            let e_max = (d.r2_max - r20) as f32;
            let onef = one as f32;
            let lim = 2.0 * BLOCK_SPAN as f32;
            let ix = &mut co.ix[j0..j0 + len];
            let iy = &mut co.iy[j0..j0 + len];
            let fx = &mut co.fx[j0..j0 + len];
            let fy = &mut co.fy[j0..j0 + len];
            for j in 0..len {
                let jf = j as i32 as f32;
                let t = jf / (w0f + swf * jf);
                let (du, dv) = (ku * t, kv * t);
                let e = (au + s * du) * du + (av + s * dv) * dv;
                let kappa = e * (k1 + k2 * (2.0 * r20f + e));
                let dud = du * (k0f + kappa) + du0f * kappa;
                let dvd = dv * (k0f + kappa) + dv0f * kappa;
                let dx = clamp_f32((x0f + dud * onef).floor(), lim);
                let dy = clamp_f32((y0f + dvd * onef).floor(), lim);
                // SAFETY: clamped to ±2^19, finite (NaN became -lim).
                let (dx, dy): (i32, i32) =
                    unsafe { (dx.to_int_unchecked(), dy.to_int_unchecked()) };
                (ix[j], iy[j], fx[j], fy[j]) = finish(job, x0i + dx, y0i + dy, e < e_max);
            }
            return;
        }
    }
    exact_run::<T, true>(job, d, l, col0, j0, len, co);
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

#[cfg(test)]
mod tests {
    use super::*;

    fn job(data: &[u8], w: usize, h: usize, m: Mat3, dist: Option<DistParams>) -> Job<'_, u8> {
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

    /// The f32 block paths (with and without distortion) agree with the
    /// exact f64 path to within one fixed-point unit (1/2048 px), including
    /// the inside/outside verdict away from the boundary.
    #[test]
    fn f32_blocks_match_exact_positions() {
        let (w, h) = (7360usize, 4912usize);
        let data = vec![0u8; w * h];
        let plate = [
            [-137.5, 137.5],
            [137.5, 137.5],
            [137.5, -137.5],
            [-137.5, -137.5],
        ];
        let views = [
            [
                [1400.0, 600.0],
                [5960.0, 600.0],
                [6900.0, 4500.0],
                [460.0, 4500.0],
            ],
            [
                [1200.0, 900.0],
                [6100.0, 300.0],
                [7300.0, 4700.0],
                [100.0, 4000.0],
            ],
            [
                [3000.0, 2000.0],
                [4000.0, 2100.0],
                [4200.0, 2900.0],
                [2900.0, 2800.0],
            ],
        ];
        let lens = RadialDistortion {
            center: [3650.0, 2500.0],
            focal_px: 8000.0,
            k1: -0.06,
            k2: 0.015,
        };
        let mut fast_blocks = 0;
        for ((k, img), dist) in views
            .iter()
            .enumerate()
            .flat_map(|v| [(v, None), (v, Some(DistParams::new(&lens)))])
        {
            let h_img = homography::homography_from_points(*img, plate).unwrap();
            // Overhanging grid (pixels outside the image) at two scales.
            let p = if k == 2 { 0.5 } else { 0.0625 };
            let g = [
                [p, 0.0, -150.0 + 0.5 * p],
                [0.0, -p, 150.0 - 0.5 * p],
                [0.0, 0.0, 1.0],
            ];
            let (hi, _) = homography::inverse(&h_img);
            let m = homography::mul(&hi, &g);
            let j = job(&data, w, h, m, dist);
            let cols = (300.0 / p) as usize;
            let (mut a, mut b) = (Coords::new(), Coords::new());
            for row in (0..cols).step_by(97) {
                for col0 in (0..cols).step_by(CHUNK) {
                    let n = CHUNK.min(cols - col0);
                    map_run(&j, row, col0, n, &mut a);
                    let r = row as f64;
                    let line = Line {
                        bx: m[0][1] * r + m[0][2],
                        by: m[1][1] * r + m[1][2],
                        bw: m[2][1] * r + m[2][2],
                        sx: m[0][0],
                        sy: m[1][0],
                        sw: m[2][0],
                    };
                    match &dist {
                        Some(d) => exact_run::<u8, true>(&j, d, &line, col0, 0, n, &mut b),
                        None => exact_run::<u8, false>(&j, &NO_DIST, &line, col0, 0, n, &mut b),
                    }
                    for i in 0..n {
                        let q = |c: &Coords| {
                            (
                                (c.ix[i].max(0) << FRAC_BITS) + c.fx[i],
                                (c.iy[i] << FRAC_BITS) + c.fy[i],
                            )
                        };
                        let ((xa, ya), (xb, yb)) = (q(&a), q(&b));
                        let edge = xb.min(j.xmax_q - xb).min(yb).min(j.ymax_q - yb);
                        if (a.ix[i] < 0) != (b.ix[i] < 0) {
                            assert!(
                                edge.abs() <= 1,
                                "verdicts differ away from the edge: row {row} col {}",
                                col0 + i
                            );
                        } else if a.ix[i] >= 0 {
                            assert!(
                                (xa - xb).abs() <= 1 && (ya - yb).abs() <= 1,
                                "row {row} col {}: {xa},{ya} vs {xb},{yb}",
                                col0 + i
                            );
                            fast_blocks += usize::from(xa != xb || ya != yb);
                        }
                    }
                }
            }
        }
        // Tiny differences show the block path really ran (and stayed within 1 unit).
        assert!(fast_blocks > 0);
    }

    /// The cached map (distortion) gives exactly the positions computed
    /// directly for the actual image size.
    #[test]
    fn position_map_matches_direct_computation() {
        let lens = RadialDistortion {
            center: [310.0, 205.0],
            focal_px: 500.0,
            k1: -0.2,
            k2: 0.05,
        };
        let h = homography::homography_from_points(
            [[120.0, 60.0], [500.0, 70.0], [590.0, 390.0], [30.0, 380.0]],
            [
                [-100.0, 100.0],
                [100.0, 100.0],
                [100.0, -100.0],
                [-100.0, -100.0],
            ],
        )
        .unwrap();
        let grid = Grid {
            x_min: -170.0,
            x_max: 170.0,
            y_min: -170.0,
            y_max: 170.0,
            pixel_mm: 0.4,
        };
        let r = Rectifier::new(h, grid, Some(lens), Interpolation::Bilinear, 0).unwrap();
        let (w, hgt) = (640usize, 420usize);
        let data = vec![0u8; w * hgt];
        let direct = job(&data, w, hgt, r.m, r.dist);
        let cached = Job {
            map: Some(r.position_map()),
            cols: grid.columns(),
            ..job(&data, w, hgt, r.m, r.dist)
        };
        let (mut a, mut b) = (Coords::new(), Coords::new());
        let (mut inside, mut outside) = (0, 0);
        for row in 0..grid.rows() {
            for col0 in (0..grid.columns()).step_by(CHUNK) {
                let n = CHUNK.min(grid.columns() - col0);
                map_run(&direct, row, col0, n, &mut a);
                map_run(&cached, row, col0, n, &mut b);
                for i in 0..n {
                    assert_eq!(a.ix[i] < 0, b.ix[i] < 0, "row {row} col {}", col0 + i);
                    if a.ix[i] >= 0 {
                        inside += 1;
                        let pa = (a.ix[i], a.iy[i], a.fx[i], a.fy[i]);
                        assert_eq!(pa, (b.ix[i], b.iy[i], b.fx[i], b.fy[i]));
                    } else {
                        outside += 1;
                    }
                }
            }
        }
        assert!(inside > 100_000 && outside > 10_000, "{inside} / {outside}");
    }
}
