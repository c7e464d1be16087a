//! Reader and writer for Common Layer Interface (CLI) laser scan vector files.
//!
//! A CLI file has an ASCII header (`$$HEADERSTART` … `$$HEADEREND`) followed by the geometry,
//! either as ASCII commands (`$$LAYER`, `$$POLYLINE`, `$$HATCHES`, and the CLI+ marking
//! parameters `$$POWER`, `$$SPEED`, `$$FOCUS`) or as little-endian binary commands
//! (127 layer long, 128 layer short, 129/130 polyline short/long, 131/132 hatches short/long).
//!
//! Everything exposed here is in millimetres: coordinates and layer z are multiplied by
//! `$$UNITS` when read and divided by it when written. `$$DIMENSION` is the exception that
//! proves the rule: real files store it in millimetres already (for instance
//! `Box_support_solid_ascii_with_params.cli` has `$$UNITS/0.001` and `$$DIMENSION/…,3.03,…`
//! where the first layer with geometry is `$$LAYER/3030`), so it is kept as given.
//!
//! Entry points:
//! - [`read`] / [`read_bytes`]: the whole file in memory.
//! - [`LayerReader`]: the header, then one layer at a time in bounded memory.
//! - [`LayerIndex`]: byte offsets of the layer starts, then random access to one layer.
//! - [`info`]: summary statistics computed by streaming.
//! - [`write_ascii`] / [`write_binary`].
//!
//! Broken input gives a [`VectorError`] naming the file, the line (ASCII) or byte offset
//! (binary) and what was expected; no input panics, and announced counts never drive an
//! allocation larger than the bytes that remain.

mod ascii;
mod binary;
mod command;
mod error;
mod header;
mod index;
mod info;
mod number;
mod numbering;
mod source;
mod stream;
pub mod synth;
mod write;

use serde::Serialize;

pub use error::VectorError;
pub use index::LayerIndex;
pub use info::{info, Info, PartInfo};
pub use numbering::{LayerMap, LayerMatch, LayerNumbering, LayerSummary, UnknownLayerMatch};
pub use stream::{read, read_bytes, LayerReader};
pub use write::{write_ascii, write_binary};

/// Encoding of the geometry section.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Format {
    Ascii,
    Binary,
}

/// Orientation of a polyline seen in negative z direction.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Code 0: clockwise, an inner contour.
    Clockwise,
    /// Code 1: counter-clockwise, an outer contour.
    CounterClockwise,
    /// Code 2: an open line.
    Open,
}

impl Direction {
    /// The code used in the file (0, 1 or 2).
    pub fn code(self) -> u32 {
        match self {
            Direction::Clockwise => 0,
            Direction::CounterClockwise => 1,
            Direction::Open => 2,
        }
    }

    /// The direction for a file code, `None` for anything but 0, 1 and 2.
    pub fn from_code(code: u64) -> Option<Direction> {
        match code {
            0 => Some(Direction::Clockwise),
            1 => Some(Direction::CounterClockwise),
            2 => Some(Direction::Open),
            _ => None,
        }
    }
}

/// The header of a CLI file.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub format: Format,
    /// `$$UNITS`: millimetres per file unit (1.0 when the header has none).
    pub units_mm: f64,
    pub version: Option<String>,
    /// `$$DATE` as written (DDMMYY or YYYYMMDD).
    pub date: Option<String>,
    /// `$$DIMENSION` x1,y1,z1,x2,y2,z2 in millimetres, as given in the file.
    pub dimension_mm: Option<[f64; 6]>,
    /// `$$LAYERS`.
    pub layers_declared: Option<u32>,
    /// `$$LABEL` part ids and names, in file order.
    pub labels: Vec<(i64, String)>,
    /// `$$ALIGN` was present (recorded only; no real file seen uses it).
    pub aligned: bool,
    /// `$$USERDATA` uid and raw bytes.
    pub user_data: Vec<(String, Vec<u8>)>,
}

impl Header {
    /// A header with the given format and units and nothing else.
    pub fn new(format: Format, units_mm: f64) -> Header {
        Header {
            format,
            units_mm,
            version: None,
            date: None,
            dimension_mm: None,
            layers_declared: None,
            labels: Vec::new(),
            aligned: false,
            user_data: Vec::new(),
        }
    }
}

/// A contour or open line of one part.
#[derive(Debug, Clone, PartialEq)]
pub struct Polyline {
    pub part: i64,
    pub direction: Direction,
    /// Points in millimetres.
    pub points: Vec<[f64; 2]>,
}

/// Hatch segments of one part.
#[derive(Debug, Clone, PartialEq)]
pub struct Hatches {
    pub part: i64,
    /// Segments `[sx, sy, ex, ey]` in millimetres.
    pub segments: Vec<[f64; 4]>,
}

/// A CLI+ marking parameter, with the value as given in the file (not scaled by units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MarkingParameter {
    Power(f64),
    Speed(f64),
    Focus(f64),
}

/// One layer in file order.
///
/// Marking parameters are the `$$POWER`/`$$SPEED`/`$$FOCUS` commands met inside this layer,
/// in order; they hold for the geometry that follows them (in the files seen they come first
/// in the layer). A parameter keeps its value for later layers until changed; that state is not
/// repeated here.
#[derive(Debug, Clone, PartialEq)]
pub struct Layer {
    /// 0-based position in the file.
    pub index: usize,
    pub z_mm: f64,
    pub polylines: Vec<Polyline>,
    pub hatches: Vec<Hatches>,
    pub parameters: Vec<MarkingParameter>,
}

impl Layer {
    /// An empty layer.
    pub fn new(index: usize, z_mm: f64) -> Layer {
        Layer {
            index,
            z_mm,
            polylines: Vec::new(),
            hatches: Vec::new(),
            parameters: Vec::new(),
        }
    }

    /// True when the layer has neither polylines nor hatches.
    pub fn is_empty(&self) -> bool {
        self.polylines.is_empty() && self.hatches.is_empty()
    }
}

/// A whole CLI file in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct VectorFile {
    pub header: Header,
    pub layers: Vec<Layer>,
}
