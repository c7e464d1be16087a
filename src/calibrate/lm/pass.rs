//! One pass over an (image, exemplar) pair at a warp: I_B sampled at W(x_i), the photometric
//! polynomial φ fitted in closed form, and the cost, gradient and normal matrix of eq. 7-10.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::pyramid::{exemplar_gradient, jacobian, Dist, Level, Pre, Spans};
use super::F32Image;
use crate::geometry::mat3::Mat3;

/// Highest supported degree of the photometric polynomial.
pub const MAX_DEGREE: usize = 3;

/// Sums of one pass over one pair. t = I_B(W(x_i)) / scale (0 outside the image).
#[derive(Clone, Default)]
pub(super) struct Sums {
    /// Σ t^k, k = 1..=2·MAX_DEGREE (index k).
    pub(super) st: [f64; 2 * MAX_DEGREE + 1],
    /// Σ e t^k, k = 1..=MAX_DEGREE.
    pub(super) set: [f64; MAX_DEGREE + 1],
    /// Σ J t^k, k = 1..=MAX_DEGREE.
    pub(super) jt: [[f64; 8]; MAX_DEGREE + 1],
    pub(super) outside: usize,
    // Distortion rows, with G_i = ∇I_E(x_i)ᵀ A⁻¹ ∂D/∂k (2 values per pixel).
    pub(super) sg_t: [[f64; 2]; MAX_DEGREE + 1],
    pub(super) sg_e: [f64; 2],
    pub(super) sgg: [[f64; 2]; 2],
    pub(super) sgj: [[f64; 8]; 2],
    // The dilation column h_i = |∇I_E(x_i)| (see [`fit_photometric`]): Σ h t^k, Σ h e, Σ h²,
    // Σ J h and Σ G h.
    pub(super) sht: [f64; MAX_DEGREE + 1],
    pub(super) she: f64,
    pub(super) shh: f64,
    pub(super) sjh: [f64; 8],
    pub(super) sgh: [f64; 2],
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
        add(&mut self.sht, &o.sht);
        self.she += o.she;
        self.shh += o.shh;
        add(&mut self.sjh, &o.sjh);
        add(&mut self.sgh, &o.sgh);
    }
}

/// What one pass needs besides the images.
#[derive(Clone, Copy)]
pub(super) struct PassSetup<'a> {
    pub(super) m: &'a Mat3,
    pub(super) dist: Option<&'a Dist>,
    /// Support threshold of the exemplar.
    pub(super) thr: f32,
    /// 1 / scale of the image values.
    pub(super) inv_scale: f64,
    pub(super) degree: usize,
    /// Accumulate the dilation column's sums.
    pub(super) dilation: bool,
}

/// One pass over a pair: samples I_B at W(x_i) for every exemplar pixel.
pub(super) fn pass(ex: &F32Image, img: &F32Image, spans: &Spans, ps: PassSetup) -> Sums {
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
                if let (true, Some(j)) = (ps.dilation, &j) {
                    let h = f64::from(gx).hypot(f64::from(gy));
                    for k in 0..=deg {
                        s.sht[k] += h * pw[k];
                    }
                    s.she += h * e;
                    s.shh += h * h;
                    for a in 0..8 {
                        s.sjh[a] += h * j[a];
                    }
                    if let Some((gk, _)) = &g {
                        for i in 0..2 {
                            s.sgh[i] += gk[i] * h;
                        }
                    }
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
pub(super) struct Photometric {
    /// φ(t) = Σ c_k t^k, t = I_B / scale.
    pub(super) coeffs: Vec<f64>,
    /// δ: the exemplar's edges moved outward by δ level pixels match the frame (0 when not
    /// fitted).
    pub(super) dilation: f64,
    pub(super) cost: f64,
    /// R: √(1 − 2·cost / Σ (e − ē)²), the correlation of I_E with φ(I_B).
    pub(super) correlation: f64,
}

/// Least-squares φ of degree `deg` (lowered if the normal matrix is singular: a flat image)
/// and, with `dilation`, the exemplar's dilation δ along with it.
///
/// The dilation: a frame's parts look wider than their vectors when partly fused powder
/// sticks to the outer tracks (a halo a fraction of a millimetre wide, as bright and as rough
/// as the part), and the std filter then sees every edge moved outward. No homography can
/// follow an outward move of every part's edge about its own part; it compromises with a
/// false scale that grows towards the frame's edges (measured on the second test renderer
/// with a 1 mm halo: 0.37 px mean, 0.97 px max, the far parts worst). The exemplar with its edges
/// moved outward by δ is, to first order, I_E + δ·|∇I_E| (the gradient of the std edge points
/// into the part), so the residual becomes r_i = e_i + δ·h_i − φ(t_i) with h_i = |∇I_E(x_i)|:
/// linear in δ, fitted in closed form with φ (variable projection), one δ per frame.
pub(super) fn fit_photometric(pre: &Pre, s: &Sums, deg: usize, dilation: bool) -> Photometric {
    let var_e = (pre.see - pre.se * pre.se / pre.n).max(0.0);
    let with_h = if dilation && s.shh > 0.0 {
        vec![true, false]
    } else {
        vec![false]
    };
    for d in (0..=deg).rev() {
        for &h in &with_h {
            let n = d + 1 + usize::from(h);
            // Columns t^0..t^d and, with h, −h_i: e ≈ Σ c_k t^k − δ h.
            let a = DMatrix::from_fn(n, n, |i, j| match (i > d, j > d) {
                (false, false) => {
                    if i + j == 0 {
                        pre.n
                    } else {
                        s.st[i + j]
                    }
                }
                (true, false) => -s.sht[j],
                (false, true) => -s.sht[i],
                (true, true) => s.shh,
            });
            let rhs = DVector::from_fn(n, |i, _| match i {
                0 => pre.se,
                i if i > d => -s.she,
                i => s.set[i],
            });
            let Some(c) = solve_scaled(&a, &rhs) else {
                continue;
            };
            let explained: f64 = (0..n).map(|i| c[i] * rhs[i]).sum();
            let cost = 0.5 * (pre.see - explained).max(0.0);
            let delta = if h { c[d + 1] } else { 0.0 };
            // The correlation is that of the dilated exemplar I_E + δh with φ(I_B): δ alone
            // can explain part of I_E by its own gradient (an unrelated image would otherwise
            // look matched).
            let var = if h {
                let sum = pre.se + delta * s.sht[0];
                let sq = pre.see + 2.0 * delta * s.she + delta * delta * s.shh;
                (sq - sum * sum / pre.n).max(0.0)
            } else {
                var_e
            };
            let r2 = if var > 0.0 {
                (1.0 - 2.0 * cost / var).max(0.0)
            } else {
                0.0
            };
            let mut coeffs = vec![0.0; deg + 1];
            coeffs[..=d].copy_from_slice(&c.as_slice()[..=d]);
            return Photometric {
                coeffs,
                dilation: delta,
                cost,
                correlation: r2.sqrt(),
            };
        }
    }
    Photometric {
        coeffs: vec![0.0; deg + 1],
        dilation: 0.0,
        cost: 0.5 * var_e,
        correlation: 0.0,
    }
}

/// Solves a symmetric positive (semi)definite system with Jacobi scaling; `None` if singular.
pub(super) fn solve_scaled(a: &DMatrix<f64>, b: &DVector<f64>) -> Option<DVector<f64>> {
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
pub(super) struct Eval {
    pub(super) cost: f64,
    pub(super) grad: Vec<f64>,
    pub(super) hess: DMatrix<f64>,
    pub(super) fits: Vec<Photometric>,
    /// Largest fraction of a pair's support outside its image.
    pub(super) outside: f64,
}

/// Cost, gradient and normal matrix at warp `m` (and distortion `dist`).
pub(super) fn evaluate(
    lv: &Level,
    m: &Mat3,
    dist: Option<&Dist>,
    degree: usize,
    dilation: bool,
) -> Eval {
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
                dilation,
            },
        );
        let fit = fit_photometric(pre, &s, degree, dilation);
        cost += fit.cost;
        if pre.support > 0 {
            outside = outside.max(s.outside as f64 / pre.support as f64);
        }
        // Jᵀr with r_i = e_i + δ h_i − Σ c_k t_i^k.
        let c = &fit.coeffs;
        let delta = fit.dilation;
        for a in 0..8 {
            let model: f64 = (1..=degree).map(|k| c[k] * s.jt[k][a]).sum();
            grad[a] += pre.jte[a] - c[0] * pre.jsum[a] - model + delta * s.sjh[a];
        }
        if dist.is_some() {
            // K = [J, −G]: the distortion rows of Kᵀr are −Σ G r.
            for i in 0..2 {
                let n_g: f64 = s.sg_t[0][i];
                let model: f64 =
                    c[0] * n_g + (1..=degree).map(|k| c[k] * s.sg_t[k][i]).sum::<f64>();
                grad[8 + i] += -(s.sg_e[i] - model + delta * s.sgh[i]);
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
