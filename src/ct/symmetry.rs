//! Rotations the registration cannot determine: a part symmetric about an axis (a plain
//! cylinder) fits its vectors equally well turned by any angle about that axis, so the angle
//! `register ct` reports about it is arbitrary. Each principal axis of the nominal part is probed
//! by turning the registered CT surface about it and measuring the fit again.

use nalgebra::{Rotation3, Unit, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{DistanceField, PartShape};

/// How far the surface is turned about each axis, degrees.
pub const PROBE_DEG: f64 = 5.0;
/// Surface points probed at most (evenly strided).
const MAX_POINTS: usize = 20_000;

/// An axis about which the registration's rotation is not determined.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FreeRotation {
    /// The axis, a unit vector in the build frame, through `center_mm`.
    pub axis: [f64; 3],
    /// The nominal part's centroid, build mm.
    pub center_mm: [f64; 3],
    /// Mean |distance| of the CT surface to the vectors as registered, µm ...
    pub mean_abs_um: f64,
    /// ... and with the CT turned ±`probe_deg` about the axis (the better of the two), µm.
    pub turned_mean_abs_um: f64,
    pub probe_deg: f64,
    pub note: String,
}

impl std::fmt::Display for FreeRotation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.note)
    }
}

/// The principal axes of `nominal` about which turning the registered surface (`points`, build
/// mm) by ±[`PROBE_DEG`] fits the field about as well as not turning it (mean |Ψ| at most twice
/// the registered one plus 5 µm): the registration's rotation about them is arbitrary.
pub fn free_rotations(
    points: &[[f64; 3]],
    field: &dyn DistanceField,
    nominal: &PartShape,
) -> Vec<FreeRotation> {
    if points.is_empty() {
        return Vec::new();
    }
    let step = points.len().div_ceil(MAX_POINTS);
    let probe: Vec<Vector3<f64>> = points.iter().step_by(step).map(|p| (*p).into()).collect();
    let trunc = field.truncation_mm();
    let center = Vector3::from(nominal.centroid);
    let mean_abs = |rotation: &Rotation3<f64>| -> f64 {
        let sum: f64 = probe
            .par_iter()
            .map(|p| {
                let q = center + rotation * (p - center);
                field
                    .sample_with_gradient([q.x, q.y, q.z])
                    .map_or(trunc, |(d, _)| d.abs().min(trunc))
            })
            .sum();
        sum / probe.len() as f64
    };
    let base = mean_abs(&Rotation3::identity());
    nominal
        .axes
        .iter()
        .filter_map(|a| {
            let axis = Unit::try_new(Vector3::from(*a), 1e-9)?;
            let turned = [PROBE_DEG, -PROBE_DEG]
                .map(|deg| mean_abs(&Rotation3::from_axis_angle(&axis, deg.to_radians())))
                .into_iter()
                .fold(f64::INFINITY, f64::min);
            (turned <= 2.0 * base + 0.005).then(|| {
                let [x, y, z] = [axis.x, axis.y, axis.z];
                let [cx, cy, cz] = nominal.centroid;
                FreeRotation {
                    axis: [x, y, z],
                    center_mm: nominal.centroid,
                    mean_abs_um: base * 1e3,
                    turned_mean_abs_um: turned * 1e3,
                    probe_deg: PROBE_DEG,
                    note: format!(
                        "the rotation about the axis ({x:.3}, {y:.3}, {z:.3}) through ({cx:.2}, {cy:.2}, {cz:.2}) mm \
                         is not determined: the part is symmetric about it (turned {PROBE_DEG}° it fits to {:.1} µm, \
                         against {:.1} µm), so the angle about it in the transform is arbitrary; register with \
                         --init points on a feature that breaks the symmetry, or treat that angle as unknown",
                        turned * 1e3,
                        base * 1e3
                    ),
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vertical cylinder r = 4 at the origin, 0 < z < 3 (exact SDF), truncated at 1 mm.
    struct Cylinder {
        fin: bool,
    }

    impl DistanceField for Cylinder {
        fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
            let d = [(p[0].hypot(p[1])) - 4.0, (p[2] - 1.5).abs() - 1.5];
            let mut v = d[0].max(d[1]).min(0.0) + d[0].max(0.0).hypot(d[1].max(0.0));
            if self.fin {
                // A 2 x 1 mm fin on the +x side.
                let q = [
                    (p[0] - 5.0).abs() - 1.0,
                    p[1].abs() - 0.5,
                    (p[2] - 1.5).abs() - 1.5,
                ];
                let out = q.iter().map(|v| v.max(0.0).powi(2)).sum::<f64>().sqrt();
                v = v.min(out + q[0].max(q[1]).max(q[2]).min(0.0));
            }
            Some((v.clamp(-1.0, 1.0), [0.0; 3]))
        }
        fn truncation_mm(&self) -> f64 {
            1.0
        }
    }

    fn surface(fin: bool) -> Vec<[f64; 3]> {
        let mut pts = Vec::new();
        for k in 0..=30 {
            let z = 0.1 * k as f64;
            for i in 0..180 {
                let a = (i as f64 * 2.0).to_radians();
                pts.push([4.0 * a.cos(), 4.0 * a.sin(), z]);
            }
            if fin {
                for i in 0..=20 {
                    let x = 4.0 + 0.1 * i as f64;
                    pts.push([x, 0.5, z]);
                    pts.push([x, -0.5, z]);
                }
            }
        }
        pts
    }

    fn shape() -> PartShape {
        PartShape {
            centroid: [0.0, 0.0, 1.5],
            axes: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            extents_mm: [8.0, 8.0, 3.0],
        }
    }

    #[test]
    fn a_plain_cylinder_is_free_about_its_axis_only() {
        let free = free_rotations(&surface(false), &Cylinder { fin: false }, &shape());
        assert_eq!(free.len(), 1, "{free:?}");
        assert!((free[0].axis[2].abs() - 1.0).abs() < 1e-9);
        assert!(free[0].note.contains("not determined"), "{}", free[0].note);
    }

    #[test]
    fn a_fin_breaks_the_symmetry() {
        let free = free_rotations(&surface(true), &Cylinder { fin: true }, &shape());
        assert!(free.is_empty(), "{free:?}");
    }
}
