//! What a CT registration takes (the distance field, how it starts, its knobs) and what it gives.

use super::surface::Threshold;
use crate::geometry::Rigid3;
use serde::{Deserialize, Serialize};

/// One correspondence: a point in CT physical mm and the same point in build mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointPair {
    pub ct: [f64; 3],
    pub build: [f64; 3],
}

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
