//! The CT registration against the laser vectors: the TSDF of the vectors as the distance field,
//! the nominal part's shape from it, the whole `layerwise register ct` run, and the CT resampled
//! into the build frame as a DICOM series.

use super::{
    register, CtParams, CtRegistration, CtSource, DistanceField, InitialTransform, PartShape,
    Volume,
};
use crate::dicom::{self, Compression, Plane, Series, Slice, Study};
use crate::rectify::Grid;
use crate::tsdf::{self, Tsdf, TsdfParams};
use crate::vectors::VectorFile;
use std::path::{Path, PathBuf};

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
}

/// Registers `volume` to the vectors and writes ct.toml (and the PLY and resampled DICOM asked for).
pub fn register_ct(request: &CtRequest, volume: &Volume) -> Result<CtRegistration, String> {
    let file = crate::vectors::read(&request.vectors).map_err(|e| e.to_string())?;
    let params = TsdfParams {
        voxel_mm: request.tsdf_voxel_mm,
        part: request.part,
        ..TsdfParams::default()
    };
    let field =
        tsdf::build(&file, &params).map_err(|e| format!("{}: {e}", request.vectors.display()))?;
    let nominal = nominal_shape(&field);
    let registered = register(volume, &field, &nominal, &request.init, &request.params)
        .map_err(|e| e.to_string())?;
    let text = registered
        .registration
        .to_toml_string_with(Some(request.source.clone()));
    std::fs::write(&request.out, text).map_err(|e| format!("{}: {e}", request.out.display()))?;
    if let Some(ply) = &request.surface_ply {
        super::ply::write_ply(
            ply,
            &registered.points_build_mm,
            &registered.distances_mm,
            field.truncation_mm.min(0.2),
        )
        .map_err(|e| e.to_string())?;
    }
    if let Some(dir) = &request.resample_dicom {
        let bbox = crate::raster::file_bbox(&file, request.part)
            .ok_or("the vectors have no geometry to resample around")?;
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
        let planes = layer_planes(&file);
        resample_to_dicom(
            volume,
            &registered.registration.transform,
            grid,
            &planes,
            &study,
            &series,
            dir,
        )?;
    }
    Ok(registered.registration)
}

/// The inverse of a rigid 4x4 transform: Rᵀ and −Rᵀt.
pub fn invert_rigid(t: &[[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut inv = [[0.0; 4]; 4];
    for r in 0..3 {
        for c in 0..3 {
            inv[r][c] = t[c][r];
        }
        inv[r][3] = -(0..3).map(|c| t[c][r] * t[c][3]).sum::<f64>();
    }
    inv[3][3] = 1.0;
    inv
}

/// A 4x4 affine transform applied to a point.
pub fn apply(t: &[[f64; 4]; 4], p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|r| t[r][0] * p[0] + t[r][1] * p[1] + t[r][2] * p[2] + t[r][3])
}

/// The inverse of a 4x4 affine transform, if it has one.
pub fn invert_affine(m: &[[f64; 4]; 4]) -> Option<[[f64; 4]; 4]> {
    let a = nalgebra::Matrix4::from_fn(|r, c| m[r][c]);
    let inv = a.try_inverse()?;
    Some(std::array::from_fn(|r| {
        std::array::from_fn(|c| inv[(r, c)])
    }))
}

/// Trilinear sample of the CT's physical values at a fractional voxel index; None outside.
fn sample(volume: &Volume, p: [f64; 3]) -> Option<f64> {
    let [nx, ny, nz] = volume.dims;
    if p.iter().any(|v| !v.is_finite()) || p[0] < 0.0 || p[1] < 0.0 || p[2] < 0.0 {
        return None;
    }
    let (i, j, k) = (
        p[0].floor() as usize,
        p[1].floor() as usize,
        p[2].floor() as usize,
    );
    if i + 1 >= nx || j + 1 >= ny || k + 1 >= nz {
        return None;
    }
    let (fx, fy, fz) = (p[0] - i as f64, p[1] - j as f64, p[2] - k as f64);
    let at = |di: usize, dj: usize, dk: usize| {
        volume.value((k + dk) * nx * ny + (j + dj) * nx + (i + di))
    };
    let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
    let c00 = lerp(at(0, 0, 0), at(1, 0, 0), fx);
    let c10 = lerp(at(0, 1, 0), at(1, 1, 0), fx);
    let c01 = lerp(at(0, 0, 1), at(1, 0, 1), fx);
    let c11 = lerp(at(0, 1, 1), at(1, 1, 1), fx);
    Some(lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz))
}

/// The study of a build (its build.json).
pub fn build_study(dir: &Path) -> Result<Study, String> {
    let manifest: crate::build_dir::BuildManifest =
        std::fs::read(dir.join(crate::build_dir::MANIFEST))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .ok_or_else(|| {
                format!(
                    "{}: no build.json: not a layerwise build directory",
                    dir.display()
                )
            })?;
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

/// (layer number from 1, z, thickness) of each layer of a vector file.
pub fn layer_planes(file: &VectorFile) -> Vec<(u32, f64, f64)> {
    file.layers
        .iter()
        .enumerate()
        .map(|(k, l)| {
            let below = if k > 0 { file.layers[k - 1].z_mm } else { 0.0 };
            let t = l.z_mm - below;
            (k as u32 + 1, l.z_mm, if t > 0.0 { t } else { 0.03 })
        })
        .collect()
}

/// One layer of the CT resampled into the build frame.
pub struct CtSlice {
    pub layer: u32,
    pub z_mm: f64,
    pub thickness_mm: f64,
    /// Row-major on the grid; the CT's value range mapped to 0..65535, 0 where the CT does not reach.
    pub pixels: Vec<u16>,
}

/// The registered CT resampled (trilinearly) onto `grid`, one slice per layer at its z.
pub fn resample_slices(
    volume: &Volume,
    ct_to_build: &[[f64; 4]; 4],
    grid: Grid,
    layers: &[(u32, f64, f64)],
) -> Result<Vec<CtSlice>, String> {
    use rayon::prelude::*;
    let build_to_ct = invert_rigid(ct_to_build);
    let mm_to_index =
        invert_affine(&volume.index_to_mm).ok_or("the CT's index-to-mm matrix is singular")?;
    let (lo, hi) = volume.value_range();
    let scale = if hi > lo { 65535.0 / (hi - lo) } else { 1.0 };
    let cols = grid.columns();
    Ok(layers
        .iter()
        .map(|&(layer, z, thickness)| {
            let mut pixels = vec![0u16; grid.rows() * cols];
            pixels
                .par_chunks_mut(cols)
                .enumerate()
                .for_each(|(r, row)| {
                    for (c, px) in row.iter_mut().enumerate() {
                        let (x, y) = grid.center_of(r as f64, c as f64);
                        let index = apply(&mm_to_index, apply(&build_to_ct, [x, y, z]));
                        if let Some(v) = sample(volume, index) {
                            *px = ((v - lo) * scale).round().clamp(0.0, 65535.0) as u16;
                        }
                    }
                });
            CtSlice {
                layer,
                z_mm: z,
                thickness_mm: thickness,
                pixels,
            }
        })
        .collect())
}

/// The registered CT resampled onto `grid` as a CT Image series in `study`, so viewers overlay
/// it on the image views. Slices the CT does not reach are left out. Returns how many were written.
pub fn resample_to_dicom(
    volume: &Volume,
    ct_to_build: &[[f64; 4]; 4],
    grid: Grid,
    layers: &[(u32, f64, f64)],
    study: &Study,
    series: &Series,
    out: &Path,
) -> Result<usize, String> {
    let mut written = 0;
    for s in resample_slices(volume, ct_to_build, grid, layers)? {
        if s.pixels.iter().all(|&p| p == 0) {
            continue;
        }
        let slice = Slice {
            layer: s.layer,
            plane: Plane {
                origin: [grid.x_min + grid.pixel_mm / 2.0, grid.y_max - grid.pixel_mm / 2.0, s.z_mm],
                pixel_mm: grid.pixel_mm,
                rows: grid.rows(),
                columns: grid.columns(),
                thickness_mm: s.thickness_mm,
            },
            pixels: &s.pixels,
            acquired: None,
            window: (32767.0, 65535.0),
            derivation: "CT resampled (trilinear) into the build frame through the CT-to-vector registration",
        };
        let path = out.join(format!("L{:05}.dcm", s.layer));
        dicom::write_slice(&path, study, series, &slice, Compression::Deflate)
            .map_err(|e| e.to_string())?;
        written += 1;
    }
    Ok(written)
}
