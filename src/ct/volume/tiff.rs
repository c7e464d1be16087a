//! Folders of TIFF slices.

use std::path::{Path, PathBuf};

use super::raw::check_voxels;
use super::voxels::{Volume, VoxelData};
use crate::ct::error::io_err;
use crate::ct::{CtError, Result};

/// Read a folder of `.tif`/`.tiff` slices sorted by name (slice k at z = k × voxel); at most
/// `max_voxels` voxels, checked from the first slice's header and the number of files before
/// anything is reserved or decoded.
pub fn read_tiff_stack(dir: &Path, voxel_mm: [f64; 3], max_voxels: usize) -> Result<Volume> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("tif") || e.eq_ignore_ascii_case("tiff"))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(CtError::Format {
            path: dir.to_path_buf(),
            message: "no .tif/.tiff files in the folder".into(),
        });
    }
    // Every slice a regular file before any is decoded: a FIFO named `*.tif` would hang the
    // read, a device never end.
    for f in &files {
        drop(crate::fsutil::open_regular(f).map_err(io_err(f))?);
    }
    let (w, h) = open_slice(&files[0], None)?
        .into_dimensions()
        .map_err(|e| CtError::Decode {
            path: files[0].clone(),
            what: "read the header of the TIFF slice",
            source: Box::new(e),
        })?;
    check_voxels(dir, [w as usize, h as usize, files.len()], max_voxels)?;
    let mut data: Option<VoxelData> = None;
    let mut wh = (0u32, 0u32);
    // A slice decodes into at most the first slice's size in 32-bit floats (4 channels of f32
    // for a colour slice), whatever its own header claims.
    let slice_bytes = (w as u64 * h as u64)
        .saturating_mul(16)
        .saturating_add(1 << 20);
    for (k, f) in files.iter().enumerate() {
        let img = open_slice(f, Some(slice_bytes))?
            .decode()
            .map_err(|e| CtError::Decode {
                path: f.clone(),
                what: "decode the TIFF slice",
                source: Box::new(e),
            })?;
        let size = (img.width(), img.height());
        if k == 0 {
            wh = size;
            let n = size.0 as usize * size.1 as usize * files.len();
            data = Some(match &img {
                image::DynamicImage::ImageLuma8(_) => VoxelData::U8(Vec::with_capacity(n)),
                image::DynamicImage::ImageLuma16(_) => VoxelData::U16(Vec::with_capacity(n)),
                _ => VoxelData::F32(Vec::with_capacity(n)),
            });
        } else if size != wh {
            return Err(CtError::Format {
                path: f.clone(),
                message: format!(
                    "slice is {}x{} but the first slice is {}x{}",
                    size.0, size.1, wh.0, wh.1
                ),
            });
        }
        match data.as_mut() {
            Some(VoxelData::U8(v)) => v.extend_from_slice(img.to_luma8().as_raw()),
            Some(VoxelData::U16(v)) => v.extend_from_slice(img.to_luma16().as_raw()),
            Some(VoxelData::F32(v)) => v.extend_from_slice(img.to_luma32f().as_raw()),
            _ => {}
        }
    }
    let data = data.unwrap_or(VoxelData::U8(Vec::new()));
    Volume::new_scaled([wh.0 as usize, wh.1 as usize, files.len()], voxel_mm, data)
}

/// A slice opened for decoding: a regular file (never waited on), its format guessed, its
/// allocations capped at `max_alloc` bytes when given.
fn open_slice(
    path: &Path,
    max_alloc: Option<u64>,
) -> Result<image::ImageReader<std::io::BufReader<std::fs::File>>> {
    let file = crate::fsutil::open_regular(path).map_err(io_err(path))?;
    let mut reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(io_err(path))?;
    let mut limits = image::Limits::default();
    limits.max_alloc = max_alloc.or(limits.max_alloc);
    reader.limits(limits);
    Ok(reader)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::volume::tests::scratch;

    #[test]
    fn tiff_stack_sorted_by_name() {
        let d = scratch("tiff");
        for (k, name) in [
            (1u16, "slice_002.tif"),
            (0, "slice_001.tif"),
            (2, "slice_010.tif"),
        ] {
            let img = image::ImageBuffer::<image::Luma<u16>, _>::from_fn(5, 4, |x, y| {
                image::Luma([1000 * k + 10 * y as u16 + x as u16])
            });
            img.save(d.join(name)).expect("tiff");
        }
        std::fs::write(d.join("notes.txt"), "ignored").expect("txt");
        let vol = read_tiff_stack(&d, [0.05; 3], crate::ct::volume::MAX_VOXELS).expect("stack");
        assert_eq!(vol.dims, [5, 4, 3]);
        assert!(matches!(vol.data, VoxelData::U16(_)));
        // Voxel (3, 2, 2) comes from slice_010.tif.
        assert_eq!(vol.value(3 + 5 * 2 + 20 * 2), 2023.0);
        let small = image::ImageBuffer::<image::Luma<u16>, _>::new(3, 3);
        small.save(d.join("slice_011.tif")).expect("tiff");
        let msg = read_tiff_stack(&d, [0.05; 3], crate::ct::volume::MAX_VOXELS)
            .expect_err("size")
            .to_string();
        assert!(
            msg.contains("slice_011.tif") && msg.contains("3x3"),
            "{msg}"
        );
    }
}
