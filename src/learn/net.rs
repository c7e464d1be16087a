//! The network: a small fully convolutional classifier with a class map (CAM). Blocks of
//! conv 3x3 (padding 1) + bias + ReLU, a 2x2 max-pool after the blocks `pool_after` says, then a
//! 1x1 convolution to one map per class. A frame's logits pool the class maps, so the same
//! forward pass gives the frame's class and every tile's class (the heat map), and a view of any
//! size is scanned in one pass.
//!
//! The pooling is the log of the mean of the tiles' exponentiated scores (`cnn-cam-lme`): a
//! frame's odds for a class are the mean of its tiles' odds, so a few tiles that show a defect
//! clearly decide the frame, while the clean powder around them, which every class's frames
//! show, need not be called that defect. With the plain mean of the scores (`cnn-cam`, the
//! models written before) every clean tile of a defect frame had to lean to the defect, and a
//! good layer, nothing but clean tiles, had no evidence of its own: the defect-free class was
//! the one learnt last and worst. Models of either kind load and run.
//!
//! Weights start from the trainer's seeded generator (He normal), never candle's.

use super::rng::Rng;
use candle_core::{DType, Device, Tensor, Var};
use serde::{Deserialize, Serialize};

/// The architecture, recorded in the model file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Arch {
    /// `cnn-cam`.
    pub kind: String,
    pub in_channels: usize,
    /// Output channels of each conv block.
    pub channels: Vec<usize>,
    /// A 2x2 max-pool after block i.
    pub pool_after: Vec<bool>,
}

/// Class maps pooled by their mean (models written before the log-mean-exp pooling).
pub const ARCH_KIND_MEAN: &str = "cnn-cam";
/// Class maps pooled by the log of the mean of their exponentials: what training builds.
pub const ARCH_KIND: &str = "cnn-cam-lme";
/// The kinds this layerwise runs.
pub const ARCH_KINDS: [&str; 2] = [ARCH_KIND, ARCH_KIND_MEAN];

impl Arch {
    pub fn cnn(in_channels: usize, channels: &[usize], pools: usize) -> Arch {
        Arch {
            kind: ARCH_KIND.into(),
            in_channels,
            channels: channels.to_vec(),
            pool_after: (0..channels.len()).map(|i| i < pools).collect(),
        }
    }

    /// Input cells per class-map tile.
    pub fn stride(&self) -> usize {
        1 << self.pool_after.iter().filter(|p| **p).count()
    }

    /// Every tensor's name and shape for `classes` classes, in a fixed order.
    pub fn shapes(&self, classes: usize) -> Vec<(String, Vec<usize>)> {
        let mut out = Vec::new();
        let mut cin = self.in_channels;
        for (i, &c) in self.channels.iter().enumerate() {
            out.push((format!("conv{i}.weight"), vec![c, cin, 3, 3]));
            out.push((format!("conv{i}.bias"), vec![c]));
            cin = c;
        }
        out.push(("head.weight".into(), vec![classes, cin, 1, 1]));
        out.push(("head.bias".into(), vec![classes]));
        out
    }
}

/// The network's tensors in [`Arch::shapes`] order.
#[derive(Clone)]
pub struct Net {
    pub arch: Arch,
    pub classes: usize,
    pub params: Vec<Tensor>,
}

impl Net {
    /// Fresh weights: He normal for the convolutions, zero biases.
    pub fn init(
        arch: &Arch,
        classes: usize,
        rng: &mut Rng,
    ) -> candle_core::Result<(Net, Vec<Var>)> {
        let mut vars = Vec::new();
        for (name, shape) in arch.shapes(classes) {
            let n: usize = shape.iter().product();
            let data: Vec<f32> = if name.ends_with(".bias") {
                vec![0.0; n]
            } else {
                let fan_in: usize = shape[1..].iter().product();
                let gain = if name.starts_with("head") { 1.0 } else { 2.0 };
                let std = (gain / fan_in as f64).sqrt();
                (0..n).map(|_| (rng.normal() * std) as f32).collect()
            };
            vars.push(Var::from_tensor(&Tensor::from_vec(
                data,
                shape,
                &Device::Cpu,
            )?)?);
        }
        let params = vars.iter().map(|v| v.as_tensor().clone()).collect();
        Ok((
            Net {
                arch: arch.clone(),
                classes,
                params,
            },
            vars,
        ))
    }

    /// The class maps `[n, classes, h / stride, w / stride]` of inputs `[n, channels, h, w]`.
    pub fn cam(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mut x = x.clone();
        for (i, pool) in self.arch.pool_after.iter().enumerate() {
            let (w, b) = (&self.params[2 * i], &self.params[2 * i + 1]);
            x = x
                .conv2d(w, 1, 1, 1, 1)?
                .broadcast_add(&b.reshape((1, (), 1, 1))?)?
                .relu()?;
            if *pool {
                x = x.max_pool2d(2)?;
            }
        }
        let k = self.arch.channels.len();
        let (w, b) = (&self.params[2 * k], &self.params[2 * k + 1]);
        x.conv2d(w, 0, 1, 1, 1)?
            .broadcast_add(&b.reshape((1, (), 1, 1))?)
    }

    /// Frame logits `[n, classes]` of inputs `[n, channels, h, w]`.
    pub fn logits(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        self.pool(&self.cam(x)?)
    }

    /// Frame logits `[n, classes]` of class maps `[n, classes, h, w]`: `ln(mean(exp(map)))`
    /// (`cnn-cam-lme`) or `mean(map)` (`cnn-cam`).
    pub fn pool(&self, cam: &Tensor) -> candle_core::Result<Tensor> {
        if self.arch.kind == ARCH_KIND_MEAN {
            return cam.mean((2, 3));
        }
        let (_, _, h, w) = cam.dims4()?;
        cam.log_sum_exp((2, 3))? - ((h * w) as f64).ln()
    }
}

/// One input `[1, channels, rows, cols]` on the CPU.
pub fn tensor(input: &super::input::Input, channels: usize) -> candle_core::Result<Tensor> {
    Tensor::from_slice(
        &input.data,
        (1, channels, input.rows, input.cols),
        &Device::Cpu,
    )
}

/// A batch of inputs of one size.
pub fn batch(inputs: &[&super::input::Input], channels: usize) -> candle_core::Result<Tensor> {
    let (rows, cols) = (inputs[0].rows, inputs[0].cols);
    let data: Vec<f32> = inputs.iter().flat_map(|i| i.data.iter().copied()).collect();
    Tensor::from_vec(data, (inputs.len(), channels, rows, cols), &Device::Cpu)
}

/// Softmax over the classes of each row.
pub fn softmax(logits: &Tensor) -> candle_core::Result<Vec<Vec<f32>>> {
    candle_nn::ops::softmax(&logits.to_dtype(DType::F32)?, 1)?.to_vec2()
}

/// The per-tile class probabilities of one input: `[tile_rows][tile_cols][classes]`.
pub fn tile_probabilities(cam: &Tensor) -> candle_core::Result<Vec<Vec<Vec<f32>>>> {
    // [1, C, h, w] -> [h, w, C], softmax over C.
    let t = cam.squeeze(0)?.permute((1, 2, 0))?.contiguous()?;
    candle_nn::ops::softmax(&t, 2)?.to_vec3()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_few_clear_tiles_decide_the_frame_under_the_log_mean_exp_pooling() {
        let arch = Arch::cnn(2, &[4], 0);
        let (net, _) = Net::init(&arch, 2, &mut Rng::new(1)).unwrap();
        // 16 tiles: class 0 scores 1 everywhere; class 1 scores 0 but 6 on one tile.
        let mut maps = vec![1f32; 16];
        maps.extend((0..16).map(|i| if i == 5 { 6.0 } else { 0.0 }));
        let cam = Tensor::from_vec(maps, (1, 2, 4, 4), &Device::Cpu).unwrap();
        let lme: Vec<Vec<f32>> = net.pool(&cam).unwrap().to_vec2().unwrap();
        let expected = ((15.0 + 6f64.exp()) / 16.0).ln() as f32;
        assert!((lme[0][1] - expected).abs() < 1e-5, "{lme:?}");
        assert!(lme[0][1] > lme[0][0], "the one clear tile decides: {lme:?}");
        let mut mean = net.clone();
        mean.arch.kind = ARCH_KIND_MEAN.into();
        let m: Vec<Vec<f32>> = mean.pool(&cam).unwrap().to_vec2().unwrap();
        assert!(m[0][1] < m[0][0], "the mean drowns it: {m:?}");
    }

    #[test]
    fn the_class_map_has_the_stride_and_the_logits_are_its_mean() {
        let arch = Arch::cnn(2, &[4, 8], 2);
        assert_eq!(arch.stride(), 4);
        let (net, vars) = Net::init(&arch, 3, &mut Rng::new(1)).unwrap();
        assert_eq!(vars.len(), 6);
        let x = Tensor::ones((2, 2, 16, 12), DType::F32, &Device::Cpu).unwrap();
        let cam = net.cam(&x).unwrap();
        assert_eq!(cam.dims(), &[2, 3, 4, 3]);
        let l = net.logits(&x).unwrap();
        assert_eq!(l.dims(), &[2, 3]);
        // A constant map pools to its value, under either pooling.
        assert_eq!(arch.kind, ARCH_KIND);
        let flat = cam.ones_like().unwrap().affine(0.0, 2.5).unwrap();
        let mut mean = net.clone();
        mean.arch.kind = ARCH_KIND_MEAN.into();
        for n in [&net, &mean] {
            let v: Vec<Vec<f32>> = n.pool(&flat).unwrap().to_vec2().unwrap();
            assert!(v.iter().flatten().all(|x| (x - 2.5).abs() < 1e-5), "{v:?}");
        }
        let (again, _) = Net::init(&arch, 3, &mut Rng::new(1)).unwrap();
        let a: Vec<f32> = net.params[0].flatten_all().unwrap().to_vec1().unwrap();
        let b: Vec<f32> = again.params[0].flatten_all().unwrap().to_vec1().unwrap();
        assert_eq!(a, b);
    }
}
