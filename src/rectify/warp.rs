//! The rectifier: grid pixel → build point → image point → sample.
//!
//! Work is split in two phases per run of up to [`CHUNK`] output pixels of a
//! row, so both stay in L1:
//! 1. [`map_run`] (in `positions.rs`): source positions as fixed-point integers (pixel + 11-bit
//!    fraction), or "outside". Along a grid row the homogeneous position is
//!    affine in the column, so each pixel costs a few adds/multiplies and
//!    one division. Blocks are evaluated in f32 relative to a pixel of the block, 8 lanes
//!    with AVX2 or 16 with AVX-512 (a whole run from its middle, [`fast_block`]; 128 pixels
//!    from their start, [`fast_block_distorted`]); near the horizon each pixel is evaluated
//!    in f64 ([`exact_run`]). With lens distortion the positions are instead
//!    computed once per `Rectifier` into a cached map (8 bytes per grid
//!    pixel), which measured ~2x faster per frame than re-evaluating the
//!    lens model (see `Rectifier::position_map`).
//! 2. a sampling kernel: scalar generic (`bilinear_run`, `bicubic_run` in `kernel.rs`) or
//!    the AVX2 / AVX-512 ones for 8-bit grey / RGB bilinear (see `simd.rs`).
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

use std::mem::{ManuallyDrop, MaybeUninit};
use std::sync::{Arc, OnceLock};

use image::{DynamicImage, GrayImage, ImageBuffer, RgbImage};
use rayon::prelude::*;

use super::footprint::{self, Footprint, FootprintCache};
use super::kernel::{Coords, DistParams, Job, RowFn, Sample, Source, CHUNK, FRAC_BITS};
use super::positions::map_run;
use super::row::row_plain;
#[cfg(target_arch = "x86_64")]
use super::simd;
use super::{os, Gray16Image, Rgb16Image};
use super::{Interpolation, RectifyError};
use crate::geometry::mat3::{self, Mat3};
use crate::geometry::{BuildPoint, CameraModel, Grid, Homography, ImagePoint};

/// Largest source image side (pixels) the rectifier samples; larger sources
/// give an all-fill result. Positions are i32 with 11 fraction bits.
pub const MAX_SOURCE_SIDE: usize = 1 << 19;

/// Output rows per rayon task.
const BAND: usize = 4;

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
    /// What it reads of a frame, for the frame size last asked ([`Rectifier::footprint`]).
    footprint: FootprintCache,
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
            footprint: Default::default(),
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
    /// into row bands over rayon and runs `row_fn` on every row. `init` turns each band into
    /// samples before its rows are rendered ([`as_is`], or [`init_band`] for a fresh buffer).
    pub(crate) fn run_into<T: Sample, U: Send, const CN: usize>(
        &self,
        data: &[T],
        width: u32,
        height: u32,
        row_fn: RowFn<T>,
        out: &mut [U],
        init: fn(&mut [U], T) -> &mut [T],
    ) {
        let row_len = self.grid.columns() * CN;
        debug_assert_eq!(out.len(), row_len * self.grid.rows());
        let fill = T::from_u32(u32::from(self.fill).min(T::MAX));
        let (w, h) = (width as usize, height as usize);
        if w < 2 || h < 2 || w > MAX_SOURCE_SIDE || h > MAX_SOURCE_SIDE || data.len() < w * h * CN {
            // No 2x2 neighbourhood, or beyond the fixed-point range: nothing is inside.
            out.par_chunks_mut(row_len.max(1))
                .for_each(|r| init(r, fill).fill(fill));
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
                let band = init(band, fill);
                for (k, row_out) in band.chunks_mut(row_len).enumerate() {
                    row_fn(&job, b * BAND + k, row_out, co);
                }
            });
    }

    /// Warps `src` into `dst`, or, when `dst` is not the grid's size, into a fresh buffer that
    /// then replaces it.
    ///
    /// The fresh buffer is never zeroed as a whole: each band is filled by the worker thread
    /// that renders it, just before (in cache), so there is no serial memset (glibc's `calloc`
    /// clears reused heap memory in the calling thread) and the pages are first touched in
    /// parallel. Huge pages are asked for, which cuts first-touch page faults ~500-fold (a 4400²
    /// RGB frame is 58 MB: ~14 000 faults otherwise).
    fn warp_to<P, T, const CN: usize>(
        &self,
        src: &ImageBuffer<P, Vec<T>>,
        row_fn: RowFn<T>,
        dst: &mut ImageBuffer<P, Vec<T>>,
    ) where
        P: image::Pixel<Subpixel = T>,
        T: Sample,
    {
        let g = self.grid();
        let (cols, rows) = (g.columns() as u32, g.rows() as u32);
        let (data, w, h) = (src.as_raw(), src.width(), src.height());
        if dst.dimensions() == (cols, rows) {
            self.run_into::<T, T, CN>(data, w, h, row_fn, dst, as_is);
            return;
        }
        let len = g.columns() * g.rows() * CN;
        let mut buf: Vec<MaybeUninit<T>> = Vec::with_capacity(len);
        // SAFETY: capacity is `len`, and `MaybeUninit` elements need no initialisation.
        unsafe { buf.set_len(len) };
        os::advise_huge_pages(&mut buf);
        self.run_into::<T, MaybeUninit<T>, CN>(data, w, h, row_fn, &mut buf, init_band);
        let mut buf = ManuallyDrop::new(buf);
        // SAFETY: run_into initialised every element (it passes every band of `buf`, and the
        // bands cover it, through `init_band` before anything else); `MaybeUninit<T>` has the
        // layout of `T`, so pointer, length and capacity describe the same allocation as a
        // `Vec<T>`, whose ownership moves here (the `ManuallyDrop` never frees it).
        let buf = unsafe { Vec::from_raw_parts(buf.as_mut_ptr().cast::<T>(), len, buf.capacity()) };
        *dst = ImageBuffer::from_raw(cols, rows, buf).expect("the buffer is the grid's size");
    }

    /// What the rectifier reads of a `width` x `height` frame (`footprint.rs`), walked once per
    /// frame size; `None` when it cannot be bounded (then the whole frame is decoded).
    pub(crate) fn footprint(&self, width: usize, height: usize) -> Option<Arc<Footprint>> {
        self.footprint.get(width, height, || {
            footprint::walk(&self.camera, self.grid, width, height)
        })
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
        if self.allow_simd && simd::available() {
            return match (self.interpolation, fast) {
                (Interpolation::Bilinear, Some(f)) => f,
                (Interpolation::Bilinear, None) => simd::row_generic::<T, CN, false>,
                (Interpolation::Bicubic, _) => simd::row_generic::<T, CN, true>,
            };
        }
        let _ = fast;
        match self.interpolation {
            Interpolation::Bilinear => row_plain::<T, CN, false>,
            Interpolation::Bicubic => row_plain::<T, CN, true>,
        }
    }
}

impl Rectifier {
    /// Rectifies an 8-bit grey frame onto the grid (see the module docs for
    /// the sampling and border rules).
    pub fn rectify_gray8(&self, src: &GrayImage) -> GrayImage {
        let mut dst = ImageBuffer::new(0, 0);
        self.rectify_gray8_into(src, &mut dst);
        dst
    }

    /// Rectifies an 8-bit RGB frame.
    pub fn rectify_rgb8(&self, src: &RgbImage) -> RgbImage {
        let mut dst = ImageBuffer::new(0, 0);
        self.rectify_rgb8_into(src, &mut dst);
        dst
    }

    /// Rectifies a 16-bit grey frame.
    pub fn rectify_gray16(&self, src: &Gray16Image) -> Gray16Image {
        let mut dst = ImageBuffer::new(0, 0);
        self.rectify_gray16_into(src, &mut dst);
        dst
    }

    /// Rectifies a 16-bit RGB frame.
    pub fn rectify_rgb16(&self, src: &Rgb16Image) -> Rgb16Image {
        let mut dst = ImageBuffer::new(0, 0);
        self.rectify_rgb16_into(src, &mut dst);
        dst
    }

    /// As [`Rectifier::rectify_gray8`], writing into `dst` (reallocated only
    /// if its size is not the grid's). Reusing `dst` across frames saves the
    /// page faults of a fresh multi-megabyte buffer per frame.
    pub fn rectify_gray8_into(&self, src: &GrayImage, dst: &mut GrayImage) {
        #[cfg(target_arch = "x86_64")]
        let fast = Some(simd::row_gray8 as RowFn<u8>);
        #[cfg(not(target_arch = "x86_64"))]
        let fast = None;
        let row_fn = self.row_fn::<u8, 1>(fast);
        self.warp_to::<_, u8, 1>(src, row_fn, dst);
    }

    /// As [`Rectifier::rectify_rgb8`], writing into `dst`.
    pub fn rectify_rgb8_into(&self, src: &RgbImage, dst: &mut RgbImage) {
        #[cfg(target_arch = "x86_64")]
        let fast = Some(simd::row_rgb8 as RowFn<u8>);
        #[cfg(not(target_arch = "x86_64"))]
        let fast = None;
        let row_fn = self.row_fn::<u8, 3>(fast);
        self.warp_to::<_, u8, 3>(src, row_fn, dst);
    }

    /// As [`Rectifier::rectify_gray16`], writing into `dst`.
    pub fn rectify_gray16_into(&self, src: &Gray16Image, dst: &mut Gray16Image) {
        let row_fn = self.row_fn::<u16, 1>(None);
        self.warp_to::<_, u16, 1>(src, row_fn, dst);
    }

    /// As [`Rectifier::rectify_rgb16`], writing into `dst`.
    pub fn rectify_rgb16_into(&self, src: &Rgb16Image, dst: &mut Rgb16Image) {
        let row_fn = self.row_fn::<u16, 3>(None);
        self.warp_to::<_, u16, 3>(src, row_fn, dst);
    }

    /// Rectifies any image: L8/Rgb8/L16/Rgb16 directly; other formats are
    /// first converted to the nearest of those (alpha dropped, LA8 → L8,
    /// RGBA8 → RGB8, LA16 → L16, RGBA16 and float RGB(A) → RGB16).
    pub fn rectify_dynamic(&self, src: &DynamicImage) -> DynamicImage {
        match src {
            DynamicImage::ImageLuma8(i) => DynamicImage::ImageLuma8(self.rectify_gray8(i)),
            DynamicImage::ImageRgb8(i) => DynamicImage::ImageRgb8(self.rectify_rgb8(i)),
            DynamicImage::ImageLuma16(i) => DynamicImage::ImageLuma16(self.rectify_gray16(i)),
            DynamicImage::ImageRgb16(i) => DynamicImage::ImageRgb16(self.rectify_rgb16(i)),
            DynamicImage::ImageLumaA8(_) => {
                DynamicImage::ImageLuma8(self.rectify_gray8(&src.to_luma8()))
            }
            DynamicImage::ImageRgba8(_) => {
                DynamicImage::ImageRgb8(self.rectify_rgb8(&src.to_rgb8()))
            }
            DynamicImage::ImageLumaA16(_) => {
                DynamicImage::ImageLuma16(self.rectify_gray16(&src.to_luma16()))
            }
            _ => DynamicImage::ImageRgb16(self.rectify_rgb16(&src.to_rgb16())),
        }
    }
}

/// A band of an initialised buffer, as it is.
fn as_is<T>(band: &mut [T], _fill: T) -> &mut [T] {
    band
}

/// A band of a fresh buffer, every element set to `fill`.
fn init_band<T: Copy>(band: &mut [MaybeUninit<T>], fill: T) -> &mut [T] {
    for v in band.iter_mut() {
        v.write(fill);
    }
    // SAFETY: every element was just written, and `MaybeUninit<T>` has the layout of `T`.
    unsafe { &mut *(band as *mut [MaybeUninit<T>] as *mut [T]) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{homography_from_points, RadialDistortion};

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
        let h = homography_from_points(
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
        let camera = CameraModel::new(h, Some(lens));
        let r = Rectifier::new(&camera, grid, Interpolation::Bilinear, 0).unwrap();
        let (w, hgt) = (640usize, 420usize);
        let data = vec![0u8; w * hgt];
        let direct = Job::for_test(&data, w, hgt, r.m, r.dist);
        let cached = Job {
            map: Some(r.position_map()),
            cols: grid.columns(),
            ..Job::for_test(&data, w, hgt, r.m, r.dist)
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
