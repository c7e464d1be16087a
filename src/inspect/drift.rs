//! Drift: each part's metrics against a running baseline of its earlier layers (median and MAD
//! of the last `drift_window` layers that raised no flag on the part), so a slow change shows
//! before it becomes a crash. A layer half-way to a drift flag is held back: it joins the baseline
//! when a later layer is back near it (it was noise), and is dropped when the part is flagged
//! (it was the run-up of a drift), so a ramp cannot carry the baseline along nor widen it for the
//! next one.

use super::detect::robust;
use crate::build_dir::inspection::PartMetrics;
use std::collections::{BTreeMap, VecDeque};

/// The metrics followed, by name.
pub const METRICS: [&str; 4] = ["post_mean", "post_contrast", "fused_fraction", "pre_mean"];

/// The followed metrics of a part; the fused fraction only when the part is wide enough to judge
/// (it has a core), since a part a cell or two wide gains or loses half its fused cells as its
/// edges move across the grid.
pub fn values(m: &PartMetrics) -> [f64; 4] {
    [
        m.post_mean,
        m.post_contrast,
        if m.unfused.is_some() {
            m.fused_fraction
        } else {
            f64::NAN
        },
        m.pre_mean.unwrap_or(f64::NAN),
    ]
}

/// A metric that left its baseline.
#[derive(Clone, Debug, PartialEq)]
pub struct Drifted {
    pub part: i64,
    pub metric: &'static str,
    pub value: f64,
    pub median: f64,
    pub sigma: f64,
    pub z: f64,
    pub layers: usize,
}

#[derive(Clone, Debug, Default)]
pub struct Baseline {
    window: usize,
    min_layers: usize,
    /// A layer with a metric this many robust sigmas from the baseline does not enter it.
    admit_z: f64,
    history: BTreeMap<i64, VecDeque<[f64; 4]>>,
    /// Layers held back, per part.
    held: BTreeMap<i64, Vec<[f64; 4]>>,
}

impl Baseline {
    pub fn new(window: usize, min_layers: usize, admit_z: f64) -> Baseline {
        Baseline {
            window,
            min_layers,
            admit_z,
            history: BTreeMap::new(),
            held: BTreeMap::new(),
        }
    }

    /// The metrics of `m` that sit `z` robust sigmas or more from the part's baseline. The MAD is
    /// floored at 2% of the median so a metric that never moved does not alarm on rounding.
    pub fn check(&self, m: &PartMetrics, z_threshold: f64) -> Vec<Drifted> {
        let Some(history) = self.history.get(&m.part) else {
            return Vec::new();
        };
        let now = values(m);
        let mut out = Vec::new();
        for (k, name) in METRICS.iter().enumerate() {
            let Some((median, sigma)) = self.stats(history, k) else {
                continue;
            };
            if !now[k].is_finite() {
                continue;
            }
            let z = (now[k] - median) / sigma;
            if z.abs() >= z_threshold {
                out.push(Drifted {
                    part: m.part,
                    metric: name,
                    value: now[k],
                    median,
                    sigma,
                    z,
                    layers: history.len(),
                });
            }
        }
        out
    }

    /// The baseline of each followed metric of `part` as [`Baseline::check`] judges a layer
    /// against it: (median, robust sigma), `None` while it has fewer than `min_layers` layers.
    pub fn band(&self, part: i64) -> [Option<(f64, f64)>; 4] {
        let mut out = [None; 4];
        if let Some(history) = self.history.get(&part) {
            for (k, slot) in out.iter_mut().enumerate() {
                *slot = self.stats(history, k);
            }
        }
        out
    }

    fn stats(&self, history: &VecDeque<[f64; 4]>, k: usize) -> Option<(f64, f64)> {
        let past = history.iter().map(|v| v[k]).filter(|v| v.is_finite());
        if past.clone().count() < self.min_layers {
            return None;
        }
        let (median, _) = robust(past.clone(), 0.0);
        let (_, sigma) = robust(past, 0.02 * median.abs() + 1e-3);
        Some((median, sigma))
    }

    /// Adds a layer's metrics of a part: a layer that raised a flag on the part never, and drops
    /// the layers held back; one `admit_z` or more from the baseline is held back; any other
    /// joins, with the layers held back before it.
    pub fn push(&mut self, m: &PartMetrics, flagged: bool) {
        let off = !flagged && !self.check(m, self.admit_z).is_empty();
        let held = self.held.entry(m.part).or_default();
        if flagged {
            held.clear();
            return;
        }
        if off {
            if held.len() < self.window {
                held.push(values(m));
            }
            return;
        }
        let mut joining = std::mem::take(held);
        joining.push(values(m));
        let h = self.history.entry(m.part).or_default();
        h.extend(joining);
        while h.len() > self.window {
            h.pop_front();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metrics(part: i64, contrast: f64) -> PartMetrics {
        PartMetrics {
            part,
            post_mean: 100.0,
            post_contrast: contrast,
            fused_fraction: 0.97,
            unfused: Some(0.0),
            ..PartMetrics::default()
        }
    }

    #[test]
    fn a_step_away_from_a_noisy_baseline_is_drift_and_noise_is_not() {
        let mut b = Baseline::new(30, 10, 5.0);
        for i in 0..9 {
            b.push(&metrics(1, 30.0 + (i % 3) as f64 * 0.3), false);
        }
        assert!(b.check(&metrics(1, 5.0), 10.0).is_empty(), "warming up");
        for i in 0..20 {
            let m = metrics(1, 30.0 + (i % 3) as f64 * 0.3);
            assert!(b.check(&m, 10.0).is_empty());
            b.push(&m, false);
        }
        let d = b.check(&metrics(1, 18.0), 10.0);
        assert_eq!(d.len(), 1);
        assert_eq!(d[0].metric, "post_contrast");
        assert!(d[0].z < -10.0, "{d:?}");
        assert!(b.check(&metrics(2, 18.0), 10.0).is_empty(), "another part");
    }

    #[test]
    fn a_ramp_does_not_carry_the_baseline_along() {
        let mut b = Baseline::new(30, 10, 5.0);
        for i in 0..30 {
            b.push(&metrics(1, 30.0 + (i % 3) as f64 * 0.3), false);
        }
        // 1 grey level per layer: half-way to a flag after a few layers, flagged before 20.
        let flagged = (1..=20).find(|&k| {
            let m = metrics(1, 30.0 - f64::from(k));
            let drifted = !b.check(&m, 10.0).is_empty();
            b.push(&m, drifted);
            drifted
        });
        assert!(flagged.is_some_and(|k| k <= 10), "{flagged:?}");
        assert_eq!(b.held[&1], Vec::<[f64; 4]>::new(), "the run-up is dropped");
        // A lone outlier is noise: it joins once the next layer is back.
        let before = b.history[&1].len();
        b.push(&metrics(1, 26.0), false);
        assert_eq!(b.held[&1].len(), 1);
        b.push(&metrics(1, 30.3), false);
        assert!(b.held[&1].is_empty());
        assert_eq!(b.history[&1].len(), (before + 2).min(30));
        assert!(b.history[&1].iter().any(|v| v[1] == 26.0));
    }
}
