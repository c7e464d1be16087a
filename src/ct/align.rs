//! Initial transform (Horn's absolute orientation) and the Levenberg-Marquardt refinement of
//! paper §3.2, equations 14-17.

use std::path::Path;

use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3, Vector6};
use rayon::prelude::*;

use crate::geometry::Rigid3;

use super::error::{io_err, CtError, Result};
use super::params::{CtParams, CtRegistration, DistanceField, PointPair, Registered, Termination};

pub const IDENTITY: [[f64; 4]; 4] = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Read POINTS.txt: one pair per line, `cx cy cz bx by bz` (whitespace or commas); `#` comments
/// and blank lines are skipped.
pub fn read_points_file(path: &Path) -> Result<Vec<PointPair>> {
    let text = crate::fsutil::read_text_bounded(path, 1 << 20).map_err(io_err(path))?;
    let mut pairs = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let err = |message: String| CtError::PointsFile {
            path: path.to_path_buf(),
            line: n + 1,
            message,
        };
        let xs: Vec<f64> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(|s| {
                s.parse::<f64>()
                    .map_err(|_| err(format!("{s:?} is not a number")))
            })
            .collect::<Result<_>>()?;
        if xs.len() != 6 {
            return Err(err(format!(
                "expected 6 numbers `cx cy cz bx by bz`, got {}",
                xs.len()
            )));
        }
        if let Some(x) = xs.iter().find(|x| !x.is_finite() || x.abs() > MAX_POINT_MM) {
            return Err(err(format!(
                "{x} is not a coordinate: give finite mm, -{MAX_POINT_MM} to {MAX_POINT_MM}"
            )));
        }
        pairs.push(PointPair {
            ct: [xs[0], xs[1], xs[2]],
            build: [xs[3], xs[4], xs[5]],
        });
    }
    Ok(pairs)
}

/// The largest coordinate of a point pair, mm: a CT or a build plate is far smaller.
const MAX_POINT_MM: f64 = 1e6;

/// Horn's closed-form absolute orientation with unit quaternions (Horn 1987): the rigid
/// transform (CT → build) minimising Σ |R·ct + t − build|².
pub fn horn(pairs: &[PointPair]) -> Result<Rigid3> {
    if pairs.len() < 3 {
        return Err(CtError::TooFewPoints(pairs.len()));
    }
    let n = pairs.len() as f64;
    let mean = |f: &dyn Fn(&PointPair) -> [f64; 3]| {
        let s = pairs
            .iter()
            .fold(Vector3::zeros(), |s, p| s + Vector3::from(f(p)));
        s / n
    };
    let ca = mean(&|p| p.ct);
    let cb = mean(&|p| p.build);
    for (which, c, get) in [
        (
            "CT",
            ca,
            &(|p: &PointPair| p.ct) as &dyn Fn(&PointPair) -> [f64; 3],
        ),
        ("build", cb, &|p: &PointPair| p.build),
    ] {
        let cov = pairs.iter().fold(Matrix3::zeros(), |m, p| {
            let d = Vector3::from(get(p)) - c;
            m + d * d.transpose()
        });
        let mut ev: Vec<f64> = cov.symmetric_eigenvalues().iter().copied().collect();
        ev.sort_by(|a, b| b.total_cmp(a));
        // Second principal spread under 1e-3 of the first: a line (or a single point).
        if ev[0] <= 0.0 || ev[1].max(0.0).sqrt() < 1e-3 * ev[0].sqrt() {
            return Err(CtError::CollinearPoints { which });
        }
    }
    let mut s = Matrix3::zeros();
    for p in pairs {
        let a = Vector3::from(p.ct) - ca;
        let b = Vector3::from(p.build) - cb;
        s += a * b.transpose();
    }
    let (sxx, sxy, sxz) = (s[(0, 0)], s[(0, 1)], s[(0, 2)]);
    let (syx, syy, syz) = (s[(1, 0)], s[(1, 1)], s[(1, 2)]);
    let (szx, szy, szz) = (s[(2, 0)], s[(2, 1)], s[(2, 2)]);
    #[rustfmt::skip]
    let nmat = Matrix4::new(
        sxx + syy + szz, syz - szy,        szx - sxz,        sxy - syx,
        syz - szy,       sxx - syy - szz,  sxy + syx,        szx + sxz,
        szx - sxz,       sxy + syx,       -sxx + syy - szz,  syz + szy,
        sxy - syx,       szx + sxz,        syz + szy,       -sxx - syy + szz,
    );
    let eig = nmat.symmetric_eigen();
    let k = eig.eigenvalues.imax();
    let q = eig.eigenvectors.column(k).normalize();
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    #[rustfmt::skip]
    let r = Matrix3::new(
        w*w + x*x - y*y - z*z, 2.0*(x*y - w*z),       2.0*(x*z + w*y),
        2.0*(y*x + w*z),       w*w - x*x + y*y - z*z, 2.0*(y*z - w*x),
        2.0*(z*x - w*y),       2.0*(z*y + w*x),       w*w - x*x - y*y + z*z,
    );
    let t = cb - r * ca;
    Ok(Rigid3::from_matrix_unchecked(to_array(&r, &t)))
}

pub(crate) fn to_array(r: &Matrix3<f64>, t: &Vector3<f64>) -> [[f64; 4]; 4] {
    let mut m = IDENTITY;
    for i in 0..3 {
        for j in 0..3 {
            m[i][j] = r[(i, j)];
        }
        m[i][3] = t[i];
    }
    m
}

pub(crate) fn split(m: &[[f64; 4]; 4]) -> (Matrix3<f64>, Vector3<f64>) {
    (
        Matrix3::from_fn(|i, j| m[i][j]),
        Vector3::new(m[0][3], m[1][3], m[2][3]),
    )
}

fn skew(w: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -w.z, w.y, w.z, 0.0, -w.x, -w.y, w.x, 0.0)
}

/// The exact SE(3) exponential of ξ = (ω, v): (R, t) with R = exp(`[ω]×`) (Rodrigues) and
/// t = V·v, V = I + (1 − cos θ)/θ² `[ω]×` + (θ − sin θ)/θ³ `[ω]×²`.
///
/// Eq. 13 of the paper is its first-order form (I + `[ω]×`, (I + ½`[ω]×`)v); we accumulate with the
/// exact map so that T stays a rotation however many steps are composed.
pub fn se3_exp(xi: &Vector6<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    let w = Vector3::new(xi[0], xi[1], xi[2]);
    let v = Vector3::new(xi[3], xi[4], xi[5]);
    let th2 = w.norm_squared();
    let th = th2.sqrt();
    let k = skew(&w);
    let k2 = k * k;
    // Taylor series below 1e-4 rad where the closed forms lose precision.
    let (a, b, c) = if th < 1e-4 {
        (1.0 - th2 / 6.0, 0.5 - th2 / 24.0, 1.0 / 6.0 - th2 / 120.0)
    } else {
        (
            th.sin() / th,
            (1.0 - th.cos()) / th2,
            (th - th.sin()) / (th2 * th),
        )
    };
    let r = Matrix3::identity() + k * a + k2 * b;
    let vmat = Matrix3::identity() + k * b + k2 * c;
    (r, vmat * v)
}

/// Rotation angle of R in radians.
pub fn rotation_angle(r: &Matrix3<f64>) -> f64 {
    ((r.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos()
}

/// Per-evaluation sums: the 6x6 normal equations, the gradient and the cost.
#[derive(Clone, Copy)]
struct Accum {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    cost: f64,
    used: usize,
    outside: usize,
}

impl Accum {
    fn zero() -> Self {
        Self {
            h: Matrix6::zeros(),
            g: Vector6::zeros(),
            cost: 0.0,
            used: 0,
            outside: 0,
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.h += o.h;
        self.g += o.g;
        self.cost += o.cost;
        self.used += o.used;
        self.outside += o.outside;
        self
    }
}

/// Huber loss ρ and IRLS weight w(r) = ρ'(r)/r; plain least squares without k.
#[inline]
fn loss(r: f64, k: Option<f64>) -> (f64, f64) {
    match k {
        Some(k) if r.abs() > k => (k * (r.abs() - 0.5 * k), k / r.abs()),
        _ => (0.5 * r * r, 1.0),
    }
}

/// Build point → (Ψ, ∇Ψ) if it carries information: inside the field and inside the band.
#[inline]
fn sample(field: &dyn DistanceField, p: [f64; 3], trunc: f64) -> Option<(f64, [f64; 3])> {
    let (d, g) = field.sample_with_gradient(p)?;
    // Truncated samples have no usable gradient: weight 0.
    (d.is_finite() && d.abs() < trunc * (1.0 - 1e-5)).then_some((d, g))
}

/// Evaluate cost and normal equations at (R, t), with the Jacobian taken about `center`.
///
/// The cost gives every point outside the band the truncation's loss, so it is one function of
/// T even as points enter and leave the band.
fn evaluate(
    points: &[[f64; 3]],
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    center: &Vector3<f64>,
    field: &dyn DistanceField,
    k: Option<f64>,
    with_jacobian: bool,
) -> Accum {
    let trunc = field.truncation_mm();
    let out_cost = loss(trunc, k).0;
    points
        .par_chunks(4096)
        .fold(Accum::zero, |mut acc, chunk| {
            for p in chunk {
                let x = r * Vector3::from(*p) + t;
                let Some((d, grad)) = sample(field, [x.x, x.y, x.z], trunc) else {
                    acc.outside += 1;
                    acc.cost += out_cost;
                    continue;
                };
                let (rho, w) = loss(d, k);
                acc.cost += rho;
                acc.used += 1;
                if with_jacobian {
                    // Eq. 17 at the transformed point (about `center`): J = ∇Ψᵀ [-[x]× | I],
                    // i.e. the rotation part is x × ∇Ψ.
                    let g = Vector3::from(grad);
                    let q = x - center;
                    let jr = q.cross(&g);
                    let j = Vector6::new(jr.x, jr.y, jr.z, g.x, g.y, g.z);
                    acc.h.ger(w, &j, &j, 1.0);
                    acc.g.axpy(w * d, &j, 1.0);
                }
            }
            acc
        })
        .reduce(Accum::zero, Accum::merge)
}

/// LM outcome for one point set.
struct LmResult {
    r: Matrix3<f64>,
    t: Vector3<f64>,
    iterations: usize,
    termination: Termination,
}

/// Levenberg-Marquardt on `T ← exp(ξ)·T` (eq. 14, 15) with Marquardt's diagonal damping.
fn levenberg_marquardt(
    points: &[[f64; 3]],
    mut r: Matrix3<f64>,
    mut t: Vector3<f64>,
    field: &dyn DistanceField,
    params: &CtParams,
    max_iterations: usize,
) -> Result<LmResult> {
    let k = params.huber_k_mm;
    let trunc = field.truncation_mm();
    // Rotating about the points' centroid instead of the build origin decouples rotation from
    // translation (parts sit tens of mm from the origin); it is the same update family, the
    // exponential conjugated by a translation.
    let c_ct = points
        .iter()
        .fold(Vector3::zeros(), |s, p| s + Vector3::from(*p))
        / points.len().max(1) as f64;
    let mut acc = evaluate(points, &r, &t, &(r * c_ct + t), field, k, true);
    let min_used = 6.max(points.len() / 100);
    if acc.used < min_used {
        return Err(CtError::NoOverlap {
            used: acc.used,
            total: points.len(),
            truncation_mm: trunc,
        });
    }
    let mut lambda = 1e-4;
    let mut last_step = (f64::INFINITY, f64::INFINITY);
    for it in 1..=max_iterations {
        let center = r * c_ct + t;
        let diag = Matrix6::from_diagonal(&acc.h.diagonal().map(|v| v.max(1e-12)));
        let Some(chol) = (acc.h + diag * lambda).cholesky() else {
            lambda *= 10.0;
            continue;
        };
        let xi = -chol.solve(&acc.g);
        let (dr, dt) = se3_exp(&xi);
        // T' = C·exp(ξ)·C⁻¹·T with C the translation to `center`.
        let r_new = dr * r;
        let t_new = dr * (t - center) + dt + center;
        let step_rot = xi.fixed_rows::<3>(0).norm();
        let step_trans = xi.fixed_rows::<3>(3).norm();
        last_step = (step_rot, step_trans);
        let small_step =
            step_rot < params.min_rotation_step_rad && step_trans < params.min_translation_step_mm;
        let trial = evaluate(
            points,
            &r_new,
            &t_new,
            &(r_new * c_ct + t_new),
            field,
            k,
            true,
        );
        if trial.cost < acc.cost {
            let rel = (acc.cost - trial.cost) / acc.cost.max(f64::MIN_POSITIVE);
            r = r_new;
            t = t_new;
            acc = trial;
            lambda = (lambda * 0.1).max(1e-12);
            if small_step {
                return Ok(LmResult {
                    r,
                    t,
                    iterations: it,
                    termination: Termination::SmallStep,
                });
            }
            if rel < params.min_relative_cost_change {
                return Ok(LmResult {
                    r,
                    t,
                    iterations: it,
                    termination: Termination::SmallCostChange,
                });
            }
        } else {
            // At a minimum a rejected step that is already below tolerance means converged.
            if small_step {
                return Ok(LmResult {
                    r,
                    t,
                    iterations: it,
                    termination: Termination::SmallStep,
                });
            }
            lambda *= 10.0;
        }
    }
    let trunc_cost = acc.cost;
    Err(CtError::NotConverged {
        iterations: max_iterations,
        rotation_rad: last_step.0,
        translation_mm: last_step.1,
        rms_um: (2.0 * trunc_cost / points.len().max(1) as f64).sqrt() * 1e3,
    })
}

/// Plate-side points (§4.2): within `slab` of the lowest transformed point along build z.
fn plate_mask(points: &[[f64; 3]], r: &Matrix3<f64>, t: &Vector3<f64>, slab: f64) -> Vec<bool> {
    let zrow = r.row(2);
    let z = |p: &[f64; 3]| zrow[0] * p[0] + zrow[1] * p[1] + zrow[2] * p[2] + t.z;
    let zmin = points.par_iter().map(z).reduce(|| f64::INFINITY, f64::min);
    points.par_iter().map(|p| z(p) < zmin + slab).collect()
}

/// Refine `t0` on CT surface points (CT physical mm) and compute the error figures.
///
/// Plate-side points are chosen with the current transform; when the refinement moves the
/// part enough to change that choice the refinement is repeated (at most 4 rounds), so a tilted
/// initial transform does not leave plate-side points in.
pub fn register_points(
    points: &[[f64; 3]],
    t0: [[f64; 4]; 4],
    field: &dyn DistanceField,
    params: &CtParams,
    threshold: f64,
) -> Result<Registered> {
    let (mut r, mut t) = split(&t0);
    // Re-orthonormalise a user matrix: the exponential updates assume a rotation.
    let svd = r.svd(true, true);
    if let (Some(u), Some(vt)) = (svd.u, svd.v_t) {
        r = u * vt;
    }
    let mut plate = plate_mask(points, &r, &t, params.plate_slab_mm);
    let mut iterations = 0;
    let mut termination = Termination::SmallStep;
    for _round in 0..4 {
        let kept: Vec<[f64; 3]> = points
            .iter()
            .zip(&plate)
            .filter(|(_, &pl)| !pl)
            .map(|(p, _)| *p)
            .collect();
        let subset = stride_subset(&kept, params.max_points);
        let budget = params.max_iterations.saturating_sub(iterations).max(1);
        let lm =
            levenberg_marquardt(&subset, r, t, field, params, budget).map_err(|e| match e {
                CtError::NotConverged {
                    rotation_rad,
                    translation_mm,
                    rms_um,
                    ..
                } => CtError::NotConverged {
                    iterations: params.max_iterations,
                    rotation_rad,
                    translation_mm,
                    rms_um,
                },
                e => e,
            })?;
        iterations += lm.iterations;
        termination = lm.termination;
        r = lm.r;
        t = lm.t;
        let new_plate = plate_mask(points, &r, &t, params.plate_slab_mm);
        let changed = new_plate.iter().zip(&plate).filter(|(a, b)| a != b).count();
        plate = new_plate;
        // A handful of points flipping at the slab boundary does not move the optimum.
        if changed * 1000 <= points.len() {
            break;
        }
    }

    // Error figures over all non-plate points (Table 2: mean |Ψ| over the CT surface points).
    let trunc = field.truncation_mm();
    let evaluated: Vec<Option<([f64; 3], f64)>> = points
        .par_iter()
        .zip(plate.par_iter())
        .filter(|(_, &pl)| !pl)
        .map(|(p, _)| {
            let x = r * Vector3::from(*p) + t;
            let x = [x.x, x.y, x.z];
            field
                .sample_with_gradient(x)
                .map(|(d, _)| (x, d.clamp(-trunc, trunc)))
        })
        .collect();
    let excluded_plate = plate.iter().filter(|&&p| p).count();
    let mut points_build = Vec::with_capacity(evaluated.len());
    let mut distances = Vec::with_capacity(evaluated.len());
    let mut outside = 0;
    let mut used = 0;
    for e in &evaluated {
        match e {
            Some((x, d)) => {
                points_build.push(*x);
                distances.push(*d);
                if d.abs() < trunc * (1.0 - 1e-5) {
                    used += 1;
                } else {
                    outside += 1;
                }
            }
            None => outside += 1,
        }
    }
    let stats = Stats::of(&distances);
    let candidates = points.len() - excluded_plate;
    if let Some(max) = params.max_outside_fraction {
        let frac = outside as f64 / candidates.max(1) as f64;
        if frac > max {
            return Err(CtError::PoorFit {
                outside_pct: 100.0 * frac,
                mean_abs_um: stats.mean_abs * 1e3,
            });
        }
    }
    let registration = CtRegistration {
        build_from_ct: Rigid3::from_matrix_unchecked(to_array(&r, &t)),
        iterations,
        termination,
        threshold,
        points_used: used,
        points_total: points.len(),
        points_excluded_plate: excluded_plate,
        points_outside: outside,
        mean_abs_um: stats.mean_abs * 1e3,
        median_abs_um: stats.median_abs * 1e3,
        p95_abs_um: stats.p95_abs * 1e3,
        max_abs_um: stats.max_abs * 1e3,
        rms_um: stats.rms * 1e3,
    };
    Ok(Registered {
        registration,
        points_build_mm: points_build,
        distances_mm: distances,
    })
}

fn stride_subset(points: &[[f64; 3]], max: Option<usize>) -> Vec<[f64; 3]> {
    match max {
        Some(m) if m > 0 && points.len() > m => {
            let step = points.len() as f64 / m as f64;
            (0..m).map(|i| points[(i as f64 * step) as usize]).collect()
        }
        _ => points.to_vec(),
    }
}

/// Summary of |Ψ| in mm.
#[derive(Debug, Clone, Copy, Default)]
pub struct Stats {
    pub mean_abs: f64,
    pub median_abs: f64,
    pub p95_abs: f64,
    pub max_abs: f64,
    pub rms: f64,
}

impl Stats {
    pub fn of(d: &[f64]) -> Self {
        if d.is_empty() {
            return Self::default();
        }
        let mut a: Vec<f64> = d.iter().map(|x| x.abs()).collect();
        a.par_sort_unstable_by(|x, y| x.total_cmp(y));
        let n = a.len();
        let pct = |q: f64| a[((q * (n - 1) as f64).round() as usize).min(n - 1)];
        Self {
            mean_abs: a.iter().sum::<f64>() / n as f64,
            median_abs: pct(0.5),
            p95_abs: pct(0.95),
            max_abs: a[n - 1],
            rms: (d.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(m: &[[f64; 4]; 4], p: [f64; 3]) -> [f64; 3] {
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    fn truth() -> [[f64; 4]; 4] {
        let r = nalgebra::Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.2, -1.0, 0.7)),
            0.6,
        );
        to_array(r.matrix(), &Vector3::new(31.0, -12.5, 4.0))
    }

    #[test]
    fn horn_recovers_an_exact_transform() {
        let m = truth();
        let ct = [
            [0.0, 0.0, 0.0],
            [10.0, 0.0, 1.0],
            [0.0, 8.0, 2.0],
            [3.0, 3.0, 9.0],
        ];
        let pairs: Vec<PointPair> = ct
            .iter()
            .map(|&c| PointPair {
                ct: c,
                build: apply(&m, c),
            })
            .collect();
        for n in [3, 4] {
            let est = *horn(&pairs[..n]).expect("horn").matrix();
            for i in 0..3 {
                for j in 0..4 {
                    assert!(
                        (est[i][j] - m[i][j]).abs() < 1e-9,
                        "{n} pairs: {est:?} vs {m:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn horn_refuses_too_few_or_collinear_points() {
        let m = truth();
        let pair = |c: [f64; 3]| PointPair {
            ct: c,
            build: apply(&m, c),
        };
        let e = horn(&[pair([0.0; 3]), pair([1.0, 0.0, 0.0])]).expect_err("2 points");
        assert!(
            e.to_string().contains("at least 3 point pairs, got 2"),
            "{e}"
        );
        let line = [
            pair([0.0; 3]),
            pair([1.0, 1.0, 1.0]),
            pair([2.0, 2.0, 2.0 + 1e-6]),
        ];
        let e = horn(&line).expect_err("collinear");
        assert!(matches!(e, CtError::CollinearPoints { .. }), "{e}");
    }

    #[test]
    fn exact_exponential_matches_rodrigues_and_first_order_form() {
        let xi = Vector6::new(0.3, -0.2, 0.5, 1.0, 2.0, -3.0);
        let (r, t) = se3_exp(&xi);
        let w = Vector3::new(0.3, -0.2, 0.5);
        let rod = nalgebra::Rotation3::from_scaled_axis(w);
        assert!((r - rod.matrix()).norm() < 1e-12);
        assert!((r.transpose() * r - Matrix3::identity()).norm() < 1e-12);
        // The exponential's translation: integrate the screw motion numerically.
        let n = 100_000;
        let (dr, dt) = se3_exp(&(xi / n as f64));
        let (mut ra, mut ta) = (Matrix3::identity(), Vector3::zeros());
        for _ in 0..n {
            ta = dr * ta + dt;
            ra = dr * ra;
        }
        assert!(
            (ra - r).norm() < 1e-9 && (ta - t).norm() < 1e-7,
            "{t} vs {ta}"
        );
        // Small steps: eq. 13's first-order form agrees to second order.
        let xs = xi * 1e-4;
        let (rs, ts) = se3_exp(&xs);
        let ws = Vector3::new(xs[0], xs[1], xs[2]);
        let vs = Vector3::new(xs[3], xs[4], xs[5]);
        let k = skew(&ws);
        assert!((rs - (Matrix3::identity() + k)).norm() < 1e-7);
        assert!((ts - (Matrix3::identity() + 0.5 * k) * vs).norm() < 1e-11);
        // Tiny angles use the series without loss.
        let (r0, t0) = se3_exp(&Vector6::new(1e-9, 0.0, 0.0, 1.0, 0.0, 0.0));
        assert!((r0[(2, 1)] - 1e-9).abs() < 1e-18 && (t0.x - 1.0).abs() < 1e-15);
    }

    /// The Jacobian of eq. 17 against finite differences of Ψ(exp(ξ)·x), on an analytic field.
    #[test]
    fn jacobian_matches_finite_differences() {
        struct Sphere;
        impl DistanceField for Sphere {
            fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
                let c = [1.0, 2.0, 0.5];
                let d = [p[0] - c[0], p[1] - 2.0 * c[1] * 0.5, (p[2] - c[2]) * 2.0];
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                Some((n - 3.0, [d[0] / n, d[1] / n, 4.0 * (p[2] - c[2]) / n]))
            }
            fn truncation_mm(&self) -> f64 {
                100.0
            }
        }
        let p = [[2.0, 3.0, 1.0]];
        let (r, t) = (Matrix3::identity(), Vector3::zeros());
        let center = Vector3::new(0.5, 0.5, 0.5);
        let acc = evaluate(&p, &r, &t, &center, &Sphere, None, true);
        let psi = |xi: &Vector6<f64>| {
            let (dr, dt) = se3_exp(xi);
            let x = dr * (Vector3::from(p[0]) - center) + dt + center;
            Sphere
                .sample_with_gradient([x.x, x.y, x.z])
                .map(|s| s.0)
                .unwrap_or(0.0)
        };
        let d0 = psi(&Vector6::zeros());
        // g = J·Ψ: recover J.
        let j = acc.g / d0;
        for k in 0..6 {
            let mut e = Vector6::zeros();
            e[k] = 1e-6;
            let fd = (psi(&e) - psi(&-e)) / 2e-6;
            assert!((fd - j[k]).abs() < 1e-6, "component {k}: {fd} vs {}", j[k]);
        }
    }

    #[test]
    fn points_file() {
        let d = crate::ct::volume::tests::scratch("points");
        let p = d.join("POINTS.txt");
        std::fs::write(
            &p,
            "# ct xyz, build xyz\n1 2 3 4 5 6\n\n7,8,9, 10,11,12 # fin tip\n",
        )
        .expect("w");
        let pairs = read_points_file(&p).expect("read");
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[1].build, [10.0, 11.0, 12.0]);
        std::fs::write(&p, "1 2 3 4 5 6\n1 2 3 4 5\n").expect("w");
        let msg = read_points_file(&p).expect_err("5 numbers").to_string();
        assert!(
            msg.contains("POINTS.txt:2") && msg.contains("got 5"),
            "{msg}"
        );
        std::fs::write(&p, "1 2 3 4 5 x\n").expect("w");
        let msg = read_points_file(&p).expect_err("x").to_string();
        assert!(
            msg.contains("POINTS.txt:1") && msg.contains("\"x\""),
            "{msg}"
        );
    }

    #[test]
    fn stats_percentiles() {
        let d: Vec<f64> = (1..=100)
            .map(|i| if i % 2 == 0 { i as f64 } else { -(i as f64) })
            .collect();
        let s = Stats::of(&d);
        assert_eq!(s.mean_abs, 50.5);
        assert_eq!(s.max_abs, 100.0);
        assert!((s.median_abs - 50.0).abs() <= 1.0);
        assert!((s.p95_abs - 95.0).abs() <= 1.0);
    }
}
