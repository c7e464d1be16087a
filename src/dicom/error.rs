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
    #[error("{what}: {source}")]
    Encoder {
        what: &'static str,
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

#[derive(Debug, thiserror::Error)]
pub enum DicomError {
    #[error("{path}: {source}")]
    Encode { path: PathBuf, source: EncodeError },
    #[error(transparent)]
    Write(#[from] crate::fsutil::WriteError),
    #[error("{path}: not a readable DICOM file ({message}); if it was cut short by a crash, delete it and re-run")]
    Read { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    Geometry { path: PathBuf, message: String },
    /// A stated length the file cannot hold (checked before any parser trusts it).
    #[error("{path}: {message}")]
    Damaged { path: PathBuf, message: String },
    #[error(
        "{path}: cannot search this folder ({source}); give an existing folder of DICOM files"
    )]
    Folder {
        path: PathBuf,
        source: std::io::Error,
    },
}
