//! CT flaws → labelled layer images (the paper's purpose for the CT registration, §3.2 and Fig. 9):
//! the internal flaws of a registered CT (gas pores, lack of fusion) found, measured and placed in
//! the build frame and in the printer's layers, and patches cut from every view of the layers
//! they sit in, with flaw-free controls, as a training set for layer-wise defect detection.
//!
//! 1. [`detect`]: the CT's part (`ct::surface::segment`: threshold, large components, internal
//!    voids filled) → low-density voxels inside it → 26-connected components (union-find over
//!    the sorted candidate voxels) → a minimum size, and a clearance from the part's exterior so
//!    the part surface is never a flaw → measures ([`Flaw`]);
//! 2. [`write_table`]: `flaws.csv`, `flaws.json` and `flaws.nrrd` (label volume in the build
//!    frame, gzip);
//! 3. [`patches`]: with a build, 16-bit patches of every view of every layer a flaw spans, on
//!    the build's rectified grid lattice (docs/frames.md), controls, `labels.json` (COCO) and
//!    `labels.csv`, and a contact sheet.

// Loops over the 3 axes index several arrays at once.
#![allow(clippy::needless_range_loop)]

mod detect;
pub mod patches;
mod run;
mod write;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use detect::{detect, CtLabels, Detection, FlawParams};
pub use patches::{cut_patches, flaw_sheet, PatchOptions, PatchSummary};
pub use run::{run, FlawsReport, FlawsRequest};
pub use write::{
    find_flaw, read_table, write_nrrd, write_table, FLAWS_CSV, FLAWS_JSON, FLAWS_NRRD,
};

/// What failed, on which input.
#[derive(Debug, thiserror::Error)]
pub enum FlawsError {
    #[error(transparent)]
    Ct(Box<crate::ct::CtError>),
    #[error(
        "{path}: not a usable registration (give the ct.toml written by `layerwise register ct`)"
    )]
    Registration {
        path: PathBuf,
        source: Box<crate::ct::CtError>,
    },
    #[error(transparent)]
    Build(#[from] crate::series::SeriesError),
    #[error("{path}: cannot read the frame")]
    Frame {
        path: PathBuf,
        source: crate::rectify::RectifyError,
    },
    #[error("patch grid: the calibration cannot rectify it")]
    Rectify(#[from] crate::rectify::RectifyError),
    #[error("cannot write {path}")]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write {path}")]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: not a flaws.json of `layerwise flaws`")]
    Table {
        path: PathBuf,
        source: serde_json::Error,
    },
    #[error("{path}: cannot read it")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error(transparent)]
    Original(#[from] crate::build_dir::original::OriginalError),
    #[error("no flaw {id} in {path} (ids 1 to {count})")]
    NoSuchFlaw {
        id: u32,
        path: PathBuf,
        count: usize,
    },
    #[error("{path}: cannot use these vectors as the nominal part")]
    Nominal {
        path: PathBuf,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("{0}")]
    Invalid(String),
}

pub type Result<T, E = FlawsError> = std::result::Result<T, E>;

impl From<crate::fsutil::WriteError> for FlawsError {
    fn from(e: crate::fsutil::WriteError) -> Self {
        FlawsError::Write {
            path: e.path,
            source: e.source,
        }
    }
}

impl From<crate::ct::CtError> for FlawsError {
    fn from(e: crate::ct::CtError) -> Self {
        FlawsError::Ct(Box::new(e))
    }
}

pub(crate) fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> FlawsError + '_ {
    move |source| FlawsError::Write {
        path: path.to_path_buf(),
        source,
    }
}

/// Kind guess from the shape (second-moment tensor of the flaw's voxels).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, PartialOrd, Ord, Hash)]
#[serde(rename_all = "snake_case")]
pub enum FlawKind {
    /// Small and round: elongation below 1.5 and the volume of its moment ellipsoid filled.
    GasPore,
    /// Flat, elongated or irregular (typically flat in the layer plane).
    LackOfFusion,
}

impl FlawKind {
    pub fn as_str(self) -> &'static str {
        match self {
            FlawKind::GasPore => "gas_pore",
            FlawKind::LackOfFusion => "lack_of_fusion",
        }
    }

    /// COCO category id.
    pub fn category(self) -> u32 {
        match self {
            FlawKind::GasPore => 1,
            FlawKind::LackOfFusion => 2,
        }
    }
}

impl std::fmt::Display for FlawKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A flaw's cut by one printer layer, in the build frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Section {
    /// Printer layer (1-based).
    pub layer: u32,
    /// Centre (x, y) of the flaw's voxels in this layer's slab, build mm.
    pub center_mm: [f64; 2],
    /// [x_min, y_min, x_max, y_max] of those voxels (voxel extents included), build mm.
    pub bbox_mm: [f64; 4],
    /// Flaw voxels in the slab (voxels within half a voxel of it when the slab holds none).
    pub voxels: usize,
}

/// One internal flaw of the CT.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Flaw {
    /// 1, 2, … in order of build z, then y, then x of the centroid.
    pub id: u32,
    pub kind: FlawKind,
    /// The vector file's part (the `--part` the CT was registered to), when known.
    pub part: Option<i64>,
    /// Partial-volume weighted centroid, build mm.
    pub centroid_mm: [f64; 3],
    /// The same in CT physical mm, and as a fractional voxel index.
    pub centroid_ct_mm: [f64; 3],
    pub centroid_voxel: [f64; 3],
    /// Axis-aligned bounds in the build frame (voxel extents included), mm: min, max.
    pub bbox_min_mm: [f64; 3],
    pub bbox_max_mm: [f64; 3],
    /// Voxel index bounds (inclusive).
    pub voxel_min: [usize; 3],
    pub voxel_max: [usize; 3],
    /// Voxels below the threshold.
    pub voxels: usize,
    /// Missing material from the partial-volume fractions around the flaw, mm³.
    pub volume_mm3: f64,
    /// Diameter of the sphere of that volume, mm.
    pub esd_mm: f64,
    /// √(λ₁/λ₃) of the second-moment tensor: 1 for a sphere.
    pub elongation: f64,
    /// Volume over the volume of the ellipsoid with the same second moments: ≈1 for
    /// ellipsoids, lower for irregular shapes.
    pub fill: f64,
    /// Semi-axes of that ellipsoid, mm, largest first.
    pub semi_axes_mm: [f64; 3],
    /// |z component| of the shortest axis: near 1 for a flaw flat in the layer plane.
    pub flat_in_layer: f64,
    /// Printer layers spanned (None where the flaw lies outside the layer stack).
    pub first_layer: Option<u32>,
    pub last_layer: Option<u32>,
    pub sections: Vec<Section>,
}

/// flaws.json: the table and how it was made.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FlawTable {
    pub ct: String,
    pub registration: String,
    pub threshold: f64,
    /// Medians of the two density classes (void, material), for partial-volume fractions.
    pub void_level: f64,
    pub material_level: f64,
    pub voxel_mm: [f64; 3],
    pub min_volume_voxels: usize,
    pub clearance_voxels: usize,
    /// Components too small, and components too close to the part's exterior (surface pits,
    /// partial-volume voxels at the surface).
    pub rejected_small: usize,
    pub rejected_surface: usize,
    /// Components whose centroid is outside the nominal part (the vectors' signed distance ≥ 0:
    /// the plate slab, supports), when the vectors were given.
    #[serde(default)]
    pub rejected_outside_part: usize,
    pub flaws: Vec<Flaw>,
}
