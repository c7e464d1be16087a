//! `layerwise rectify`: one frame through a calibration, to a PNG (colour kept) or to a DICOM
//! slice (luma, as the live series hold it).

use super::{decode_frame, decode_frame_luma, Calibration, Grid, Interpolation, Rectifier};
use crate::dicom::{self, Compression, Plane, Series, Slice, Study};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum RectifyFileError {
    #[error(transparent)]
    Calibration(#[from] super::CalibrationError),
    /// The frame could not be read from the disk.
    #[error("{path}: cannot read")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    /// The frame could not be decoded (the cause says why).
    #[error("{path}")]
    Decode {
        path: String,
        #[source]
        source: super::RectifyError,
    },
    /// The rectified picture could not be written.
    #[error("{path}: cannot write")]
    Write {
        path: String,
        #[source]
        source: image::ImageError,
    },
    #[error(transparent)]
    Rectify(#[from] super::RectifyError),
    #[error(transparent)]
    Dicom(#[from] dicom::DicomError),
    #[error("{path}: the output must end in .png or .dcm")]
    OutputKind { path: String },
}

/// Rectifies `image` through `calibration` onto `grid` (the configuration's `[rectify]`) and
/// writes `out`.
pub fn rectify_file(
    calibration: &Path,
    image: &Path,
    out: &Path,
    layer: u32,
    layer_thickness_mm: f64,
    grid: Grid,
) -> Result<Grid, RectifyFileError> {
    let calibration = Calibration::load(calibration)?;
    if let Some(note) = calibration.grid_note(&grid) {
        tracing::info!("{note}");
    }
    let rectifier = Rectifier::new(&calibration.camera(), grid, Interpolation::Bilinear, 0)?;
    let path = || image.display().to_string();
    let bad_image = |source| RectifyFileError::Decode {
        path: path(),
        source,
    };
    let bytes = crate::fsutil::read_regular(image).map_err(|source| RectifyFileError::Read {
        path: path(),
        source,
    })?;
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("png") => {
            let decoded = decode_frame(&bytes).map_err(bad_image)?;
            rectifier
                .rectify_dynamic(&decoded)
                .save(out)
                .map_err(|source| RectifyFileError::Write {
                    path: out.display().to_string(),
                    source,
                })?;
        }
        Some("dcm") => {
            let rectified = decode_frame_luma(&bytes)
                .map_err(bad_image)?
                .rectified(&rectifier);
            let (window, derivation) = (rectified.window(), rectified.derivation());
            let now = chrono::Utc::now();
            let study_uid = crate::dicom::new_uid();
            let study = Study {
                frame_of_reference_uid: dicom::derived_uid(&study_uid, "frame-of-reference"),
                study_instance_uid: study_uid,
                date: now.format("%Y%m%d").to_string(),
                time: now.format("%H%M%S").to_string(),
                patient_name: "layerwise^".into(),
                patient_id: "rectify".into(),
                study_id: "1".into(),
                description: format!("layerwise rectify {}", image.display()),
            };
            let series = Series::named(&study, 1, "rectified");
            let plane = Plane {
                origin: [
                    grid.x_min + grid.pixel_mm / 2.0,
                    grid.y_max - grid.pixel_mm / 2.0,
                    layer as f64 * layer_thickness_mm,
                ],
                pixel_mm: grid.pixel_mm,
                rows: grid.rows(),
                columns: grid.columns(),
                thickness_mm: layer_thickness_mm,
            };
            let slice = Slice {
                layer,
                plane,
                pixels: rectified.samples(),
                acquired: None,
                window,
                derivation,
            };
            dicom::write_slice(out, &study, &series, &slice, Compression::None)?;
        }
        _ => {
            return Err(RectifyFileError::OutputKind {
                path: out.display().to_string(),
            })
        }
    }
    Ok(grid)
}
