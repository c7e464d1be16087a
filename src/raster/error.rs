//! Why a raster could not be made or written.

use std::path::PathBuf;

/// Why a raster could not be made or written.
#[derive(Debug, thiserror::Error)]
pub enum RasterError {
    #[error("invalid grid")]
    InvalidGrid(#[from] crate::geometry::GridError),
    #[error("standard deviation window must be odd and positive, got {0}")]
    InvalidWindow(usize),
    #[error("buffer of {len} values does not hold {width} x {height} pixels")]
    SizeMismatch {
        len: usize,
        width: usize,
        height: usize,
    },
    #[error("no layer {index}: the file has {len} layers")]
    NoSuchLayer { index: usize, len: usize },
    #[error("no geometry{}", part.map(|p| format!(" for part {p}")).unwrap_or_default())]
    NoGeometry { part: Option<i64> },
    #[error("unknown raster kind '{0}' (expected mask, coverage, rgb or exemplar)")]
    UnknownKind(String),
    #[error("{path}: cannot write")]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}
