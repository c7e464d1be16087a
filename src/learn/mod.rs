//! Learning: a small convolutional defect classifier (candle, on the CPU, in the binary) trained
//! on labelled pictures (a folder of class folders, a `flaws` output of CT-labelled patches, or
//! a build's operator verdicts), stored in one safetensors file with a JSON header, and run on
//! pictures (`learn predict`, `learn eval`) and live on every layer's rectified views, after the
//! classical inspection ([`live`]). See docs/learning.md.

pub mod augment;
pub mod average;
pub mod crossval;
pub mod data;
pub mod error;
pub mod file;
pub mod framing;
pub mod input;
pub mod live;
pub mod metrics;
pub mod net;
pub mod predict;
pub mod rng;
pub mod select;
pub mod source;
pub mod train;
pub mod verdicts;

pub use crossval::{cross_validate, CrossValidation, FoldReport};
pub use data::{Dataset, Part};
pub use error::{LearnError, ModelError};
pub use file::{Header, Model, RefitInfo, Use};
pub use metrics::Metrics;
pub use predict::{heatmap, Prediction};
pub use train::{train, Epoch, TrainOptions};
