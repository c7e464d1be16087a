//! CT volumes and their readers: GE phoenix `.vol` + `.pcr` ([`read_phoenix`]), VGStudio `.vgi`
//! ([`read_vgi`]), explicit raw ([`read_raw`]), TIFF stacks ([`read_tiff_stack`]) and
//! (feature-free) DICOM series ([`read_dicom_series`]).
//!
//! Voxels keep their stored type (a 1024³ u16 volume is 2 GiB, not 4 as f32) and raw files are
//! read slice by slice, so peak memory is the volume plus one slice.

mod dicom;
mod ini;
mod phoenix;
mod raw;
mod tiff;
mod vgi;

use std::path::{Path, PathBuf};

use super::{io_err, CtError, Result};

pub use dicom::read_dicom_series;
pub use phoenix::{phoenix_spec, read_phoenix, write_phoenix};
pub use raw::{check_voxels, read_raw, RawDtype, RawSpec, MAX_VOXELS};
pub use tiff::read_tiff_stack;
pub use vgi::{read_vgi, vgi_spec};

/// Voxel values in their stored type; `Volume::rescale` maps them to physical units.
#[derive(Debug, Clone, PartialEq)]
pub enum VoxelData {
    U8(Vec<u8>),
    U16(Vec<u16>),
    I16(Vec<i16>),
    F32(Vec<f32>),
}

impl VoxelData {
    pub fn len(&self) -> usize {
        match self {
            VoxelData::U8(v) => v.len(),
            VoxelData::U16(v) => v.len(),
            VoxelData::I16(v) => v.len(),
            VoxelData::F32(v) => v.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A stored voxel type.
pub trait Voxel: Copy + Send + Sync + 'static {
    fn to_f32(self) -> f32;
}
impl Voxel for u8 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for u16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for i16 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
impl Voxel for f32 {
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

/// Run a generic body on the stored slice, whatever its type.
macro_rules! with_voxels {
    ($data:expr, $v:ident => $body:expr) => {
        match $data {
            $crate::ct::volume::VoxelData::U8($v) => $body,
            $crate::ct::volume::VoxelData::U16($v) => $body,
            $crate::ct::volume::VoxelData::I16($v) => $body,
            $crate::ct::volume::VoxelData::F32($v) => $body,
        }
    };
}
pub(crate) use with_voxels;

/// A CT volume: x (column) fastest, then y (row), then z (slice).
#[derive(Debug, Clone)]
pub struct Volume {
    pub dims: [usize; 3],
    /// Spacing along the index axes, mm.
    pub voxel_mm: [f64; 3],
    /// Voxel index (i, j, k, 1) → CT physical mm (DICOM patient coordinates, or index × voxel
    /// size for raw volumes).
    pub index_to_mm: [[f64; 4]; 4],
    pub data: VoxelData,
    /// Physical value = stored × slope + intercept (DICOM RescaleSlope/Intercept; 1, 0 else).
    pub rescale_slope: f64,
    pub rescale_intercept: f64,
}

impl Volume {
    /// A volume whose physical coordinates are index × voxel size (raw files, TIFF stacks).
    pub fn new_scaled(dims: [usize; 3], voxel_mm: [f64; 3], data: VoxelData) -> Result<Self> {
        let n = dims[0]
            .checked_mul(dims[1])
            .and_then(|v| v.checked_mul(dims[2]))
            .ok_or_else(|| CtError::Invalid(format!("volume dims {dims:?} overflow")))?;
        if n != data.len() {
            return Err(CtError::Invalid(format!(
                "volume dims {dims:?} need {n} voxels, data has {}",
                data.len()
            )));
        }
        if voxel_mm.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(CtError::Invalid(format!(
                "voxel size {voxel_mm:?} mm must be positive"
            )));
        }
        let mut m = [[0.0; 4]; 4];
        for a in 0..3 {
            m[a][a] = voxel_mm[a];
        }
        m[3][3] = 1.0;
        Ok(Self {
            dims,
            voxel_mm,
            index_to_mm: m,
            data,
            rescale_slope: 1.0,
            rescale_intercept: 0.0,
        })
    }

    pub fn len(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Physical value of voxel `i` (linear index).
    pub fn value(&self, i: usize) -> f64 {
        let raw = with_voxels!(&self.data, v => v[i].to_f32()) as f64;
        raw * self.rescale_slope + self.rescale_intercept
    }

    /// Continuous voxel index → CT physical mm.
    pub fn index_to_physical(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.index_to_mm;
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    /// Smallest and largest physical value.
    pub fn value_range(&self) -> (f64, f64) {
        use rayon::prelude::*;
        let (lo, hi) = with_voxels!(&self.data, v => v
            .par_chunks(1 << 16)
            .map(|c| c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), x| {
                let x = x.to_f32();
                (lo.min(x), hi.max(x))
            }))
            .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1))));
        let a = lo as f64 * self.rescale_slope + self.rescale_intercept;
        let b = hi as f64 * self.rescale_slope + self.rescale_intercept;
        (a.min(b), a.max(b))
    }
}

/// Where a CT volume comes from (what the command line names).
#[derive(Debug, Clone, PartialEq)]
pub enum VolumeSource {
    /// GE phoenix `.pcr` or `.vol` (the other is found beside it).
    Phoenix(PathBuf),
    /// VGStudio `.vgi` and the raw file it names.
    Vgi(PathBuf),
    /// Headerless raw with an explicit layout (`--size --voxel-mm --dtype`).
    Raw(PathBuf, RawSpec),
    /// Folder of `.tif` slices with an isotropic voxel size in mm.
    Tiff(PathBuf, f64),
    /// Folder holding one DICOM series.
    Dicom(PathBuf),
}

impl VolumeSource {
    /// Guess from a path: `.pcr`/`.vol` → phoenix, `.vgi` → VGStudio, a folder with `.tif` files
    /// → TIFF stack (needs `voxel_mm`), any other folder → DICOM.
    pub fn detect(path: &Path, voxel_mm: Option<f64>) -> Result<Self> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        if path.is_dir() {
            let has_tiff = std::fs::read_dir(path).map_err(io_err(path))?.any(|e| {
                e.ok().is_some_and(|e| {
                    let p = e.path();
                    let x = p
                        .extension()
                        .map(|x| x.to_string_lossy().to_ascii_lowercase());
                    matches!(x.as_deref(), Some("tif" | "tiff"))
                })
            });
            return Ok(match (has_tiff, voxel_mm) {
                (true, Some(v)) => VolumeSource::Tiff(path.to_path_buf(), v),
                (true, None) => {
                    return Err(CtError::Invalid(format!(
                        "{}: a TIFF stack needs the voxel size (--voxel-mm)",
                        path.display()
                    )))
                }
                (false, _) => VolumeSource::Dicom(path.to_path_buf()),
            });
        }
        match ext.as_str() {
            "pcr" | "vol" => Ok(VolumeSource::Phoenix(path.to_path_buf())),
            "vgi" => Ok(VolumeSource::Vgi(path.to_path_buf())),
            _ => Err(CtError::Invalid(format!(
                "{}: not a .pcr/.vol/.vgi file or a folder; for other raw files give --size, \
                 --voxel-mm and --dtype",
                path.display()
            ))),
        }
    }
}

/// Read a CT volume from any supported source, at most [`MAX_VOXELS`] voxels.
pub fn read_volume(source: &VolumeSource) -> Result<Volume> {
    read_volume_capped(source, MAX_VOXELS)
}

/// Read a CT volume from any supported source; a volume of more than `max_voxels` voxels is
/// refused from its header, before anything is allocated.
pub fn read_volume_capped(source: &VolumeSource, max_voxels: usize) -> Result<Volume> {
    match source {
        VolumeSource::Phoenix(p) => read_phoenix(p, max_voxels),
        VolumeSource::Vgi(p) => read_vgi(p, max_voxels),
        VolumeSource::Raw(p, spec) => read_raw(p, spec, max_voxels),
        VolumeSource::Tiff(p, v) => read_tiff_stack(p, [*v; 3], max_voxels),
        VolumeSource::Dicom(p) => read_dicom_series(p, max_voxels),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A fresh scratch folder for one test.
    pub(crate) fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("layerwise-ct-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("scratch dir");
        d
    }

    /// `n` little-endian u16 voxels written to `path`.
    pub(crate) fn write_u16(path: &Path, n: usize) -> Vec<u16> {
        let v: Vec<u16> = (0..n).map(|i| (i * 7 % 65521) as u16).collect();
        let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
        std::fs::write(path, bytes).expect("write raw");
        v
    }

    #[test]
    fn detect_sources() {
        let d = scratch("detect");
        assert_eq!(
            VolumeSource::detect(&d.join("a.PCR"), None).expect("pcr"),
            VolumeSource::Phoenix(d.join("a.PCR"))
        );
        assert!(matches!(
            VolumeSource::detect(&d.join("a.vgi"), None),
            Ok(VolumeSource::Vgi(_))
        ));
        assert!(matches!(
            VolumeSource::detect(&d, None),
            Ok(VolumeSource::Dicom(_))
        ));
        std::fs::write(d.join("s0.tif"), b"x").expect("w");
        assert!(VolumeSource::detect(&d, None).is_err());
        assert!(matches!(
            VolumeSource::detect(&d, Some(0.05)),
            Ok(VolumeSource::Tiff(_, _))
        ));
        assert!(VolumeSource::detect(&d.join("a.raw"), None).is_err());
    }
}
