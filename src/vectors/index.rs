//! Random access to layers through an index of byte offsets.

use std::io::{Seek, SeekFrom};
use std::path::{Path, PathBuf};

use super::source::Src;
use super::stream::{open_file, open_stream, LayerStream, Parser};
use super::{Header, Layer, VectorError};

#[derive(Debug, Clone, Copy)]
struct LayerStart {
    offset: u64,
    line: u64,
    z_mm: f64,
    has_geometry: bool,
}

/// Byte offsets of every layer start, built by one pass over the file that keeps no geometry;
/// [`read_layer`](LayerIndex::read_layer) then seeks and parses only the layer asked for.
///
/// Building checks the structure (commands, counts, lengths); the numbers of a layer are
/// checked when that layer is read.
#[derive(Debug, Clone)]
pub struct LayerIndex {
    path: PathBuf,
    name: String,
    header: Header,
    starts: Vec<LayerStart>,
}

impl LayerIndex {
    pub fn build(path: &Path) -> Result<LayerIndex, VectorError> {
        let (reader, len, name) = open_file(path)?;
        let (header, mut stream) = open_stream(Src::new(reader, 0, len), &name)?;
        let mut starts = Vec::new();
        while let Some((layer, pos)) = stream.next_layer(false)? {
            starts.push(LayerStart {
                offset: pos.offset,
                line: pos.line,
                z_mm: layer.z_mm,
                has_geometry: stream.last_had_geometry,
            });
        }
        Ok(LayerIndex {
            path: path.to_path_buf(),
            name,
            header,
            starts,
        })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// Number of layers.
    pub fn len(&self) -> usize {
        self.starts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.starts.is_empty()
    }

    /// z of layer `k` in millimetres.
    pub fn z_mm(&self, k: usize) -> Option<f64> {
        self.starts.get(k).map(|s| s.z_mm)
    }

    /// The match of printer layers to this file's layers.
    pub fn layer_map(&self, numbering: super::LayerNumbering) -> super::LayerMap {
        let summary: Vec<super::LayerSummary> = self
            .starts
            .iter()
            .map(|s| super::LayerSummary {
                z_mm: s.z_mm,
                has_geometry: s.has_geometry,
            })
            .collect();
        super::LayerMap::new(&summary, numbering)
    }

    /// Byte offset of the layer command of layer `k` in the file.
    pub fn offset(&self, k: usize) -> Option<u64> {
        self.starts.get(k).map(|s| s.offset)
    }

    /// Reads layer `k` (0-based, file order) by seeking to its start.
    pub fn read_layer(&self, k: usize) -> Result<Layer, VectorError> {
        let start = self.starts.get(k).ok_or_else(|| VectorError::NoSuchLayer {
            file: self.name.clone(),
            index: k,
            len: self.starts.len(),
        })?;
        let (mut reader, len, _) = open_file(&self.path)?;
        reader
            .seek(SeekFrom::Start(start.offset))
            .map_err(|source| VectorError::Io {
                file: self.name.clone(),
                source,
            })?;
        let src = Src::new(reader, start.offset, len);
        let parser = Parser::new(src, &self.header, &self.name, start.line, false);
        let mut stream = LayerStream::new(parser, k);
        match stream.next_layer(true)? {
            Some((layer, _)) => Ok(layer),
            None => Err(VectorError::NoSuchLayer {
                file: self.name.clone(),
                index: k,
                len: self.starts.len(),
            }),
        }
    }
}
