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
mod voxels;

use std::path::{Path, PathBuf};

use super::error::io_err;
use super::{CtError, Result};

pub use dicom::read_dicom_series;
pub use phoenix::{phoenix_spec, read_phoenix, write_phoenix};
pub use raw::{check_voxels, read_raw, RawDtype, RawSpec, MAX_VOXELS};
pub use tiff::read_tiff_stack;
pub use vgi::{read_vgi, vgi_spec};
pub(crate) use voxels::with_voxels;
pub use voxels::{Volume, Voxel, VoxelData};

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
