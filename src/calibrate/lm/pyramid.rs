//! The pyramid levels of an alignment: downsampling, the warp between levels, and per level the
//! exemplar's constant IC Jacobian, its Gauss-Newton Hessian and the pixels in the cost.

use rayon::prelude::*;

use super::F32Image;
use crate::geometry::mat3::{self, Mat3};
use crate::geometry::RadialDistortion;

/// Default pyramid depth for an exemplar of `width` x `height`: the coarsest level keeps at
/// least 64 pixels on its short side; at most 4 levels.
pub fn default_levels(width: usize, height: usize) -> usize {
    let short = width.min(height) as f64;
    if short < 128.0 {
        return 1;
    }
    ((short / 64.0).log2().floor() as usize + 1).clamp(1, 4)
}

/// 2x2 box average (odd last row/column dropped); pixel centers map as x_fine = 2·x_coarse + ½.
pub fn downsample(img: &F32Image) -> F32Image {
    let (w, h) = (img.width / 2, img.height / 2);
    let mut data = vec![0.0f32; w * h];
    if w > 0 {
        data.par_chunks_mut(w).enumerate().for_each(|(r, dst)| {
            let a = &img.data[2 * r * img.width..];
            let b = &img.data[(2 * r + 1) * img.width..];
            for (c, d) in dst.iter_mut().enumerate() {
                *d = 0.25 * (a[2 * c] + a[2 * c + 1] + b[2 * c] + b[2 * c + 1]);
            }
        });
    }
    F32Image {
        width: w,
        height: h,
        data,
    }
}

/// Level-l pixel → level-0 pixel: x0 = s·x + (s − 1)/2, s = 2^l.
pub(super) fn level_scale(level: usize) -> Mat3 {
    let s = (1usize << level) as f64;
    let t = 0.5 * (s - 1.0);
    [[s, 0.0, t], [0.0, s, t], [0.0, 0.0, 1.0]]
}

/// The warp at `level` from the full-resolution one (both sides are downsampled alike).
pub(super) fn warp_to_level(m0: &Mat3, level: usize) -> Mat3 {
    let s = level_scale(level);
    let s_inv = mat3::mat_inv(&s).unwrap_or(s);
    mat3::mul(&s_inv, &mat3::mul(m0, &s))
}

pub(super) fn warp_from_level(ml: &Mat3, level: usize) -> Mat3 {
    let s = level_scale(level);
    let s_inv = mat3::mat_inv(&s).unwrap_or(s);
    mat3::mul(&s, &mat3::mul(ml, &s_inv))
}

/// Radial distortion in one level's pixel units.
#[derive(Clone, Copy, Debug)]
pub(super) struct Dist {
    pub(super) cx: f64,
    pub(super) cy: f64,
    pub(super) f: f64,
    pub(super) k1: f64,
    pub(super) k2: f64,
}

impl Dist {
    pub(super) fn at_level(d: &RadialDistortion, level: usize) -> Dist {
        let s = (1usize << level) as f64;
        let t = 0.5 * (s - 1.0);
        Dist {
            cx: (d.center[0] - t) / s,
            cy: (d.center[1] - t) / s,
            f: d.focal_px / s,
            k1: d.k1,
            k2: d.k2,
        }
    }
}

/// Per-pair constants of one level.
pub(super) struct Pre {
    /// Σ J_i e_i, Σ J_i.
    pub(super) jte: [f64; 8],
    pub(super) jsum: [f64; 8],
    pub(super) n: f64,
    pub(super) se: f64,
    pub(super) see: f64,
    /// Exemplar values above this are "support" (near a part).
    pub(super) support_thr: f32,
    pub(super) support: usize,
    /// RMS of the image: I_B is fitted as t = I_B / scale so the powers of t stay near 1.
    pub(super) scale: f64,
}

pub(super) struct Level {
    pub(super) level: usize,
    pub(super) exemplars: Vec<F32Image>,
    pub(super) images: Vec<F32Image>,
    pub(super) pre: Vec<Pre>,
    /// Per pair, the exemplar pixels that enter the cost.
    pub(super) spans: Vec<Spans>,
    /// Σ over pairs of JᵀJ (symmetric, full).
    pub(super) jtj: [[f64; 8]; 8],
}

/// Central differences inside, one-sided at the borders.
#[inline]
pub(super) fn exemplar_gradient(ex: &F32Image, row: usize, c: usize) -> (f32, f32) {
    let w = ex.width;
    let h = ex.height;
    let (l, r) = (c.saturating_sub(1), (c + 1).min(w - 1));
    let (u, d) = (row.saturating_sub(1), (row + 1).min(h - 1));
    let gx = if r > l {
        (ex.data[row * w + r] - ex.data[row * w + l]) / (r - l) as f32
    } else {
        0.0
    };
    let gy = if d > u {
        (ex.data[d * w + c] - ex.data[u * w + c]) / (d - u) as f32
    } else {
        0.0
    };
    (gx, gy)
}

/// J_i of eq. 9-10 at exemplar pixel (u, v) with exemplar gradient (gx, gy).
#[inline]
pub(super) fn jacobian(gx: f64, gy: f64, u: f64, v: f64) -> [f64; 8] {
    let s = gx * u + gy * v;
    [gx * u, gx * v, gx, gy * u, gy * v, gy, -u * s, -v * s]
}

/// Per row, the half-open column ranges of the pixels that enter the cost.
pub(super) type Spans = Vec<Vec<(usize, usize)>>;

/// The pixels within `radius` (square neighbourhood) of a value above `thr`; every pixel when
/// `radius` is `None`.
pub(super) fn active_spans(ex: &F32Image, thr: f32, radius: Option<usize>) -> Spans {
    let (w, h) = (ex.width, ex.height);
    let Some(rad) = radius else {
        return vec![vec![(0, w)]; h];
    };
    // Horizontal dilation per row, then a running count down each column.
    let horiz: Vec<Vec<bool>> = (0..h)
        .into_par_iter()
        .map(|r| {
            let row = &ex.data[r * w..(r + 1) * w];
            let mut pre = vec![0u32; w + 1];
            for (c, &e) in row.iter().enumerate() {
                pre[c + 1] = pre[c] + u32::from(e > thr);
            }
            (0..w)
                .map(|c| pre[(c + rad + 1).min(w)] > pre[c.saturating_sub(rad)])
                .collect()
        })
        .collect();
    let mut count = vec![0u32; w];
    let mut spans = Vec::with_capacity(h);
    let add = |count: &mut [u32], r: usize, d: i32| {
        for (n, &on) in count.iter_mut().zip(&horiz[r]) {
            if on {
                *n = n.wrapping_add_signed(d);
            }
        }
    };
    for r in 0..rad.min(h) {
        add(&mut count, r, 1);
    }
    for r in 0..h {
        if r + rad < h {
            add(&mut count, r + rad, 1);
        }
        if r > rad {
            add(&mut count, r - rad - 1, -1);
        }
        let mut row = Vec::new();
        let mut c = 0;
        while c < w {
            if count[c] > 0 {
                let start = c;
                while c < w && count[c] > 0 {
                    c += 1;
                }
                row.push((start, c));
            } else {
                c += 1;
            }
        }
        spans.push(row);
    }
    spans
}

pub(super) fn precompute(ex: &F32Image, spans: &Spans) -> (Pre, [[f64; 8]; 8]) {
    struct Row {
        jtj: [[f64; 8]; 8],
        jte: [f64; 8],
        jsum: [f64; 8],
        se: f64,
        see: f64,
        max: f32,
    }
    let rows: Vec<Row> = (0..ex.height)
        .into_par_iter()
        .map(|r| {
            let mut acc = Row {
                jtj: [[0.0; 8]; 8],
                jte: [0.0; 8],
                jsum: [0.0; 8],
                se: 0.0,
                see: 0.0,
                max: 0.0,
            };
            let v = r as f64;
            for c in spans[r].iter().flat_map(|&(a, b)| a..b) {
                let e = ex.data[r * ex.width + c];
                acc.max = acc.max.max(e);
                let e = f64::from(e);
                acc.se += e;
                acc.see += e * e;
                let (gx, gy) = exemplar_gradient(ex, r, c);
                if gx == 0.0 && gy == 0.0 {
                    continue;
                }
                let j = jacobian(f64::from(gx), f64::from(gy), c as f64, v);
                for a in 0..8 {
                    acc.jte[a] += j[a] * e;
                    acc.jsum[a] += j[a];
                    for b in a..8 {
                        acc.jtj[a][b] += j[a] * j[b];
                    }
                }
            }
            acc
        })
        .collect();
    let mut jtj = [[0.0; 8]; 8];
    let mut pre = Pre {
        jte: [0.0; 8],
        jsum: [0.0; 8],
        n: spans.iter().flatten().map(|(a, b)| b - a).sum::<usize>() as f64,
        se: 0.0,
        see: 0.0,
        support_thr: 0.0,
        support: 0,
        scale: 1.0,
    };
    let mut max = 0.0f32;
    for row in &rows {
        for a in 0..8 {
            pre.jte[a] += row.jte[a];
            pre.jsum[a] += row.jsum[a];
            for b in a..8 {
                jtj[a][b] += row.jtj[a][b];
            }
        }
        pre.se += row.se;
        pre.see += row.see;
        max = max.max(row.max);
    }
    for a in 0..8 {
        for b in 0..a {
            jtj[a][b] = jtj[b][a];
        }
    }
    pre.support_thr = 0.01 * max;
    pre.support = ex.data.par_iter().filter(|&&e| e > pre.support_thr).count();
    (pre, jtj)
}
