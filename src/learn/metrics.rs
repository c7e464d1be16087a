//! Accuracy, per-class precision and recall, the balanced accuracy (macro recall) and the
//! confusion matrix (rows = true class, columns = predicted), as `learn eval` prints them and
//! the model file records them. Each class's recall comes with its 95 % Wilson score interval:
//! on a class of 8 held-out frames, 7 right is anywhere from 0.53 to 0.98, and a quality
//! department has to see that before it reads 0.875.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassMetrics {
    pub precision: f64,
    pub recall: f64,
    pub support: usize,
    /// The recall's 95 % Wilson score interval, `[low, high]`; absent without pictures of the
    /// class, and in files written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recall_ci95: Option<[f64; 2]>,
}

/// The 95 % Wilson score interval of a proportion of `k` in `n` (`None` for `n = 0`). Unlike
/// the normal approximation it stays inside [0, 1] and is not empty at 0 or `n` of `n`.
pub fn wilson95(k: usize, n: usize) -> Option<[f64; 2]> {
    if n == 0 {
        return None;
    }
    const Z: f64 = 1.959_963_984_540_054;
    let (k, n) = (k.min(n) as f64, n as f64);
    let p = k / n;
    let z2 = Z * Z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = Z / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    // At 0 and at n of n the bound is exactly 0 or 1; rounding would leave it a hair inside.
    let low = if k == 0.0 {
        0.0
    } else {
        (centre - half).max(0.0)
    };
    let high = if k == n {
        1.0
    } else {
        (centre + half).min(1.0)
    };
    Some([low, high])
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metrics {
    pub accuracy: f64,
    /// The mean of the per-class recalls (classes with examples), the balanced accuracy.
    pub macro_recall: f64,
    pub classes: Vec<String>,
    pub per_class: BTreeMap<String, ClassMetrics>,
    /// `confusion[true][predicted]`, classes in `classes` order.
    pub confusion: Vec<Vec<usize>>,
}

impl Metrics {
    /// From (true, predicted) class indices.
    pub fn new(classes: &[String], pairs: &[(usize, usize)]) -> Metrics {
        let n = classes.len();
        let mut confusion = vec![vec![0usize; n]; n];
        for &(t, p) in pairs {
            confusion[t][p] += 1;
        }
        let total = pairs.len();
        let right: usize = (0..n).map(|i| confusion[i][i]).sum();
        let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
        let mut per_class = BTreeMap::new();
        let mut recalls = Vec::new();
        for (i, name) in classes.iter().enumerate() {
            let support: usize = confusion[i].iter().sum();
            let predicted: usize = (0..n).map(|t| confusion[t][i]).sum();
            let recall = ratio(confusion[i][i], support);
            if support > 0 {
                recalls.push(recall);
            }
            per_class.insert(
                name.clone(),
                ClassMetrics {
                    precision: ratio(confusion[i][i], predicted),
                    recall,
                    support,
                    recall_ci95: wilson95(confusion[i][i], support),
                },
            );
        }
        Metrics {
            accuracy: ratio(right, total),
            macro_recall: if recalls.is_empty() {
                0.0
            } else {
                recalls.iter().sum::<f64>() / recalls.len() as f64
            },
            classes: classes.to_vec(),
            per_class,
            confusion,
        }
    }
}

impl fmt::Display for Metrics {
    /// A per-class table, then the confusion matrix.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let total: usize = self.confusion.iter().flatten().sum();
        writeln!(
            f,
            "{total} images: accuracy {:.3}, macro recall {:.3}",
            self.accuracy, self.macro_recall
        )?;
        let width = self
            .classes
            .iter()
            .map(|c| c.len())
            .max()
            .unwrap_or(5)
            .max(5);
        writeln!(
            f,
            "{:width$}  precision  recall  support  recall, 95% interval",
            "class"
        )?;
        for (i, c) in self.classes.iter().enumerate() {
            let m = &self.per_class[c];
            // From the confusion matrix, so files from before the interval was recorded show it.
            let right = self.confusion.get(i).and_then(|r| r.get(i)).copied();
            let interval = match right.and_then(|k| wilson95(k, m.support)) {
                Some([low, high]) => format!("{low:.2}-{high:.2}"),
                None => "-".into(),
            };
            writeln!(
                f,
                "{c:width$}  {:9.3}  {:6.3}  {:7}  {interval}",
                m.precision, m.recall, m.support
            )?;
        }
        writeln!(
            f,
            "confusion (rows: true class, columns: predicted, in the order above):"
        )?;
        for (c, row) in self.classes.iter().zip(&self.confusion) {
            let cells: Vec<String> = row.iter().map(|v| format!("{v:4}")).collect();
            writeln!(f, "{c:width$} {}", cells.join(""))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recall_precision_and_confusion() {
        let classes = vec!["a".to_string(), "b".to_string()];
        let m = Metrics::new(&classes, &[(0, 0), (0, 1), (1, 1), (1, 1)]);
        assert_eq!(m.confusion, vec![vec![1, 1], vec![0, 2]]);
        assert_eq!(m.accuracy, 0.75);
        assert_eq!(m.per_class["a"].recall, 0.5);
        assert!((m.per_class["b"].precision - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(m.macro_recall, 0.75);
        assert!(m.to_string().contains("confusion"));
        // 1 of 2 right: the Wilson interval of 1 in 2.
        let [low, high] = m.per_class["a"].recall_ci95.unwrap();
        assert!((low - 0.0945).abs() < 1e-3 && (high - 0.9055).abs() < 1e-3);
        assert!(m.to_string().contains("0.09-0.91"), "{m}");
    }

    #[test]
    fn wilson_intervals_match_the_published_values() {
        // Newcombe (1998), Table I: 81 of 263 gives 0.2553-0.3662; 15 of 148 gives
        // 0.0624-0.1605; 0 of 20 gives 0-0.1611; 1 of 29 gives 0.0061-0.1718.
        let cases = [
            (81, 263, 0.2553, 0.3662),
            (15, 148, 0.0624, 0.1605),
            (0, 20, 0.0, 0.1611),
            (1, 29, 0.0061, 0.1718),
        ];
        for (k, n, low, high) in cases {
            let [l, h] = wilson95(k, n).unwrap();
            assert!(
                (l - low).abs() < 1e-4 && (h - high).abs() < 1e-4,
                "{k}/{n}: {l} {h}"
            );
        }
        // All right is not certainty: 8 of 8 is 0.68-1.00, 7 of 8 is 0.53-0.98.
        let [l, h] = wilson95(8, 8).unwrap();
        assert!((l - 0.6756).abs() < 1e-3 && h == 1.0);
        let [l, h] = wilson95(7, 8).unwrap();
        assert!(
            (l - 0.5291).abs() < 1e-3 && (h - 0.9776).abs() < 1e-3,
            "{l} {h}"
        );
        assert_eq!(wilson95(0, 0), None);
        // Every one right or none right: the bound is the recall itself, for every n.
        for n in 1..=300 {
            assert_eq!(wilson95(n, n).unwrap()[1], 1.0, "{n} of {n}");
            assert_eq!(wilson95(0, n).unwrap()[0], 0.0, "0 of {n}");
        }
    }

    #[test]
    fn files_without_the_interval_load_and_show_it() {
        let old = r#"{"accuracy":0.5,"macro_recall":0.5,"classes":["a","b"],
            "per_class":{"a":{"precision":1.0,"recall":0.5,"support":2},
                         "b":{"precision":0.0,"recall":0.0,"support":0}},
            "confusion":[[1,1],[0,0]]}"#;
        let m: Metrics = serde_json::from_str(old).unwrap();
        assert_eq!(m.per_class["a"].recall_ci95, None);
        let text = m.to_string();
        assert!(text.contains("0.09-0.91"), "{text}");
        // A class without pictures has no interval.
        let b_line = text.lines().find(|l| l.starts_with("b ")).unwrap();
        assert!(b_line.trim_end().ends_with('-'), "{b_line}");
    }
}
