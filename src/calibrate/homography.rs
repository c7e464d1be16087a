//! Inverse-compositional Levenberg-Marquardt (IC-LM) alignment of std-filtered build images to
//! exemplars (paper §3.1, eq. 7-10; Baker & Matthews 2004).
//!
//! The warp maps exemplar pixel coordinates x = (u_e, v_e) to (undistorted) image pixel
//! coordinates: W(x; M) = proj(M x̄), with M the 3x3 exemplar → image matrix. Each iteration
//! solves for an update ΔH = I + [[p1, p2, p3], [p4, p5, p6], [p7, p8, 0]] acting on the
//! exemplar's coordinates and composes its inverse: M ← M · ΔH⁻¹ (eq. 8). The Jacobian of one
//! pixel, J_i = ∇I_E(x_i)ᵀ · ∂proj(ΔH x̄_i)/∂p at ΔH = I (eq. 9-10), does not depend on M, so J
//! and the Gauss-Newton Hessian JᵀJ are computed once per pyramid level; an iteration is one
//! pass over the exemplar that samples I_B at W(x_i; M) and accumulates the gradient.
//!
//! Two additions to eq. 7, both documented where they act:
//! - **Photometric match.** The exemplar (uniform 0..255 noise against 0) and the frame (metal
//!   speckle against powder speckle) give std images of different levels *and shapes*: across
//!   an edge the exemplar overshoots (the noise's mean differs from the zeros'), the frame rises
//!   from the powder's floor. Plain SSD then pulls every edge inward (a brighter template gains
//!   by shrinking onto the part): measured 0.9 px mean on the mock camera; an affine gain and
//!   offset leaves 0.4 px. So each image's samples are mapped by a polynomial φ of degree ≤ 3
//!   fitted in closed form on every pass (variable projection): the cost is
//!   ½ Σ (I_E(x_i) − φ(I_B(W(x_i))))², minimised over φ. Only Σ J_i t_i^k (k ≤ 3) are needed
//!   per pass besides the sums of powers of t = I_B / scale.
//! - **Radial distortion** (optional): W(x) = D_k(proj(M x̄)) with D the Brown k1/k2 model of
//!   [`RadialDistortion`]. The homography part stays inverse-compositional with the constant
//!   Jacobian above; k1 and k2 are updated forward-additively (k ← k + Δk), their Jacobian
//!   recomputed on every pass as G_i = ∇I_E(x_i)ᵀ A_i⁻¹ ∂D/∂k: the image-side motion of a
//!   change of k pulled back to the exemplar through the warp's 2x2 Jacobian A_i, i.e. the same
//!   template-side linearisation as the IC rows (with the frame's own gradient instead, the
//!   blocks of the normal matrix disagree in scale and LM crawls). The 10x10 normal matrix is
//!   [[JᵀJ, −JᵀG], [−GᵀJ, GᵀG]]; only the 8x8 block is precomputed.
//!
//! The sum runs over the exemplar pixels within `support_margin_px` of the parts' std support
//! (default 24 px; `None`: every pixel, eq. 7 as written), fixed per level: what the vectors do
//! not model (the plate's edge, other parts) stays out of the fit, and far fewer pixels are
//! visited. Pixels that map outside the image sample 0 (zero padding), so the cost is always a
//! sum over the same exemplar pixels; exemplar "support" pixels (near the parts) leaving the image are
//! counted and reported as divergence.
//!
//! Several (image, exemplar) pairs share one warp: their costs, gradients and Hessians add.
//! All exemplars of a call share one grid (the same pixel coordinates), so one ΔH serves all.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::exemplar::F32Image;
use super::{mat_inv, mat_mul, singularity, Mat3, RegistrationError};
use crate::rectify::RadialDistortion;

/// One image to align and the exemplar it should match. All exemplars of one [`align`] call have
/// the same size (they are rendered on one grid).
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// I_B: the std-filtered build image.
    pub image: &'a F32Image,
    /// I_E: the exemplar.
    pub exemplar: &'a F32Image,
}

/// Optimiser settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LmOptions {
    /// Pyramid levels (1 = full resolution only); `None` picks [`default_levels`].
    pub levels: Option<usize>,
    /// LM iterations per level at most.
    pub max_iterations: usize,
    /// Stop when a step moves no exemplar corner by more than this, in pixels of the level.
    pub step_tol_px: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub cost_tol: f64,
    /// Initial LM damping λ (H_lm = JᵀJ + λ diag(JᵀJ)).
    pub lambda0: f64,
    /// Refuse a result whose correlation between I_E and the matched I_B is below this.
    pub min_correlation: f64,
    /// Divergence: more than this fraction of an exemplar's support (pixels near parts) newly
    /// mapping outside its image.
    pub max_outside: f64,
    /// Degree of the polynomial φ matching I_B to I_E (1 = gain and offset; at most 3).
    pub photometric_degree: usize,
    /// The cost sums over the exemplar pixels within this many (full-resolution) pixels of the
    /// parts' std support only; `None`: over every exemplar pixel (eq. 7 as written). What the
    /// vectors do not model (the plate's edge, a recoater streak, a part of another file) then
    /// stays out of the photometric fit: a plate-wide exemplar that reached the plate's edge
    /// was 1.2 px off instead of 0.16 px.
    pub support_margin_px: Option<f64>,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            levels: None,
            max_iterations: 60,
            step_tol_px: 1e-4,
            cost_tol: 1e-10,
            lambda0: 1e-3,
            min_correlation: 0.5,
            max_outside: 0.01,
            photometric_degree: 3,
            support_margin_px: Some(24.0),
        }
    }
}

/// Why the iterations of a level stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The proposed step moved the exemplar by less than `step_tol_px`.
    SmallStep,
    /// An accepted step lowered the cost by less than `cost_tol`.
    CostStalled,
    /// No damping found a lower cost (λ ran to its cap): a minimum within precision.
    NoDecrease,
    /// `max_iterations` reached.
    MaxIterations,
}

impl Termination {
    pub fn name(self) -> &'static str {
        match self {
            Termination::SmallStep => "small step",
            Termination::CostStalled => "cost stalled",
            Termination::NoDecrease => "no decrease",
            Termination::MaxIterations => "max iterations",
        }
    }
}

/// What happened on one pyramid level (level 0 = full resolution).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelReport {
    pub level: usize,
    /// Downsampling factor 2^level.
    pub scale: usize,
    /// Exemplar size at this level.
    pub width: usize,
    pub height: usize,
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Size of the last proposed step, exemplar pixels of this level.
    pub last_step_px: f64,
    pub termination: Termination,
    /// Lowest correlation of the pairs at the end of the level.
    pub correlation: f64,
}

/// The photometric match and quality of one pair at full resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct PairFit {
    /// φ: `I_E ≈ Σ_k photometric[k]·I_B^k`.
    pub photometric: Vec<f64>,
    /// Correlation R of I_E with φ(I_B(W)) at the starting warp and at the result.
    pub initial_correlation: f64,
    pub correlation: f64,
    /// √(2·cost / pixels): RMS of the matched residual, in exemplar units.
    pub rms: f64,
    pub pixels: usize,
}

/// The result of [`align`].
#[derive(Clone, Debug, PartialEq)]
pub struct Alignment {
    /// Exemplar pixel → undistorted image pixel.
    pub warp: Mat3,
    /// The refined distortion, when one was given.
    pub distortion: Option<RadialDistortion>,
    /// Coarsest level first.
    pub levels: Vec<LevelReport>,
    pub pairs: Vec<PairFit>,
}

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
fn level_scale(level: usize) -> Mat3 {
    let s = (1usize << level) as f64;
    let t = 0.5 * (s - 1.0);
    [[s, 0.0, t], [0.0, s, t], [0.0, 0.0, 1.0]]
}

/// The warp at `level` from the full-resolution one (both sides are downsampled alike).
fn warp_to_level(m0: &Mat3, level: usize) -> Mat3 {
    let s = level_scale(level);
    let s_inv = mat_inv(&s).unwrap_or(s);
    mat_mul(&s_inv, &mat_mul(m0, &s))
}

fn warp_from_level(ml: &Mat3, level: usize) -> Mat3 {
    let s = level_scale(level);
    let s_inv = mat_inv(&s).unwrap_or(s);
    mat_mul(&s, &mat_mul(ml, &s_inv))
}

/// Radial distortion in one level's pixel units.
#[derive(Clone, Copy, Debug)]
struct Dist {
    cx: f64,
    cy: f64,
    f: f64,
    k1: f64,
    k2: f64,
}

impl Dist {
    fn at_level(d: &RadialDistortion, level: usize) -> Dist {
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
struct Pre {
    /// Σ J_i e_i, Σ J_i.
    jte: [f64; 8],
    jsum: [f64; 8],
    n: f64,
    se: f64,
    see: f64,
    /// Exemplar values above this are "support" (near a part).
    support_thr: f32,
    support: usize,
    /// RMS of the image: I_B is fitted as t = I_B / scale so the powers of t stay near 1.
    scale: f64,
}

struct Level {
    level: usize,
    exemplars: Vec<F32Image>,
    images: Vec<F32Image>,
    pre: Vec<Pre>,
    /// Per pair, the exemplar pixels that enter the cost.
    spans: Vec<Spans>,
    /// Σ over pairs of JᵀJ (symmetric, full).
    jtj: [[f64; 8]; 8],
}

/// Central differences inside, one-sided at the borders.
#[inline]
fn exemplar_gradient(ex: &F32Image, row: usize, c: usize) -> (f32, f32) {
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
fn jacobian(gx: f64, gy: f64, u: f64, v: f64) -> [f64; 8] {
    let s = gx * u + gy * v;
    [gx * u, gx * v, gx, gy * u, gy * v, gy, -u * s, -v * s]
}

/// Per row, the half-open column ranges of the pixels that enter the cost.
type Spans = Vec<Vec<(usize, usize)>>;

/// The pixels within `radius` (square neighbourhood) of a value above `thr`; every pixel when
/// `radius` is `None`.
fn active_spans(ex: &F32Image, thr: f32, radius: Option<usize>) -> Spans {
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

fn precompute(ex: &F32Image, spans: &Spans) -> (Pre, [[f64; 8]; 8]) {
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

/// Highest supported degree of the photometric polynomial.
pub const MAX_DEGREE: usize = 3;

/// Sums of one pass over one pair. t = I_B(W(x_i)) / scale (0 outside the image).
#[derive(Clone, Default)]
struct Sums {
    /// Σ t^k, k = 1..=2·MAX_DEGREE (index k).
    st: [f64; 2 * MAX_DEGREE + 1],
    /// Σ e t^k, k = 1..=MAX_DEGREE.
    set: [f64; MAX_DEGREE + 1],
    /// Σ J t^k, k = 1..=MAX_DEGREE.
    jt: [[f64; 8]; MAX_DEGREE + 1],
    outside: usize,
    // Distortion rows, with G_i = ∇I_E(x_i)ᵀ A⁻¹ ∂D/∂k (2 values per pixel).
    sg_t: [[f64; 2]; MAX_DEGREE + 1],
    sg_e: [f64; 2],
    sgg: [[f64; 2]; 2],
    sgj: [[f64; 8]; 2],
}

impl Sums {
    fn add(&mut self, o: &Sums) {
        let add = |a: &mut [f64], b: &[f64]| a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        add(&mut self.st, &o.st);
        add(&mut self.set, &o.set);
        for k in 0..=MAX_DEGREE {
            add(&mut self.jt[k], &o.jt[k]);
            add(&mut self.sg_t[k], &o.sg_t[k]);
        }
        self.outside += o.outside;
        add(&mut self.sg_e, &o.sg_e);
        for i in 0..2 {
            add(&mut self.sgg[i], &o.sgg[i]);
            add(&mut self.sgj[i], &o.sgj[i]);
        }
    }
}

/// What one pass needs besides the images.
#[derive(Clone, Copy)]
struct PassSetup<'a> {
    m: &'a Mat3,
    dist: Option<&'a Dist>,
    /// Support threshold of the exemplar.
    thr: f32,
    /// 1 / scale of the image values.
    inv_scale: f64,
    degree: usize,
}

/// One pass over a pair: samples I_B at W(x_i) for every exemplar pixel.
fn pass(ex: &F32Image, img: &F32Image, spans: &Spans, ps: PassSetup) -> Sums {
    let m = ps.m;
    let (iw, ih) = (img.width, img.height);
    let (max_x, max_y) = (iw as f64 - 1.0, ih as f64 - 1.0);
    let deg = ps.degree;
    let rows: Vec<Sums> = (0..ex.height)
        .into_par_iter()
        .map(|r| {
            let mut s = Sums::default();
            let v = r as f64;
            // Row-constant parts of M x̄.
            let (bx, by, bz) = (
                m[0][1] * v + m[0][2],
                m[1][1] * v + m[1][2],
                m[2][1] * v + m[2][2],
            );
            let erow = &ex.data[r * ex.width..(r + 1) * ex.width];
            for c in spans[r].iter().flat_map(|&(a, b)| a..b) {
                let e = erow[c];
                let u = c as f64;
                let z = m[2][0] * u + bz;
                let inv = 1.0 / z;
                let mut px = (m[0][0] * u + bx) * inv;
                let mut py = (m[1][0] * u + by) * inv;
                let (gx, gy) = exemplar_gradient(ex, r, c);
                let j =
                    (gx != 0.0 || gy != 0.0).then(|| jacobian(f64::from(gx), f64::from(gy), u, v));
                // Distortion rows: G_i = ∇I_E(x_i)ᵀ A⁻¹ ∂D/∂k, the image-side motion ∂D/∂k
                // pulled back to the exemplar through the warp's Jacobian A — the same
                // template-side linearisation as the IC rows, so the blocks of KᵀK agree.
                let mut g = None;
                if let Some(d) = ps.dist {
                    let (dx, dy) = (px - d.cx, py - d.cy);
                    let f2 = d.f * d.f;
                    let r2 = (dx * dx + dy * dy) / f2;
                    let sc = 1.0 + r2 * (d.k1 + r2 * d.k2);
                    if let Some(j) = &j {
                        // A = ∂D/∂p · ∂proj(M x̄)/∂x.
                        let pj = [
                            [
                                (m[0][0] - px * m[2][0]) * inv,
                                (m[0][1] - px * m[2][1]) * inv,
                            ],
                            [
                                (m[1][0] - py * m[2][0]) * inv,
                                (m[1][1] - py * m[2][1]) * inv,
                            ],
                        ];
                        let ds = 2.0 * (d.k1 + 2.0 * d.k2 * r2) / f2;
                        let dp = [
                            [sc + ds * dx * dx, ds * dx * dy],
                            [ds * dy * dx, sc + ds * dy * dy],
                        ];
                        let a = [
                            [
                                dp[0][0] * pj[0][0] + dp[0][1] * pj[1][0],
                                dp[0][0] * pj[0][1] + dp[0][1] * pj[1][1],
                            ],
                            [
                                dp[1][0] * pj[0][0] + dp[1][1] * pj[1][0],
                                dp[1][0] * pj[0][1] + dp[1][1] * pj[1][1],
                            ],
                        ];
                        let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
                        // ∇eᵀ A⁻¹ (a row vector).
                        let (ga, gb) = (f64::from(gx), f64::from(gy));
                        let w0 = (ga * a[1][1] - gb * a[1][0]) / det;
                        let w1 = (-ga * a[0][1] + gb * a[0][0]) / det;
                        // ∂D/∂k1 = (p − c)·r², ∂D/∂k2 = (p − c)·r⁴.
                        let gk = [(w0 * dx + w1 * dy) * r2, (w0 * dx + w1 * dy) * r2 * r2];
                        if gk.iter().all(|v| v.is_finite()) {
                            g = Some((gk, *j));
                        }
                    }
                    px = d.cx + dx * sc;
                    py = d.cy + dy * sc;
                }
                let e = f64::from(e);
                let inside = z > 0.0 && px >= 0.0 && py >= 0.0 && px <= max_x && py <= max_y;
                // Powers t^0..t^(2·deg); outside the image t = 0 (zero padding).
                let mut pw = [0.0f64; 2 * MAX_DEGREE + 1];
                pw[0] = 1.0;
                if inside {
                    let (x0, y0) = (px as usize, py as usize);
                    let (fx, fy) = ((px - x0 as f64) as f32, (py - y0 as f64) as f32);
                    let x1 = (x0 + 1).min(iw - 1);
                    let y1 = (y0 + 1).min(ih - 1);
                    let p00 = img.data[y0 * iw + x0];
                    let p01 = img.data[y0 * iw + x1];
                    let p10 = img.data[y1 * iw + x0];
                    let p11 = img.data[y1 * iw + x1];
                    let top = p00 + fx * (p01 - p00);
                    let bot = p10 + fx * (p11 - p10);
                    let t = f64::from(top + fy * (bot - top)) * ps.inv_scale;
                    for k in 1..=2 * deg {
                        pw[k] = pw[k - 1] * t;
                        s.st[k] += pw[k];
                    }
                    for k in 1..=deg {
                        s.set[k] += e * pw[k];
                    }
                    if let Some(j) = &j {
                        for k in 1..=deg {
                            for a in 0..8 {
                                s.jt[k][a] += j[a] * pw[k];
                            }
                        }
                    }
                } else if e > f64::from(ps.thr) {
                    s.outside += 1;
                }
                if let Some((gk, j)) = g {
                    for i in 0..2 {
                        for k in 0..=deg {
                            s.sg_t[k][i] += gk[i] * pw[k];
                        }
                        s.sg_e[i] += gk[i] * e;
                        for k in 0..2 {
                            s.sgg[i][k] += gk[i] * gk[k];
                        }
                        for a in 0..8 {
                            s.sgj[i][a] += gk[i] * j[a];
                        }
                    }
                }
            }
            s
        })
        .collect();
    // Summed in row order so results do not depend on thread scheduling.
    let mut total = Sums::default();
    for s in &rows {
        total.add(s);
    }
    total
}

/// The photometric fit of one pair at one warp.
#[derive(Clone, Debug, Default)]
struct Photometric {
    /// φ(t) = Σ c_k t^k, t = I_B / scale.
    coeffs: Vec<f64>,
    cost: f64,
    /// R: √(1 − 2·cost / Σ (e − ē)²), the correlation of I_E with φ(I_B).
    correlation: f64,
}

/// Least-squares φ of degree `deg` (lowered if the normal matrix is singular: a flat image).
fn fit_photometric(pre: &Pre, s: &Sums, deg: usize) -> Photometric {
    let var_e = (pre.see - pre.se * pre.se / pre.n).max(0.0);
    for d in (0..=deg).rev() {
        let n = d + 1;
        let a = DMatrix::from_fn(n, n, |i, j| if i + j == 0 { pre.n } else { s.st[i + j] });
        let rhs = DVector::from_fn(n, |i, _| if i == 0 { pre.se } else { s.set[i] });
        let Some(c) = solve_scaled(&a, &rhs) else {
            continue;
        };
        let explained: f64 = (0..n).map(|i| c[i] * rhs[i]).sum();
        let cost = 0.5 * (pre.see - explained).max(0.0);
        let r2 = if var_e > 0.0 {
            (1.0 - 2.0 * cost / var_e).max(0.0)
        } else {
            0.0
        };
        let mut coeffs = vec![0.0; deg + 1];
        coeffs[..n].copy_from_slice(c.as_slice());
        return Photometric {
            coeffs,
            cost,
            correlation: r2.sqrt(),
        };
    }
    Photometric {
        coeffs: vec![0.0; deg + 1],
        cost: 0.5 * var_e,
        correlation: 0.0,
    }
}

/// Solves a symmetric positive (semi)definite system with Jacobi scaling; `None` if singular.
fn solve_scaled(a: &DMatrix<f64>, b: &DVector<f64>) -> Option<DVector<f64>> {
    let n = b.len();
    let d: Vec<f64> = (0..n).map(|i| a[(i, i)].sqrt()).collect();
    if !d.iter().all(|v| v.is_finite() && *v > 0.0) {
        return None;
    }
    let scaled = DMatrix::from_fn(n, n, |i, j| a[(i, j)] / (d[i] * d[j]));
    let rhs = DVector::from_fn(n, |i, _| b[i] / d[i]);
    let ch = scaled.cholesky()?;
    // Reject near-singular systems: the scaled diagonal of the factor collapses.
    let l = ch.l();
    if !(0..n).all(|i| l[(i, i)] > 1e-7) {
        return None;
    }
    let y = ch.solve(&rhs);
    let x = DVector::from_fn(n, |i, _| y[i] / d[i]);
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// The state at one warp: cost, gradient Kᵀr and normal matrix KᵀK.
struct Eval {
    cost: f64,
    grad: Vec<f64>,
    hess: DMatrix<f64>,
    fits: Vec<Photometric>,
    /// Largest fraction of a pair's support outside its image.
    outside: f64,
}

/// Cost, gradient and normal matrix at warp `m` (and distortion `dist`).
fn evaluate(lv: &Level, m: &Mat3, dist: Option<&Dist>, degree: usize) -> Eval {
    let np = if dist.is_some() { 10 } else { 8 };
    let mut grad = vec![0.0; np];
    let mut hess = DMatrix::<f64>::zeros(np, np);
    for a in 0..8 {
        for b in 0..8 {
            hess[(a, b)] = lv.jtj[a][b];
        }
    }
    let mut cost = 0.0;
    let mut fits = Vec::with_capacity(lv.pre.len());
    let mut outside = 0.0f64;
    for (((ex, img), pre), spans) in lv
        .exemplars
        .iter()
        .zip(&lv.images)
        .zip(&lv.pre)
        .zip(&lv.spans)
    {
        let s = pass(
            ex,
            img,
            spans,
            PassSetup {
                m,
                dist,
                thr: pre.support_thr,
                inv_scale: 1.0 / pre.scale,
                degree,
            },
        );
        let fit = fit_photometric(pre, &s, degree);
        cost += fit.cost;
        if pre.support > 0 {
            outside = outside.max(s.outside as f64 / pre.support as f64);
        }
        // Jᵀr with r_i = e_i − Σ c_k t_i^k.
        let c = &fit.coeffs;
        for a in 0..8 {
            let model: f64 = (1..=degree).map(|k| c[k] * s.jt[k][a]).sum();
            grad[a] += pre.jte[a] - c[0] * pre.jsum[a] - model;
        }
        if dist.is_some() {
            // K = [J, −G]: the distortion rows of Kᵀr are −Σ G r.
            for i in 0..2 {
                let n_g: f64 = s.sg_t[0][i];
                let model: f64 =
                    c[0] * n_g + (1..=degree).map(|k| c[k] * s.sg_t[k][i]).sum::<f64>();
                grad[8 + i] += -(s.sg_e[i] - model);
                for k in 0..2 {
                    hess[(8 + i, 8 + k)] += s.sgg[i][k];
                }
                for a in 0..8 {
                    hess[(8 + i, a)] -= s.sgj[i][a];
                    hess[(a, 8 + i)] -= s.sgj[i][a];
                }
            }
        }
        fits.push(fit);
    }
    Eval {
        cost,
        grad,
        hess,
        fits,
        outside,
    }
}

/// Solves (H + λ diag H) δ = −g with Jacobi scaling (the eq. 10 parameters differ in scale by
/// the square of the image size, so the unscaled system is badly conditioned).
fn lm_step(hess: &DMatrix<f64>, grad: &[f64], lambda: f64) -> Option<Vec<f64>> {
    let n = grad.len();
    let diag_max = (0..n).map(|i| hess[(i, i)]).fold(0.0, f64::max);
    if !(diag_max > 0.0) {
        return None;
    }
    let d: Vec<f64> = (0..n)
        .map(|i| hess[(i, i)].max(1e-12 * diag_max).sqrt())
        .collect();
    let a = DMatrix::from_fn(n, n, |i, j| {
        let v = hess[(i, j)] / (d[i] * d[j]);
        if i == j {
            v * (1.0 + lambda)
        } else {
            v
        }
    });
    let b = DVector::from_fn(n, |i, _| -grad[i] / d[i]);
    let y = match a.clone().cholesky() {
        Some(ch) => ch.solve(&b),
        None => a.lu().solve(&b)?,
    };
    let step: Vec<f64> = (0..n).map(|i| y[i] / d[i]).collect();
    step.iter().all(|v| v.is_finite()).then_some(step)
}

fn delta_h(p: &[f64]) -> Mat3 {
    [
        [1.0 + p[0], p[1], p[2]],
        [p[3], 1.0 + p[4], p[5]],
        [p[6], p[7], 1.0],
    ]
}

fn project(m: &Mat3, u: f64, v: f64) -> Option<(f64, f64)> {
    let z = m[2][0] * u + m[2][1] * v + m[2][2];
    (z > 0.0).then(|| {
        (
            (m[0][0] * u + m[0][1] * v + m[0][2]) / z,
            (m[1][0] * u + m[1][1] * v + m[1][2]) / z,
        )
    })
}

fn corners(w: usize, h: usize) -> [(f64, f64); 4] {
    let (a, b) = (w as f64 - 1.0, h as f64 - 1.0);
    [(0.0, 0.0), (a, 0.0), (a, b), (0.0, b)]
}

/// Largest displacement of an exemplar corner by the step, level pixels: ΔH on the exemplar
/// side plus the change of the distortion at the corners' image points.
fn step_size(p: &[f64], m: &Mat3, dist: Option<&Dist>, w: usize, h: usize) -> f64 {
    let dh = delta_h(p);
    let mut worst = 0.0f64;
    for (u, v) in corners(w, h) {
        let mut d = match project(&dh, u, v) {
            Some((x, y)) => (x - u).hypot(y - v),
            None => f64::INFINITY,
        };
        if let (Some(dist), Some((x, y))) = (dist, project(m, u, v)) {
            let (dx, dy) = (x - dist.cx, y - dist.cy);
            let r2 = (dx * dx + dy * dy) / (dist.f * dist.f);
            let dk = r2 * (p[8] + r2 * p[9]);
            d += dx.hypot(dy) * dk.abs();
        }
        worst = worst.max(d);
    }
    worst
}

/// Normalises the warp so its denominator is 1 at the exemplar center; `None` if the warp is
/// degenerate: singular, or some exemplar corner at or behind the horizon.
fn normalise_warp(m: &Mat3, w: usize, h: usize) -> Option<Mat3> {
    let (cu, cv) = (0.5 * (w as f64 - 1.0), 0.5 * (h as f64 - 1.0));
    let zc = m[2][0] * cu + m[2][1] * cv + m[2][2];
    if !(zc.abs() > 0.0) || m.iter().flatten().any(|v| !v.is_finite()) {
        return None;
    }
    let mut out = *m;
    for v in out.iter_mut().flatten() {
        *v /= zc;
    }
    let ok = corners(w, h)
        .iter()
        .all(|&(u, v)| out[2][0] * u + out[2][1] * v + out[2][2] > 1e-6)
        && singularity(&out) > 1e-12;
    ok.then_some(out)
}

fn diverged(level: usize, reason: String) -> RegistrationError {
    RegistrationError::Diverged { level, reason }
}

/// Aligns the pairs: refines `warp` (exemplar pixel → undistorted image pixel) and, when
/// `distortion` is given, its k1 and k2 (center and focal length stay), coarse to fine.
///
/// Errors: exemplars of different sizes or without structure, a degenerate starting warp,
/// divergence (the parts leave an image, the warp degenerates, the cost ends above its start),
/// or a final correlation below `min_correlation`.
pub fn align(
    pairs: &[Pair],
    warp: Mat3,
    distortion: Option<RadialDistortion>,
    opts: &LmOptions,
) -> Result<Alignment, RegistrationError> {
    let first = pairs
        .first()
        .ok_or_else(|| RegistrationError::Invalid("no images to align".into()))?;
    let (ew, eh) = (first.exemplar.width, first.exemplar.height);
    for (k, p) in pairs.iter().enumerate() {
        let sizes_ok = p.exemplar.width == ew
            && p.exemplar.height == eh
            && p.exemplar.data.len() == ew * eh
            && p.image.data.len() == p.image.width * p.image.height
            && p.image.width >= 2
            && p.image.height >= 2;
        if !sizes_ok {
            return Err(RegistrationError::Invalid(format!(
                "pair {k}: exemplar {}x{} (first is {ew}x{eh}) or image {}x{} unusable",
                p.exemplar.width, p.exemplar.height, p.image.width, p.image.height
            )));
        }
    }
    if ew < 8 || eh < 8 {
        return Err(RegistrationError::Invalid(format!(
            "exemplar of {ew}x{eh} pixels is too small to align"
        )));
    }
    let levels = opts
        .levels
        .unwrap_or_else(|| default_levels(ew, eh))
        .clamp(1, 8);
    // Keep at least 8 pixels on the coarsest exemplar side.
    let levels = (1..=levels)
        .rev()
        .find(|&l| (ew.min(eh) >> (l - 1)) >= 8)
        .unwrap_or(1);
    let mut m0 = normalise_warp(&warp, ew, eh).ok_or_else(|| {
        RegistrationError::Invalid(
            "the starting warp is degenerate (singular, or the exemplar crosses the horizon)"
                .into(),
        )
    })?;
    let mut dist = distortion;

    // Pyramids, finest first.
    let mut pyramid: Vec<Level> = Vec::with_capacity(levels);
    for l in 0..levels {
        let (exemplars, images): (Vec<F32Image>, Vec<F32Image>) = if l == 0 {
            pairs
                .iter()
                .map(|p| (p.exemplar.clone(), p.image.clone()))
                .unzip()
        } else {
            let prev = &pyramid[l - 1];
            prev.exemplars
                .iter()
                .zip(&prev.images)
                .map(|(e, i)| (downsample(e), downsample(i)))
                .unzip()
        };
        let mut jtj = [[0.0; 8]; 8];
        let mut pre = Vec::with_capacity(exemplars.len());
        let mut spans = Vec::with_capacity(exemplars.len());
        let radius = opts
            .support_margin_px
            .map(|m| (m / (1usize << l) as f64).ceil() as usize + 1);
        for (e, img) in exemplars.iter().zip(&images) {
            let max = e.data.par_iter().copied().reduce(|| 0.0f32, f32::max);
            let active = active_spans(e, 0.01 * max, radius);
            let (mut p, j) = precompute(e, &active);
            spans.push(active);
            let sq: f64 = img
                .data
                .par_iter()
                .map(|&v| f64::from(v) * f64::from(v))
                .sum();
            p.scale = (sq / img.data.len().max(1) as f64).sqrt().max(1e-6);
            for a in 0..8 {
                for b in 0..8 {
                    jtj[a][b] += j[a][b];
                }
            }
            pre.push(p);
        }
        if !(0..8).all(|a| jtj[a][a] > 0.0) {
            return Err(RegistrationError::Invalid(format!(
                "the exemplar has no structure at pyramid level {l} (no fused area in its grid)"
            )));
        }
        pyramid.push(Level {
            level: l,
            exemplars,
            images,
            pre,
            spans,
            jtj,
        });
    }

    let mut reports = Vec::with_capacity(levels);
    for lv in pyramid.iter().rev() {
        let l = lv.level;
        let (w, h) = (lv.exemplars[0].width, lv.exemplars[0].height);
        let mut m = normalise_warp(&warp_to_level(&m0, l), w, h)
            .ok_or_else(|| diverged(l, "the warp became degenerate between levels".into()))?;
        let mut d = dist.as_ref().map(|d| Dist::at_level(d, l));
        let deg = opts.photometric_degree.clamp(1, MAX_DEGREE);
        let mut cur = evaluate(lv, &m, d.as_ref(), deg);
        let outside0 = cur.outside;
        let initial_cost = cur.cost;
        let mut lambda = opts.lambda0;
        let mut iterations = 0;
        let mut last_step = f64::INFINITY;
        let mut termination = Termination::MaxIterations;
        while iterations < opts.max_iterations {
            iterations += 1;
            let Some(step) = lm_step(&cur.hess, &cur.grad, lambda) else {
                lambda *= 10.0;
                if lambda > 1e12 {
                    termination = Termination::NoDecrease;
                    break;
                }
                continue;
            };
            last_step = step_size(&step, &m, d.as_ref(), w, h);
            if last_step < opts.step_tol_px {
                termination = Termination::SmallStep;
                break;
            }
            // Eq. 8: M ← M · ΔH⁻¹ (ΔH acts on the exemplar side).
            let trial_m = mat_inv(&delta_h(&step))
                .map(|inv| mat_mul(&m, &inv))
                .and_then(|t| normalise_warp(&t, w, h));
            let trial_d = d.map(|dd| Dist {
                k1: dd.k1 + step[8],
                k2: dd.k2 + step[9],
                ..dd
            });
            let trial = trial_m.map(|tm| (tm, evaluate(lv, &tm, trial_d.as_ref(), deg)));
            match trial {
                Some((tm, ev)) if ev.cost < cur.cost => {
                    if ev.outside > outside0 + opts.max_outside {
                        return Err(diverged(
                            l,
                            format!(
                                "{:.1}% of the parts' pixels now map outside the image",
                                100.0 * ev.outside
                            ),
                        ));
                    }
                    let gain = (cur.cost - ev.cost) / cur.cost.max(f64::MIN_POSITIVE);
                    m = tm;
                    d = trial_d;
                    cur = ev;
                    lambda = (lambda / 10.0).max(1e-12);
                    if gain < opts.cost_tol {
                        termination = Termination::CostStalled;
                        break;
                    }
                }
                _ => {
                    lambda *= 10.0;
                    if lambda > 1e12 {
                        termination = Termination::NoDecrease;
                        break;
                    }
                }
            }
        }
        m0 = warp_from_level(&m, l);
        if let (Some(full), Some(dl)) = (dist.as_mut(), d) {
            full.k1 = dl.k1;
            full.k2 = dl.k2;
        }
        reports.push(LevelReport {
            level: l,
            scale: 1 << l,
            width: w,
            height: h,
            iterations,
            initial_cost,
            final_cost: cur.cost,
            last_step_px: last_step,
            termination,
            correlation: cur
                .fits
                .iter()
                .map(|f| f.correlation)
                .fold(f64::INFINITY, f64::min),
        });
    }

    // Quality at full resolution: the result against the start.
    let fine = &pyramid[0];
    let m_final =
        normalise_warp(&m0, ew, eh).ok_or_else(|| diverged(0, "the warp is degenerate".into()))?;
    let start_warp = normalise_warp(&warp, ew, eh).unwrap_or(warp);
    let start_dist = distortion.as_ref().map(|d| Dist::at_level(d, 0));
    let deg = opts.photometric_degree.clamp(1, MAX_DEGREE);
    let start = evaluate(fine, &start_warp, start_dist.as_ref(), deg);
    let end = evaluate(
        fine,
        &m_final,
        dist.as_ref().map(|d| Dist::at_level(d, 0)).as_ref(),
        deg,
    );
    if end.cost > start.cost {
        return Err(diverged(
            0,
            format!(
                "the cost grew from {:.6e} to {:.6e} at full resolution",
                start.cost, end.cost
            ),
        ));
    }
    let fits: Vec<PairFit> = end
        .fits
        .iter()
        .zip(&start.fits)
        .zip(&fine.pre)
        .map(|((e, s), pre)| PairFit {
            photometric: e
                .coeffs
                .iter()
                .enumerate()
                .map(|(k, c)| c / pre.scale.powi(k as i32))
                .collect(),
            initial_correlation: s.correlation,
            correlation: e.correlation,
            rms: (2.0 * e.cost / pre.n).sqrt(),
            pixels: pre.n as usize,
        })
        .collect();
    if let Some((k, f)) = fits
        .iter()
        .enumerate()
        .find(|(_, f)| !(f.correlation >= opts.min_correlation))
    {
        return Err(RegistrationError::NotConverged {
            image: format!("#{k}"),
            correlation: f.correlation,
            initial: f.initial_correlation,
            min: opts.min_correlation,
        });
    }
    Ok(Alignment {
        warp: m_final,
        distortion: dist,
        levels: reports,
        pairs: fits,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const BLOB_CENTERS: [(f64, f64); 4] =
        [(60.0, 50.0), (130.0, 70.0), (90.0, 120.0), (40.0, 130.0)];

    /// A smooth blob image: sum of Gaussians, defined on continuous coordinates.
    fn blobs(x: f64, y: f64) -> f64 {
        let g = |cx: f64, cy: f64, s: f64, a: f64| {
            a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
        };
        g(60.0, 50.0, 9.0, 80.0)
            + g(130.0, 70.0, 12.0, 60.0)
            + g(90.0, 120.0, 7.0, 90.0)
            + g(40.0, 130.0, 10.0, 50.0)
    }

    fn render(w: usize, h: usize, f: impl Fn(f64, f64) -> f64 + Sync) -> F32Image {
        let data = (0..w * h)
            .into_par_iter()
            .map(|i| f((i % w) as f64, (i / w) as f64) as f32)
            .collect();
        F32Image {
            width: w,
            height: h,
            data,
        }
    }

    fn apply(m: &Mat3, x: f64, y: f64) -> (f64, f64) {
        project(m, x, y).expect("in front")
    }

    #[test]
    fn warp_level_conjugation_round_trips() {
        let m = [[1.1, 0.02, 5.0], [-0.01, 0.95, -3.0], [1e-4, -2e-4, 1.0]];
        for l in 0..4 {
            let back = warp_from_level(&warp_to_level(&m, l), l);
            for (a, b) in back.iter().flatten().zip(m.iter().flatten()) {
                assert!((a - b).abs() < 1e-12);
            }
            // A level-l point maps like its level-0 image.
            let ml = warp_to_level(&m, l);
            let s = level_scale(l);
            let (x, y) = apply(&ml, 7.0, 9.0);
            let (x0, y0) = apply(&s, 7.0, 9.0);
            let (fx, fy) = apply(&m, x0, y0);
            let (sx, sy) = apply(&s, x, y);
            assert!((fx - sx).abs() < 1e-9 && (fy - sy).abs() < 1e-9);
        }
    }

    #[test]
    fn active_spans_dilate_the_support_by_a_square() {
        let mut img = F32Image {
            width: 20,
            height: 12,
            data: vec![0.0; 240],
        };
        img.data[5 * 20 + 7] = 3.0;
        img.data[5 * 20 + 8] = 3.0;
        let spans = active_spans(&img, 1.0, Some(2));
        for (r, row) in spans.iter().enumerate() {
            let want: Vec<(usize, usize)> = if (3..=7).contains(&r) {
                vec![(5, 11)]
            } else {
                vec![]
            };
            assert_eq!(row, &want, "row {r}");
        }
        assert_eq!(active_spans(&img, 1.0, None)[0], vec![(0, 20)]);
    }

    #[test]
    fn downsample_averages_2x2() {
        let img = F32Image {
            width: 5,
            height: 3,
            data: (0..15).map(|v| v as f32).collect(),
        };
        let d = downsample(&img);
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.data, vec![3.0, 5.0]);
    }

    #[test]
    fn recovers_a_known_warp_on_smooth_images() {
        // Image = template seen through a known homography.
        let truth = [
            [1.03, 0.04, 12.0],
            [-0.03, 0.98, 7.0],
            [1.5e-4, -1.0e-4, 1.0],
        ];
        let inv = mat_inv(&truth).expect("invertible");
        let template = render(180, 170, blobs);
        let image = render(240, 230, |u, v| {
            let (x, y) = apply(&inv, u, v);
            blobs(x, y) * 0.5 + 7.0
        });
        let start = [[1.0, 0.0, 9.0], [0.0, 1.0, 10.0], [0.0, 0.0, 1.0]];
        let got = align(
            &[Pair {
                image: &image,
                exemplar: &template,
            }],
            start,
            None,
            &LmOptions::default(),
        )
        .expect("converges");
        // Where the template has structure: the blob centers.
        let mut worst = 0.0f64;
        for (u, v) in BLOB_CENTERS {
            let (a, b) = apply(&got.warp, u, v);
            let (c, d) = apply(&truth, u, v);
            worst = worst.max((a - c).hypot(b - d));
        }
        assert!(worst < 0.01, "error {worst} px; {:?}", got.levels);
        let f = &got.pairs[0];
        assert!(f.correlation > 0.999, "{f:?}");
    }

    #[test]
    fn recovers_radial_distortion_jointly() {
        let truth = [[1.0, 0.02, 20.0], [-0.01, 1.0, 15.0], [0.0, 0.0, 1.0]];
        let inv = mat_inv(&truth).expect("invertible");
        let true_d = RadialDistortion {
            center: [109.5, 104.5],
            focal_px: 150.0,
            k1: -0.08,
            k2: 0.0,
        };
        let template = render(180, 170, blobs);
        let image = render(220, 210, |u, v| {
            let (x, y) = true_d.undistort(u, v);
            let (x, y) = apply(&inv, x, y);
            blobs(x, y)
        });
        let start_d = RadialDistortion { k1: 0.0, ..true_d };
        let opts = LmOptions {
            levels: Some(2),
            ..LmOptions::default()
        };
        let pair = [Pair {
            image: &image,
            exemplar: &template,
        }];
        let got = align(&pair, truth, Some(start_d), &opts).expect("converges");
        let d = got.distortion.expect("distortion");
        assert!((d.k1 + 0.08).abs() < 0.004, "{d:?} {:?}", got.levels);
        let mut worst = 0.0f64;
        for (u, v) in BLOB_CENTERS {
            let (a, b) = apply(&got.warp, u, v);
            let (a, b) = d.distort(a, b);
            let (c, e) = apply(&truth, u, v);
            let (c, e) = true_d.distort(c, e);
            worst = worst.max((a - c).hypot(b - e));
        }
        assert!(worst < 0.02, "error {worst} px; {d:?} {:?}", got.levels);
    }

    #[test]
    fn an_unrelated_image_does_not_converge() {
        let template = render(180, 170, blobs);
        // Structure elsewhere only: the blobs moved far beyond the capture range.
        let image = render(240, 230, |u, v| blobs(u + 300.0, v - 250.0) + 5.0);
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let err = align(
            &[Pair {
                image: &image,
                exemplar: &template,
            }],
            id,
            None,
            &LmOptions::default(),
        )
        .unwrap_err();
        assert!(
            matches!(
                err,
                RegistrationError::NotConverged { .. } | RegistrationError::Diverged { .. }
            ),
            "{err}"
        );
    }

    #[test]
    fn refuses_structureless_exemplars_and_mismatched_sizes() {
        let flat = F32Image {
            width: 64,
            height: 64,
            data: vec![0.0; 64 * 64],
        };
        let img = render(64, 64, blobs);
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let err = align(
            &[Pair {
                image: &img,
                exemplar: &flat,
            }],
            id,
            None,
            &LmOptions::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("no structure"), "{err}");
        let small = render(32, 32, blobs);
        let err = align(
            &[
                Pair {
                    image: &img,
                    exemplar: &img,
                },
                Pair {
                    image: &img,
                    exemplar: &small,
                },
            ],
            id,
            None,
            &LmOptions::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(err.contains("pair 1"), "{err}");
    }
}
