//! `[views]`: the phases captured for each layer and the lights switched in turn for each phase.

use super::Invalid;
use crate::shot::{Light, Phase, View};
use serde::{Deserialize, Serialize};

/// A key left out takes its value from [`ViewsConfig::default`]: every phase, every light.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewsConfig {
    /// Phases to capture, in order.
    pub phases: Vec<Phase>,
    /// Lights to switch in turn, in order, for each phase.
    pub lights: Vec<Light>,
}

impl Default for ViewsConfig {
    fn default() -> Self {
        ViewsConfig {
            phases: Phase::ALL.to_vec(),
            lights: Light::ALL.to_vec(),
        }
    }
}

impl ViewsConfig {
    pub fn all(&self) -> Vec<View> {
        let mut out = Vec::new();
        for &phase in &self.phases {
            for &light in &self.lights {
                out.push(View { phase, light });
            }
        }
        out
    }

    /// Checks the section: at least one phase and one light, none named twice.
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.phases.is_empty() || self.lights.is_empty() {
            return Err(Invalid::new(
                "views",
                "needs at least one phase and one light",
            ));
        }
        for (key, twice) in [
            ("views.phases", has_duplicates(&self.phases)),
            ("views.lights", has_duplicates(&self.lights)),
        ] {
            if twice {
                return Err(Invalid::new(key, "names an entry twice"));
            }
        }
        Ok(())
    }
}

fn has_duplicates<T: Ord>(items: &[T]) -> bool {
    let mut seen = std::collections::BTreeSet::new();
    !items.iter().all(|i| seen.insert(i))
}
