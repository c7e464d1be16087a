//! [`CtError`]: everything the CT registration can refuse, with the file or the number that
//! explains it. Wrapped errors stay reachable through `source()` and are not repeated in the
//! message.

use std::path::{Path, PathBuf};

use crate::dicom::DicomError;
use crate::tsdf::TsdfError;
use crate::vectors::VectorError;

/// Everything that can go wrong, with the file or the number that explains it.
#[derive(Debug, thiserror::Error)]
pub enum CtError {
    /// Reading or writing a file failed; the OS error is the source.
    #[error("cannot {action} {path}")]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: missing key `{key}`{}", section_note(.section))]
    MissingKey {
        path: PathBuf,
        section: String,
        key: String,
    },
    #[error("{path}: bad value {value:?} for `{key}`: {reason}")]
    BadValue {
        path: PathBuf,
        key: String,
        value: String,
        reason: String,
    },
    #[error("{path}: unknown voxel data type {dtype:?} (expected {expected})")]
    UnknownDtype {
        path: PathBuf,
        dtype: String,
        expected: &'static str,
    },
    #[error(
        "{path}: the raw file is {actual} bytes but {dims:?} voxels of {bytes_per_voxel} byte(s) \
         (plus a {header}-byte header) need {expected} bytes"
    )]
    SizeMismatch {
        path: PathBuf,
        dims: [usize; 3],
        bytes_per_voxel: usize,
        header: u64,
        expected: u64,
        actual: u64,
    },
    #[error("{path}: {message}")]
    Format { path: PathBuf, message: String },
    /// A file of a known format that its decoder refused; the decoder's error is the source.
    #[error("cannot {what} {path}")]
    Decode {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A DICOM attribute whose value cannot be read as the number(s) it holds.
    #[error("{path}: cannot read {key}")]
    DicomValue {
        path: PathBuf,
        key: String,
        #[source]
        source: dicom_core::value::ConvertValueError,
    },
    /// A DICOM Part 10 file of the series that its parser refused.
    #[error("{path}: not a readable DICOM file (export the series again)")]
    UnreadableDicom {
        path: PathBuf,
        #[source]
        source: Box<dicom_object::ReadError>,
    },
    #[error("{path} is not a valid ct.toml (write it with `layerwise register ct`)")]
    Toml {
        path: PathBuf,
        #[source]
        source: Box<toml::de::Error>,
    },
    #[error("cannot read the laser vectors")]
    Vectors(#[source] VectorError),
    #[error("cannot build the distance field of the laser vectors {path}")]
    DistanceField {
        path: PathBuf,
        #[source]
        source: TsdfError,
    },
    #[error(
        "{path}: the laser vectors have no geometry{} to resample the CT around",
        part.map(|p| format!(" for part {p}")).unwrap_or_default()
    )]
    NoVectorGeometry { path: PathBuf, part: Option<i64> },
    #[error(
        "{dir} is not a layerwise build folder (its build.json cannot be read): give the \
         build's output folder"
    )]
    NotABuild {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path} is not a layerwise build manifest")]
    BadManifest {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error(
        "the CT's voxel index → mm matrix {matrix:?} has no inverse: check the volume's voxel \
         size and orientation"
    )]
    SingularGeometry { matrix: Box<[[f64; 4]; 4]> },
    #[error("cannot write the CT resampled into the build frame")]
    ResampledDicom(#[source] DicomError),
    #[error("invalid input: {0}")]
    Invalid(String),
    #[error(
        "empty threshold: no voxel is at or above {threshold} (the volume's values span \
         {min}..{max}): lower the threshold"
    )]
    EmptyThreshold { threshold: f64, min: f64, max: f64 },
    #[error(
        "threshold {threshold} selects every voxel (the volume's values span {min}..{max}): \
         there is no background to find a surface against"
    )]
    FullThreshold { threshold: f64, min: f64, max: f64 },
    #[error("the thresholded part has no surface inside the volume")]
    NoSurface,
    #[error("the initial transform needs at least 3 point pairs, got {0}")]
    TooFewPoints(usize),
    #[error(
        "the {which} points of the point pairs are (nearly) collinear: the rotation about their \
         line is undetermined; pick 3 points that span a triangle"
    )]
    CollinearPoints { which: &'static str },
    #[error("{path}:{line}: {message}")]
    PointsFile {
        path: PathBuf,
        line: usize,
        message: String,
    },
    #[error(
        "the CT part is {ratio:.2}x the size of the vectors: check the voxel size \
         (CT principal extents {ct:.3?} mm, vectors {vectors:.3?} mm)"
    )]
    ScaleMismatch {
        ratio: f64,
        ct: [f64; 3],
        vectors: [f64; 3],
    },
    #[error(
        "only {used} of {total} CT surface points fall inside the distance field's truncation \
         band (±{truncation_mm} mm) after the initial transform: check the initial transform \
         (point pairs) or the field's extent"
    )]
    NoOverlap {
        used: usize,
        total: usize,
        truncation_mm: f64,
    },
    #[error(
        "the registration converged to a poor fit: {outside_pct:.1}% of the surface points lie \
         beyond the distance field's truncation band and the mean |Ψ| is {mean_abs_um:.1} µm; \
         likely a wrong local minimum (e.g. a rotation by a symmetry of the part): start from \
         point pairs"
    )]
    PoorFit { outside_pct: f64, mean_abs_um: f64 },
    #[error(
        "the registration did not converge in {iterations} iterations (last step {rotation_rad:.3e} \
         rad, {translation_mm:.3e} mm; rms Ψ {rms_um:.2} µm): check the initial transform \
         or raise max_iterations"
    )]
    NotConverged {
        iterations: usize,
        rotation_rad: f64,
        translation_mm: f64,
        rms_um: f64,
    },
}

fn section_note(section: &str) -> String {
    if section.is_empty() {
        String::new()
    } else {
        format!(" in [{section}]")
    }
}

pub type Result<T, E = CtError> = std::result::Result<T, E>;

/// Maps an I/O error on reading `path` to [`CtError::Io`].
pub(crate) fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> CtError + '_ {
    move |source| CtError::Io {
        path: path.to_path_buf(),
        action: "read",
        source,
    }
}

/// Maps an I/O error on writing `path` to [`CtError::Io`].
pub(crate) fn write_err(path: &Path) -> impl FnOnce(std::io::Error) -> CtError + '_ {
    move |source| CtError::Io {
        path: path.to_path_buf(),
        action: "write",
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::error::Error;

    #[test]
    fn io_errors_name_the_file_once_and_keep_the_cause() {
        let path = Path::new("/nonexistent/layerwise/ct.toml");
        let e = std::fs::read(path)
            .map_err(io_err(path))
            .expect_err("missing");
        assert_eq!(e.to_string(), "cannot read /nonexistent/layerwise/ct.toml");
        let cause = e.source().expect("the OS error is the source");
        assert!(cause.downcast_ref::<std::io::Error>().is_some());
        // The chain as `{:#}` prints it: each part once.
        let chain = format!("{e}: {cause}");
        assert_eq!(chain.matches("No such file").count(), 1, "{chain}");
    }
}
