//! `[inspection.model]`: a trained defect model (`layerwise learn train`) run on every layer in
//! the processing worker after the classical checks, never on the capture path. Leave the
//! section out to run without one. The file is checked when the daemon starts (and by
//! `layerwise check-config`): a damaged, foreign or unusable model stops the start.

use super::Invalid;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A key left out takes its value from [`ModelConfig::default`]; `file` is required.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    /// The model file (`*.safetensors` from `layerwise learn train`).
    pub file: PathBuf,
    /// mm per model cell on the plate, for a model trained on camera frames of unknown scale
    /// (a model trained on flaws patches or verdicts knows its own and ignores this).
    #[serde(default)]
    pub cell_mm: Option<f64>,
    /// A tile is flagged when its most likely class is not the normal one and at least this
    /// likely.
    #[serde(default = "default_min_probability")]
    pub min_probability: f64,
    /// Flags at least this likely are critical (they switch the alarm at its default setting).
    #[serde(default = "default_critical_probability")]
    pub critical_probability: f64,
    /// The views the model looks at (`pre_top`, …); empty: every view of the layer.
    #[serde(default)]
    pub views: Vec<String>,
}

fn default_min_probability() -> f64 {
    0.8
}
fn default_critical_probability() -> f64 {
    0.95
}

impl ModelConfig {
    /// A model file with every other key at its default.
    pub fn for_file(file: PathBuf) -> ModelConfig {
        ModelConfig {
            file,
            cell_mm: None,
            min_probability: default_min_probability(),
            critical_probability: default_critical_probability(),
            views: Vec::new(),
        }
    }

    /// Values serde cannot check.
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.file.as_os_str().is_empty() {
            return Err(Invalid::new("inspection.model.file", "names no file"));
        }
        if !(0.0..=1.0).contains(&self.min_probability)
            || !(self.min_probability..=1.0).contains(&self.critical_probability)
        {
            return Err(Invalid::new(
                "inspection.model.min_probability / critical_probability",
                format!(
                    "must satisfy 0 ≤ min_probability ≤ critical_probability ≤ 1, got {} and {}",
                    self.min_probability, self.critical_probability
                ),
            ));
        }
        if let Some(mm) = self.cell_mm {
            if !(mm.is_finite() && mm > 0.0) {
                return Err(Invalid::new(
                    "inspection.model.cell_mm",
                    format!("must be a finite number above 0, got {mm}"),
                ));
            }
        }
        for v in &self.views {
            if crate::shot::Shot::from_stem(&format!("L1_{v}")).is_none() {
                return Err(Invalid::new(
                    "inspection.model.views",
                    format!("{v:?} is not a view (pre_top, post_side, …)"),
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_checks() {
        let m: ModelConfig = toml::from_str("file = \"m.safetensors\"").unwrap();
        assert_eq!((m.min_probability, m.critical_probability), (0.8, 0.95));
        assert!(m.validate().is_ok());
        let bad: ModelConfig = toml::from_str("file = \"m\"\nmin_probability = 0.99").unwrap();
        assert!(bad.validate().is_err());
        assert!(
            toml::from_str::<ModelConfig>("file = \"m\"\nviews = [\"nope\"]")
                .unwrap()
                .validate()
                .is_err()
        );
    }
}
