//! What the IC-LM consumes: the exemplars rendered from the vectors and the frames' luma,
//! std-filtered with windows matching the exemplar's footprint, and the checks that a frame can
//! be registered at all.

use std::path::Path;

use image::DynamicImage;
use rayon::prelude::*;

use super::{exemplar, filter, F32Image, Frame, RegistrationError};
use crate::geometry::{Grid, Homography};
use crate::rectify::luma;
use crate::vectors::Layer;

/// The exemplar of `layer` on `grid` with a `window`-pixel std window, rendered on a grid
/// `supersampling` times finer (window scaled and made odd) and box-averaged back, so edges
/// along the grid axes land to 1/(2·supersampling) pixel; and the window's extent, mm.
pub fn render_exemplar(
    layer: &Layer,
    grid: &Grid,
    window: usize,
    supersampling: usize,
    seed: u64,
) -> Result<(F32Image, f64), RegistrationError> {
    let ss = supersampling.clamp(1, 8);
    let fine_window = if (ss * window) % 2 == 1 {
        ss * window
    } else {
        ss * window + 1
    };
    let fine_grid = Grid {
        pixel_mm: grid.pixel_mm / ss as f64,
        ..*grid
    };
    let fine = exemplar::exemplar(layer, &fine_grid, fine_window, seed)?;
    Ok((
        box_downsample(&fine, ss),
        fine_window as f64 * fine_grid.pixel_mm,
    ))
}

/// I_B: the frame's luma std-filtered where the exemplar `grid` lies under `build_from_image`,
/// plus a margin (0 elsewhere). With `match_footprint` each pixel's window spans `extent_mm` on
/// the plate along u and v ([`filter`]); without, a square of `extent_mm / pixel_mm` pixels.
/// Also returns the window used at the grid's center, pixels.
pub fn filter_frame(
    lum: &F32Image,
    build_from_image: &Homography,
    grid: &Grid,
    extent_mm: f64,
    match_footprint: bool,
) -> Result<(F32Image, (f64, f64)), RegistrationError> {
    let beyond = || {
        RegistrationError::Invalid(
            "the start points put the parts beyond the image's horizon".into(),
        )
    };
    let image_from_build = build_from_image.inverse().ok_or_else(beyond)?;
    let image_from_exemplar = image_from_build.compose(&Homography::build_from_grid(grid));
    let square_w = extent_mm / grid.pixel_mm;
    let windows = |u: f64, v: f64| {
        if match_footprint {
            footprint_px(build_from_image, u, v, extent_mm).unwrap_or((1.0, 1.0))
        } else {
            (square_w, square_w)
        }
    };
    let center = (
        0.5 * (grid.x_min + grid.x_max),
        0.5 * (grid.y_min + grid.y_max),
    );
    let (cu, cv) = image_from_build
        .apply(center.0, center.1)
        .ok_or_else(beyond)?;
    let (gw, gh) = (grid.columns(), grid.rows());
    let (roi, max_window) =
        filter_roi(&image_from_exemplar, gw, gh, lum.width, lum.height, windows);
    let data =
        filter::std_filter_footprint(&lum.data, lum.width, lum.height, roi, max_window, windows);
    Ok((
        F32Image {
            width: lum.width,
            height: lum.height,
            data,
        },
        windows(cu, cv),
    ))
}

/// Refuses a frame whose layer has no fused area, whose parts do not map into it under the
/// start warp, or which shows no contrast where the parts map.
pub(super) fn check_frame(
    f: &Frame,
    ib: &F32Image,
    ie: &F32Image,
    image_from_exemplar: &Homography,
    min_contrast: f64,
) -> Result<(), RegistrationError> {
    let max = ie.data.par_iter().copied().reduce(|| 0.0f32, f32::max);
    if !(max > 0.0) {
        return Err(RegistrationError::NoFusedArea {
            layer: f.layer_number,
        });
    }
    // Support: near a part (the std window reaches it). Part: well inside (the exemplar's
    // noise level). Powder: out of the window's reach.
    let (support_thr, part_thr) = (0.01 * max, 0.5 * max);
    struct Acc {
        support: usize,
        outside: usize,
        part: (f64, usize),
        powder: (f64, usize),
    }
    let zero = || Acc {
        support: 0,
        outside: 0,
        part: (0.0, 0),
        powder: (0.0, 0),
    };
    let acc = (0..ie.height)
        .into_par_iter()
        .fold(zero, |mut acc, r| {
            for c in 0..ie.width {
                let e = ie.data[r * ie.width + c];
                let (u, v) = image_from_exemplar
                    .apply(c as f64, r as f64)
                    .unwrap_or((f64::NAN, f64::NAN));
                let (ui, vi) = (u.round(), v.round());
                let inside =
                    ui >= 0.0 && vi >= 0.0 && ui < ib.width as f64 && vi < ib.height as f64;
                if e > support_thr {
                    acc.support += 1;
                    if !inside {
                        acc.outside += 1;
                    }
                }
                if !inside {
                    continue;
                }
                let b = f64::from(ib.data[vi as usize * ib.width + ui as usize]);
                if e > part_thr {
                    acc.part.0 += b;
                    acc.part.1 += 1;
                } else if e == 0.0 {
                    acc.powder.0 += b;
                    acc.powder.1 += 1;
                }
            }
            acc
        })
        .reduce(zero, |a, b| Acc {
            support: a.support + b.support,
            outside: a.outside + b.outside,
            part: (a.part.0 + b.part.0, a.part.1 + b.part.1),
            powder: (a.powder.0 + b.powder.0, a.powder.1 + b.powder.1),
        });
    let out_frac = acc.outside as f64 / acc.support.max(1) as f64;
    if out_frac > 0.01 {
        return Err(RegistrationError::NotInView {
            image: f.name.to_string(),
            layer: f.layer_number,
            detail: format!(
                "{:.1}% of the area near its contours maps outside the {}x{} frame under the \
                 start points",
                100.0 * out_frac,
                ib.width,
                ib.height
            ),
        });
    }
    let part = acc.part.0 / acc.part.1.max(1) as f64;
    let powder = acc.powder.0 / acc.powder.1.max(1) as f64;
    if acc.part.1 == 0 || acc.powder.1 == 0 || !(part >= min_contrast * powder && part > 0.0) {
        return Err(RegistrationError::NoContrast {
            image: f.name.to_string(),
            layer: f.layer_number,
            part,
            powder,
            min_ratio: min_contrast,
        });
    }
    Ok(())
}

/// Decodes a frame as the daemon does: JPEG through zune-jpeg, camera raw (NEF) through rawler,
/// anything else through `image`.
pub fn load_image(path: &Path) -> Result<DynamicImage, RegistrationError> {
    let bytes = crate::fsutil::read_regular(path).map_err(|source| RegistrationError::Read {
        file: path.to_path_buf(),
        source,
    })?;
    crate::rectify::decode_frame(&bytes).map_err(|source| RegistrationError::Image {
        image: path.display().to_string(),
        source,
    })
}

/// BT.601 luma as f32 0..255 (the rectifier's luma for RGB frames).
pub fn luma_f32(img: &DynamicImage) -> F32Image {
    match img {
        DynamicImage::ImageLuma8(g) => F32Image::from_gray(g),
        DynamicImage::ImageRgb8(rgb) => F32Image::from_gray(&luma(rgb)),
        other => F32Image::from_gray(&luma(&other.to_rgb8())),
    }
}

/// Mean of each s x s block (s divides both sides).
fn box_downsample(img: &F32Image, s: usize) -> F32Image {
    if s <= 1 {
        return img.clone();
    }
    let (w, h) = (img.width / s, img.height / s);
    let mut data = vec![0.0f32; w * h];
    let norm = 1.0 / (s * s) as f32;
    if w > 0 {
        data.par_chunks_mut(w).enumerate().for_each(|(r, dst)| {
            for i in 0..s {
                let src = &img.data[(s * r + i) * img.width..];
                for (c, d) in dst.iter_mut().enumerate() {
                    *d += src[s * c..s * c + s].iter().sum::<f32>();
                }
            }
            for d in dst.iter_mut() {
                *d *= norm;
            }
        });
    }
    F32Image {
        width: w,
        height: h,
        data,
    }
}

/// Image pixels spanned along u and along v by `extent_mm` on the plate at image pixel (u, v):
/// `extent_mm` over the lengths of ∂(x, y)/∂u and ∂(x, y)/∂v of H there.
fn footprint_px(
    build_from_image: &Homography,
    u: f64,
    v: f64,
    extent_mm: f64,
) -> Option<(f64, f64)> {
    let h = build_from_image.matrix();
    let w = h[2][0] * u + h[2][1] * v + h[2][2];
    if !(w > 0.0) {
        return None;
    }
    let x = (h[0][0] * u + h[0][1] * v + h[0][2]) / w;
    let y = (h[1][0] * u + h[1][1] * v + h[1][2]) / w;
    let mm_u = (h[0][0] - x * h[2][0]).hypot(h[1][0] - y * h[2][0]) / w;
    let mm_v = (h[0][1] - x * h[2][1]).hypot(h[1][1] - y * h[2][1]) / w;
    let (wx, wy) = (extent_mm / mm_u, extent_mm / mm_v);
    let ok = |w: f64| w.is_finite() && w > 0.0;
    (ok(wx) && ok(wy)).then_some((wx, wy))
}

/// The image region the exemplar covers under `image_from_exemplar`, plus a margin for
/// the refinement to move in, and the largest window there.
fn filter_roi(
    image_from_exemplar: &Homography,
    gw: usize,
    gh: usize,
    width: usize,
    height: usize,
    windows: impl Fn(f64, f64) -> (f64, f64),
) -> (filter::Roi, f64) {
    let (a, b) = (gw as f64 - 1.0, gh as f64 - 1.0);
    let pts: Vec<(f64, f64)> = [(0.0, 0.0), (a, 0.0), (a, b), (0.0, b)]
        .iter()
        .filter_map(|&(u, v)| image_from_exemplar.apply(u, v))
        .collect();
    let full = ([0, height, 0, width], 64.0);
    if pts.len() < 4 {
        return full;
    }
    let (u0, u1, v0, v1) = pts.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(u, v)| (a.min(u), b.max(u), c.min(v), d.max(v)),
    );
    let margin = (0.1 * (u1 - u0).max(v1 - v0)).max(64.0);
    let clamp = |x: f64, hi: usize| x.clamp(0.0, hi as f64) as usize;
    let roi = [
        clamp((v0 - margin).floor(), height),
        clamp((v1 + margin).ceil() + 1.0, height),
        clamp((u0 - margin).floor(), width),
        clamp((u1 + margin).ceil() + 1.0, width),
    ];
    let max_window = [
        (roi[2], roi[0]),
        (roi[3], roi[0]),
        (roi[2], roi[1]),
        (roi[3], roi[1]),
    ]
    .iter()
    .map(|&(u, v)| {
        let (wx, wy) = windows(u as f64, v as f64);
        wx.max(wy)
    })
    .fold(1.0, f64::max);
    // Windows vary monotonically under a homography, so the corners bound them; 255 px is far
    // beyond any useful window.
    (roi, (max_window * 1.05 + 1.0).min(255.0))
}
