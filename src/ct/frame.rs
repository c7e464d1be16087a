//! A registered CT's frame: its transform to the build frame (from ct.toml) and, when the CT can
//! be read, its voxel index geometry, so build points can be found in the CT and back.

use super::vectors_field::{apply, invert_affine, invert_rigid};
use serde::Serialize;
use std::path::Path;

/// Where a build point is in the registered CT.
#[derive(Clone, Debug, Serialize)]
pub struct CtLocation {
    /// CT physical mm (DICOM patient coordinates of the CT, or voxel index x voxel size).
    pub ct_mm: [f64; 3],
    /// Fractional voxel index (i, j, k), when the CT volume could be read.
    pub voxel: Option<[f64; 3]>,
}

/// The CT transform of a ct.toml and, when its source can be read, the CT's index geometry.
pub struct CtFrame {
    pub ct_to_build: [[f64; 4]; 4],
    pub mm_to_index: Option<[[f64; 4]; 4]>,
}

impl CtFrame {
    pub fn open(ct_toml: &Path) -> Result<CtFrame, super::CtError> {
        let registration = super::CtRegistration::read_toml(ct_toml)?;
        let mm_to_index = registration
            .source
            .as_ref()
            .and_then(|s| s.read().ok())
            .and_then(|v| invert_affine(&v.index_to_mm));
        Ok(CtFrame {
            ct_to_build: registration.transform,
            mm_to_index,
        })
    }

    /// CT mm → build mm.
    pub fn to_build(&self, ct_mm: [f64; 3]) -> [f64; 3] {
        apply(&self.ct_to_build, ct_mm)
    }

    /// Build mm → CT mm and voxel.
    pub fn locate(&self, build_mm: [f64; 3]) -> CtLocation {
        let ct_mm = apply(&invert_rigid(&self.ct_to_build), build_mm);
        CtLocation {
            ct_mm,
            voxel: self.mm_to_index.map(|m| apply(&m, ct_mm)),
        }
    }
}
