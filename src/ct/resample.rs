//! The registered CT resampled (trilinearly) into the build frame: one slice per layer on an
//! export grid, as pixels or as a DICOM CT series.

use std::path::Path;

use super::{CtError, Result, Volume};
use crate::dicom::{self, Compression, Plane, Series, Slice, Study};
use crate::geometry::{Affine3, Grid, Rigid3};
use crate::vectors::{LayerMap, VectorFile};

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

/// CT physical mm → fractional voxel index of `volume`.
pub fn index_from_ct(volume: &Volume) -> Result<Affine3> {
    let singular = || CtError::SingularGeometry {
        matrix: Box::new(volume.index_to_mm),
    };
    Affine3::from_matrix(volume.index_to_mm)
        .map_err(|_| singular())?
        .inverse()
        .ok_or_else(singular)
}

/// (printer layer from 1, z, thickness) of each layer of a vector file that `map` pairs with a
/// printer layer.
pub fn layer_planes(file: &VectorFile, map: &LayerMap) -> Vec<(u32, f64, f64)> {
    file.layers
        .iter()
        .enumerate()
        .filter_map(|(k, l)| {
            let layer = map.layer(k)?;
            let below = if k > 0 { file.layers[k - 1].z_mm } else { 0.0 };
            let t = l.z_mm - below;
            Some((layer, l.z_mm, if t > 0.0 { t } else { 0.03 }))
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
    build_from_ct: &Rigid3,
    grid: Grid,
    layers: &[(u32, f64, f64)],
) -> Result<Vec<CtSlice>> {
    use rayon::prelude::*;
    let ct_from_build = build_from_ct.inverse();
    let index_from_ct = index_from_ct(volume)?;
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
                        let index = index_from_ct.apply(ct_from_build.apply([x, y, z]));
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
    build_from_ct: &Rigid3,
    grid: Grid,
    layers: &[(u32, f64, f64)],
    study: &Study,
    series: &Series,
    out: &Path,
) -> Result<usize> {
    let mut written = 0;
    for s in resample_slices(volume, build_from_ct, grid, layers)? {
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
            pixels: (&s.pixels).into(),
            acquired: None,
            window: (32767.0, 65535.0),
            derivation: "CT resampled (trilinear) into the build frame through the CT-to-vector registration",
        };
        let path = out.join(format!("L{:05}.dcm", s.layer));
        dicom::write_slice(&path, study, series, &slice, Compression::Deflate)
            .map_err(CtError::ResampledDicom)?;
        written += 1;
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::VoxelData;

    #[test]
    fn a_singular_volume_geometry_is_a_typed_error() {
        let mut volume =
            Volume::new_scaled([2, 2, 2], [1.0; 3], VoxelData::U8(vec![0; 8])).expect("volume");
        volume.index_to_mm[2][2] = 0.0;
        let grid = Grid::on_plate_lattice([0.0, 0.0, 1.0, 1.0], 1.0, 0.5);
        let e = resample_slices(&volume, &Rigid3::IDENTITY, grid, &[(1, 0.5, 0.03)])
            .err()
            .expect("singular");
        assert!(matches!(e, CtError::SingularGeometry { .. }), "{e}");
    }
}
