//! An exponential moving average of the weights (Polyak averaging), taken after every step.
//!
//! With a few hundred pictures an epoch is a dozen steps, and the weights after the last one
//! are a point on a noisy path: two epochs of the same validation figures can sit on either
//! side of a minimum, and which one a seed ends on is luck. The average of the recent steps'
//! weights sits nearer the middle, so it depends less on the seed and on the last batch. The
//! network has no batch statistics to recompute, so the averaged weights are used as they are:
//! for validation, for choosing the epoch, and in the file.
//!
//! The decay grows to its value over the first steps, `min(decay, (1 + t) / (10 + t))` at step
//! `t`, so the average forgets the random start within a few steps rather than `1 / (1 − decay)`.

use super::net::Net;
use candle_core::Tensor;

/// The running average of a network's weights.
pub struct Average {
    decay: f64,
    steps: usize,
    params: Vec<Tensor>,
}

impl Average {
    /// Starts at the network's weights.
    pub fn new(net: &Net, decay: f64) -> candle_core::Result<Average> {
        Ok(Average {
            decay,
            steps: 0,
            params: net
                .params
                .iter()
                .map(|t| Ok(t.copy()?.detach()))
                .collect::<candle_core::Result<_>>()?,
        })
    }

    /// The decay used at the next step.
    fn next_decay(&self) -> f64 {
        let t = self.steps as f64;
        self.decay.min((1.0 + t) / (10.0 + t))
    }

    /// Takes the network's weights after a step into the average.
    pub fn update(&mut self, net: &Net) -> candle_core::Result<()> {
        let d = self.next_decay();
        for (a, p) in self.params.iter_mut().zip(&net.params) {
            // New storage every step, detached: the average never joins the loss's graph and
            // never shares storage with a variable the optimiser writes in place.
            *a = (a.affine(d, 0.0)? + p.detach().affine(1.0 - d, 0.0)?)?.detach();
        }
        self.steps += 1;
        Ok(())
    }

    /// The network with the averaged weights.
    pub fn net(&self, like: &Net) -> Net {
        Net {
            arch: like.arch.clone(),
            classes: like.classes,
            params: self.params.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::learn::net::Arch;
    use crate::learn::rng::Rng;

    fn values(t: &Tensor) -> Vec<f32> {
        t.flatten_all().unwrap().to_vec1().unwrap()
    }

    #[test]
    fn the_average_follows_the_steps_with_the_decay_warming_up() {
        let arch = Arch::cnn(2, &[2], 0);
        let (net, vars) = Net::init(&arch, 2, &mut Rng::new(3)).unwrap();
        let start = values(&net.params[0]);
        let mut avg = Average::new(&net, 0.5).unwrap();
        // Steps: the weights set to 1, 2, ..., 10 (the optimiser writes the variables in place).
        let mut expected = start.clone();
        for k in 0..10 {
            let value = (k + 1) as f32;
            let ones = vars[0].as_tensor().ones_like().unwrap();
            vars[0]
                .set(&ones.affine(f64::from(value), 0.0).unwrap())
                .unwrap();
            avg.update(&net).unwrap();
            // Decays 0.1, 2/11, 0.25, ..., reaching the 0.5 asked for at the ninth step.
            let d = (0.5f32).min((1 + k) as f32 / (10 + k) as f32);
            assert_eq!(d == 0.5, k >= 8);
            for e in &mut expected {
                *e = *e * d + value * (1.0 - d);
            }
            let got = values(&avg.net(&net).params[0]);
            for (g, e) in got.iter().zip(&expected) {
                assert!((g - e).abs() < 1e-4, "step {k}: {g} against {e}");
            }
        }
        // The network's own weights are the last step's, untouched by the average.
        assert!(values(&net.params[0]).iter().all(|&v| v == 10.0));
        assert_ne!(values(&avg.net(&net).params[0]), values(&net.params[0]));
    }
}
