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
mod params;
pub mod phantom;
pub mod ply;
pub mod register;
pub mod resample;
pub mod surface;
pub mod symmetry;
#[cfg(any(test, feature = "testkit"))]
pub mod synth;
pub mod volume;

pub use align::{horn, read_points_file};
pub use ct_toml::{CtSource, CtToml, Percentiles, PointCounts};
pub(crate) use error::{io_err, write_err};
pub use error::{CtError, Result};
pub use frame::{CtFrame, CtLocation};
pub use params::{
    CtParams, CtRegistration, DistanceField, InitialTransform, PointPair, Registered, Termination,
};
pub use register::{register_ct, CtOutcome, CtRequest};
pub use surface::{PartShape, Threshold};
pub use volume::{read_volume, RawDtype, RawSpec, Volume, VolumeSource, VoxelData};

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
