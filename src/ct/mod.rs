//! CT-to-laser-vector registration (paper §3.2, equations 11-17, and §4.2).
//!
//! A part printed layer by layer is CT-scanned after the build. We find the rigid transform `T`
//! (4x4, CT physical mm → build mm, docs/frames.md) that puts the CT surface onto the zero level
//! of the truncated signed distance field Ψ of the laser vectors:
//!
//! 1. threshold (Otsu by default) → part mask (6-connected components above a fraction of the
//!    largest) with internal voids filled ([`surface::segment`]);
//! 2. surface points at sub-voxel positions: linear interpolation of the iso-crossing between
//!    each inside/outside voxel pair along x, y and z ([`surface::surface_points`]);
//! 3. initial transform: Horn's absolute orientation from ≥ 3 point pairs, or R = I with the CT
//!    part centroid moved onto the vectors' centroid ([`align::horn`]);
//! 4. plate-side points (the lowest slab of the part along build z, §4.2) are left out;
//! 5. Levenberg-Marquardt on a Lie-algebra update, `T ← exp(ξ)·T` (eq. 14-17), with an optional
//!    Huber loss against CT reflections ([`align`]);
//! 6. the error of Table 2: mean |Ψ| over the CT surface points, in µm, plus percentiles.
//!
//! The distance field is abstract ([`DistanceField`]): the lead implements it for `tsdf::Tsdf`;
//! the tests use the analytic or voxelised SDF of the synthetic part in [`synth`].

// Loops over the 3 axes index several arrays at once; they read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod align;
pub mod frame;
pub mod ply;
pub mod surface;
pub mod synth;
pub mod vectors_field;
pub mod volume;

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

pub use align::{horn, read_points_file, PointPair};
pub use frame::{CtFrame, CtLocation};
pub use surface::{PartShape, Threshold};
pub use volume::{read_volume, RawDtype, RawSpec, Volume, VolumeSource, VoxelData};

/// Signed distance to the laser-vector surface, in build mm: negative inside the part, positive
/// outside, truncated at ± [`DistanceField::truncation_mm`].
pub trait DistanceField: Sync {
    /// Ψ(p) and ∇Ψ(p) at a build point; `None` outside the field's grid.
    fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])>;
    /// The truncation distance: samples with |Ψ| at this value carry no alignment information.
    fn truncation_mm(&self) -> f64;
}

/// Everything that can go wrong, with the file or the number that explains it.
#[derive(Debug, thiserror::Error)]
pub enum CtError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: missing key `{key}`{}", section_note(.section))]
    MissingKey {
        path: PathBuf,
        section: String,
        key: String,
    },
    #[error("{path}: bad value {value:?} for `{key}`: {reason}")]
    BadValue {
        path: PathBuf,
        key: String,
        value: String,
        reason: String,
    },
    #[error("{path}: unknown voxel data type {dtype:?} (expected {expected})")]
    UnknownDtype {
        path: PathBuf,
        dtype: String,
        expected: &'static str,
    },
    #[error(
        "{path}: the raw file is {actual} bytes but {dims:?} voxels of {bytes_per_voxel} byte(s) \
         (plus a {header}-byte header) need {expected} bytes"
    )]
    SizeMismatch {
        path: PathBuf,
        dims: [usize; 3],
        bytes_per_voxel: usize,
        header: u64,
        expected: u64,
        actual: u64,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    #[error("invalid input: {0}")]
    Invalid(String),
    #[error(
        "empty threshold: no voxel is at or above {threshold} (the volume's values span \
         {min}..{max}): lower the threshold"
    )]
    EmptyThreshold { threshold: f64, min: f64, max: f64 },
    #[error(
        "threshold {threshold} selects every voxel (the volume's values span {min}..{max}): \
         there is no background to find a surface against"
    )]
    FullThreshold { threshold: f64, min: f64, max: f64 },
    #[error("the thresholded part has no surface inside the volume")]
    NoSurface,
    #[error("the initial transform needs at least 3 point pairs, got {0}")]
    TooFewPoints(usize),
    #[error(
        "the {which} points of the point pairs are (nearly) collinear: the rotation about their \
         line is undetermined; pick 3 points that span a triangle"
    )]
    CollinearPoints { which: &'static str },
    #[error("{path}:{line}: {message}")]
    PointsFile {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error(
        "the CT part is {ratio:.2}x the size of the vectors: check the voxel size \
         (CT principal extents {ct:.3?} mm, vectors {vectors:.3?} mm)"
    )]
    ScaleMismatch {
        ratio: f64,
        ct: [f64; 3],
        vectors: [f64; 3],
    },
    #[error(
        "only {used} of {total} CT surface points fall inside the distance field's truncation \
         band (±{truncation_mm} mm) after the initial transform: check the initial transform \
         (point pairs) or the field's extent"
    )]
    NoOverlap {
        used: usize,
        total: usize,
        truncation_mm: f64,
    },
    #[error(
        "the registration converged to a poor fit: {outside_pct:.1}% of the surface points lie \
         beyond the distance field's truncation band and the mean |Ψ| is {mean_abs_um:.1} µm; \
         likely a wrong local minimum (e.g. a rotation by a symmetry of the part): start from \
         point pairs"
    )]
    PoorFit { outside_pct: f64, mean_abs_um: f64 },
    #[error(
        "the registration did not converge in {iterations} iterations (last step {rotation_rad:.3e} \
         rad, {translation_mm:.3e} mm; rms Ψ {rms_um:.2} µm): check the initial transform \
         or raise max_iterations"
    )]
    NotConverged {
        iterations: usize,
        rotation_rad: f64,
        translation_mm: f64,
        rms_um: f64,
    },
}

fn section_note(section: &str) -> String {
    if section.is_empty() {
        String::new()
    } else {
        format!(" in [{section}]")
    }
}

pub type Result<T, E = CtError> = std::result::Result<T, E>;

pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> CtError + '_ {
    move |source| CtError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// How the registration starts.
#[derive(Debug, Clone)]
pub enum InitialTransform {
    /// R = I, translation moving the CT part's centroid onto the vectors' centroid
    /// ([`PartShape::centroid`] of the nominal part). For CT volumes roughly pre-oriented by the
    /// analyst (paper §3.2).
    Centroid,
    /// Horn's absolute orientation from ≥ 3 point pairs (CT mm, build mm), e.g. POINTS.txt.
    Points(Vec<PointPair>),
    /// A known transform (e.g. the result of an earlier registration).
    Matrix([[f64; 4]; 4]),
}

/// Tuning knobs; [`CtParams::default`] is what the paper does.
#[derive(Debug, Clone)]
pub struct CtParams {
    pub threshold: Threshold,
    /// Keep every 6-connected component with at least this fraction of the largest one's voxels.
    pub keep_fraction: f64,
    /// Points within this slab above the part's lowest point (build z) are plate-side (§4.2).
    pub plate_slab_mm: f64,
    /// Huber loss threshold in mm (IRLS weights), against CT reflections; `None` = least squares.
    pub huber_k_mm: Option<f64>,
    pub max_iterations: usize,
    /// Converged when a step rotates less than this ...
    pub min_rotation_step_rad: f64,
    /// ... and translates less than this.
    pub min_translation_step_mm: f64,
    /// Converged when an accepted step lowers the cost by less than this fraction.
    pub min_relative_cost_change: f64,
    /// Refuse when the CT part's size differs from the vectors' by more than this fraction.
    /// `None` skips the check.
    pub scale_tolerance: Option<f64>,
    /// Use at most this many (evenly strided) surface points in the optimisation; the error
    /// statistics always use all of them. `None` = all.
    pub max_points: Option<usize>,
    /// Refuse a converged result with more than this fraction of the (non-plate) surface points
    /// beyond the truncation band: a wrong local minimum (e.g. the staircase one step off).
    /// `None` accepts any result.
    pub max_outside_fraction: Option<f64>,
}

impl Default for CtParams {
    fn default() -> Self {
        Self {
            threshold: Threshold::Otsu,
            keep_fraction: 0.1,
            plate_slab_mm: 0.2,
            huber_k_mm: None,
            max_iterations: 100,
            min_rotation_step_rad: 1e-7,
            min_translation_step_mm: 1e-6,
            min_relative_cost_change: 1e-10,
            scale_tolerance: Some(0.1),
            max_points: None,
            max_outside_fraction: Some(0.05),
        }
    }
}

/// Why the optimisation stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Termination {
    /// The step fell below the rotation and translation tolerances.
    SmallStep,
    /// An accepted step changed the cost by less than the relative tolerance.
    SmallCostChange,
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Termination::SmallStep => "small_step",
            Termination::SmallCostChange => "small_cost_change",
        })
    }
}

/// The result: the transform and the error figures of Table 2 (all distances in µm).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CtRegistration {
    /// CT physical mm → build mm.
    pub transform: [[f64; 4]; 4],
    /// Levenberg-Marquardt iterations (linear solves), over all plate-exclusion rounds.
    pub iterations: usize,
    pub termination: Termination,
    /// The threshold used, in the volume's (rescaled) units.
    pub threshold: f64,
    /// Points inside the field's truncation band with a nonzero weight at the end.
    pub points_used: usize,
    /// All CT surface points extracted.
    pub points_total: usize,
    /// Plate-side points left out (§4.2).
    pub points_excluded_plate: usize,
    /// Points outside the field or beyond its truncation at the end (weight 0).
    pub points_outside: usize,
    pub mean_abs_um: f64,
    pub median_abs_um: f64,
    pub p95_abs_um: f64,
    pub max_abs_um: f64,
    pub rms_um: f64,
}

/// The registration plus the evaluated surface, for the PLY export.
#[derive(Debug, Clone)]
pub struct Registered {
    pub registration: CtRegistration,
    /// Non-plate CT surface points inside the field, in build mm.
    pub points_build_mm: Vec<[f64; 3]>,
    /// Ψ at each of those points, in mm (positive = additive error).
    pub distances_mm: Vec<f64>,
}

/// Register a CT volume to the vectors' distance field.
///
/// `nominal` summarises the vectors (centroid for [`InitialTransform::Centroid`], principal
/// extents for the voxel-size check).
pub fn register(
    volume: &Volume,
    field: &dyn DistanceField,
    nominal: &PartShape,
    init: &InitialTransform,
    params: &CtParams,
) -> Result<Registered> {
    let seg = surface::segment(volume, &params.threshold, params.keep_fraction)?;
    let shape = surface::solid_shape(volume, &seg);
    if let Some(tol) = params.scale_tolerance {
        check_scale(&shape, nominal, tol)?;
    }
    let points = surface::surface_points(volume, &seg);
    if points.is_empty() {
        return Err(CtError::NoSurface);
    }
    let t0 = match init {
        InitialTransform::Centroid => {
            let mut t = align::IDENTITY;
            for a in 0..3 {
                t[a][3] = nominal.centroid[a] - shape.centroid[a];
            }
            t
        }
        InitialTransform::Points(pairs) => horn(pairs)?,
        InitialTransform::Matrix(m) => *m,
    };
    align::register_points(&points, t0, field, params, seg.threshold)
}

/// The voxel-size sanity check: the geometric mean of the sorted principal-extent ratios.
pub fn check_scale(ct: &PartShape, vectors: &PartShape, tolerance: f64) -> Result<f64> {
    let ratio = ct.size_ratio(vectors);
    if !ratio.is_finite() || (ratio - 1.0).abs() > tolerance {
        return Err(CtError::ScaleMismatch {
            ratio,
            ct: ct.extents_mm,
            vectors: vectors.extents_mm,
        });
    }
    Ok(ratio)
}

/// The on-disk layout of `ct.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CtToml {
    /// 4x4, CT physical mm → build mm.
    pub transform: [[f64; 4]; 4],
    pub iterations: usize,
    pub termination: Termination,
    pub threshold: f64,
    pub mean_abs_distance_um: f64,
    pub rms_distance_um: f64,
    pub percentiles: Percentiles,
    pub points: PointCounts,
    /// Where the CT came from, so `layerwise export --ct ct.toml` can resample it again.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<CtSource>,
}

/// How to read the registered CT volume again.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CtSource {
    pub path: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voxel_mm: Option<f64>,
    /// Raw volumes only: `X,Y,Z` voxels and the sample type.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dtype: Option<String>,
}

impl CtSource {
    /// Reads the volume it names.
    pub fn read(&self) -> Result<Volume> {
        let path = std::path::PathBuf::from(&self.path);
        let source = match (&self.size, &self.dtype, self.voxel_mm) {
            (Some(size), Some(dtype), Some(voxel)) => {
                VolumeSource::Raw(path, RawSpec::from_args(size, voxel, dtype)?)
            }
            _ => VolumeSource::detect(&path, self.voxel_mm)?,
        };
        read_volume(&source)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    pub p50_um: f64,
    pub p95_um: f64,
    pub max_um: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PointCounts {
    pub used: usize,
    pub total: usize,
    pub excluded_plate: usize,
    pub outside_field: usize,
}

impl CtRegistration {
    pub fn to_toml_string(&self) -> String {
        self.to_toml_string_with(None)
    }

    /// `ct.toml` text, recording where the CT came from.
    pub fn to_toml_string_with(&self, source: Option<CtSource>) -> String {
        let file = CtToml {
            transform: self.transform,
            iterations: self.iterations,
            termination: self.termination,
            threshold: self.threshold,
            mean_abs_distance_um: self.mean_abs_um,
            rms_distance_um: self.rms_um,
            percentiles: Percentiles {
                p50_um: self.median_abs_um,
                p95_um: self.p95_abs_um,
                max_um: self.max_abs_um,
            },
            points: PointCounts {
                used: self.points_used,
                total: self.points_total,
                excluded_plate: self.points_excluded_plate,
                outside_field: self.points_outside,
            },
            source,
        };
        // Serialising plain numbers and tables cannot fail.
        toml::to_string(&file).unwrap_or_default()
    }

    /// Write `ct.toml`.
    pub fn write_toml(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.to_toml_string()).map_err(io_err(path))
    }

    /// Read a `ct.toml` back (e.g. to apply the transform).
    pub fn read_toml(path: &Path) -> Result<CtToml> {
        let text = std::fs::read_to_string(path).map_err(io_err(path))?;
        toml::from_str(&text).map_err(|e| CtError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}
