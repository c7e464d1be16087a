//! `[calibration]`: the camera's calibration and how frames are rectified with it.

use super::{BuildConfig, Invalid};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// calibration.toml from `layerwise register images`; frames are rectified once it is set.
    #[serde(default)]
    pub file: Option<PathBuf>,
    /// bilinear (default) or bicubic.
    #[serde(default)]
    pub interpolation: crate::geometry::Interpolation,
    /// Grey level of grid pixels that fall outside the camera frame.
    #[serde(default)]
    pub fill: u16,
    /// Rectify only around this part of the vector file (build.vectors), plus `crop_margin_mm`:
    /// series stay small when one part matters.
    #[serde(default)]
    pub crop_part: Option<i64>,
    /// 5 mm when `[calibration]` leaves it out (without the section, `Default` gives 0: there is
    /// no `crop_part` then to grow).
    #[serde(default = "default_crop_margin")]
    pub crop_margin_mm: f64,
}

fn default_crop_margin() -> f64 {
    5.0
}

impl CalibrationConfig {
    /// Checks the section: a margin of 0 mm or more, and a part to crop to only with the vector
    /// file that outlines it (`build`).
    pub fn validate(&self, build: &BuildConfig) -> Result<(), Invalid> {
        if !(self.crop_margin_mm.is_finite() && self.crop_margin_mm >= 0.0) {
            return Err(Invalid::new(
                "calibration.crop_margin_mm",
                "must be a finite number of mm, 0 or more",
            ));
        }
        if self.crop_part.is_some() && build.vectors.is_none() {
            return Err(Invalid::new(
                "calibration.crop_part",
                "needs build.vectors: the part's outline comes from the vector file",
            ));
        }
        Ok(())
    }
}
