//! `[build]`: what is being built, where its record goes, and how its layers pair with the
//! vector file (docs/frames.md).

use super::{Invalid, MAX_LAYER};
use crate::vectors::{LayerMatch, LayerNumbering};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildConfig {
    /// Human name of the build; becomes the DICOM PatientName.
    pub name: String,
    /// Short id of the build; becomes the DICOM PatientID. Defaults to the name.
    #[serde(default)]
    pub id: Option<String>,
    /// Where originals, the journal and the DICOM series go; not needed (and not used) with
    /// `builds_dir`, where each build gets a folder of its own.
    #[serde(default)]
    pub output_dir: PathBuf,
    /// Layers the build will have, if known: the status command forecasts disk use from it.
    #[serde(default)]
    pub layers: Option<u32>,
    /// The build's laser scan vector file (CLI): printer layer k's z is the z of the file's
    /// layer that `layer_match` pairs with it (docs/frames.md).
    #[serde(default)]
    pub vectors: Option<PathBuf>,
    /// Without a vector file, layer k sits at z = k x this.
    #[serde(default = "default_layer_thickness")]
    pub layer_thickness_mm: f64,
    /// How printer layers pair with the vector file's layers: `geometry` (layer 1 is the first
    /// layer with geometry), `position` (layer n is the file's n-th layer) or `z`
    /// (z = n x layer_thickness_mm).
    #[serde(default)]
    pub layer_match: LayerMatch,
    /// Printer layers before the vector file's first (geometry, position): may be negative.
    #[serde(default)]
    pub layer_offset: i64,
    /// With this set, operators start and end builds with `layerwise build start|stop`: the
    /// daemon records into the folder (under this directory) of the build last started, with
    /// its name, vectors and layers; `output_dir`, `name` and `vectors` above are the
    /// defaults of a build that does not give its own. Without it, the daemon records into
    /// `output_dir`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub builds_dir: Option<PathBuf>,
}

/// Longest build name or id: a DICOM PatientID (LO) holds 64 characters, a PatientName
/// component group 64.
pub const MAX_DICOM_TEXT: usize = 64;

/// Refuses what a DICOM text value of the build cannot hold as given: more than
/// [`MAX_DICOM_TEXT`] characters (cut silently otherwise), a control or bidirectional-override
/// character (a newline or NUL in PatientID, a right-to-left override reversing PatientName in
/// a viewer), or a backslash (DICOM's value separator: one id would read as two).
pub fn check_dicom_text(key: &str, text: &str, attribute: &str) -> Result<(), Invalid> {
    let chars = text.chars().count();
    if chars > MAX_DICOM_TEXT {
        return Err(Invalid::new(
            key,
            format!(
                "is {chars} characters; at most {MAX_DICOM_TEXT} (it becomes the DICOM \
                 {attribute}, which holds no more)"
            ),
        ));
    }
    if let Some(c) = text.chars().find(|&c| crate::logging::is_hidden_char(c)) {
        return Err(Invalid::new(
            key,
            format!(
                "holds the control or bidirectional character {} (newline, NUL, U+202E, …): it \
                 goes into the DICOM {attribute} and the logs; use printable text",
                c.escape_unicode()
            ),
        ));
    }
    if text.contains('\\') {
        return Err(Invalid::new(
            key,
            format!(
                "holds a backslash, DICOM's value separator: the {attribute} would read as two \
                 values; use another character"
            ),
        ));
    }
    Ok(())
}

fn default_layer_thickness() -> f64 {
    0.03
}

impl BuildConfig {
    /// The numbering that pairs printer layers with the vector file's layers.
    pub fn numbering(&self) -> LayerNumbering {
        LayerNumbering {
            rule: self.layer_match,
            offset: self.layer_offset,
            thickness_mm: self.layer_thickness_mm,
        }
    }

    /// Checks the section: a printable name, a layer count and thickness in range, directories
    /// that are named.
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.name.trim().is_empty() {
            return Err(Invalid::new("build.name", "must not be empty"));
        }
        check_dicom_text("build.name", &self.name, "PatientName")?;
        if let Some(id) = &self.id {
            if id.trim().is_empty() {
                return Err(Invalid::new(
                    "build.id",
                    "must not be empty (leave the key out to use the name)",
                ));
            }
            check_dicom_text("build.id", id, "PatientID")?;
        }
        if let Some(layers) = self.layers {
            if layers == 0 || layers > MAX_LAYER {
                return Err(Invalid::new(
                    "build.layers",
                    format!("must be 1 to {MAX_LAYER} (file names hold 5 digits)"),
                ));
            }
        }
        if !(self.layer_thickness_mm > 0.0 && self.layer_thickness_mm <= 10.0) {
            return Err(Invalid::new(
                "build.layer_thickness_mm",
                "must be a positive number of mm, at most 10 (a powder layer is about 0.03)",
            ));
        }
        if self.output_dir.as_os_str().is_empty() && self.builds_dir.is_none() {
            return Err(Invalid::new(
                "build.output_dir",
                "must name a directory (or set build.builds_dir and start builds with \
                 `layerwise build start`)",
            ));
        }
        if self
            .builds_dir
            .as_ref()
            .is_some_and(|d| d.as_os_str().is_empty())
        {
            return Err(Invalid::new(
                "build.builds_dir",
                "must name a directory (or leave the key out)",
            ));
        }
        Ok(())
    }
}
