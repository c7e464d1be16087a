//! Rasterisation of laser scan vectors onto the rectified grid (paper §3.1), and the
//! exemplar the build-image registration aligns to.
//!
//! A layer's fused area is the union of
//! - the interior of its contours (direction 0 and 1), filled by the nonzero winding rule over
//!   the points' own orientation ([`FillRule::NonZero`], the default) or by even-odd;
//! - its hatch segments and open polylines (direction 2), each the set of points within half
//!   the spot width of the segment;
//! - optionally the contours themselves stroked with their own width
//!   ([`RasterOptions::contour_width_mm`], 0 by default: the contour only bounds the fill).
//!
//! Sampling: [`mask`] tests each pixel center (0 or 255); [`coverage`] counts S x S
//! sub-samples per pixel (default 4 x 4 = 16) and scales the covered fraction to 0..255.
//!
//! # What the real files need
//! In every file in `shared/data/cli` the direction code agrees with the geometry (code 1
//! counter-clockwise, code 0 clockwise by the shoelace sign):
//! - `s_Cylinder_ex.cli`: 230 counter-clockwise contours and 3 clockwise ones; the clockwise
//!   ones are degenerate 4-point slivers (|area| ≤ 0.0003 mm²), two of them inside an outer
//!   contour, so inner contours are clockwise but there are no real holes. Some outer contours
//!   of a layer touch or overlap: nonzero keeps those pixels filled, even-odd empties them
//!   (4 pixels over the file at 0.0625 mm). Nonzero is the rule the file needs.
//! - `frustrum_ASCII.cli`: one counter-clockwise contour per layer plus hatches; both rules agree.
//! - `Box_support_solid_ascii_with_params.cli`: no contours at all. Each layer holds one
//!   direction-2 (open) polyline whose ends meet, counter-clockwise: the outline of a support
//!   block. By default it is drawn as a line like a hatch; set
//!   [`RasterOptions::fill_closed_open`] to fill such closed open polylines as contours.
//! - `s_MiniCooper_ex.cli`: counter-clockwise contours only; both rules agree.
//!
//! Even-odd remains available for files whose inner contours are not reversed.

mod draw;
mod error;
mod options;
mod scan;
pub mod sheet;
mod stdfilt;

use std::fmt;
use std::path::Path;
use std::str::FromStr;

use image::{GrayImage, ImageFormat, Rgb, RgbImage};
use rayon::prelude::*;

pub use crate::geometry::{Grid, DEFAULT_PIXEL_MM, MAX_PIXELS, MAX_SIDE, PLATE_HALF_MM};
pub use error::RasterError;
pub use options::{FillRule, RasterOptions, DEFAULT_SPOT_WIDTH_MM};
pub use stdfilt::{std_filter, F32Image};

pub(crate) use scan::is_closed;

use crate::vectors::{Direction, Layer, VectorFile};

/// Default standard deviation window of the exemplar, in pixels (≈ 0.7 mm at 0.0625 mm):
/// a starting value until the calibration tunes it on real build images.
pub const DEFAULT_STD_WINDOW: usize = 11;
/// Default seed of the exemplar's white noise.
pub const DEFAULT_SEED: u64 = 0x5EED;
/// Margin in mm around the geometry of [`default_grid`].
pub const DEFAULT_MARGIN_MM: f64 = 2.0;

/// Background, fused area, contour and hatch colours of [`rgb`] (the paper's Fig. 9 left).
pub const RGB_BACKGROUND: Rgb<u8> = Rgb([0, 0, 0]);
pub const RGB_FUSED: Rgb<u8> = Rgb([64, 64, 64]);
pub const RGB_CONTOUR: Rgb<u8> = Rgb([0, 0, 255]);
pub const RGB_HATCH: Rgb<u8> = Rgb([255, 0, 0]);

/// What [`render_to_png`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RasterKind {
    /// 8-bit, 0 or 255.
    Mask,
    /// 8-bit anti-aliased coverage 0..255.
    Coverage,
    /// 8-bit RGB: fused area grey, contours blue, hatches red.
    Rgb,
    /// 16-bit grey: the exemplar scaled so that its maximum is 65535.
    Exemplar,
}

impl FromStr for RasterKind {
    type Err = RasterError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "mask" => Ok(RasterKind::Mask),
            "coverage" => Ok(RasterKind::Coverage),
            "rgb" => Ok(RasterKind::Rgb),
            "exemplar" => Ok(RasterKind::Exemplar),
            _ => Err(RasterError::UnknownKind(s.to_string())),
        }
    }
}

impl fmt::Display for RasterKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RasterKind::Mask => "mask",
            RasterKind::Coverage => "coverage",
            RasterKind::Rgb => "rgb",
            RasterKind::Exemplar => "exemplar",
        })
    }
}

/// Fused-area mask: 255 where the pixel center is fused, else 0.
pub fn mask(layer: &Layer, grid: &Grid, opts: &RasterOptions) -> Result<GrayImage, RasterError> {
    render(layer, grid, opts, 1, true)
}

/// Anti-aliased fused-area coverage: the fraction of `opts.subsamples`² sub-samples fused,
/// 0..255. Summed over the image and divided by 255, it approximates the fused area in pixels.
pub fn coverage(
    layer: &Layer,
    grid: &Grid,
    opts: &RasterOptions,
) -> Result<GrayImage, RasterError> {
    render(layer, grid, opts, opts.subsamples, false)
}

fn render(
    layer: &Layer,
    grid: &Grid,
    opts: &RasterOptions,
    s: usize,
    binary: bool,
) -> Result<GrayImage, RasterError> {
    grid.validate()?;
    let (w, h) = (grid.columns(), grid.rows());
    let mut buf = vec![0u8; w * h];
    scan::Scene::new(layer, grid, opts).render(s, binary, &mut buf);
    // validate() keeps both sides within u32.
    GrayImage::from_raw(w as u32, h as u32, buf)
        .ok_or_else(|| RasterError::InvalidGrid(crate::geometry::GridError(format!("{w} x {h}"))))
}

/// The filled mask as bytes (0/255, row-major, pixel centers) without the image wrapper, for
/// callers that sample other grids (the TSDF's voxel slices).
pub(crate) fn mask_into(layer: &Layer, grid: &Grid, opts: &RasterOptions, out: &mut [u8]) {
    scan::Scene::new(layer, grid, opts).render(1, true, out);
}

/// Colour rendering: black background, fused area ([`mask`]) dark grey, hatches red and
/// polylines (contours and open lines) blue, both one pixel wide, contours drawn last.
pub fn rgb(layer: &Layer, grid: &Grid, opts: &RasterOptions) -> Result<RgbImage, RasterError> {
    let m = mask(layer, grid, opts)?;
    let mut img = RgbImage::from_pixel(m.width(), m.height(), RGB_BACKGROUND);
    img.par_chunks_mut(3)
        .zip(m.as_raw().par_iter())
        .for_each(|(px, &v)| {
            if v != 0 {
                px.copy_from_slice(&RGB_FUSED.0);
            }
        });
    let keep = |part: i64| opts.part.is_none_or(|want| want == part);
    for h in layer.hatches.iter().filter(|h| keep(h.part)) {
        for s in &h.segments {
            draw::line(&mut img, grid, [s[0], s[1]], [s[2], s[3]], RGB_HATCH);
        }
    }
    for p in layer.polylines.iter().filter(|p| keep(p.part)) {
        let n = p.points.len();
        for i in 0..n.saturating_sub(1) {
            draw::line(&mut img, grid, p.points[i], p.points[i + 1], RGB_CONTOUR);
        }
        if p.direction != Direction::Open && n > 2 {
            draw::line(&mut img, grid, p.points[n - 1], p.points[0], RGB_CONTOUR);
        }
    }
    Ok(img)
}

/// The exemplar of paper §3.1: the [`mask`] with its ones replaced by uniform white noise
/// 0..255 (deterministic for a seed), zeros kept, then [`std_filter`] with `window`, exactly
/// as the build images are filtered, so both show the same dilation at part edges.
pub fn exemplar(
    layer: &Layer,
    grid: &Grid,
    opts: &RasterOptions,
    window: usize,
    seed: u64,
) -> Result<F32Image, RasterError> {
    let m = mask(layer, grid, opts)?;
    let (w, h) = (m.width() as usize, m.height() as usize);
    let noisy: Vec<f32> = m
        .as_raw()
        .par_iter()
        .enumerate()
        .map(|(i, &v)| {
            if v != 0 {
                stdfilt::noise_byte(seed, i as u64) as f32
            } else {
                0.0
            }
        })
        .collect();
    let data = std_filter(&noisy, w, h, window)?;
    Ok(F32Image {
        width: w,
        height: h,
        data,
    })
}

/// Bounding box [x_min, y_min, x_max, y_max] of one layer's polylines and hatches (of `part`
/// only, when given); `None` without geometry.
pub fn layer_bbox(layer: &Layer, part: Option<i64>) -> Option<[f64; 4]> {
    let mut bb = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    let keep = |p: i64| part.is_none_or(|want| want == p);
    let mut grow = |x: f64, y: f64| {
        if x.is_finite() && y.is_finite() {
            bb = [bb[0].min(x), bb[1].min(y), bb[2].max(x), bb[3].max(y)];
        }
    };
    for p in layer.polylines.iter().filter(|p| keep(p.part)) {
        for q in &p.points {
            grow(q[0], q[1]);
        }
    }
    for h in layer.hatches.iter().filter(|h| keep(h.part)) {
        for s in &h.segments {
            grow(s[0], s[1]);
            grow(s[2], s[3]);
        }
    }
    (bb[0] <= bb[2] && bb[1] <= bb[3]).then_some(bb)
}

/// Bounding box over all layers of a file (of `part` only, when given).
pub fn file_bbox(file: &VectorFile, part: Option<i64>) -> Option<[f64; 4]> {
    file.layers
        .iter()
        .filter_map(|l| layer_bbox(l, part))
        .reduce(|a, b| {
            [
                a[0].min(b[0]),
                a[1].min(b[1]),
                a[2].max(b[2]),
                a[3].max(b[3]),
            ]
        })
}

/// The CLI's default grid: around the part's (or all) geometry over the whole file, plus
/// [`DEFAULT_MARGIN_MM`], at [`DEFAULT_PIXEL_MM`], snapped to the plate lattice. Whole-file
/// rather than per-layer so that every layer of a part renders onto the same pixels.
pub fn default_grid(file: &VectorFile, part: Option<i64>) -> Result<Grid, RasterError> {
    let bb = file_bbox(file, part).ok_or(RasterError::NoGeometry { part })?;
    let grid = Grid::on_plate_lattice(bb, DEFAULT_MARGIN_MM, DEFAULT_PIXEL_MM);
    grid.validate()?;
    Ok(grid)
}

/// Renders layer `layer_index` (0-based position in the file) and writes a PNG:
/// mask and coverage 8-bit grey, rgb 8-bit colour, exemplar 16-bit grey scaled so that its
/// maximum is 65535 (window [`DEFAULT_STD_WINDOW`], seed [`DEFAULT_SEED`]). Other options are
/// [`RasterOptions::default`] with the given part filter.
pub fn render_to_png(
    file: &VectorFile,
    layer_index: usize,
    kind: RasterKind,
    grid: &Grid,
    part: Option<i64>,
    out: &Path,
) -> Result<(), RasterError> {
    let layer = file
        .layers
        .get(layer_index)
        .ok_or(RasterError::NoSuchLayer {
            index: layer_index,
            len: file.layers.len(),
        })?;
    let opts = RasterOptions {
        part,
        ..RasterOptions::default()
    };
    let written = match kind {
        RasterKind::Mask => mask(layer, grid, &opts)?.save_with_format(out, ImageFormat::Png),
        RasterKind::Coverage => {
            coverage(layer, grid, &opts)?.save_with_format(out, ImageFormat::Png)
        }
        RasterKind::Rgb => rgb(layer, grid, &opts)?.save_with_format(out, ImageFormat::Png),
        RasterKind::Exemplar => exemplar(layer, grid, &opts, DEFAULT_STD_WINDOW, DEFAULT_SEED)?
            .to_gray16_scaled()
            .save_with_format(out, ImageFormat::Png),
    };
    written.map_err(|source| RasterError::Write {
        path: out.to_path_buf(),
        source,
    })
}
