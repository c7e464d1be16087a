//! Why a slice could not be encoded or written, and why a DICOM file or folder could not be
//! read.

use std::path::PathBuf;

/// Why a slice could not be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    #[error("{rows} x {columns} pixels cannot be a DICOM image (1 to 65535 each way)")]
    Size { rows: usize, columns: usize },
    #[error("{len} pixels for a {rows} x {columns} image")]
    PixelCount {
        len: usize,
        rows: usize,
        columns: usize,
    },
    /// dicom-rs could not build or write the file (`what` says which step).
    #[error("{what}")]
    Encoder {
        what: &'static str,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    #[error("this layerwise was built without JPEG-LS; rebuild with `--features jpegls` (needs cmake and g++) or choose deflate")]
    NoJpegLs,
}

impl EncodeError {
    pub(super) fn encoder(
        what: &'static str,
    ) -> impl FnOnce(Box<dyn std::error::Error + Send + Sync>) -> EncodeError {
        move |source| EncodeError::Encoder { what, source }
    }
}

/// Why a DICOM file could not be written or read, or a folder of them searched.
#[derive(Debug, thiserror::Error)]
pub enum DicomError {
    #[error("{path}")]
    Encode {
        path: PathBuf,
        #[source]
        source: EncodeError,
    },
    #[error(transparent)]
    Write(#[from] crate::fsutil::WriteError),
    /// dicom-rs could not parse the file.
    #[error(
        "{path}: not a readable DICOM file (if it was cut short by a crash, delete it and re-run)"
    )]
    Read {
        path: PathBuf,
        #[source]
        source: Box<dicom_object::ReadError>,
    },
    #[error("{path}: {message}")]
    Geometry { path: PathBuf, message: String },
    /// The file could not be opened or read.
    #[error("{path}: cannot read")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// A stated length the file cannot hold (checked before any parser trusts it).
    #[error("{path}: {message}")]
    Damaged { path: PathBuf, message: String },
    #[error("{path}: cannot search this folder (give an existing folder of DICOM files)")]
    Folder {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}
