//! The error type of the vectors module.

/// Why a CLI file could not be read.
///
/// The display names the file and where the problem is, for instance
/// `frustrum_ASCII.cli: line 12: expected a number in $$POLYLINE, found 'abc'` or
/// `x.cli: byte 1034: truncated $$HATCHES (command 132): 4n=400 f32 values announced, 96 bytes left`.
#[derive(Debug, thiserror::Error)]
pub enum VectorError {
    /// The file could not be opened or read.
    #[error("{file}: cannot read")]
    Io {
        file: String,
        #[source]
        source: std::io::Error,
    },
    /// A problem in the ASCII header or ASCII geometry, at a 1-based line.
    #[error("{file}: line {line}: {message}")]
    AtLine {
        file: String,
        line: u64,
        message: String,
    },
    /// A problem in binary geometry, at a byte offset from the start of the file.
    #[error("{file}: byte {offset}: {message}")]
    AtByte {
        file: String,
        offset: u64,
        message: String,
    },
    /// [`LayerIndex::read_layer`](super::LayerIndex::read_layer) was asked for a layer the file does not have.
    #[error("{file}: no layer {index}: the file has {len} layers")]
    NoSuchLayer {
        file: String,
        index: usize,
        len: usize,
    },
}

impl VectorError {
    /// The 1-based line of an ASCII problem.
    pub fn line(&self) -> Option<u64> {
        match self {
            VectorError::AtLine { line, .. } => Some(*line),
            _ => None,
        }
    }

    /// The byte offset of a binary problem.
    pub fn offset(&self) -> Option<u64> {
        match self {
            VectorError::AtByte { offset, .. } => Some(*offset),
            _ => None,
        }
    }
}
