//! The errors of learning: the model file's load checks ([`ModelError`], each naming the file
//! and what to do) and those of training, evaluation and prediction ([`LearnError`]).

use std::path::PathBuf;

/// A model file that cannot be used, checked in this order when it is loaded.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: cannot read the model file")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{path}: {size} bytes is more than a model file holds (at most {max}); is it a model?"
    )]
    TooLarge { path: PathBuf, size: u64, max: u64 },
    #[error("{path}: the model file is damaged or not a safetensors file")]
    Damaged {
        path: PathBuf,
        #[source]
        source: safetensors::SafeTensorError,
    },
    #[error("{path}: not a layerwise model (no \"layerwise.model\" header); models are written by `layerwise learn train`")]
    NotLayerwise { path: PathBuf },
    #[error("{path}: the model's header is damaged at `{at}`")]
    Header {
        path: PathBuf,
        at: String,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: the model's header is damaged at `{at}`: {detail}; retrain the model (`layerwise learn train`) or use an undamaged copy")]
    Input {
        path: PathBuf,
        at: &'static str,
        detail: String,
    },
    #[error("{path}: written by a newer layerwise (model format {found}, this one reads {reads}); update layerwise or retrain the model")]
    Newer {
        path: PathBuf,
        found: u64,
        reads: u32,
    },
    #[error("{path}: model format {found} is not read any more (the oldest this layerwise reads is {reads}); retrain it with `layerwise learn train`")]
    Older {
        path: PathBuf,
        found: u64,
        reads: u32,
    },
    #[error("{path}: damaged: the weights do not match their checksum (weights_sha256)")]
    Checksum { path: PathBuf },
    #[error("{path}: does not match its architecture: {detail}")]
    Architecture { path: PathBuf, detail: String },
    #[error("{path}: damaged: {tensor} holds values that are not finite")]
    NotFinite { path: PathBuf, tensor: String },
    #[error("{path}: {detail}")]
    Unusable { path: PathBuf, detail: String },
    #[error("{path}: cannot write the model file")]
    Write {
        path: PathBuf,
        #[source]
        source: crate::fsutil::WriteError,
    },
    #[error("cannot put the model's tensors together")]
    Tensor(#[from] candle_core::Error),
    #[error("cannot serialise the model's tensors")]
    Serialise(#[source] safetensors::SafeTensorError),
}

/// Training, evaluation and prediction.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("{path}: cannot read")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode the picture")]
    Decode {
        path: PathBuf,
        #[source]
        source: crate::rectify::RectifyError,
    },
    #[error("{path}: cannot parse")]
    Parse {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: {detail}")]
    Data { path: PathBuf, detail: String },
    #[error("{path}: the model was refit on every picture after its epoch was chosen (`learn train --refit`), so its {part} part is not held out; the held-out figures are the selection run's (`layerwise learn info`); evaluate it on pictures it never saw (`--part all` on other data)")]
    RefitPart { path: PathBuf, part: &'static str },
    #[error("{path}: cannot write")]
    Write {
        path: PathBuf,
        #[source]
        source: crate::fsutil::WriteError,
    },
    #[error("tensor computation failed")]
    Tensor(#[from] candle_core::Error),
    #[error("{path}: cannot open the build")]
    Build {
        path: PathBuf,
        #[source]
        source: Box<crate::series::SeriesError>,
    },
    #[error("{path}: cannot read the verdicts")]
    Verdicts {
        path: PathBuf,
        #[source]
        source: crate::build_dir::JournalError,
    },
    #[error("{path}: cannot {what}")]
    Dicom {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

impl LearnError {
    pub(crate) fn data(path: &std::path::Path, detail: impl Into<String>) -> LearnError {
        LearnError::Data {
            path: path.to_path_buf(),
            detail: detail.into(),
        }
    }
}
