//! The whole `layerwise register ct` run: the TSDF of the laser vectors as the distance field,
//! the nominal part's shape from it, the registration, and the files asked for (ct.toml, the
//! surface PLY, the CT resampled into the build frame as a DICOM series).

use std::path::{Path, PathBuf};

use super::resample::{layer_planes, resample_to_dicom};
use super::symmetry::{free_rotations, FreeRotation};
use super::{
    register, CtError, CtParams, CtRegistration, CtSource, DistanceField, InitialTransform,
    PartShape, Result, Volume,
};
use crate::dicom::{self, Series, Study};
use crate::geometry::Grid;
use crate::tsdf::{self, Tsdf, TsdfParams};

impl DistanceField for Tsdf {
    fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
        Tsdf::sample_with_gradient(self, p)
            .map(|(d, g)| (d as f64, [g[0] as f64, g[1] as f64, g[2] as f64]))
    }
    fn truncation_mm(&self) -> f64 {
        self.truncation_mm
    }
}

/// Centroid, principal axes and extents of the part the vectors describe: the centers of the
/// TSDF voxels inside it.
pub fn nominal_shape(field: &Tsdf) -> PartShape {
    let [nx, ny, nz] = field.dims;
    let mut inside = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                if field.get(i, j, k).is_some_and(|d| d < 0.0) {
                    inside.push(field.index_to_build(i, j, k));
                }
            }
        }
    }
    PartShape::from_points(&inside)
}

/// What `layerwise register ct` is asked to do.
#[derive(Clone, Debug)]
pub struct CtRequest {
    pub vectors: PathBuf,
    pub part: Option<i64>,
    pub init: InitialTransform,
    pub out: PathBuf,
    pub surface_ply: Option<PathBuf>,
    pub resample_dicom: Option<PathBuf>,
    /// The build whose study and frame of reference the resampled CT joins (else a new study).
    pub build: Option<PathBuf>,
    pub tsdf_voxel_mm: f64,
    pub params: CtParams,
    /// Recorded in ct.toml so the export can read the CT again.
    pub source: CtSource,
    /// How printer layers pair with the vector file's layers (the resampled series' numbers).
    pub numbering: crate::vectors::LayerNumbering,
}

/// What `register ct` found and wrote.
#[derive(Debug, Clone)]
pub struct CtOutcome {
    pub registration: CtRegistration,
    /// Axes about which the rotation is arbitrary (each also logged at WARN and noted in ct.toml).
    pub free_rotations: Vec<FreeRotation>,
}

/// Registers `volume` to the vectors and writes ct.toml (and the PLY and resampled DICOM asked for).
pub fn register_ct(request: &CtRequest, volume: &Volume) -> Result<CtOutcome> {
    let file = crate::vectors::read(&request.vectors).map_err(CtError::Vectors)?;
    let params = TsdfParams {
        voxel_mm: request.tsdf_voxel_mm,
        part: request.part,
        ..TsdfParams::default()
    };
    let field = tsdf::build(&file, &params).map_err(|source| CtError::DistanceField {
        path: request.vectors.clone(),
        source,
    })?;
    let nominal = nominal_shape(&field);
    let registered = register(volume, &field, &nominal, &request.init, &request.params)?;
    let free_rotations = free_rotations(&registered.points_build_mm, &field, &nominal);
    for free in &free_rotations {
        tracing::warn!("{}: {free}", request.ct_name());
    }
    let text = registered
        .registration
        .to_toml_string_noting(Some(request.source.clone()), &free_rotations);
    std::fs::write(&request.out, text).map_err(super::write_err(&request.out))?;
    if let Some(ply) = &request.surface_ply {
        super::ply::write_ply(
            ply,
            &registered.points_build_mm,
            &registered.distances_mm,
            field.truncation_mm.min(0.2),
        )?;
    }
    if let Some(dir) = &request.resample_dicom {
        let bbox = crate::raster::file_bbox(&file, request.part).ok_or_else(|| {
            CtError::NoVectorGeometry {
                path: request.vectors.clone(),
                part: request.part,
            }
        })?;
        let grid = Grid::on_plate_lattice(bbox, 1.0, 0.0625);
        let study = match request.build.as_deref() {
            Some(build) => build_study(build)?,
            None => standalone_study(),
        };
        let name = format!(
            "ct{}",
            request
                .part
                .map(|p| format!(" part {p}"))
                .unwrap_or_default()
        );
        let series = Series::named(&study, 50, &name);
        let map = crate::vectors::LayerMap::of_file(&file, request.numbering);
        let planes = layer_planes(&file, &map);
        resample_to_dicom(
            volume,
            &registered.registration.build_from_ct,
            grid,
            &planes,
            &study,
            &series,
            dir,
        )?;
    }
    Ok(CtOutcome {
        registration: registered.registration,
        free_rotations,
    })
}

impl CtRequest {
    /// The CT's path as the user gave it to be recorded.
    fn ct_name(&self) -> &str {
        &self.source.path
    }
}

/// The study of a build (its build.json).
pub fn build_study(dir: &Path) -> Result<Study> {
    let path = dir.join(crate::build_dir::MANIFEST);
    let bytes = crate::build_dir::read_record_file(&path).map_err(|source| CtError::NotABuild {
        dir: dir.to_path_buf(),
        source,
    })?;
    let manifest: crate::build_dir::BuildManifest =
        serde_json::from_slice(&bytes).map_err(|source| CtError::BadManifest { path, source })?;
    Ok(manifest.study())
}

fn standalone_study() -> Study {
    let uid = crate::dicom::new_uid();
    let now = chrono::Utc::now();
    Study {
        frame_of_reference_uid: dicom::derived_uid(&uid, "frame-of-reference"),
        study_instance_uid: uid,
        date: now.format("%Y%m%d").to_string(),
        time: now.format("%H%M%S").to_string(),
        patient_name: "layerwise^".into(),
        patient_id: "ct".into(),
        study_id: "1".into(),
        description: "layerwise CT resampled to the build frame".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error;

    #[test]
    fn build_study_names_the_folder_and_keeps_the_cause() {
        let dir = crate::ct::volume::tests::scratch("not-a-build");
        let e = build_study(&dir).expect_err("no build.json");
        assert!(matches!(e, CtError::NotABuild { .. }), "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("not-a-build") && msg.contains("build.json"),
            "{msg}"
        );
        assert!(
            !msg.contains("os error"),
            "the cause is the source, not the message: {msg}"
        );
        assert!(e.source().is_some());
        std::fs::write(dir.join(crate::build_dir::MANIFEST), "{").expect("write");
        let e = build_study(&dir).expect_err("bad json");
        assert!(matches!(e, CtError::BadManifest { .. }), "{e}");
    }
}
