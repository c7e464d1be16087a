//! Training: class-balanced batches of augmented pictures, AdamW with a plain cross-entropy, and
//! the epoch chosen on the balanced validation accuracy, then the balanced validation loss
//! ([`super::select`]): the learning rate cut by 0.3 after 3 epochs without progress (neither a
//! better epoch nor a lower balanced loss), an early stop after `patience` such epochs, and a
//! time budget that ends training cleanly after the epoch that would overrun it. The weights of
//! the best epoch are the ones kept. Deterministic for a seed: one generator drives the weights,
//! the batches and every augmentation.

use super::augment::Augment;
use super::average::Average;
use super::data::{read_item, DataKind, Dataset, Part};
use super::error::LearnError;
use super::file::{DataInfo, Header, RefitInfo, SplitInfo, TrainingInfo, FORMAT};
use super::framing::Framing;
use super::input::{
    Gray, Input, InputSpec, Normalisation, CHANNELS, MAX_CELLS, MAX_CELL_PX, MAX_FRAME_PX,
};
use super::metrics::Metrics;
use super::net::{self, Arch, Net};
use super::rng::Rng;
use super::select::{self, Score, Selection, Step};
use candle_core::{Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use rayon::prelude::*;
use std::time::Instant;

/// `learn train`'s settings.
#[derive(Clone, Debug)]
pub struct TrainOptions {
    pub epochs: usize,
    pub val_fraction: f64,
    pub seed: u64,
    /// Frames: the side of the canonical square, px.
    pub frame_px: usize,
    /// Frames: pixels per cell of the canonical square.
    pub cell_px: usize,
    /// mm per cell to record for frames of a known scale.
    pub cell_mm: Option<f64>,
    /// The defect-free class (class folders).
    pub normal: Option<String>,
    pub channels: Vec<usize>,
    pub batch: usize,
    pub learning_rate: f64,
    pub patience: usize,
    pub max_seconds: f64,
    /// After the epoch is chosen, train afresh on every picture (the validation part and the
    /// guard frames too) for that many epochs, with the same learning-rate cuts, and keep that.
    pub refit: bool,
    /// Validate and keep the moving average of the weights with this decay per step
    /// ([`super::average`]), not the last step's weights.
    pub average: Option<f64>,
    /// How the cells become the input ([`Normalisation`]).
    pub normalisation: Normalisation,
    /// Frames: what part of the picture the model reads ([`Framing`]).
    pub framing: Framing,
}

impl Default for TrainOptions {
    fn default() -> Self {
        TrainOptions {
            epochs: 40,
            val_fraction: 0.2,
            seed: 1,
            frame_px: 512,
            cell_px: 4,
            cell_mm: None,
            normal: None,
            channels: vec![8, 16, 32, 64],
            batch: 16,
            learning_rate: 2e-3,
            patience: 6,
            max_seconds: 540.0,
            refit: false,
            average: None,
            normalisation: Normalisation::default(),
            framing: Framing::CentreSquare,
        }
    }
}

/// One epoch, for the progress line.
#[derive(Clone, Debug)]
pub struct Epoch {
    pub epoch: usize,
    pub epochs: usize,
    pub loss: f64,
    pub val_loss: Option<f64>,
    /// The mean over classes of each class's mean validation loss: the criterion.
    pub val_balanced_loss: Option<f64>,
    pub val: Option<Metrics>,
    pub seconds: f64,
    /// Of which preparing the augmented inputs.
    pub prepare_seconds: f64,
    /// An epoch of the refit on every picture (no validation part).
    pub refit: bool,
}

/// The refit's generator stream (`learn train --refit`).
const REFIT_STREAM: u64 = 0x7265_6669_7400;

/// What takes the steps: AdamW at the options' learning rate, and the moving average of the
/// weights when the options ask for it.
struct Steps {
    opt: AdamW,
    average: Option<Average>,
}

impl Steps {
    fn new(
        net: &Net,
        vars: Vec<candle_core::Var>,
        opts: &TrainOptions,
    ) -> Result<Steps, LearnError> {
        let opt = AdamW::new(
            vars,
            ParamsAdamW {
                lr: opts.learning_rate,
                weight_decay: 1e-4,
                ..ParamsAdamW::default()
            },
        )?;
        let average = opts.average.map(|d| Average::new(net, d)).transpose()?;
        Ok(Steps { opt, average })
    }

    fn cut_learning_rate(&mut self) {
        self.opt.set_learning_rate(self.opt.learning_rate() * 0.3);
    }

    /// The weights to validate and keep: the average's, or the last step's.
    fn weights(&self, net: &Net) -> Net {
        self.average
            .as_ref()
            .map_or_else(|| net.clone(), |a| a.net(net))
    }
}

/// What every epoch of a training uses: the decoded pictures and how they are fed.
struct Pass<'a> {
    data: &'a Dataset,
    spec: &'a InputSpec,
    augment: Augment,
    /// Canonical pictures by item (those the training uses).
    pictures: Vec<Option<Gray>>,
    batch: usize,
}

impl Pass<'_> {
    fn picture(&self, i: usize) -> &Gray {
        // Every item a part uses was decoded; the first one stands in otherwise.
        self.pictures[i]
            .as_ref()
            .or_else(|| self.pictures.iter().flatten().next())
            .expect("the training decodes its pictures before any pass")
    }

    /// The items of `idx` by class.
    fn by_class(&self, idx: &[usize]) -> Vec<Vec<usize>> {
        (0..self.data.classes.len())
            .map(|c| {
                idx.iter()
                    .copied()
                    .filter(|&i| self.data.items[i].class == c)
                    .collect()
            })
            .collect()
    }

    /// One epoch of `per_epoch` class-balanced draws (equal shares per class, each a fresh
    /// augmentation), each step taken into `average`; the mean loss and the seconds spent
    /// preparing the inputs.
    fn epoch(
        &self,
        net: &Net,
        steps: &mut Steps,
        by_class: &[Vec<usize>],
        per_epoch: usize,
        rng: &mut Rng,
        epoch: usize,
    ) -> Result<(f64, f64), LearnError> {
        let classes: Vec<&Vec<usize>> = by_class.iter().filter(|c| !c.is_empty()).collect();
        let mut draws: Vec<usize> = (0..per_epoch)
            .map(|k| {
                let class = classes[k % classes.len()];
                class[rng.below(class.len())]
            })
            .collect();
        rng.shuffle(&mut draws);
        let stream = rng.fork(epoch as u64);
        let mut loss_sum = 0.0;
        let mut prepare_seconds = 0.0;
        for (b, chunk) in draws.chunks(self.batch).enumerate() {
            let t1 = Instant::now();
            let inputs: Vec<Input> = chunk
                .par_iter()
                .enumerate()
                .map(|(k, &i)| {
                    let mut r = stream.fork((b * self.batch + k) as u64);
                    input_of(self.spec, &self.augment.apply(self.picture(i), &mut r))
                })
                .collect();
            prepare_seconds += t1.elapsed().as_secs_f64();
            let refs: Vec<&Input> = inputs.iter().collect();
            let x = net::batch(&refs, CHANNELS.len())?;
            let targets: Vec<u32> = chunk
                .iter()
                .map(|&i| self.data.items[i].class as u32)
                .collect();
            let y = Tensor::from_vec(targets, chunk.len(), &Device::Cpu)?;
            let loss = candle_nn::loss::cross_entropy(&net.logits(&x)?, &y)?;
            steps.opt.backward_step(&loss)?;
            if let Some(a) = &mut steps.average {
                a.update(net)?;
            }
            loss_sum += f64::from(loss.to_scalar::<f32>()?) * chunk.len() as f64;
        }
        Ok((loss_sum / draws.len() as f64, prepare_seconds))
    }
}

/// The input recipe and the network for a data set.
fn design(
    data: &Dataset,
    opts: &TrainOptions,
    first: &Gray,
) -> Result<(InputSpec, Arch), LearnError> {
    let blocks = opts.channels.len().max(1);
    let fit = |cells: usize| {
        (0..blocks.min(4))
            .rev()
            .find(|&p| cells >> p >= 4)
            .unwrap_or(0)
    };
    let (spec, pools) = match data.kind {
        DataKind::ClassFolders => {
            let cells = opts.frame_px / opts.cell_px.max(1);
            if cells < 4 {
                return Err(LearnError::data(
                    &data.root,
                    format!("--frame-px {} / --cell-px {} leaves {cells} cells a side; at least 4 are needed", opts.frame_px, opts.cell_px),
                ));
            }
            if opts.cell_px > MAX_CELL_PX || opts.frame_px > MAX_FRAME_PX || cells > MAX_CELLS {
                return Err(LearnError::data(
                    &data.root,
                    format!("--frame-px {} / --cell-px {}: a model takes frames of at most {MAX_FRAME_PX} px, cells of at most {MAX_CELL_PX} px and {MAX_CELLS} cells a side", opts.frame_px, opts.cell_px),
                ));
            }
            let pools = fit(cells);
            (
                InputSpec {
                    channels: CHANNELS.map(String::from).to_vec(),
                    cells: [cells, cells],
                    cell_px: opts.cell_px.max(1),
                    frame_px: Some(cells * opts.cell_px.max(1)),
                    cell_mm: opts.cell_mm,
                    map_stride_cells: 1 << pools,
                    normalisation: opts.normalisation,
                    framing: opts.framing,
                },
                pools,
            )
        }
        DataKind::Flaws | DataKind::Verdicts => {
            let side = first.width.min(first.height);
            let pools = fit(side).min(2);
            let stride = 1 << pools;
            let cells = side / stride * stride;
            if cells < 4 {
                return Err(LearnError::data(
                    &data.root,
                    format!("patches of {side} px are too small to learn from (4 px at least)"),
                ));
            }
            if cells > MAX_CELLS {
                return Err(LearnError::data(
                    &data.root,
                    format!("patches of {side} px are larger than a model takes ({MAX_CELLS} px at most)"),
                ));
            }
            (
                InputSpec {
                    channels: CHANNELS.map(String::from).to_vec(),
                    cells: [cells, cells],
                    cell_px: 1,
                    frame_px: None,
                    cell_mm: data.pixel_mm,
                    map_stride_cells: stride,
                    normalisation: opts.normalisation,
                    framing: Framing::CentreSquare,
                },
                pools,
            )
        }
    };
    if let Some(mm) = spec.cell_mm.filter(|mm| !(mm.is_finite() && *mm > 0.0)) {
        return Err(LearnError::data(
            &data.root,
            format!(
                "a cell of {mm} mm (--cell-mm, or the patches' pixel size): it must be positive"
            ),
        ));
    }
    // What the file's loader checks (Model::load), so that no model is written that would not
    // load again.
    spec.check(1 << pools).map_err(|(at, detail)| {
        LearnError::data(
            &data.root,
            format!("the model's input ({at}: {detail}) would not load"),
        )
    })?;
    Ok((spec, Arch::cnn(CHANNELS.len(), &opts.channels, pools)))
}

/// The model's input of a canonical picture.
pub fn input_of(spec: &InputSpec, canonical: &Gray) -> Input {
    spec.input(canonical)
}

/// Each input's loss and predicted class, in batches.
fn evaluate(
    net: &Net,
    inputs: &[(Input, usize)],
    batch: usize,
) -> Result<(Vec<f64>, Vec<usize>), LearnError> {
    let mut losses = Vec::with_capacity(inputs.len());
    let mut predicted = Vec::with_capacity(inputs.len());
    for chunk in inputs.chunks(batch.max(1)) {
        let refs: Vec<&Input> = chunk.iter().map(|(i, _)| i).collect();
        let x = net::batch(&refs, CHANNELS.len())?;
        let logits = net.logits(&x)?.to_vec2::<f32>()?;
        for (row, (_, class)) in logits.iter().zip(chunk) {
            losses.push(select::cross_entropy(row, *class));
            let best = (0..row.len()).fold(0, |b, k| if row[k] > row[b] { k } else { b });
            predicted.push(best);
        }
    }
    Ok((losses, predicted))
}

/// Trains a model on `data`; `progress` sees every epoch. Returns the network (the best
/// validation epoch's weights) and its header (without the weights' checksum).
pub fn train(
    data: &Dataset,
    opts: &TrainOptions,
    mut progress: impl FnMut(&Epoch),
) -> Result<(Net, Header), LearnError> {
    let started = Instant::now();
    let parts = data.split(opts.val_fraction);
    let train_idx: Vec<usize> = (0..data.items.len())
        .filter(|&i| parts[i] == Part::Train)
        .collect();
    let val_idx: Vec<usize> = (0..data.items.len())
        .filter(|&i| parts[i] == Part::Val)
        .collect();
    for (c, name) in data.classes.iter().enumerate() {
        if !train_idx.iter().any(|&i| data.items[i].class == c) {
            return Err(LearnError::data(
                &data.root,
                format!("class {name} has no training pictures"),
            ));
        }
    }
    let first = read_item(&data.items[train_idx[0]])?;
    let (spec, arch) = design(data, opts, &first)?;
    // The canonical pictures, decoded once (frames: 512 px squares, 1 MB each as f32): those of
    // both parts, and for a refit the guard frames between them too.
    let wanted: Vec<usize> = if opts.refit {
        (0..data.items.len()).collect()
    } else {
        train_idx.iter().chain(&val_idx).copied().collect()
    };
    let decoded: Vec<(usize, Gray)> = wanted
        .par_iter()
        .map(|&i| {
            let item = &data.items[i];
            let img = read_item(item)?;
            let canonical = spec.canonical(&img).ok_or_else(|| {
                LearnError::data(
                    &item.path,
                    format!(
                        "{}x{} px is smaller than the input of {:?} px",
                        img.width,
                        img.height,
                        spec.input_px()
                    ),
                )
            })?;
            Ok((i, canonical))
        })
        .collect::<Result<_, LearnError>>()?;
    let mut pictures: Vec<Option<Gray>> = vec![None; data.items.len()];
    for (i, g) in decoded {
        pictures[i] = Some(g);
    }
    let pass = Pass {
        data,
        spec: &spec,
        augment: Augment {
            isotropic: data.kind != DataKind::ClassFolders,
        },
        pictures,
        batch: opts.batch.max(1),
    };
    let val_inputs: Vec<(Input, usize)> = val_idx
        .par_iter()
        .map(|&i| (input_of(&spec, pass.picture(i)), data.items[i].class))
        .collect();
    let mut rng = Rng::new(opts.seed);
    let (mut net, vars) = Net::init(&arch, data.classes.len(), &mut rng)?;
    let mut steps = Steps::new(&net, vars, opts)?;
    let by_class = pass.by_class(&train_idx);
    let per_epoch = train_idx.len().max(opts.batch);
    let mut best: Option<(Vec<Tensor>, Option<Metrics>)> = None;
    let mut selection = Selection::new(opts.patience);
    let mut stopped = "epochs";
    let mut epochs_run = 0;
    let mut cuts = Vec::new();
    for epoch in 1..=opts.epochs.max(1) {
        let t0 = Instant::now();
        let (loss, prepare_seconds) =
            pass.epoch(&net, &mut steps, &by_class, per_epoch, &mut rng, epoch)?;
        epochs_run = epoch;
        let offered = steps.weights(&net);
        let (val_loss, val_balanced_loss, val) = if val_inputs.is_empty() {
            (None, None, None)
        } else {
            let (losses, predicted) = evaluate(&offered, &val_inputs, opts.batch)?;
            let truth: Vec<usize> = val_inputs.iter().map(|(_, c)| *c).collect();
            let pairs: Vec<(usize, usize)> = truth.iter().copied().zip(predicted).collect();
            (
                Some(losses.iter().sum::<f64>() / losses.len() as f64),
                Some(select::balanced_loss(&losses, &truth, data.classes.len())),
                Some(Metrics::new(&data.classes, &pairs)),
            )
        };
        let seconds = t0.elapsed().as_secs_f64();
        progress(&Epoch {
            epoch,
            epochs: opts.epochs,
            loss,
            val_loss,
            val_balanced_loss,
            val: val.clone(),
            seconds,
            prepare_seconds,
            refit: false,
        });
        // Without a validation part, the training loss (its draws are class-balanced too).
        let score = Score {
            balanced_accuracy: val.as_ref().map_or(0.0, |m| m.macro_recall),
            balanced_loss: val_balanced_loss.unwrap_or(loss),
        };
        match selection.offer(epoch, score) {
            Step::Best => {
                let copy = offered
                    .params
                    .iter()
                    .map(|t| t.copy())
                    .collect::<Result<_, _>>()?;
                best = Some((copy, val));
            }
            Step::NotBetter { cut, stop } => {
                if cut {
                    steps.cut_learning_rate();
                    cuts.push(epoch);
                }
                if stop {
                    stopped = "plateau";
                    break;
                }
            }
        }
        let elapsed = started.elapsed().as_secs_f64();
        if epoch < opts.epochs && elapsed + seconds > opts.max_seconds {
            stopped = "time budget";
            break;
        }
    }
    let ((params, val), (best_epoch, _)) = best
        .zip(selection.best())
        .ok_or_else(|| LearnError::data(&data.root, "no epoch ran"))?;
    net.params = params;
    let refit = if opts.refit {
        cuts.retain(|&e| e < best_epoch);
        let all: Vec<usize> = (0..data.items.len()).collect();
        let t0 = Instant::now();
        // The selection run's initial weights (the same seed), then draws of its own stream.
        let mut rng = Rng::new(opts.seed);
        let (fresh, vars) = Net::init(&arch, data.classes.len(), &mut rng)?;
        let mut rng = rng.fork(REFIT_STREAM);
        let mut steps = Steps::new(&fresh, vars, opts)?;
        let by_class = pass.by_class(&all);
        for epoch in 1..=best_epoch {
            let t1 = Instant::now();
            let (loss, prepare_seconds) =
                pass.epoch(&fresh, &mut steps, &by_class, per_epoch, &mut rng, epoch)?;
            progress(&Epoch {
                epoch,
                epochs: best_epoch,
                loss,
                val_loss: None,
                val_balanced_loss: None,
                val: None,
                seconds: t1.elapsed().as_secs_f64(),
                prepare_seconds,
                refit: true,
            });
            if cuts.contains(&epoch) {
                steps.cut_learning_rate();
            }
        }
        net = steps.weights(&fresh);
        Some(RefitInfo {
            epochs: best_epoch,
            lr_cuts: cuts,
            counts: data.counts(None),
            seconds: t0.elapsed().as_secs_f64(),
        })
    } else {
        None
    };
    let split = SplitInfo {
        rule: data.rule().into(),
        val_fraction: opts.val_fraction,
        train: data.counts(Some((&parts, Part::Train))),
        val: data.counts(Some((&parts, Part::Val))),
        dropped: parts.iter().filter(|p| **p == Part::Dropped).count(),
    };
    let augmentation = pass.augment.describe();
    drop(pass);
    let header = Header {
        format: FORMAT.into(),
        version: super::file::version_for(&spec),
        arch,
        classes: data.classes.clone(),
        normal_class: data.normal.clone(),
        input: spec,
        training: TrainingInfo {
            data: DataInfo {
                kind: data.kind.name().into(),
                root: data.root.display().to_string(),
                counts: data.counts(None),
                sha256: data.hash()?,
            },
            split,
            seed: opts.seed,
            epochs: opts.epochs,
            epochs_run,
            best_epoch,
            selection: select::CRITERION.into(),
            plateau: select::PLATEAU.into(),
            average: opts.average,
            stopped: stopped.into(),
            seconds: started.elapsed().as_secs_f64(),
            augmentation,
            layerwise: env!("CARGO_PKG_VERSION").into(),
            candle: "0.11.1".into(),
            refit,
        },
        validation: val.unwrap_or_else(|| Metrics::new(&data.classes, &[])),
        weights_sha256: String::new(),
    };
    Ok((net, header))
}
