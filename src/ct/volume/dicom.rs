//! DICOM CT series: one slice per file, any orientation.

use std::path::{Path, PathBuf};

use super::voxels::{with_voxels, Volume, Voxel, VoxelData};
use crate::ct::error::io_err;
use crate::ct::{CtError, Result};

/// One slice's header, read without its pixels.
struct DicomSlice {
    path: PathBuf,
    position: [f64; 3],
    rows: usize,
    columns: usize,
    spacing: [f64; 2],
    orientation: [f64; 6],
    slope: f64,
    intercept: f64,
}

/// Farthest a slice may be from the patient origin, mm.
const MAX_POSITION_MM: f64 = 1e6;

fn dicom_err(path: &Path, message: impl Into<String>) -> CtError {
    CtError::Format {
        path: path.to_path_buf(),
        message: message.into(),
    }
}

fn value_err(path: &Path, key: &str, source: dicom_core::value::ConvertValueError) -> CtError {
    CtError::DicomValue {
        path: path.to_path_buf(),
        key: key.to_string(),
        source,
    }
}

type DicomObject = dicom_object::DefaultDicomObject;

fn dicom_numbers(
    obj: &DicomObject,
    path: &Path,
    tag: dicom_core::Tag,
    name: &str,
    n: usize,
) -> Result<Vec<f64>> {
    let e = obj.element(tag).map_err(|_| CtError::MissingKey {
        path: path.to_path_buf(),
        section: String::new(),
        key: name.to_string(),
    })?;
    let v = e
        .to_multi_float64()
        .map_err(|source| value_err(path, name, source))?;
    if v.len() < n || v.iter().any(|x| !x.is_finite()) {
        return Err(dicom_err(
            path,
            format!("{name} has {} values {v:?}, expected {n}", v.len()),
        ));
    }
    Ok(v)
}

fn dicom_optional(
    obj: &DicomObject,
    path: &Path,
    tag: dicom_core::Tag,
    name: &str,
    default: f64,
) -> Result<f64> {
    match obj.element_opt(tag).ok().flatten() {
        None => Ok(default),
        Some(e) if dicom_core::header::HasLength::is_empty(e) => Ok(default),
        Some(e) => e
            .to_float64()
            .map_err(|source| value_err(path, name, source)),
    }
}

fn dicom_uint(obj: &DicomObject, path: &Path, tag: dicom_core::Tag, name: &str) -> Result<usize> {
    obj.element(tag)
        .map_err(|_| CtError::MissingKey {
            path: path.to_path_buf(),
            section: String::new(),
            key: name.to_string(),
        })?
        .to_int::<u32>()
        .map(|v| v as usize)
        .map_err(|source| value_err(path, name, source))
}

/// Read a folder holding one DICOM CT series (one slice per file, any orientation).
///
/// Geometry from ImagePositionPatient, ImageOrientationPatient and PixelSpacing; the slice axis
/// is the step between consecutive positions (so gantry tilt is kept) and must be uniform.
/// Values are RescaleSlope × stored + RescaleIntercept.
pub fn read_dicom_series(dir: &Path, max_voxels: usize) -> Result<Volume> {
    use dicom_dictionary_std::tags;
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io_err(dir))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    entries.sort();
    // Pass 1: headers only, to order the slices.
    let mut slices = Vec::new();
    for path in entries {
        // Every stated length must fit in the file before the parser sizes a read by it.
        let part10 = crate::dicom::check_lengths(&path).map_err(|e| match e {
            crate::dicom::DicomError::Damaged { message, .. } => dicom_err(&path, message),
            crate::dicom::DicomError::Io { source, .. } => io_err(&path)(source),
            other => CtError::Decode {
                path: path.clone(),
                what: "check the lengths of",
                source: Box::new(other),
            },
        })?;
        let obj = match dicom_object::OpenFileOptions::new()
            .read_until(tags::PIXEL_DATA)
            .open_file(&path)
        {
            Ok(obj) => obj,
            // A DICOM file that does not parse is damaged: named, never silently left out.
            Err(e) if part10 => {
                return Err(CtError::UnreadableDicom {
                    path,
                    source: Box::new(e),
                })
            }
            // Not a DICOM file (a DICOMDIR's companions, notes, thumbnails): skip it.
            Err(_) => continue,
        };
        if obj.element_opt(tags::ROWS).ok().flatten().is_none() {
            continue; // no image (e.g. a DICOMDIR or a structured report)
        }
        if dicom_optional(&obj, &path, tags::NUMBER_OF_FRAMES, "NumberOfFrames", 1.0)? > 1.0 {
            return Err(dicom_err(
                &path,
                "multi-frame DICOM is not supported: export one slice per file",
            ));
        }
        let position = dicom_numbers(
            &obj,
            &path,
            tags::IMAGE_POSITION_PATIENT,
            "ImagePositionPatient",
            3,
        )?;
        let orientation = dicom_numbers(
            &obj,
            &path,
            tags::IMAGE_ORIENTATION_PATIENT,
            "ImageOrientationPatient",
            6,
        )?;
        // Past a kilometre the slices' steps overflow (1e308 - -1e308 is infinite) and the
        // spacing check below means nothing.
        if position[..3]
            .iter()
            .any(|p| !p.is_finite() || p.abs() > MAX_POSITION_MM)
        {
            return Err(dicom_err(
                &path,
                format!(
                    "ImagePositionPatient {:?} mm: each must be a number within {MAX_POSITION_MM} \
                     mm of the origin",
                    &position[..3]
                ),
            ));
        }
        let spacing = dicom_numbers(&obj, &path, tags::PIXEL_SPACING, "PixelSpacing", 2)?;
        // A negative or zero spacing mirrors or collapses the volume: a registration would
        // fit the mirror image.
        let fine = crate::dicom::MIN_PIXEL_SPACING_MM;
        if spacing[..2].iter().any(|s| !(*s >= fine && *s <= 1000.0)) {
            return Err(dicom_err(
                &path,
                format!(
                    "PixelSpacing {:?} mm: each must be positive, from {fine} mm (a nanometre) \
                     to 1000 mm",
                    &spacing[..2]
                ),
            ));
        }
        slices.push(DicomSlice {
            rows: dicom_uint(&obj, &path, tags::ROWS, "Rows")?,
            columns: dicom_uint(&obj, &path, tags::COLUMNS, "Columns")?,
            position: [position[0], position[1], position[2]],
            spacing: [spacing[0], spacing[1]],
            orientation: std::array::from_fn(|i| orientation[i]),
            slope: dicom_optional(&obj, &path, tags::RESCALE_SLOPE, "RescaleSlope", 1.0)?,
            intercept: dicom_optional(
                &obj,
                &path,
                tags::RESCALE_INTERCEPT,
                "RescaleIntercept",
                0.0,
            )?,
            path,
        });
    }
    let Some(first) = slices.first() else {
        return Err(dicom_err(dir, "no DICOM image in the folder"));
    };
    let o = first.orientation;
    let row = nalgebra::Vector3::new(o[0], o[1], o[2]);
    let col = nalgebra::Vector3::new(o[3], o[4], o[5]);
    let normal = row.cross(&col);
    if (row.norm() - 1.0).abs() > 1e-3
        || (col.norm() - 1.0).abs() > 1e-3
        || row.dot(&col).abs() > 1e-3
    {
        return Err(dicom_err(
            &first.path,
            format!("ImageOrientationPatient {o:?} is not two orthonormal vectors"),
        ));
    }
    let (rows, columns, spacing) = (first.rows, first.columns, first.spacing);
    for s in &slices {
        let same_orientation = s
            .orientation
            .iter()
            .zip(&o)
            .all(|(a, b)| (a - b).abs() < 1e-4);
        if s.rows != rows || s.columns != columns || !same_orientation || s.spacing != spacing {
            return Err(dicom_err(
                &s.path,
                format!(
                    "slice is {}x{} at spacing {:?}, orientation {:?}; the first slice ({}) is \
                     {}x{} at {:?}, {:?}: not one series",
                    s.columns,
                    s.rows,
                    s.spacing,
                    s.orientation,
                    first.path.display(),
                    columns,
                    rows,
                    spacing,
                    o
                ),
            ));
        }
    }
    let proj = |s: &DicomSlice| normal.dot(&nalgebra::Vector3::from(s.position));
    slices.sort_by(|a, b| proj(a).total_cmp(&proj(b)));
    for w in slices.windows(2) {
        if (proj(&w[1]) - proj(&w[0])).abs() < 1e-6 {
            return Err(dicom_err(
                &w[1].path,
                format!("same slice position as {}", w[0].path.display()),
            ));
        }
    }
    let nz = slices.len();
    super::raw::check_voxels(dir, [columns, rows, nz], max_voxels)?;
    let p0 = nalgebra::Vector3::from(slices[0].position);
    let step = if nz > 1 {
        (nalgebra::Vector3::from(slices[nz - 1].position) - p0) / (nz - 1) as f64
    } else {
        // A single slice: unit thickness along the normal.
        normal * spacing[0]
    };
    let dz = step.norm();
    for (k, s) in slices.iter().enumerate() {
        let expect = p0 + step * k as f64;
        if (nalgebra::Vector3::from(s.position) - expect).norm() > 0.01 * dz {
            return Err(dicom_err(
                &s.path,
                format!(
                    "non-uniform slice spacing: slice {k} is at {:?}, expected {:?}",
                    s.position,
                    [expect.x, expect.y, expect.z]
                ),
            ));
        }
    }
    // Index (i = column, j = row, k = slice) → patient mm. PixelSpacing is [row spacing
    // (between rows, along the column direction), column spacing].
    let ex = row * spacing[1];
    let ey = col * spacing[0];
    let mut m = [[0.0; 4]; 4];
    for r in 0..3 {
        m[r] = [ex[r], ey[r], step[r], p0[r]];
    }
    m[3][3] = 1.0;

    // Pass 2: pixels in slice order, appended to one typed vector.
    let uniform_rescale = slices
        .iter()
        .all(|s| s.slope == slices[0].slope && s.intercept == slices[0].intercept);
    let n = rows * columns;
    let mut data: Option<VoxelData> = None;
    for s in &slices {
        use dicom_pixeldata::PixelDecoder;
        let obj = dicom_object::open_file(&s.path).map_err(|e| CtError::Decode {
            path: s.path.clone(),
            what: "read the DICOM file",
            source: Box::new(e),
        })?;
        let px = obj.decode_pixel_data().map_err(|e| CtError::Decode {
            path: s.path.clone(),
            what: "decode the pixel data of",
            source: Box::new(e),
        })?;
        let bits = px.bits_allocated();
        let signed = matches!(
            px.pixel_representation(),
            dicom_pixeldata::PixelRepresentation::Signed
        );
        if px.samples_per_pixel() != 1 {
            return Err(dicom_err(&s.path, "not a grayscale image"));
        }
        let bytes = px.data();
        if bytes.len() < n * (bits as usize / 8).max(1) {
            return Err(dicom_err(
                &s.path,
                format!(
                    "pixel data is {} bytes for {columns}x{rows} pixels of {bits} bits",
                    bytes.len()
                ),
            ));
        }
        let stored = px.bits_stored().clamp(1, 16) as u32;
        // Sign-extend signed values stored in fewer bits than allocated.
        let sext = |v: u16| -> i16 {
            let shift = 16 - stored;
            ((v << shift) as i16) >> shift
        };
        let slice_vals: VoxelData = match (bits, signed) {
            (8, false) => VoxelData::U8(bytes[..n].to_vec()),
            (16, false) => VoxelData::U16(
                bytes[..2 * n]
                    .chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect(),
            ),
            (16, true) => VoxelData::I16(
                bytes[..2 * n]
                    .chunks_exact(2)
                    .map(|c| sext(u16::from_le_bytes([c[0], c[1]])))
                    .collect(),
            ),
            _ => {
                return Err(CtError::UnknownDtype {
                    path: s.path.clone(),
                    dtype: format!(
                        "BitsAllocated={bits}, PixelRepresentation={}",
                        if signed { 1 } else { 0 }
                    ),
                    expected: "8-bit unsigned or 16-bit pixels",
                })
            }
        };
        // Slices with their own rescale are converted to physical f32 values.
        let slice_vals = if uniform_rescale {
            slice_vals
        } else {
            let v: Vec<f32> = with_voxels!(&slice_vals, v => v.iter().map(|x| (x.to_f32() as f64 * s.slope + s.intercept) as f32).collect());
            VoxelData::F32(v)
        };
        let total = n * nz;
        let acc = data.get_or_insert_with(|| match &slice_vals {
            VoxelData::U8(_) => VoxelData::U8(Vec::with_capacity(total)),
            VoxelData::U16(_) => VoxelData::U16(Vec::with_capacity(total)),
            VoxelData::I16(_) => VoxelData::I16(Vec::with_capacity(total)),
            VoxelData::F32(_) => VoxelData::F32(Vec::with_capacity(total)),
        });
        match (acc, slice_vals) {
            (VoxelData::U8(a), VoxelData::U8(b)) => a.extend(b),
            (VoxelData::U16(a), VoxelData::U16(b)) => a.extend(b),
            (VoxelData::I16(a), VoxelData::I16(b)) => a.extend(b),
            (VoxelData::F32(a), VoxelData::F32(b)) => a.extend(b),
            _ => {
                return Err(dicom_err(
                    &s.path,
                    "pixel type differs from the first slice's",
                ))
            }
        }
    }
    let data = data.unwrap_or(VoxelData::U8(Vec::new()));
    let (slope, intercept) = if uniform_rescale {
        (slices[0].slope, slices[0].intercept)
    } else {
        (1.0, 0.0)
    };
    Ok(Volume {
        dims: [columns, rows, nz],
        voxel_mm: [spacing[1], spacing[0], dz],
        index_to_mm: m,
        data,
        rescale_slope: slope,
        rescale_intercept: intercept,
    })
}
