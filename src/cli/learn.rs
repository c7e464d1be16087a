//! `layerwise learn`: train a defect model on labelled pictures, evaluate it, run it on
//! pictures, show what a model file says about itself (docs/learning.md).

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use layerwise::learn::{self, Model, Part, TrainOptions};
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum LearnCommand {
    /// Train a classifier on labelled pictures and write one model file.
    Train(TrainArgs),
    /// Accuracy, per-class precision and recall and the confusion matrix on labelled pictures.
    Eval(EvalArgs),
    /// Class and probabilities per picture; with --heatmap, where the decision came from.
    Predict(PredictArgs),
    /// What a model file holds: classes, input, training data, validation metrics.
    Info(InfoArgs),
    /// The model side by side with the classical inspection on the same labelled frames: per
    /// class, frames found (false alarms for the normal class) by each.
    Compare(super::learn_compare::CompareArgs),
    /// Block cross-validation: every picture held out once, by blocks of its sequence (or of
    /// the layers), a model trained on the rest for each block; per-class recall pooled.
    Cv(CvArgs),
}

impl LearnCommand {
    pub fn run(self) -> Result<()> {
        match self {
            LearnCommand::Train(a) => a.run(),
            LearnCommand::Eval(a) => a.run(),
            LearnCommand::Predict(a) => a.run(),
            LearnCommand::Info(a) => a.run(),
            LearnCommand::Compare(a) => a.run(),
            LearnCommand::Cv(a) => a.run(),
        }
    }
}

#[derive(Args)]
pub struct TrainArgs {
    /// A folder with one subfolder of pictures per class, a `flaws` output folder (labels.json)
    /// or a build with operator verdicts (verdicts.jsonl).
    #[arg(long)]
    data: PathBuf,
    /// The model file to write (.safetensors).
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    training: TrainingArgs,
    /// Once the epoch is chosen on the held-out part, train afresh on every picture (both
    /// parts and the frames between them) for that many epochs and write that model; the file
    /// keeps the selection run's held-out metrics.
    #[arg(long)]
    refit: bool,
}

/// How a model is trained: `learn train` and each fold of `learn cv`.
#[derive(Args)]
pub struct TrainingArgs {
    /// Most epochs (training stops earlier after `--patience` epochs without progress).
    #[arg(long, default_value_t = 40)]
    epochs: usize,
    /// Share of every sequence (its last frames) or of the layers (the last ones) held out for
    /// validation (`learn cv`: of what each fold's model is given, to choose its epoch).
    #[arg(long, default_value_t = 0.2)]
    val_fraction: f64,
    /// Seed of the weights, batches and augmentations (the same seed, the same model).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Class folders: the defect-free class (default: one named No_Defect, normal, control, ok
    /// or good).
    #[arg(long)]
    normal: Option<String>,
    /// Frames: the side their centred square is resampled to, px.
    #[arg(long, default_value_t = 512)]
    frame_px: usize,
    /// Frames: pixels per cell of that square.
    #[arg(long, default_value_t = 4)]
    cell_px: usize,
    /// Frames of a known scale: mm per cell on the plate (lets the daemon run the model).
    #[arg(long)]
    cell_mm: Option<f64>,
    /// Stop after the epoch that would end past this many seconds.
    #[arg(long, default_value_t = 540.0)]
    max_seconds: f64,
    /// Pictures per batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Epochs without progress (a better epoch or a lower balanced validation loss) before stopping.
    #[arg(long, default_value_t = 6)]
    patience: usize,
    /// Output channels of the convolution blocks, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "8,16,32,64")]
    channels: Vec<usize>,
    /// Validate and keep the moving average of the weights, with this decay per step
    /// (0: the last step's weights).
    #[arg(long, default_value_t = 0.0)]
    average: f64,
    /// How the cells become the model's input: `equalised` (to first order), so a camera's tone
    /// curve does not change it; `flatfield`, grey levels (the models before December 2026).
    #[arg(long, value_enum, default_value_t = Recipe::Equalised)]
    normalisation: Recipe,
    /// What part of a camera frame the model reads: `centre-square`, the centred square (as
    /// every model before); `bed`, the frame without its dark margins (walls, a surround),
    /// stretched to the square, so a camera that sees past the bed gives the same input
    /// (docs/learning.md measures what it costs). Camera frames only: patches and verdicts are
    /// read as they are.
    #[arg(long, value_enum, default_value_t = FrameField::CentreSquare)]
    framing: FrameField,
}

/// `--framing` ([`learn::framing::Framing`]).
#[derive(Clone, Copy, Debug, ValueEnum)]
enum FrameField {
    CentreSquare,
    Bed,
}

/// `--normalisation` ([`learn::input::Normalisation`]).
#[derive(Clone, Copy, Debug, ValueEnum)]
enum Recipe {
    Equalised,
    Flatfield,
}

impl TrainingArgs {
    fn options(&self, refit: bool) -> Result<TrainOptions> {
        if !(0.0..0.9).contains(&self.val_fraction) {
            bail!(
                "--val-fraction {} must be at least 0 and below 0.9",
                self.val_fraction
            );
        }
        if self.channels.is_empty() || self.channels.iter().any(|&c| c == 0 || c > 512) {
            bail!("--channels must be 1 to 512 each");
        }
        if !(0.0..1.0).contains(&self.average) {
            bail!(
                "--average {} must be at least 0 (off) and below 1",
                self.average
            );
        }
        Ok(TrainOptions {
            epochs: self.epochs.max(1),
            val_fraction: self.val_fraction,
            seed: self.seed,
            frame_px: self.frame_px,
            cell_px: self.cell_px.max(1),
            cell_mm: self.cell_mm,
            normal: self.normal.clone(),
            channels: self.channels.clone(),
            batch: self.batch.max(1),
            learning_rate: 2e-3,
            patience: self.patience.max(1),
            max_seconds: self.max_seconds,
            refit,
            average: (self.average > 0.0).then_some(self.average),
            normalisation: match self.normalisation {
                Recipe::Equalised => learn::input::Normalisation::Equalised,
                Recipe::Flatfield => learn::input::Normalisation::Flatfield,
            },
            framing: match self.framing {
                FrameField::Bed => learn::framing::Framing::Bed,
                FrameField::CentreSquare => learn::framing::Framing::CentreSquare,
            },
        })
    }
}

/// What was read from `--data`: the folder, its kind, pictures and classes.
fn data_line(dir: &Path, data: &learn::Dataset) -> String {
    format!(
        "{} ({}): {} pictures in {} classes",
        dir.display(),
        data.kind.name(),
        data.items.len(),
        data.classes.len()
    )
}

/// The progress line of an epoch.
fn epoch_line(e: &learn::Epoch) -> String {
    let val = match (&e.val_loss, &e.val_balanced_loss, &e.val) {
        (Some(l), Some(b), Some(m)) => format!(
            "  val loss {l:.3}  balanced {b:.3}  val acc {:.3}  macro recall {:.3}",
            m.accuracy, m.macro_recall
        ),
        _ => String::new(),
    };
    let what = if e.refit { "refit epoch" } else { "epoch" };
    format!(
        "{what} {}/{}  loss {:.3}{val}  {:.1} s ({:.1} s preparing pictures)",
        e.epoch, e.epochs, e.loss, e.seconds, e.prepare_seconds
    )
}

impl TrainArgs {
    fn run(self) -> Result<()> {
        let opts = self.training.options(self.refit)?;
        let data = learn::source::open(&self.data, opts.normal.as_deref())?;
        let parts = data.split(opts.val_fraction);
        let count = |p: Part| parts.iter().filter(|x| **x == p).count();
        eprintln!(
            "{}; {} for training, {} for validation, {} left out between them",
            data_line(&self.data, &data),
            count(Part::Train),
            count(Part::Val),
            count(Part::Dropped)
        );
        let (net, mut header) = learn::train(&data, &opts, |e| eprintln!("{}", epoch_line(e)))?;
        Model::save(&self.out, &net, &mut header)?;
        let t = &header.training;
        eprintln!(
            "stopped: {} after {} epochs (best {} by the {}; cuts and stop counting {}), {:.0} s",
            t.stopped, t.epochs_run, t.best_epoch, t.selection, t.plateau, t.seconds
        );
        println!("validation ({}):", t.split.rule);
        print!("{}", header.validation);
        if let Some(d) = t.average {
            println!("{}", average_line(d));
        }
        if let Some(r) = &t.refit {
            println!("{}", refit_line(r));
        }
        println!(
            "wrote {} (weights {})",
            self.out.display(),
            &header.weights_sha256[..16]
        );
        Ok(())
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Which {
    /// Every labelled picture of the folder.
    All,
    /// The training part of the model's split rule.
    Train,
    /// The validation part of the model's split rule.
    Val,
}

#[derive(Args)]
pub struct EvalArgs {
    /// The model file.
    #[arg(long)]
    model: PathBuf,
    /// Labelled pictures, as for `learn train --data`.
    #[arg(long)]
    data: PathBuf,
    /// Which pictures: all (default), or the training or validation part of the split.
    #[arg(long, value_enum, default_value = "all")]
    part: Which,
    /// One JSON object: accuracy, macro_recall, classes, per_class {precision, recall, support,
    /// recall_ci95 (the recall's 95% Wilson interval)}, confusion (rows: true class, columns:
    /// predicted).
    #[arg(long)]
    json: bool,
}

impl EvalArgs {
    fn run(self) -> Result<()> {
        let model = Model::load(&self.model)?;
        let data = learn::source::open(&self.data, Some(&model.header.normal_class))
            .or_else(|_| learn::source::open(&self.data, None))?;
        let part = match self.part {
            Which::All => None,
            Which::Train => Some(Part::Train),
            Which::Val => Some(Part::Val),
        };
        let metrics = model.evaluate(&data, part)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&metrics)?);
        } else {
            print!("{metrics}");
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct PredictArgs {
    /// The model file.
    #[arg(long)]
    model: PathBuf,
    /// Pictures (JPEG, PNG, TIFF).
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Write where the decision came from: the picture tinted red by each tile's probability of
    /// a defect (PNG). With several pictures, one file each: OUT with the picture's name added.
    #[arg(long)]
    heatmap: Option<PathBuf>,
    /// One JSON object per picture.
    #[arg(long)]
    json: bool,
}

fn heatmap_name(out: &Path, image: &Path, several: bool) -> PathBuf {
    if !several {
        return out.to_path_buf();
    }
    let stem = out
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("heatmap");
    let name = image
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("image");
    out.with_file_name(format!("{stem}_{name}.png"))
}

impl PredictArgs {
    fn run(self) -> Result<()> {
        let model = Model::load(&self.model)?;
        let several = self.images.len() > 1;
        for path in &self.images {
            let (img, p) = model.predict_file(path)?;
            if self.json {
                let mut v = serde_json::to_value(&p)?;
                v["image"] = serde_json::Value::String(path.display().to_string());
                println!("{}", serde_json::to_string(&v)?);
            } else {
                let all: Vec<String> = p
                    .probabilities
                    .iter()
                    .map(|(c, v)| format!("{c} {v:.3}"))
                    .collect();
                println!(
                    "{}: {} ({:.3}); {}",
                    path.display(),
                    p.class,
                    p.probability,
                    all.join(", ")
                );
            }
            if let Some(out) = &self.heatmap {
                let file = heatmap_name(out, path, several);
                let mut png = std::io::Cursor::new(Vec::new());
                learn::heatmap(&model, &img, &p)
                    .write_to(&mut png, image::ImageFormat::Png)
                    .context("cannot encode the heat map")?;
                layerwise::fsutil::write_atomic(&file, &png.into_inner(), false)?;
            }
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct InfoArgs {
    /// The model file.
    #[arg(long)]
    model: PathBuf,
    /// The whole header as JSON.
    #[arg(long)]
    json: bool,
}

impl InfoArgs {
    fn run(self) -> Result<()> {
        let model = Model::load(&self.model)?;
        let h = &model.header;
        if self.json {
            println!("{}", serde_json::to_string_pretty(h)?);
            return Ok(());
        }
        let t = &h.training;
        println!(
            "{}: {} model format {}, {} classes {:?} (normal: {})",
            self.model.display(),
            h.arch.kind,
            h.version,
            h.classes.len(),
            h.classes,
            h.normal_class
        );
        println!(
            "input: {}x{} cells of {} px{}{}, {}",
            h.input.cells[1],
            h.input.cells[0],
            h.input.cell_px,
            h.input
                .frame_px
                .map(|f| format!(" (frames: {}, to {f} px a side)", h.input.framing.name()))
                .unwrap_or_default(),
            h.input
                .cell_mm
                .map(|m| format!(", {m} mm a cell"))
                .unwrap_or_default(),
            h.input.normalisation.name()
        );
        println!(
            "trained on {} ({}, data sha256 {}), split {} (validation {:?}), seed {}, {} epochs (best {} by the {}; cuts and stop counting {}; stopped: {}), {:.0} s",
            t.data.root, t.data.kind, &t.data.sha256[..16.min(t.data.sha256.len())], t.split.rule, t.split.val, t.seed, t.epochs_run, t.best_epoch, t.selection, t.plateau, t.stopped, t.seconds
        );
        print!("{}", h.validation);
        if let Some(d) = t.average {
            println!("{}", average_line(d));
        }
        if let Some(r) = &t.refit {
            println!("{}", refit_line(r));
        }
        Ok(())
    }
}

/// What a file of averaged weights says of them.
fn average_line(decay: f64) -> String {
    format!("the weights are the moving average of the steps' weights (decay {decay} a step)")
}

/// What a refit model's file says of the refit.
fn refit_line(r: &learn::RefitInfo) -> String {
    format!(
        "then refit on every picture ({} in all: {:?}) for {} epochs (learning rate cut after epochs {:?}), {:.0} s: the weights are the refit's, the figures above the selection run's",
        r.counts.values().sum::<usize>(),
        r.counts,
        r.epochs,
        r.lr_cuts,
        r.seconds
    )
}

#[derive(Args)]
pub struct CvArgs {
    /// Labelled pictures, as for `learn train --data`.
    #[arg(long)]
    data: PathBuf,
    /// Blocks every sequence (or the run of layers) is cut into; one model is trained per block.
    #[arg(long, default_value_t = 4)]
    folds: usize,
    /// One JSON object: rule, seed, folds (each: fold, given, held_out, left_out, epochs_run,
    /// best_epoch, stopped, refit_on, seconds, metrics) and pooled (accuracy, macro_recall, classes,
    /// per_class, confusion), never_held_out, refit.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    training: TrainingArgs,
    /// Each fold's model as `learn train --refit` makes it: its epoch chosen on the tail of
    /// what it is given, then trained afresh on all it is given (measures the refit on
    /// pictures it never saw).
    #[arg(long)]
    refit: bool,
}

impl CvArgs {
    fn run(self) -> Result<()> {
        let opts = self.training.options(self.refit)?;
        let data = learn::source::open(&self.data, opts.normal.as_deref())?;
        eprintln!(
            "{}, {} folds by {}{}",
            data_line(&self.data, &data),
            self.folds,
            learn::crossval::RULE,
            if self.refit {
                ", each fold's model refit"
            } else {
                ""
            }
        );
        let json = self.json;
        let cv = learn::cross_validate(
            &data,
            &opts,
            self.folds,
            |fold, e| eprintln!("fold {fold}: {}", epoch_line(e)),
            |f| {
                let refit = f
                    .refit_on
                    .map_or(String::new(), |n| format!(", refit on {n}"));
                let line = format!(
                    "fold {}/{}: given {}, held out {}, left out {}; epoch {} of {} ({}){refit}, {:.0} s: accuracy {:.3}, macro recall {:.3}",
                    f.fold, self.folds, f.given, f.held_out, f.left_out, f.best_epoch, f.epochs_run,
                    f.stopped, f.seconds, f.metrics.accuracy, f.metrics.macro_recall
                );
                if json {
                    eprintln!("{line}");
                } else {
                    println!("{line}");
                }
            },
        )?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&cv)?);
            return Ok(());
        }
        println!(
            "pooled over {} folds (every picture classified by the model that did not see it{}):",
            cv.folds.len(),
            match cv.never_held_out {
                0 => String::new(),
                n => format!("; {n} never held out"),
            }
        );
        print!("{}", cv.pooled);
        Ok(())
    }
}
