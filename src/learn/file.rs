//! The model file: one safetensors file, the network's tensors (F32) plus one metadata key,
//! `layerwise.model`, holding the JSON [`Header`]: format version, architecture, classes, the
//! input recipe, what it was trained on (counts per class, a hash of the data), how the training
//! went, its validation metrics and the SHA-256 of the tensor bytes.
//!
//! [`Model::load`] checks, in order, each with its own message: size, safetensors structure,
//! the header's presence, its JSON, the format version, the weights' checksum, every tensor
//! against the architecture, finite values, the input's sizes ([`InputSpec::check`]: a header is
//! not covered by the checksum, and its sizes decide allocations). [`Model::check_use`] then checks the input against
//! what it is used on.

use super::error::ModelError;
use super::input::{InputSpec, MAX_CELLS};
use super::metrics::Metrics;
use super::net::{Arch, Net, ARCH_KINDS};
use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

pub const FORMAT: &str = "layerwise-model";
/// The newest model format this layerwise reads and writes: 2 for files of the
/// [`Normalisation::Equalised`](super::input::Normalisation) input, which a layerwise that reads
/// only 1 must refuse (it would normalise the frames the old way); 3 for files that read frames by
/// the [`Framing::Bed`](super::framing::Framing) (a layerwise reading 2 would refuse the header's
/// field anyway, and says "newer" this way). Files of the older inputs are still written as 1 and
/// 2 ([`version_for`]).
pub const VERSION: u32 = 3;
/// The oldest format read.
pub const MIN_VERSION: u32 = 1;

/// The format a file of `input` is written in: the oldest that can hold it.
pub fn version_for(input: &InputSpec) -> u32 {
    if !input.framing.is_centre_square() {
        return 3;
    }
    match input.normalisation {
        super::input::Normalisation::Flatfield => 1,
        super::input::Normalisation::Equalised => 2,
    }
}
pub const METADATA_KEY: &str = "layerwise.model";
/// A model is tens of kilobytes; nothing larger is read.
pub const MAX_BYTES: u64 = 64 << 20;

/// What the model was trained on.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DataInfo {
    /// `class-folders`, `flaws` or `verdicts`.
    pub kind: String,
    pub root: String,
    /// Images per class.
    pub counts: BTreeMap<String, usize>,
    /// SHA-256 over the sorted lines `class/relative-path TAB sha256(file)`.
    pub sha256: String,
}

/// How the data was split.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SplitInfo {
    /// `sequence-tail` (frames) or `layer-tail` (patches, verdicts).
    pub rule: String,
    pub val_fraction: f64,
    pub train: BTreeMap<String, usize>,
    pub val: BTreeMap<String, usize>,
    /// Left out of both (guard bands between the parts, flaws seen in both).
    pub dropped: usize,
}

/// How the training went.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainingInfo {
    pub data: DataInfo,
    pub split: SplitInfo,
    pub seed: u64,
    pub epochs: usize,
    pub epochs_run: usize,
    pub best_epoch: usize,
    /// What chose the best epoch and the plateau ([`super::select`]); files written before it
    /// was recorded were chosen on the plain mean validation loss.
    #[serde(default = "old_selection")]
    pub selection: String,
    /// What the learning-rate cuts and the early stop counted; files written before it was
    /// recorded counted epochs without a better epoch.
    #[serde(default = "old_plateau")]
    pub plateau: String,
    /// The weights are the moving average of the steps' weights with this decay per step
    /// (`learn train --average`); absent: the last step's weights of the kept epoch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub average: Option<f64>,
    /// `plateau`, `epochs` or `time budget`.
    pub stopped: String,
    pub seconds: f64,
    pub augmentation: String,
    pub layerwise: String,
    pub candle: String,
    /// The refit on every picture after the epoch was chosen (`learn train --refit`): the
    /// weights are the refit's, the validation metrics the selection run's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refit: Option<RefitInfo>,
}

/// `learn train --refit`: trained afresh on every picture for the chosen number of epochs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RefitInfo {
    pub epochs: usize,
    /// The epochs after which the learning rate was cut (the selection run's, before its best).
    pub lr_cuts: Vec<usize>,
    /// Pictures per class it was trained on.
    pub counts: BTreeMap<String, usize>,
    pub seconds: f64,
}

fn old_selection() -> String {
    super::select::OLD_CRITERION.into()
}

fn old_plateau() -> String {
    super::select::OLD_PLATEAU.into()
}

/// The JSON header of a model file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    pub format: String,
    pub version: u32,
    pub arch: Arch,
    pub classes: Vec<String>,
    /// The class that is not a defect (no flag is raised for it).
    pub normal_class: String,
    pub input: InputSpec,
    pub training: TrainingInfo,
    /// Metrics on the held-out validation part.
    pub validation: Metrics,
    pub weights_sha256: String,
}

/// A loaded, checked model.
#[derive(Clone)]
pub struct Model {
    pub path: PathBuf,
    pub header: Header,
    pub net: Net,
}

/// What a model is used on, for [`Model::check_use`].
#[derive(Clone, Copy, Debug)]
pub enum Use {
    /// Whole frames or pictures (`predict`, `eval` on class folders).
    Frames,
    /// Patches of `w` x `h` pixels.
    Patches { w: usize, h: usize },
    /// Rectified views of `pixel_mm` per pixel and `w` x `h` pixels, with `cell_mm` from the
    /// configuration when the model has no scale.
    View {
        pixel_mm: f64,
        w: usize,
        h: usize,
        cell_mm: Option<f64>,
    },
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

fn serialise(net: &Net, header: Option<&str>) -> Result<Vec<u8>, ModelError> {
    let names: Vec<String> = net
        .arch
        .shapes(net.classes)
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    let tensors: Vec<(String, &Tensor)> = names.into_iter().zip(&net.params).collect();
    let meta = header.map(|h| HashMap::from([(METADATA_KEY.to_string(), h.to_string())]));
    safetensors::tensor::serialize(tensors, meta).map_err(ModelError::Serialise)
}

impl Model {
    /// Writes the model (atomically); fills in `weights_sha256`.
    pub fn save(path: &Path, net: &Net, header: &mut Header) -> Result<(), ModelError> {
        let bare = serialise(net, None)?;
        let n = u64::from_le_bytes(bare[..8].try_into().unwrap_or_default()) as usize;
        header.weights_sha256 = sha256_hex(&bare[8 + n..]);
        let json = serde_json::to_string(header).map_err(|source| ModelError::Header {
            path: path.to_path_buf(),
            at: ".".into(),
            source,
        })?;
        let bytes = serialise(net, Some(&json))?;
        crate::fsutil::write_atomic(path, &bytes, true).map_err(|source| ModelError::Write {
            path: path.to_path_buf(),
            source,
        })
    }

    /// Reads and checks a model file.
    pub fn load(path: &Path) -> Result<Model, ModelError> {
        let p = || path.to_path_buf();
        let size = std::fs::metadata(path)
            .map_err(|source| ModelError::Read { path: p(), source })?
            .len();
        if size > MAX_BYTES {
            return Err(ModelError::TooLarge {
                path: p(),
                size,
                max: MAX_BYTES,
            });
        }
        let bytes = std::fs::read(path).map_err(|source| ModelError::Read { path: p(), source })?;
        Model::from_bytes(path, &bytes)
    }

    /// The checks of [`Model::load`] on the file's bytes.
    pub fn from_bytes(path: &Path, bytes: &[u8]) -> Result<Model, ModelError> {
        let p = || path.to_path_buf();
        let st = safetensors::SafeTensors::deserialize(bytes)
            .map_err(|source| ModelError::Damaged { path: p(), source })?;
        let (n, meta) = safetensors::SafeTensors::read_metadata(bytes)
            .map_err(|source| ModelError::Damaged { path: p(), source })?;
        let json = meta
            .metadata()
            .as_ref()
            .and_then(|m| m.get(METADATA_KEY))
            .ok_or_else(|| ModelError::NotLayerwise { path: p() })?;
        let header_error = |at: String, source| ModelError::Header {
            path: p(),
            at,
            source,
        };
        let loose: serde_json::Value =
            serde_json::from_str(json).map_err(|e| header_error(".".into(), e))?;
        if loose.get("format").and_then(|f| f.as_str()) != Some(FORMAT) {
            return Err(ModelError::NotLayerwise { path: p() });
        }
        match loose.get("version").and_then(|v| v.as_u64()) {
            Some(v) if v > u64::from(VERSION) => {
                return Err(ModelError::Newer {
                    path: p(),
                    found: v,
                    reads: VERSION,
                })
            }
            Some(v) if v < u64::from(MIN_VERSION) => {
                return Err(ModelError::Older {
                    path: p(),
                    found: v,
                    reads: MIN_VERSION,
                })
            }
            _ => {}
        }
        let header: Header = serde_path_to_error::deserialize(loose).map_err(|e| {
            let at = e.path().to_string();
            header_error(at, e.into_inner())
        })?;
        if sha256_hex(&bytes[8 + n..]) != header.weights_sha256 {
            return Err(ModelError::Checksum { path: p() });
        }
        let arch_error = |detail: String| ModelError::Architecture { path: p(), detail };
        if !ARCH_KINDS.contains(&header.arch.kind.as_str())
            || header.arch.channels.is_empty()
            || header.arch.channels.len() != header.arch.pool_after.len()
            || header.arch.in_channels != header.input.channels.len()
            || header.classes.len() < 2
            || !header.classes.contains(&header.normal_class)
        {
            return Err(arch_error(format!(
                "arch {:?} with {} input channels and classes {:?} (normal {:?}) is not a cnn-cam this layerwise builds",
                header.arch, header.input.channels.len(), header.classes, header.normal_class
            )));
        }
        if header.arch.channels.iter().any(|&c| c == 0 || c > 1024) {
            return Err(arch_error(format!("channels {:?}", header.arch.channels)));
        }
        // At most one pool per halving of the largest input (the stride is 2^pools).
        let pools = header.arch.pool_after.iter().filter(|&&p| p).count();
        if 1 << pools.min(63) > MAX_CELLS {
            return Err(arch_error(format!(
                "{pools} pooling steps (a tile of 2^{pools} cells; inputs are at most {MAX_CELLS} cells a side)"
            )));
        }
        let expected = header.arch.shapes(header.classes.len());
        let mut params = Vec::new();
        for (name, shape) in &expected {
            let view = st
                .tensor(name)
                .map_err(|_| arch_error(format!("{name} is missing")))?;
            if view.dtype() != safetensors::Dtype::F32 || view.shape() != shape.as_slice() {
                return Err(arch_error(format!(
                    "{name} is {:?} {:?}, expected F32 {shape:?}",
                    view.dtype(),
                    view.shape()
                )));
            }
            let values: Vec<f32> = view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            if values.iter().any(|v| !v.is_finite()) {
                return Err(ModelError::NotFinite {
                    path: p(),
                    tensor: name.clone(),
                });
            }
            params.push(Tensor::from_vec(values, shape.clone(), &Device::Cpu)?);
        }
        if let Some(extra) = st
            .names()
            .into_iter()
            .find(|n| !expected.iter().any(|(e, _)| e == n))
        {
            return Err(arch_error(format!("{extra} is not part of it")));
        }
        header
            .input
            .check(header.arch.stride())
            .map_err(|(at, detail)| ModelError::Input {
                path: p(),
                at,
                detail,
            })?;
        Ok(Model {
            path: p(),
            net: Net {
                arch: header.arch.clone(),
                classes: header.classes.len(),
                params,
            },
            header,
        })
    }

    /// Whether the model can run on `what`; the message says why not and what to do.
    pub fn check_use(&self, what: Use) -> Result<(), ModelError> {
        let i = &self.header.input;
        let unusable = |detail: String| ModelError::Unusable {
            path: self.path.clone(),
            detail,
        };
        let [h, w] = i.input_px();
        let stride = self.header.arch.stride();
        match what {
            Use::Frames => {
                if i.frame_px.is_none() {
                    return Err(unusable(format!(
                        "the model takes {w}x{h}-pixel patches, not whole frames; use it on patches or views"
                    )));
                }
            }
            Use::Patches { w: pw, h: ph } => {
                if i.frame_px.is_some() {
                    return Err(unusable(format!(
                        "the model takes whole frames ({} px square), not {pw}x{ph} patches",
                        i.frame_px.unwrap_or_default()
                    )));
                }
                if pw < w || ph < h {
                    return Err(unusable(format!(
                        "the model takes {}x{} cells of {} px ({w}x{h} px); these patches are {pw}x{ph}",
                        i.cells[1], i.cells[0], i.cell_px
                    )));
                }
            }
            Use::View {
                pixel_mm,
                w: vw,
                h: vh,
                cell_mm,
            } => {
                let Some(mm) = i.cell_mm.or(cell_mm) else {
                    return Err(unusable(
                        "the model has no scale (trained on camera frames): retrain it with --cell-mm or set [inspection.model] cell_mm".into(),
                    ));
                };
                let px = mm / pixel_mm;
                if !(0.5..=64.0).contains(&px) {
                    return Err(unusable(format!(
                        "its cells of {mm} mm are {px:.2} pixels of these {pixel_mm} mm views (0.5 to 64 work)"
                    )));
                }
                let cells = |n: usize| (n as f64 / px) as usize;
                if cells(vw) < stride || cells(vh) < stride {
                    return Err(unusable(format!(
                        "a view of {vw}x{vh} px is smaller than one tile of the model ({stride} cells of {mm} mm)"
                    )));
                }
            }
        }
        Ok(())
    }
}
