//! Accuracy, per-class precision and recall, the balanced accuracy (macro recall) and the
//! confusion matrix (rows = true class, columns = predicted), as `learn eval` prints them and
//! the model file records them.

use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClassMetrics {
    pub precision: f64,
    pub recall: f64,
    pub support: usize,
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
        writeln!(f, "{:width$}  precision  recall  support", "class")?;
        for c in &self.classes {
            let m = &self.per_class[c];
            writeln!(
                f,
                "{c:width$}  {:9.3}  {:6.3}  {:7}",
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
    }
}
