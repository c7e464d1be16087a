//! Block cross-validation (`learn cv`): every picture held out once, by blocks of its sequence.
//!
//! One held-out tail (`learn train`'s split) says how a model does on a few frames at the end of
//! each sequence; with small classes (2 or 3 held-out frames) that figure moves by 30 to 50 points
//! with one frame. Here every sequence (class folders) or the run of layers (flaws, verdicts) is
//! cut into `folds` consecutive blocks. For fold k, block k of every sequence is held out, the
//! frames next to it on either side are left out (neighbouring frames of one recoat look alike:
//! 2 frames for sequences of 20 or more, else 1; patches: the layer on either side, and every
//! patch of a flaw that reaches the held-out layers), and a model is trained on the rest exactly
//! as `learn train` trains one (its epoch chosen on the tail of what it was given, never on the
//! held-out block; with `refit`, then trained afresh on all it was given for that many epochs, as
//! `learn train --refit` does). Each fold's model classifies its held-out block; the pooled
//! confusion matrix covers every picture once.

use super::data::{guard_frames, DataKind, Dataset, Item, Part};
use super::error::LearnError;
use super::file::{Model, TrainingInfo};
use super::metrics::Metrics;
use super::train::{train, Epoch, TrainOptions};
use serde::Serialize;
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::time::Instant;

/// Name of the rule in the report.
pub const RULE: &str = "sequence-blocks";

/// One fold's figures.
#[derive(Clone, Debug, Serialize)]
pub struct FoldReport {
    /// 1-based.
    pub fold: usize,
    /// Pictures the fold's model was given (its own training and selection parts).
    pub given: usize,
    pub held_out: usize,
    pub left_out: usize,
    pub epochs_run: usize,
    pub best_epoch: usize,
    pub stopped: String,
    /// With `refit`: the pictures the refit trained on (all the fold was given).
    pub refit_on: Option<usize>,
    pub seconds: f64,
    /// On the held-out block.
    pub metrics: Metrics,
}

/// `learn cv`'s result.
#[derive(Clone, Debug, Serialize)]
pub struct CrossValidation {
    pub rule: &'static str,
    pub folds: Vec<FoldReport>,
    /// Every fold's held-out block together: each picture classified once, by the model that
    /// did not see it.
    pub pooled: Metrics,
    /// Pictures never held out (sequences too short to be cut into blocks).
    pub never_held_out: usize,
    pub seed: u64,
    /// Each fold's model was refit on all it was given once its epoch was chosen.
    pub refit: bool,
}

/// The parts of fold `k` (0-based) of `folds`: block k held out, its neighbours left out.
pub fn fold_parts(data: &Dataset, folds: usize, k: usize) -> Vec<Part> {
    let mut parts = vec![Part::Train; data.items.len()];
    match data.kind {
        DataKind::ClassFolders => {
            for idx in data.sequences() {
                let n = idx.len();
                let (start, end) = (k * n / folds, (k + 1) * n / folds);
                if start == end {
                    continue;
                }
                let guard = guard_frames(n);
                for (pos, &i) in idx.iter().enumerate() {
                    if (start..end).contains(&pos) {
                        parts[i] = Part::Val;
                    } else if pos + guard >= start && pos < end + guard {
                        parts[i] = Part::Dropped;
                    }
                }
            }
        }
        DataKind::Flaws | DataKind::Verdicts => {
            let layers = data.layers();
            let n = layers.len();
            let (start, end) = (k * n / folds, (k + 1) * n / folds);
            if start == end {
                return parts;
            }
            let held: BTreeSet<i64> = layers[start..end].iter().copied().collect();
            let before = start.checked_sub(1).map(|s| layers[s]);
            let after = layers.get(end).copied();
            for (i, it) in data.items.iter().enumerate() {
                if held.contains(&it.order) {
                    parts[i] = Part::Val;
                } else if Some(it.order) == before || Some(it.order) == after {
                    parts[i] = Part::Dropped;
                }
            }
            data.leave_out_held_flaws(&mut parts);
        }
    }
    parts
}

/// The same data set with only `items`.
fn subset(data: &Dataset, items: Vec<Item>) -> Dataset {
    Dataset {
        items,
        ..data.clone()
    }
}

/// Trains one model per fold on everything but its block and its neighbours, and classifies
/// the block with it. `progress` gets the fold (1-based) and each epoch.
pub fn cross_validate(
    data: &Dataset,
    opts: &TrainOptions,
    folds: usize,
    mut progress: impl FnMut(usize, &Epoch),
    mut fold_done: impl FnMut(&FoldReport),
) -> Result<CrossValidation, LearnError> {
    let units = match data.kind {
        DataKind::ClassFolders => data.sequences().iter().map(Vec::len).max().unwrap_or(0),
        DataKind::Flaws | DataKind::Verdicts => data.layers().len(),
    };
    if folds < 2 || folds > units {
        let what = match data.kind {
            DataKind::ClassFolders => "frames in its longest sequence",
            _ => "layers",
        };
        return Err(LearnError::data(
            &data.root,
            format!("{folds} folds need 2 to {units} ({units} {what}); pass --folds in that range"),
        ));
    }
    let mut reports = Vec::with_capacity(folds);
    let mut pairs = Vec::new();
    let mut held_once = vec![false; data.items.len()];
    for k in 0..folds {
        let started = Instant::now();
        let parts = fold_parts(data, folds, k);
        let given: Vec<Item> = data
            .items
            .iter()
            .zip(&parts)
            .filter(|(_, p)| **p == Part::Train)
            .map(|(i, _)| i.clone())
            .collect();
        let held: Vec<usize> = (0..data.items.len())
            .filter(|&i| parts[i] == Part::Val)
            .collect();
        let train_set = subset(data, given);
        let (net, header) = train(&train_set, opts, |e| progress(k + 1, e))?;
        let model = Model {
            path: PathBuf::from(format!("fold {} of {folds}", k + 1)),
            header,
            net,
        };
        let items: Vec<&Item> = held.iter().map(|&i| &data.items[i]).collect();
        let fold_pairs = model.classify_items(data, &items)?;
        for &i in &held {
            held_once[i] = true;
        }
        let TrainingInfo {
            epochs_run,
            best_epoch,
            stopped,
            refit,
            ..
        } = model.header.training;
        let report = FoldReport {
            fold: k + 1,
            given: train_set.items.len(),
            held_out: held.len(),
            left_out: parts.iter().filter(|p| **p == Part::Dropped).count(),
            epochs_run,
            best_epoch,
            stopped,
            refit_on: refit.map(|r| r.counts.values().sum()),
            seconds: started.elapsed().as_secs_f64(),
            metrics: Metrics::new(&data.classes, &fold_pairs),
        };
        fold_done(&report);
        reports.push(report);
        pairs.extend(fold_pairs);
    }
    Ok(CrossValidation {
        rule: RULE,
        folds: reports,
        pooled: Metrics::new(&data.classes, &pairs),
        never_held_out: held_once.iter().filter(|h| !**h).count(),
        seed: opts.seed,
        refit: opts.refit,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn frames(per_class: &[(usize, &str, usize)]) -> Dataset {
        let mut items = Vec::new();
        for &(class, seq, n) in per_class {
            for order in 0..n {
                items.push(Item {
                    path: PathBuf::from(format!("{seq}{order:04}.png")),
                    rel: format!("{class}/{seq}{order:04}.png"),
                    class,
                    seq: seq.into(),
                    order: order as i64,
                    flaw: None,
                    window: None,
                });
            }
        }
        Dataset {
            kind: DataKind::ClassFolders,
            root: Path::new("data").into(),
            classes: vec!["a".into(), "b".into()],
            normal: "a".into(),
            items,
            pixel_mm: None,
        }
    }

    #[test]
    fn every_frame_is_held_out_once_with_its_neighbours_left_out() {
        let data = frames(&[(0, "s", 40), (1, "x_", 4), (1, "y_", 4)]);
        let folds = 4;
        let mut held = vec![0; data.items.len()];
        for k in 0..folds {
            let parts = fold_parts(&data, folds, k);
            for (i, p) in parts.iter().enumerate() {
                if *p == Part::Val {
                    held[i] += 1;
                }
            }
            // Sequence of 40: block k is frames 10k..10k+10, two guards either side.
            let s: Vec<Part> = parts[..40].to_vec();
            for (pos, p) in s.iter().enumerate() {
                let want = if (10 * k..10 * k + 10).contains(&pos) {
                    Part::Val
                } else if (10 * k).saturating_sub(2) <= pos && pos < 10 * k + 12 {
                    Part::Dropped
                } else {
                    Part::Train
                };
                assert_eq!(*p, want, "fold {k}, frame {pos}");
            }
            // Sequences of 4: one frame held out, one guard either side, the rest given.
            for seq in [&parts[40..44], &parts[44..48]] {
                assert_eq!(seq.iter().filter(|p| **p == Part::Val).count(), 1);
                assert!(seq.contains(&Part::Train), "fold {k}: {seq:?}");
            }
        }
        assert!(held.iter().all(|&h| h == 1), "{held:?}");
    }

    #[test]
    fn patches_leave_out_the_neighbouring_layers_and_the_held_out_flaws() {
        let mut items = Vec::new();
        for layer in 1..=6i64 {
            for (class, flaw) in [(0, None), (1, Some(7u32)), (1, Some(layer as u32))] {
                items.push(Item {
                    path: PathBuf::from(format!("p{layer}_{class}.png")),
                    rel: format!("p{layer}_{class}_{flaw:?}.png"),
                    class,
                    seq: String::new(),
                    order: layer,
                    flaw,
                    window: None,
                });
            }
        }
        let data = Dataset {
            kind: DataKind::Flaws,
            items,
            ..frames(&[])
        };
        let parts = fold_parts(&data, 3, 1);
        for (it, p) in data.items.iter().zip(&parts) {
            let want = match it.order {
                3 | 4 => Part::Val,
                2 | 5 => Part::Dropped,
                // Flaw 7 reaches layers 3-4: its patches elsewhere are left out.
                _ if it.flaw == Some(7) => Part::Dropped,
                _ => Part::Train,
            };
            assert_eq!(*p, want, "{}", it.rel);
        }
    }

    #[test]
    fn more_folds_than_frames_is_refused_with_the_range() {
        let data = frames(&[(0, "s", 3), (1, "t", 3)]);
        let err = cross_validate(&data, &TrainOptions::default(), 5, |_, _| {}, |_| {})
            .expect_err("refused");
        let text = err.to_string();
        assert!(text.contains("5 folds need 2 to 3"), "{text}");
        assert!(text.contains("--folds"), "{text}");
    }
}
