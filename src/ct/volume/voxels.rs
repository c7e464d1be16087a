//! Voxels in their stored type and the volume that holds them.

use crate::ct::{CtError, Result};

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
