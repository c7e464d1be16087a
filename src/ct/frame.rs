//! A registered CT's frame: its transform to the build frame (from ct.toml) and, when the CT can
//! be read, its voxel index geometry, so build points can be found in the CT and back.

use std::path::Path;

use serde::Serialize;

use super::{CtError, CtRegistration};
use crate::geometry::{Affine3, Rigid3};

/// Where a build point is in the registered CT.
#[derive(Clone, Debug, Serialize)]
pub struct CtLocation {
    /// CT physical mm (DICOM patient coordinates of the CT, or voxel index x voxel size).
    pub ct_mm: [f64; 3],
    /// Fractional voxel index (i, j, k), when the CT volume could be read.
    pub voxel: Option<[f64; 3]>,
}

/// The CT transform of a ct.toml and, when its source can be read, the CT's index geometry.
#[derive(Clone, Debug)]
pub struct CtFrame {
    /// CT physical mm → build mm (ct.toml's `transform`).
    pub build_from_ct: Rigid3,
    /// CT physical mm → fractional voxel index; `None` when the CT volume cannot be read.
    pub index_from_ct: Option<Affine3>,
}

impl CtFrame {
    /// The frame of a ct.toml; the CT it names is read for its voxel geometry if it can be.
    pub fn open(ct_toml: &Path) -> Result<CtFrame, CtError> {
        let registration = CtRegistration::read_toml(ct_toml)?;
        let index_from_ct = registration
            .source
            .as_ref()
            .and_then(|s| s.read().ok())
            .and_then(|v| super::resample::index_from_ct(&v).ok());
        Ok(CtFrame {
            build_from_ct: registration.build_from_ct,
            index_from_ct,
        })
    }

    /// CT mm → build mm.
    pub fn to_build(&self, ct_mm: [f64; 3]) -> [f64; 3] {
        self.build_from_ct.apply(ct_mm)
    }

    /// Build mm → CT mm and voxel.
    pub fn locate(&self, build_mm: [f64; 3]) -> CtLocation {
        let ct_mm = self.build_from_ct.inverse().apply(build_mm);
        CtLocation {
            ct_mm,
            voxel: self.index_from_ct.map(|m| m.apply(ct_mm)),
        }
    }
}
