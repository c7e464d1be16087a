//! Headerless little-endian raw volumes with an explicit layout.

use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::Path;

use super::voxels::{Volume, VoxelData};
use crate::ct::error::io_err;
use crate::ct::{CtError, Result};

/// Stored type of a raw volume.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawDtype {
    U8,
    U16,
    I16,
    F32,
}

impl RawDtype {
    pub fn bytes(self) -> usize {
        match self {
            RawDtype::U8 => 1,
            RawDtype::U16 | RawDtype::I16 => 2,
            RawDtype::F32 => 4,
        }
    }

    /// `u8`, `u16`, `i16` or `f32` (the `--dtype` option).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "u8" | "uint8" => Some(RawDtype::U8),
            "u16" | "uint16" => Some(RawDtype::U16),
            "i16" | "int16" => Some(RawDtype::I16),
            "f32" | "float32" | "float" => Some(RawDtype::F32),
            _ => None,
        }
    }
}

/// A headerless little-endian raw volume: x fastest, then y, then z.
#[derive(Debug, Clone, PartialEq)]
pub struct RawSpec {
    pub dims: [usize; 3],
    pub voxel_mm: [f64; 3],
    pub dtype: RawDtype,
    /// Bytes to skip at the start of the file.
    pub header_bytes: u64,
}

impl RawSpec {
    /// From the command line: `--size X,Y,Z --voxel-mm S --dtype u8|u16|f32`.
    pub fn from_args(size: &str, voxel_mm: f64, dtype: &str) -> Result<Self> {
        let parts: Vec<&str> = size
            .split([',', 'x', ' '])
            .filter(|s| !s.is_empty())
            .collect();
        let dims: Vec<usize> = parts.iter().filter_map(|s| s.trim().parse().ok()).collect();
        if parts.len() != 3 || dims.len() != 3 || dims.contains(&0) {
            return Err(CtError::Invalid(format!(
                "--size {size:?}: expected three positive integers X,Y,Z"
            )));
        }
        let dtype = RawDtype::parse(dtype).ok_or_else(|| {
            CtError::Invalid(format!("--dtype {dtype:?}: expected u8, u16, i16 or f32"))
        })?;
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(CtError::Invalid(format!(
                "--voxel-mm {voxel_mm}: must be positive"
            )));
        }
        Ok(Self {
            dims: [dims[0], dims[1], dims[2]],
            voxel_mm: [voxel_mm; 3],
            dtype,
            header_bytes: 0,
        })
    }
}

/// Largest volume read by default, in voxels (2 G: 4 GB of 16-bit voxels; the registration
/// bench's CT is 0.17 G voxels). `register ct --max-voxels N` lifts it for a bigger scan.
pub const MAX_VOXELS: usize = 1 << 31;

/// Refuses a volume of `dims` with more than `max_voxels` voxels, before anything is allocated;
/// returns the voxel count.
pub fn check_voxels(path: &Path, dims: [usize; 3], max_voxels: usize) -> Result<usize> {
    let [nx, ny, nz] = dims;
    nx.checked_mul(ny)
        .and_then(|v| v.checked_mul(nz))
        .filter(|&n| n <= max_voxels)
        .ok_or_else(|| {
            CtError::Invalid(format!(
                "{}: {nx} x {ny} x {nz} voxels is more than the {max_voxels} voxels a CT may \
                 have here (the default cap is {} G voxels): check the size, crop the volume, or \
                 lift the cap with --max-voxels N if the machine has the memory",
                path.display(),
                MAX_VOXELS >> 30
            ))
        })
}

/// Read a raw volume, one slice at a time; at most `max_voxels` voxels.
pub fn read_raw(path: &Path, spec: &RawSpec, max_voxels: usize) -> Result<Volume> {
    let [nx, ny, nz] = spec.dims;
    let bpv = spec.dtype.bytes();
    // The voxel count first: it names the file and the cap, and bounds what follows.
    let voxels = check_voxels(path, spec.dims, max_voxels)?;
    let overflow = || {
        CtError::Invalid(format!(
            "{}: {nx} x {ny} x {nz} voxels of {bpv} bytes after a header of {} bytes are more              bytes than a file can hold: check the size in the volume's description",
            path.display(),
            spec.header_bytes
        ))
    };
    let slice_bytes = nx
        .checked_mul(ny)
        .and_then(|v| v.checked_mul(bpv))
        .ok_or_else(overflow)?;
    let expected = (slice_bytes as u64)
        .checked_mul(nz as u64)
        .and_then(|v| v.checked_add(spec.header_bytes))
        .ok_or_else(overflow)?;
    let file = crate::fsutil::open_regular(path).map_err(io_err(path))?;
    let actual = file.metadata().map_err(io_err(path))?.len();
    if actual != expected {
        return Err(CtError::SizeMismatch {
            path: path.to_path_buf(),
            dims: spec.dims,
            bytes_per_voxel: bpv,
            header: spec.header_bytes,
            expected,
            actual,
        });
    }
    let mut reader = BufReader::with_capacity(1 << 20, file);
    reader
        .seek(SeekFrom::Start(spec.header_bytes))
        .map_err(io_err(path))?;
    let n = voxels;
    let mut buf = vec![0u8; slice_bytes];
    // Decode each slice into the final vector: no full-size byte copy.
    macro_rules! read_as {
        ($t:ty, $variant:ident) => {{
            let mut out: Vec<$t> = Vec::with_capacity(n);
            for _ in 0..nz {
                reader.read_exact(&mut buf).map_err(io_err(path))?;
                out.extend(
                    buf.chunks_exact(std::mem::size_of::<$t>())
                        .map(|c| <$t>::from_le_bytes(c.try_into().unwrap_or_default())),
                );
            }
            VoxelData::$variant(out)
        }};
    }
    let data = match spec.dtype {
        RawDtype::U8 => read_as!(u8, U8),
        RawDtype::U16 => read_as!(u16, U16),
        RawDtype::I16 => read_as!(i16, I16),
        RawDtype::F32 => read_as!(f32, F32),
    };
    Volume::new_scaled(spec.dims, spec.voxel_mm, data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::volume::tests::{scratch, write_u16};

    #[test]
    fn explicit_raw_spec() {
        let d = scratch("explicit");
        let v = write_u16(&d.join("x.raw"), 24);
        let spec = RawSpec::from_args("4,3,2", 0.1, "u16").expect("spec");
        let vol = read_raw(&d.join("x.raw"), &spec, MAX_VOXELS).expect("read");
        assert_eq!(vol.data, VoxelData::U16(v));
        assert!(RawSpec::from_args("4,3", 0.1, "u16").is_err());
        let msg = RawSpec::from_args("4,3,2", 0.1, "u12")
            .expect_err("u12")
            .to_string();
        assert!(msg.contains("u12"), "{msg}");
        let msg = read_raw(
            &d.join("x.raw"),
            &RawSpec::from_args("4,3,2", 0.1, "f32").expect("spec"),
            MAX_VOXELS,
        )
        .expect_err("f32 needs 96 bytes")
        .to_string();
        assert!(msg.contains("96") && msg.contains("48"), "{msg}");
    }

    #[test]
    fn sizes_past_any_file_name_the_file() {
        let d = scratch("overflow");
        write_u16(&d.join("x.raw"), 24);
        let huge = usize::MAX / 4;
        for (dims, cap) in [([6, huge, 6], MAX_VOXELS), ([huge, 3, 1], usize::MAX)] {
            let spec = RawSpec {
                dims,
                voxel_mm: [0.1; 3],
                dtype: RawDtype::U16,
                header_bytes: 0,
            };
            let msg = read_raw(&d.join("x.raw"), &spec, cap)
                .expect_err("no such file")
                .to_string();
            assert!(msg.contains("x.raw") && msg.contains("voxels"), "{msg}");
        }
    }
}
