//! The rectifier: grid pixel → build point → image point → sample.
//!
//! Work is split in two phases per run of up to [`CHUNK`] output pixels of a
//! row, so both stay in L1:
//! 1. [`map_run`] (in `positions.rs`): source positions as fixed-point integers (pixel + 11-bit
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

use super::positions::map_run;
use super::{Interpolation, RectifyError};
use crate::geometry::mat3::{self, Mat3};
use crate::geometry::{BuildPoint, CameraModel, Grid, Homography, ImagePoint, RadialDistortion};

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
    /// Cached positions (see [`Rectifier::position_map`]), grid row-major.
    pub(crate) map: Option<&'a [[i32; 2]]>,
    pub(crate) cols: usize,
}

/// Renders one output row (`out` = one grid row, `CN` samples per pixel).
pub(crate) type RowFn<T> = fn(&Job<'_, T>, usize, &mut [T], &mut Coords);

/// Warps camera frames onto a top-down [`Grid`] of the build plate.
#[derive(Clone, Debug)]
pub struct Rectifier {
    /// The camera, its homography normalised to `H[2][2]` = 1.
    camera: CameraModel,
    grid: Grid,
    pub(crate) dist: Option<DistParams>,
    interpolation: Interpolation,
    fill: u16,
    /// `image_from_grid`: grid (col, row, 1) → undistorted image, i.e. `H⁻¹ · G`.
    pub(crate) m: Mat3,
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
    /// A rectifier for `camera` onto `grid`. Its homography (`build_from_image`, image (u, v, 1)
    /// to build (x, y, 1) in mm, up to scale) is normalised so that `H[2][2]` = 1. `fill` is
    /// used for grid pixels that see no image (clamped to 255 for 8-bit output).
    pub fn new(
        camera: &CameraModel,
        grid: Grid,
        interpolation: Interpolation,
        fill: u16,
    ) -> Result<Rectifier, RectifyError> {
        let homography = camera.build_from_image().matrix();
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
        let (h_inv, measure) = mat3::inverse(&h);
        if measure.is_nan() || measure <= 1e-12 || h_inv.iter().flatten().any(|v| !v.is_finite()) {
            return Err(RectifyError::SingularHomography(measure));
        }
        grid.validate()?;
        let distortion = camera.distortion();
        if let Some(d) = &distortion {
            d.validate()?;
        }
        Ok(Rectifier {
            camera: CameraModel::new(Homography::from_matrix(h), distortion),
            grid,
            dist: distortion.as_ref().map(DistParams::new),
            interpolation,
            fill,
            m: mat3::mul(&h_inv, &mat3::grid_matrix(&grid)),
            allow_simd: true,
            map: Default::default(),
        })
    }

    /// The camera, its homography normalised to `H[2][2]` = 1.
    pub fn camera(&self) -> &CameraModel {
        &self.camera
    }

    pub fn grid(&self) -> Grid {
        self.grid
    }

    pub fn interpolation(&self) -> Interpolation {
        self.interpolation
    }

    pub fn fill(&self) -> u16 {
        self.fill
    }

    /// Where a build point lands in the original (recorded, distorted) image:
    /// [`CameraModel::image_point`] of the rectifier's camera. `None` beyond the horizon or past
    /// the distortion's fold; points off the frame still return `Some`.
    pub fn image_point(&self, p: BuildPoint) -> Option<ImagePoint> {
        self.camera.image_point(p)
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
    pub(crate) fn position_map(&self) -> &[[i32; 2]] {
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
