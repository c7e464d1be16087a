//! The on-disk `ct.toml`: the transform, the error figures and where the CT came from.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::symmetry::FreeRotation;
use super::{
    io_err, write_err, CtError, CtRegistration, RawSpec, Result, Termination, Volume, VolumeSource,
};
use crate::geometry::Rigid3;

/// The on-disk layout of `ct.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CtToml {
    /// CT physical mm → build mm, the 4x4 `transform` in the file.
    #[serde(rename = "transform")]
    pub build_from_ct: Rigid3,
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
    /// Axes about which the rotation is not determined (a part symmetric about them): the
    /// angle about each is arbitrary.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub free_rotation: Vec<FreeRotation>,
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
    /// Reads the volume it names (at most the default [`super::volume::MAX_VOXELS`]).
    pub fn read(&self) -> Result<Volume> {
        self.read_capped(super::volume::MAX_VOXELS)
    }

    /// Reads the volume it names, refusing one of more than `max_voxels` voxels from its header.
    pub fn read_capped(&self, max_voxels: usize) -> Result<Volume> {
        let path = std::path::PathBuf::from(&self.path);
        let source = match (&self.size, &self.dtype, self.voxel_mm) {
            (Some(size), Some(dtype), Some(voxel)) => {
                VolumeSource::Raw(path, RawSpec::from_args(size, voxel, dtype)?)
            }
            _ => VolumeSource::detect(&path, self.voxel_mm)?,
        };
        super::volume::read_volume_capped(&source, max_voxels)
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
    /// A transform known from elsewhere (a fixture's truth, another tool's registration): no
    /// iterations, no error figures.
    pub fn given(build_from_ct: Rigid3, threshold: f64) -> Self {
        Self {
            build_from_ct,
            iterations: 0,
            termination: Termination::SmallStep,
            threshold,
            points_used: 0,
            points_total: 0,
            points_excluded_plate: 0,
            points_outside: 0,
            mean_abs_um: 0.0,
            median_abs_um: 0.0,
            p95_abs_um: 0.0,
            max_abs_um: 0.0,
            rms_um: 0.0,
        }
    }

    pub fn to_toml_string(&self) -> String {
        self.to_toml_string_with(None)
    }

    /// `ct.toml` text, recording where the CT came from.
    pub fn to_toml_string_with(&self, source: Option<CtSource>) -> String {
        self.to_toml_string_noting(source, &[])
    }

    /// `ct.toml` text, recording where the CT came from and the rotations it does not determine.
    pub fn to_toml_string_noting(&self, source: Option<CtSource>, free: &[FreeRotation]) -> String {
        let file = CtToml {
            build_from_ct: self.build_from_ct,
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
            free_rotation: free.to_vec(),
        };
        // Serialising plain numbers and tables cannot fail.
        toml::to_string(&file).unwrap_or_default()
    }

    /// Write `ct.toml`.
    pub fn write_toml(&self, path: &Path) -> Result<()> {
        crate::fsutil::write_atomic(path, self.to_toml_string().as_bytes(), true)
            .map_err(|e| write_err(path)(e.source))
    }

    /// Read a `ct.toml` back (e.g. to apply the transform).
    pub fn read_toml(path: &Path) -> Result<CtToml> {
        let text = crate::fsutil::read_text_bounded(path, 1 << 20).map_err(io_err(path))?;
        toml::from_str(&text).map_err(|source| CtError::Toml {
            path: path.to_path_buf(),
            source: Box::new(source),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The layout ct.toml had before the transform became a [`Rigid3`]: a plain 4x4 array.
    #[derive(Serialize)]
    struct LegacyCtToml {
        transform: [[f64; 4]; 4],
        iterations: usize,
        termination: Termination,
        threshold: f64,
        mean_abs_distance_um: f64,
        rms_distance_um: f64,
        percentiles: Percentiles,
        points: PointCounts,
        #[serde(skip_serializing_if = "Option::is_none")]
        source: Option<CtSource>,
    }

    fn registration() -> CtRegistration {
        // A rotation by an odd angle about a tilted axis, as a registration produces it.
        let (s, c) = 0.3f64.sin_cos();
        let m = [
            [c, -s, 0.0, 12.345678901234],
            [s * 0.6, c * 0.6, -0.8, -3.0e-5],
            [s * 0.8, c * 0.8, 0.6, 101.1],
            [0.0, 0.0, 0.0, 1.0],
        ];
        CtRegistration {
            build_from_ct: Rigid3::from_matrix(m).expect("rigid"),
            iterations: 17,
            termination: Termination::SmallCostChange,
            threshold: 1234.5,
            points_used: 9000,
            points_total: 10000,
            points_excluded_plate: 800,
            points_outside: 200,
            mean_abs_um: 3.25,
            median_abs_um: 2.5,
            p95_abs_um: 8.75,
            max_abs_um: 40.0,
            rms_um: 4.0,
        }
    }

    fn legacy_text(r: &CtRegistration, source: Option<CtSource>) -> String {
        toml::to_string(&LegacyCtToml {
            transform: *r.build_from_ct.matrix(),
            iterations: r.iterations,
            termination: r.termination,
            threshold: r.threshold,
            mean_abs_distance_um: r.mean_abs_um,
            rms_distance_um: r.rms_um,
            percentiles: Percentiles {
                p50_um: r.median_abs_um,
                p95_um: r.p95_abs_um,
                max_um: r.max_abs_um,
            },
            points: PointCounts {
                used: r.points_used,
                total: r.points_total,
                excluded_plate: r.points_excluded_plate,
                outside_field: r.points_outside,
            },
            source,
        })
        .expect("legacy toml")
    }

    #[test]
    fn a_ct_toml_of_the_array_layout_loads_and_is_written_the_same() {
        let r = registration();
        let source = CtSource {
            path: "/data/scan.pcr".into(),
            voxel_mm: Some(0.05),
            size: None,
            dtype: None,
        };
        for source in [None, Some(source)] {
            let legacy = legacy_text(&r, source.clone());
            assert!(legacy.contains("transform = [["), "{legacy}");
            assert_eq!(r.to_toml_string_with(source.clone()), legacy);
            let dir = crate::ct::volume::tests::scratch("ct-toml-legacy");
            let path = dir.join("ct.toml");
            std::fs::write(&path, &legacy).expect("write");
            let back = CtRegistration::read_toml(&path).expect("legacy ct.toml loads");
            assert_eq!(back.build_from_ct, r.build_from_ct);
            assert_eq!(back.iterations, r.iterations);
            assert_eq!(back.points.excluded_plate, r.points_excluded_plate);
            assert_eq!(back.source, source);
        }
    }

    #[test]
    fn a_ct_toml_with_a_non_rigid_transform_is_refused() {
        let r = registration();
        let mut text = legacy_text(&r, None);
        let m = *r.build_from_ct.matrix();
        text = text.replacen(&format!("[[{:?}, ", m[0][0]), "[[2.0, ", 1);
        assert!(text.contains("[[2.0, "), "{text}");
        let dir = crate::ct::volume::tests::scratch("ct-toml-scaled");
        let path = dir.join("ct.toml");
        std::fs::write(&path, &text).expect("write");
        let e = CtRegistration::read_toml(&path).expect_err("scaled");
        assert!(matches!(e, CtError::Toml { .. }), "{e}");
        let chain = format!("{e}: {}", std::error::Error::source(&e).expect("source"));
        assert!(chain.contains("not a rotation"), "{chain}");
    }
}
