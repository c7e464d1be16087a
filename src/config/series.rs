//! `[series]`: how the live DICOM series (and `layerwise export`) are made from the originals.

use serde::{Deserialize, Serialize};

pub use crate::shot::SeriesTake;

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SeriesConfig {
    /// Which take a slice shows when a repeated layer signal retook its frame
    /// (`raw/L…_{view}.r2.jpg`): `"first"` (the default) or `"last"`, which replaces the
    /// slice (with its own SOP Instance UID) each time a retake is stored. Originals are
    /// never touched.
    pub take: SeriesTake,
}
