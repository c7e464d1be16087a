//! Inverse-compositional Levenberg-Marquardt (IC-LM) alignment of std-filtered build images to
//! exemplars (paper §3.1, eq. 7-10; Baker & Matthews 2004).
//!
//! The warp maps exemplar pixel coordinates x = (u_e, v_e) to (undistorted) image pixel
//! coordinates: W(x; M) = proj(M x̄), with M the 3x3 exemplar → image matrix. Each iteration
//! solves for an update ΔH = I + [[p1, p2, p3], [p4, p5, p6], [p7, p8, 0]] acting on the
//! exemplar's coordinates and composes its inverse: M ← M · ΔH⁻¹ (eq. 8). The Jacobian of one
//! pixel, J_i = ∇I_E(x_i)ᵀ · ∂proj(ΔH x̄_i)/∂p at ΔH = I (eq. 9-10), does not depend on M, so J
//! and the Gauss-Newton Hessian JᵀJ are computed once per pyramid level; an iteration is one
//! pass over the exemplar that samples I_B at W(x_i; M) and accumulates the gradient.
//!
//! Three additions to eq. 7, each documented where it acts:
//! - **Photometric match.** The exemplar (uniform 0..255 noise against 0) and the frame (metal
//!   speckle against powder speckle) give std images of different levels *and shapes*: across
//!   an edge the exemplar overshoots (the noise's mean differs from the zeros'), the frame rises
//!   from the powder's floor. Plain SSD then pulls every edge inward (a brighter template gains
//!   by shrinking onto the part): measured 0.9 px mean on the mock camera; an affine gain and
//!   offset leaves 0.4 px. So each image's samples are mapped by a polynomial φ of degree ≤ 3
//!   fitted in closed form on every pass (variable projection): the cost is
//!   ½ Σ (I_E(x_i) − φ(I_B(W(x_i))))², minimised over φ. Only Σ J_i t_i^k (k ≤ 3) are needed
//!   per pass besides the sums of powers of t = I_B / scale.
//! - **Dilation** (`fit_dilation`, on by default): partly fused powder sticking to the outer
//!   tracks makes every part look wider in the frame than its vectors; a homography cannot
//!   follow that and turns it into a false scale, worst at the far parts. Each frame gets one δ
//!   (the exemplar's edges moved outward by δ pixels, to first order I_E + δ·|∇I_E|), fitted in
//!   closed form with φ (`pass::fit_photometric`). Measured on tests/it/renderer2.rs's frames
//!   (a 0.8 mm halo): 0.197 → 0.154 px mean, 0.38 → 0.27 px max (a 1 mm halo: 0.365 → 0.153
//!   and 0.97 → 0.27 px); on the mock camera's frames (no halo) δ ≈ 0.03 px and the result is
//!   unchanged.
//! - **Radial distortion** (optional): W(x) = D_k(proj(M x̄)) with D the Brown k1/k2 model of
//!   [`RadialDistortion`]. The homography part stays inverse-compositional with the constant
//!   Jacobian above; k1 and k2 are updated forward-additively (k ← k + Δk), their Jacobian
//!   recomputed on every pass as G_i = ∇I_E(x_i)ᵀ A_i⁻¹ ∂D/∂k: the image-side motion of a
//!   change of k pulled back to the exemplar through the warp's 2x2 Jacobian A_i, i.e. the same
//!   template-side linearisation as the IC rows (with the frame's own gradient instead, the
//!   blocks of the normal matrix disagree in scale and LM crawls). The 10x10 normal matrix is
//!   [[JᵀJ, −JᵀG], [−GᵀJ, GᵀG]]; only the 8x8 block is precomputed.
//!
//! The sum runs over the exemplar pixels within `support_margin_px` of the parts' std support
//! (default 24 px; `None`: every pixel, eq. 7 as written), fixed per level: what the vectors do
//! not model (the plate's edge, other parts) stays out of the fit, and far fewer pixels are
//! visited. Pixels that map outside the image sample 0 (zero padding), so the cost is always a
//! sum over the same exemplar pixels; exemplar "support" pixels (near the parts) leaving the image are
//! counted and reported as divergence.
//!
//! Several (image, exemplar) pairs share one warp: their costs, gradients and Hessians add.
//! All exemplars of a call share one grid (the same pixel coordinates), so one ΔH serves all.

//!
//! Files: `pyramid.rs` (levels, the constant Jacobian and its Hessian, the active pixels),
//! `pass.rs` (one pass over a pair: sampling, photometric fit, gradient and normal matrix),
//! `driver.rs` (the LM iterations coarse to fine: [`align`]).

mod driver;
mod pass;
mod pyramid;
#[cfg(test)]
mod tests;

use crate::geometry::{Homography, RadialDistortion};

use super::exemplar::F32Image;

pub use driver::align;
pub use pass::MAX_DEGREE;
pub use pyramid::{default_levels, downsample};

/// One image to align and the exemplar it should match. All exemplars of one [`align`] call have
/// the same size (they are rendered on one grid).
#[derive(Clone, Copy, Debug)]
pub struct Pair<'a> {
    /// I_B: the std-filtered build image.
    pub image: &'a F32Image,
    /// I_E: the exemplar.
    pub exemplar: &'a F32Image,
}

/// Optimiser settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LmOptions {
    /// Pyramid levels (1 = full resolution only); `None` picks [`default_levels`].
    pub levels: Option<usize>,
    /// LM iterations per level at most.
    pub max_iterations: usize,
    /// Stop when a step moves no exemplar corner by more than this, in pixels of the level.
    pub step_tol_px: f64,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub cost_tol: f64,
    /// Initial LM damping λ (H_lm = JᵀJ + λ diag(JᵀJ)).
    pub lambda0: f64,
    /// Refuse a result whose correlation between I_E and the matched I_B is below this.
    pub min_correlation: f64,
    /// Divergence: more than this fraction of an exemplar's support (pixels near parts) newly
    /// mapping outside its image.
    pub max_outside: f64,
    /// Degree of the polynomial φ matching I_B to I_E (1 = gain and offset; at most 3).
    pub photometric_degree: usize,
    /// The cost sums over the exemplar pixels within this many (full-resolution) pixels of the
    /// parts' std support only; `None`: over every exemplar pixel (eq. 7 as written). What the
    /// vectors do not model (the plate's edge, a recoater streak, a part of another file) then
    /// stays out of the photometric fit: a plate-wide exemplar that reached the plate's edge
    /// was 1.2 px off instead of 0.16 px.
    pub support_margin_px: Option<f64>,
    /// Keep the distortion's k2 at its start value (fit k1 only): set when the frames cannot
    /// tell k2 from k1 and the homography (`calibrate::identify`).
    pub fix_k2: bool,
    /// Fit, per frame, how far the frame's parts look wider than their vectors (a halo of
    /// partly fused powder; `pass::fit_photometric`), so it is not taken for a scale.
    pub fit_dilation: bool,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            levels: None,
            max_iterations: 60,
            step_tol_px: 1e-4,
            cost_tol: 1e-10,
            lambda0: 1e-3,
            min_correlation: 0.5,
            max_outside: 0.01,
            photometric_degree: 3,
            support_margin_px: Some(24.0),
            fix_k2: false,
            fit_dilation: true,
        }
    }
}

/// Why the iterations of a level stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Termination {
    /// The proposed step moved the exemplar by less than `step_tol_px`.
    SmallStep,
    /// An accepted step lowered the cost by less than `cost_tol`.
    CostStalled,
    /// No damping found a lower cost (λ ran to its cap): a minimum within precision.
    NoDecrease,
    /// `max_iterations` reached.
    MaxIterations,
}

impl Termination {
    pub fn name(self) -> &'static str {
        match self {
            Termination::SmallStep => "small step",
            Termination::CostStalled => "cost stalled",
            Termination::NoDecrease => "no decrease",
            Termination::MaxIterations => "max iterations",
        }
    }
}

/// What happened on one pyramid level (level 0 = full resolution).
#[derive(Clone, Debug, PartialEq)]
pub struct LevelReport {
    pub level: usize,
    /// Downsampling factor 2^level.
    pub scale: usize,
    /// Exemplar size at this level.
    pub width: usize,
    pub height: usize,
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Size of the last proposed step, exemplar pixels of this level.
    pub last_step_px: f64,
    pub termination: Termination,
    /// Lowest correlation of the pairs at the end of the level.
    pub correlation: f64,
}

/// The photometric match and quality of one pair at full resolution.
#[derive(Clone, Debug, PartialEq)]
pub struct PairFit {
    /// φ: `I_E ≈ Σ_k photometric[k]·I_B^k`.
    pub photometric: Vec<f64>,
    /// How far the frame's parts look wider than the vectors (edges moved outward), exemplar
    /// pixels at full resolution; 0 when not fitted.
    pub dilation_px: f64,
    /// Correlation R of I_E with φ(I_B(W)) at the starting warp and at the result.
    pub initial_correlation: f64,
    pub correlation: f64,
    /// √(2·cost / pixels): RMS of the matched residual, in exemplar units.
    pub rms: f64,
    pub pixels: usize,
}

/// The result of [`align`].
#[derive(Clone, Debug, PartialEq)]
pub struct Alignment {
    /// Exemplar pixel → undistorted image pixel, normalised to w = 1 at the exemplar center.
    pub image_from_exemplar: Homography,
    /// The refined distortion, when one was given.
    pub distortion: Option<RadialDistortion>,
    /// Coarsest level first.
    pub levels: Vec<LevelReport>,
    pub pairs: Vec<PairFit>,
}
