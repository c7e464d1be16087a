//! Radial (Brown, k1/k2) lens distortion.

/// Lens distortion parameters that cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct DistortionError(pub String);

/// Radial lens distortion about `center`.
///
/// For an undistorted pixel (u, v): `n = ((u − cu)/focal_px, (v − cv)/focal_px)`,
/// `r² = |n|²`; the camera records it at
/// `(cu, cv) + focal_px·n·(1 + k1·r² + k2·r⁴)`.
/// The homography maps undistorted pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RadialDistortion {
    pub center: [f64; 2],
    pub focal_px: f64,
    pub k1: f64,
    pub k2: f64,
}

impl RadialDistortion {
    /// Undistorted pixel → where the camera records it.
    ///
    /// Plain evaluation of the model, also beyond the radius where the
    /// polynomial stops being monotonic (see [`RadialDistortion::max_r2`]).
    pub fn distort(&self, u: f64, v: f64) -> (f64, f64) {
        let [cu, cv] = self.center;
        let (du, dv) = (u - cu, v - cv);
        let r2 = (du * du + dv * dv) / (self.focal_px * self.focal_px);
        let k = 1.0 + r2 * (self.k1 + r2 * self.k2);
        (cu + du * k, cv + dv * k)
    }

    /// [`RadialDistortion::distort`] where the model is monotonic; `None` at or past the
    /// radius where the polynomial folds back ([`RadialDistortion::max_r2`]), where points far
    /// outside the image would land inside it.
    pub fn distort_within_fold(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let [cu, cv] = self.center;
        let (du, dv) = (u - cu, v - cv);
        let r2 = (du * du + dv * dv) / (self.focal_px * self.focal_px);
        // NaN r2 fails the comparison.
        (r2 < self.max_r2()).then(|| self.distort(u, v))
    }

    /// Recorded (distorted) pixel → undistorted pixel, to ~1e-9 px.
    ///
    /// Solves the radial equation `r·(1 + k1·r² + k2·r⁴) = r_d` by safeguarded
    /// Newton iteration on the branch where the model is monotonic. Returns
    /// `(NaN, NaN)` for a recorded point the model cannot produce (beyond the
    /// fold of a strongly barrel-distorting polynomial) or for invalid
    /// parameters.
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let [cu, cv] = self.center;
        let f = self.focal_px;
        let (dx, dy) = ((u - cu) / f, (v - cv) / f);
        let rd = (dx * dx + dy * dy).sqrt();
        // f ≤ 0 or NaN parameters give a non-finite rd or f.
        if !rd.is_finite() || f.is_nan() || f <= 0.0 {
            return (f64::NAN, f64::NAN);
        }
        if rd == 0.0 {
            return (u, v);
        }
        let g = |r: f64| {
            let r2 = r * r;
            r * (1.0 + r2 * (self.k1 + r2 * self.k2))
        };
        let dg = |r: f64| {
            let r2 = r * r;
            1.0 + r2 * (3.0 * self.k1 + 5.0 * self.k2 * r2)
        };
        // Bracket [lo, hi] with g(lo) <= rd <= g(hi) on the monotonic branch.
        let (mut lo, mut hi) = (0.0_f64, self.max_r2().sqrt());
        if hi.is_finite() {
            if g(hi) < rd {
                return (f64::NAN, f64::NAN);
            }
        } else {
            // g is increasing and unbounded here: grow until it passes rd.
            hi = rd.max(1.0);
            while g(hi) < rd {
                hi *= 2.0;
                if !hi.is_finite() {
                    return (f64::NAN, f64::NAN);
                }
            }
        }
        let mut r = rd.clamp(lo, hi);
        for _ in 0..100 {
            let e = g(r) - rd;
            if e > 0.0 {
                hi = r;
            } else {
                lo = r;
            }
            let d = dg(r);
            let mut next = r - e / d;
            // Fall back to bisection when Newton leaves the bracket.
            let in_bracket = next > lo && next < hi && d.is_finite() && d > 0.0;
            if !in_bracket {
                next = 0.5 * (lo + hi);
            }
            let step = (next - r).abs();
            r = next;
            if step <= 1e-15 * (1.0 + r) || hi - lo <= 1e-15 * (1.0 + r) {
                break;
            }
        }
        let s = r / rd;
        (cu + (u - cu) * s, cv + (v - cv) * s)
    }

    /// Largest normalised r² (= |n|²) up to which the model is monotonic,
    /// i.e. `d/dr [r·(1 + k1·r² + k2·r⁴)] > 0`; `f64::INFINITY` if always.
    ///
    /// Beyond it the polynomial folds back (points far outside the image would
    /// land inside it), so the rectifier treats such points as outside.
    pub fn max_r2(&self) -> f64 {
        // Smallest positive root t of 1 + 3·k1·t + 5·k2·t² = 0 (t = r²).
        let (a, b) = (5.0 * self.k2, 3.0 * self.k1);
        if a == 0.0 {
            return if b < 0.0 { -1.0 / b } else { f64::INFINITY };
        }
        let disc = b * b - 4.0 * a;
        if disc < 0.0 {
            return f64::INFINITY;
        }
        let sq = disc.sqrt();
        [(-b - sq) / (2.0 * a), (-b + sq) / (2.0 * a)]
            .into_iter()
            .filter(|t| *t > 0.0)
            .fold(f64::INFINITY, f64::min)
    }

    pub fn validate(&self) -> Result<(), DistortionError> {
        let all = [
            self.center[0],
            self.center[1],
            self.focal_px,
            self.k1,
            self.k2,
        ];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(DistortionError(format!("non-finite value in {self:?}")));
        }
        if self.focal_px <= 0.0 {
            return Err(DistortionError(format!(
                "focal_px must be > 0, got {}",
                self.focal_px
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens() -> RadialDistortion {
        RadialDistortion {
            center: [410.0, 290.0],
            focal_px: 700.0,
            k1: -0.12,
            k2: 0.03,
        }
    }

    #[test]
    fn distort_undistort_round_trip() {
        for d in [
            lens(),
            RadialDistortion {
                k1: 0.08,
                k2: 0.01,
                ..lens()
            },
            RadialDistortion {
                k1: -0.2,
                k2: 0.0,
                ..lens()
            },
        ] {
            for u in (-100..=900).step_by(37) {
                for v in (-80..=680).step_by(41) {
                    let (u, v) = (u as f64, v as f64);
                    let (du, dv) = d.distort(u, v);
                    let (uu, vu) = d.undistort(du, dv);
                    assert!(
                        (uu - u).abs() < 1e-6 && (vu - v).abs() < 1e-6,
                        "{d:?} {u},{v}"
                    );
                    let (ru, rv) = d.undistort(u, v);
                    if ru.is_nan() {
                        // Only a folding model has recorded points it cannot produce.
                        assert!(d.max_r2().is_finite() && d.k1 == -0.2, "{d:?} {u},{v}");
                        continue;
                    }
                    let (bu, bv) = d.distort(ru, rv);
                    assert!(
                        (bu - u).abs() < 1e-6 && (bv - v).abs() < 1e-6,
                        "{d:?} {u},{v}"
                    );
                }
            }
        }
        // Strong barrel folds back: past the fold undistort reports NaN.
        let fold = RadialDistortion {
            k1: -0.5,
            k2: 0.0,
            ..lens()
        };
        assert!(fold.max_r2().is_finite());
        assert!(fold.undistort(410.0 + 5000.0, 290.0).0.is_nan());
    }

    #[test]
    fn distort_within_fold_refuses_the_folded_side() {
        let fold = RadialDistortion {
            k1: -0.5,
            k2: 0.0,
            ..lens()
        };
        // Normalised r² at the fold: 1/(3·0.5); the radius in pixels is 700·√(2/3) ≈ 571.5.
        assert_eq!(
            fold.distort_within_fold(410.0 + 500.0, 290.0),
            Some(fold.distort(910.0, 290.0))
        );
        assert_eq!(fold.distort_within_fold(410.0 + 600.0, 290.0), None);
        assert_eq!(fold.distort_within_fold(f64::NAN, 290.0), None);
        // A model that never folds accepts any radius.
        assert!(lens().max_r2().is_infinite());
        assert!(lens().distort_within_fold(1e5, 0.0).is_some());
    }
}
