//! The Levenberg-Marquardt iterations, coarse to fine: [`align`].

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::pass::{evaluate, MAX_DEGREE};
use super::pyramid::{
    active_spans, default_levels, downsample, precompute, warp_from_level, warp_to_level, Dist,
    Level,
};
use super::{Alignment, F32Image, LevelReport, LmOptions, Pair, PairFit, Termination};
use crate::calibrate::RegistrationError;
use crate::geometry::mat3::{self, Mat3};
use crate::geometry::{Homography, RadialDistortion};

/// Solves (H + λ diag H) δ = −g with Jacobi scaling (the eq. 10 parameters differ in scale by
/// the square of the image size, so the unscaled system is badly conditioned).
pub(super) fn lm_step(hess: &DMatrix<f64>, grad: &[f64], lambda: f64) -> Option<Vec<f64>> {
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

pub(super) fn delta_h(p: &[f64]) -> Mat3 {
    [
        [1.0 + p[0], p[1], p[2]],
        [p[3], 1.0 + p[4], p[5]],
        [p[6], p[7], 1.0],
    ]
}

pub(super) fn corners(w: usize, h: usize) -> [(f64, f64); 4] {
    let (a, b) = (w as f64 - 1.0, h as f64 - 1.0);
    [(0.0, 0.0), (a, 0.0), (a, b), (0.0, b)]
}

/// Largest displacement of an exemplar corner by the step, level pixels: ΔH on the exemplar
/// side plus the change of the distortion at the corners' image points.
pub(super) fn step_size(p: &[f64], m: &Mat3, dist: Option<&Dist>, w: usize, h: usize) -> f64 {
    let dh = delta_h(p);
    let mut worst = 0.0f64;
    for (u, v) in corners(w, h) {
        let mut d = match mat3::project(&dh, u, v) {
            Some((x, y)) => (x - u).hypot(y - v),
            None => f64::INFINITY,
        };
        if let (Some(dist), Some((x, y))) = (dist, mat3::project(m, u, v)) {
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
pub(super) fn normalise_warp(m: &Mat3, w: usize, h: usize) -> Option<Mat3> {
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
        && mat3::singularity(&out) > 1e-12;
    ok.then_some(out)
}

pub(super) fn diverged(level: usize, reason: String) -> RegistrationError {
    RegistrationError::Diverged { level, reason }
}

/// Aligns the pairs: refines `image_from_exemplar` (exemplar pixel → undistorted image pixel)
/// and, when
/// `distortion` is given, its k1 and k2 (center and focal length stay), coarse to fine.
///
/// Errors: exemplars of different sizes or without structure, a degenerate starting warp,
/// divergence (the parts leave an image, the warp degenerates, the cost ends above its start),
/// or a final correlation below `min_correlation`.
pub fn align(
    pairs: &[Pair],
    image_from_exemplar: Homography,
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
    let warp = image_from_exemplar.matrix();
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
        let mut cur = evaluate(lv, &m, d.as_ref(), deg, opts.fit_dilation);
        let outside0 = cur.outside;
        let initial_cost = cur.cost;
        let mut lambda = opts.lambda0;
        let mut iterations = 0;
        let mut last_step = f64::INFINITY;
        let mut termination = Termination::MaxIterations;
        while iterations < opts.max_iterations {
            iterations += 1;
            let step = if opts.fix_k2 && cur.grad.len() > 9 {
                let (mut hess, mut grad) = (cur.hess.clone(), cur.grad.clone());
                hess.row_mut(9).fill(0.0);
                hess.column_mut(9).fill(0.0);
                hess[(9, 9)] = 1.0;
                grad[9] = 0.0;
                lm_step(&hess, &grad, lambda)
            } else {
                lm_step(&cur.hess, &cur.grad, lambda)
            };
            let Some(step) = step else {
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
            let trial_m = mat3::mat_inv(&delta_h(&step))
                .map(|inv| mat3::mul(&m, &inv))
                .and_then(|t| normalise_warp(&t, w, h));
            let trial_d = d.map(|dd| Dist {
                k1: dd.k1 + step[8],
                k2: dd.k2 + step[9],
                ..dd
            });
            let trial = trial_m.map(|tm| {
                (
                    tm,
                    evaluate(lv, &tm, trial_d.as_ref(), deg, opts.fit_dilation),
                )
            });
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
    let start = evaluate(
        fine,
        &start_warp,
        start_dist.as_ref(),
        deg,
        opts.fit_dilation,
    );
    let end = evaluate(
        fine,
        &m_final,
        dist.as_ref().map(|d| Dist::at_level(d, 0)).as_ref(),
        deg,
        opts.fit_dilation,
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
            dilation_px: e.dilation,
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
        image_from_exemplar: Homography::from_matrix(m_final),
        distortion: dist,
        levels: reports,
        pairs: fits,
    })
}
