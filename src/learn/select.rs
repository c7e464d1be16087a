//! Which epoch to keep and when to stop, on a class-balanced criterion. The training draws are
//! class-balanced, so the epoch is chosen the same way: first by the *balanced accuracy* on the
//! validation part (the mean of the classes' recalls, what "every class's recall" asks for),
//! then, between epochs of the same balanced accuracy, by the *balanced validation loss*, the
//! mean over classes of each class's mean cross-entropy. A plain mean over the validation
//! pictures lets the large classes outvote a small one (3 good frames among 55 weigh 5 %), so an
//! epoch that gets every large-class picture a little more right and every picture of a small
//! class wrong would win; here each class weighs the same. The balanced loss alone is not enough
//! either: a class of 2 validation frames makes it the loss of one frame, and an epoch that
//! makes one confidently wrong frame less wrong while others turn wrong would win.
//!
//! The learning-rate cut and the early stop count epochs without *progress*: neither a better
//! criterion nor a balanced loss lower than every epoch before by `MIN_GAIN` or more. On a small
//! validation part an early epoch can reach a balanced accuracy that later ones only equal by
//! luck (2 frames of a class give it three values); counting from that epoch alone would cut and
//! stop while the loss is still falling, and freeze the model at the lucky epoch. Training goes on
//! while either measure improves; which epoch is kept is still decided by the criterion alone.

/// The criterion's name, recorded in the model file (`training.selection`).
pub const CRITERION: &str = "balanced validation accuracy, then the balanced validation loss (mean over classes of each class's mean cross-entropy)";
/// What model files written before the criterion was recorded were selected on.
pub const OLD_CRITERION: &str = "mean validation loss";
/// What the learning-rate cuts and the early stop count, recorded in the model file
/// (`training.plateau`).
pub const PLATEAU: &str =
    "epochs without progress (a better epoch, or a balanced validation loss lower than any before)";
/// What they counted in model files written before `training.plateau` was recorded.
pub const OLD_PLATEAU: &str = "epochs without a better epoch";
/// An epoch's balanced loss must beat the best by this much to count as better.
const MIN_GAIN: f64 = 1e-3;
/// Balanced accuracies closer than this are the same.
const SAME: f64 = 1e-9;
/// Epochs without progress before each learning-rate cut.
pub const CUT_AFTER: usize = 3;

/// An epoch's criterion.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Score {
    /// The mean of the classes' recalls (0 without a validation part).
    pub balanced_accuracy: f64,
    /// The mean over classes of each class's mean loss (the training loss without a validation
    /// part).
    pub balanced_loss: f64,
}

impl Score {
    /// A higher balanced accuracy, or the same and a lower balanced loss.
    pub fn beats(&self, best: &Score) -> bool {
        if self.balanced_accuracy > best.balanced_accuracy + SAME {
            return true;
        }
        self.balanced_accuracy >= best.balanced_accuracy - SAME
            && self.balanced_loss < best.balanced_loss - MIN_GAIN
    }
}

/// Each picture's cross-entropy, `logsumexp(logits) - logits[class]`, from one row of logits.
pub fn cross_entropy(logits: &[f32], class: usize) -> f64 {
    let max = logits
        .iter()
        .fold(f64::NEG_INFINITY, |m, &v| m.max(f64::from(v)));
    let sum: f64 = logits.iter().map(|&v| (f64::from(v) - max).exp()).sum();
    max + sum.ln() - f64::from(logits[class])
}

/// The mean over the classes that have pictures of each class's mean loss.
pub fn balanced_loss(losses: &[f64], classes: &[usize], n_classes: usize) -> f64 {
    let mut sum = vec![0.0; n_classes];
    let mut count = vec![0usize; n_classes];
    for (&l, &c) in losses.iter().zip(classes) {
        sum[c] += l;
        count[c] += 1;
    }
    let means: Vec<f64> = sum
        .iter()
        .zip(&count)
        .filter(|(_, &n)| n > 0)
        .map(|(s, &n)| s / n as f64)
        .collect();
    means.iter().sum::<f64>() / means.len().max(1) as f64
}

/// What an epoch's criterion means for the training.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// The best so far: keep its weights.
    Best,
    /// Not better; `cut`: lower the learning rate now; `stop`: the plateau is long enough.
    /// Both false while the balanced loss still falls.
    NotBetter { cut: bool, stop: bool },
}

/// The best epoch so far, the lowest balanced loss so far and the epochs without progress.
#[derive(Clone, Debug)]
pub struct Selection {
    patience: usize,
    best: Option<(Score, usize)>,
    lowest_loss: f64,
    since_progress: usize,
}

impl Selection {
    pub fn new(patience: usize) -> Selection {
        Selection {
            patience: patience.max(1),
            best: None,
            lowest_loss: f64::INFINITY,
            since_progress: 0,
        }
    }

    /// Takes epoch `epoch`'s criterion.
    pub fn offer(&mut self, epoch: usize, score: Score) -> Step {
        let lower_loss = score.balanced_loss < self.lowest_loss - MIN_GAIN;
        self.lowest_loss = self.lowest_loss.min(score.balanced_loss);
        let best = self.best.is_none_or(|(b, _)| score.beats(&b));
        if best || lower_loss {
            self.since_progress = 0;
        } else {
            self.since_progress += 1;
        }
        if best {
            self.best = Some((score, epoch));
            return Step::Best;
        }
        Step::NotBetter {
            cut: self.since_progress > 0 && self.since_progress.is_multiple_of(CUT_AFTER),
            stop: self.since_progress >= self.patience,
        }
    }

    /// The best epoch and its criterion.
    pub fn best(&self) -> Option<(usize, Score)> {
        self.best.map(|(c, e)| (e, c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(balanced_accuracy: f64, balanced_loss: f64) -> Score {
        Score {
            balanced_accuracy,
            balanced_loss,
        }
    }

    /// Which of `steps` cut the learning rate.
    fn cuts(steps: &[Step]) -> Vec<bool> {
        steps
            .iter()
            .map(|s| matches!(s, Step::NotBetter { cut: true, .. }))
            .collect()
    }

    #[test]
    fn an_epoch_better_on_the_plain_mean_but_worse_for_a_small_class_is_not_kept() {
        // 50 pictures of a large class, 3 of a small one.
        let classes: Vec<usize> = (0..53).map(|i| usize::from(i >= 50)).collect();
        // Epoch 1: every picture right (p ≈ 0.7).
        let first: Vec<f64> = classes
            .iter()
            .map(|&c| if c == 0 { 0.30 } else { 0.40 })
            .collect();
        // Epoch 2: the large class more right, the small one wrong (p ≈ 0.1).
        let second: Vec<f64> = classes
            .iter()
            .map(|&c| if c == 0 { 0.10 } else { 2.30 })
            .collect();
        let mean = |l: &[f64]| l.iter().sum::<f64>() / l.len() as f64;
        assert!(
            mean(&second) < mean(&first),
            "the old rule would keep epoch 2"
        );
        assert!((balanced_loss(&first, &classes, 2) - 0.35).abs() < 1e-12);
        assert!((balanced_loss(&second, &classes, 2) - 1.20).abs() < 1e-12);

        let mut s = Selection::new(6);
        let one = score(1.0, balanced_loss(&first, &classes, 2));
        assert_eq!(s.offer(1, one), Step::Best);
        let two = score(0.5, balanced_loss(&second, &classes, 2));
        assert_eq!(
            s.offer(2, two),
            Step::NotBetter {
                cut: false,
                stop: false
            }
        );
        assert_eq!(s.best(), Some((1, one)));
    }

    #[test]
    fn the_balanced_accuracy_decides_and_the_balanced_loss_breaks_ties() {
        // A class of 2 frames: one confidently wrong frame made less wrong lowers the balanced
        // loss, while another class loses a frame: not better.
        assert!(!score(0.81, 0.34).beats(&score(0.90, 0.45)));
        assert!(score(0.90, 0.45).beats(&score(0.81, 0.34)));
        assert!(score(0.90, 0.40).beats(&score(0.90, 0.45)));
        assert!(!score(0.90, 0.4495).beats(&score(0.90, 0.45)));
        assert!(!score(0.90, 0.50).beats(&score(0.90, 0.45)));
    }

    #[test]
    fn the_plateau_cuts_every_third_epoch_and_stops_at_the_patience() {
        let mut s = Selection::new(6);
        assert_eq!(s.offer(1, score(0.5, 1.0)), Step::Best);
        // Better by less than the minimum gain: not better.
        let steps: Vec<Step> = (2..=7).map(|e| s.offer(e, score(0.5, 0.9995))).collect();
        assert_eq!(cuts(&steps), [false, false, true, false, false, true]);
        assert_eq!(
            steps[5],
            Step::NotBetter {
                cut: true,
                stop: true
            }
        );
        assert_eq!(s.best(), Some((1, score(0.5, 1.0))));
        assert_eq!(s.offer(8, score(0.5, 0.5)), Step::Best);
    }

    #[test]
    fn a_falling_balanced_loss_holds_off_the_cut_and_the_stop_but_not_the_choice() {
        let mut s = Selection::new(6);
        // A lucky early epoch: every validation frame right, by a small margin.
        let lucky = score(1.0, 0.60);
        assert_eq!(s.offer(1, lucky), Step::Best);
        // Nine epochs of a lower balanced accuracy and a falling loss: training goes on.
        let on = Step::NotBetter {
            cut: false,
            stop: false,
        };
        for e in 2..=10 {
            assert_eq!(
                s.offer(e, score(0.9, 0.60 - 0.05 * e as f64)),
                on,
                "epoch {e}"
            );
        }
        assert_eq!(s.best(), Some((1, lucky)));
        // Then the loss stops falling: cuts at 3 and 6 epochs without progress, the stop at 6.
        let steps: Vec<Step> = (11..=16).map(|e| s.offer(e, score(0.9, 0.2))).collect();
        assert_eq!(cuts(&steps), [false, false, true, false, false, true]);
        assert!(matches!(steps[5], Step::NotBetter { stop: true, .. }));
        // An epoch that equals the lucky one's accuracy with a lower loss is kept.
        assert_eq!(s.offer(17, score(1.0, 0.3)), Step::Best);
        assert_eq!(s.best(), Some((17, score(1.0, 0.3))));
    }

    #[test]
    fn cross_entropy_of_logits() {
        let l = cross_entropy(&[0.0, 0.0], 1);
        assert!((l - 2f64.ln()).abs() < 1e-12);
        // Large logits do not overflow.
        assert!(cross_entropy(&[1000.0, 0.0], 0) < 1e-9);
        assert!((cross_entropy(&[1000.0, 0.0], 1) - 1000.0).abs() < 1e-9);
        // A class without pictures does not count.
        assert_eq!(balanced_loss(&[1.0, 3.0], &[0, 0], 3), 2.0);
    }
}
