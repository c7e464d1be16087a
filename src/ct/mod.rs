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
//! the tests use the analytic or voxelised SDF of the synthetic part in `synth` (cargo feature
//! `testkit`).

// Loops over the 3 axes index several arrays at once; they read like the equations.
#![allow(clippy::needless_range_loop)]

pub mod align;
mod ct_toml;
mod error;
pub mod frame;
pub mod phantom;
pub mod ply;
pub mod register;
pub mod resample;
pub mod surface;
pub mod symmetry;
#[cfg(any(test, feature = "testkit"))]
pub mod synth;
pub mod volume;

use serde::{Deserialize, Serialize};

use crate::geometry::Rigid3;

pub use align::{horn, read_points_file, PointPair};
pub use ct_toml::{CtSource, CtToml, Percentiles, PointCounts};
pub(crate) use error::{io_err, write_err};
pub use error::{CtError, Result};
pub use frame::{CtFrame, CtLocation};
pub use register::{register_ct, CtOutcome, CtRequest};
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

/// How the registration starts.
#[derive(Debug, Clone)]
pub enum InitialTransform {
    /// R = I, translation moving the CT part's centroid onto the vectors' centroid
    /// ([`PartShape::centroid`] of the nominal part). For CT volumes roughly pre-oriented by the
    /// analyst (paper §3.2).
    Centroid,
    /// Horn's absolute orientation from ≥ 3 point pairs (CT mm, build mm), e.g. POINTS.txt.
    Points(Vec<PointPair>),
    /// A known transform, CT mm → build mm (e.g. the result of an earlier registration).
    Matrix(Rigid3),
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
    /// CT physical mm → build mm (`transform` in ct.toml).
    #[serde(rename = "transform")]
    pub build_from_ct: Rigid3,
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
        InitialTransform::Points(pairs) => *horn(pairs)?.matrix(),
        InitialTransform::Matrix(m) => *m.matrix(),
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
