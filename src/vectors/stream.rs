//! Assembling commands into layers, shared by [`read`], [`LayerReader`],
//! [`LayerIndex`](super::LayerIndex) and [`info`](super::info).

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::ascii::AsciiParser;
use super::binary::BinaryParser;
use super::command::{Command, Pos};
use super::header::parse_header;
use super::source::Src;
use super::{Format, Header, Layer, VectorError, VectorFile};

/// Buffer size of the streaming readers.
const BUFFER: usize = 1 << 18;

pub(crate) enum Parser<R> {
    Ascii(AsciiParser<R>),
    Binary(BinaryParser<R>),
}

impl<R: BufRead> Parser<R> {
    /// A parser for the geometry at the source's position. `line` is the line number there
    /// (ASCII); `at_header_end` tells the binary parser to skip a line break first.
    pub(crate) fn new(
        src: Src<R>,
        header: &Header,
        name: &str,
        line: u64,
        at_header_end: bool,
    ) -> Self {
        match header.format {
            Format::Ascii => Parser::Ascii(AsciiParser::new(src, header.units_mm, name, line)),
            Format::Binary => {
                Parser::Binary(BinaryParser::new(src, header.units_mm, name, at_header_end))
            }
        }
    }

    fn next_command(&mut self, store: bool) -> Result<Option<(Command, Pos)>, VectorError> {
        match self {
            Parser::Ascii(p) => p.next_command(store),
            Parser::Binary(p) => p.next_command(store),
        }
    }

    fn error(&self, pos: Pos, message: String) -> VectorError {
        match self {
            Parser::Ascii(p) => p.error(pos.line, message),
            Parser::Binary(p) => p.error(pos.offset, message),
        }
    }

    fn layer_word(&self) -> &'static str {
        match self {
            Parser::Ascii(_) => "$$LAYER",
            Parser::Binary(_) => "a layer command (127 or 128)",
        }
    }
}

/// Turns a command stream into layers, one at a time.
pub(crate) struct LayerStream<R> {
    parser: Parser<R>,
    /// A layer command already read: it starts the next layer.
    pending: Option<(f64, Pos)>,
    next_index: usize,
    finished: bool,
    /// Whether the layer last returned had polylines or hatches (also when they were not kept).
    pub(crate) last_had_geometry: bool,
}

impl<R: BufRead> LayerStream<R> {
    pub(crate) fn new(parser: Parser<R>, first_index: usize) -> Self {
        LayerStream {
            parser,
            pending: None,
            next_index: first_index,
            last_had_geometry: false,
            finished: false,
        }
    }

    /// The next layer with the position of its layer command. With `store` false the layer
    /// comes back without geometry (for indexing). After an error or the end, always `None`.
    pub(crate) fn next_layer(&mut self, store: bool) -> Result<Option<(Layer, Pos)>, VectorError> {
        if self.finished {
            return Ok(None);
        }
        let r = self.next_layer_inner(store);
        if !matches!(r, Ok(Some(_))) {
            self.finished = true;
        }
        r
    }

    fn next_layer_inner(&mut self, store: bool) -> Result<Option<(Layer, Pos)>, VectorError> {
        let (z, pos) = match self.pending.take() {
            Some(p) => p,
            None => match self.parser.next_command(store)? {
                None => return Ok(None),
                Some((Command::Layer(z), pos)) => (z, pos),
                Some((_, pos)) => {
                    let msg = format!("expected {} before {}", self.parser.layer_word(), pos.what);
                    return Err(self.parser.error(pos, msg));
                }
            },
        };
        let mut layer = Layer::new(self.next_index, z);
        self.last_had_geometry = false;
        loop {
            match self.parser.next_command(store)? {
                None => break,
                Some((Command::Layer(z), p)) => {
                    self.pending = Some((z, p));
                    break;
                }
                Some((Command::Polyline(p), _)) => {
                    self.last_had_geometry = true;
                    if store {
                        layer.polylines.push(p);
                    }
                }
                Some((Command::Hatches(h), _)) => {
                    self.last_had_geometry = true;
                    if store {
                        layer.hatches.push(h);
                    }
                }
                Some((Command::Parameter(m), _)) => layer.parameters.push(m),
            }
        }
        self.next_index += 1;
        Ok(Some((layer, pos)))
    }
}

/// Parses the header from `src` and sets up the layer stream after it.
pub(crate) fn open_stream<R: BufRead>(
    mut src: Src<R>,
    name: &str,
) -> Result<(Header, LayerStream<R>), VectorError> {
    let (header, line) = parse_header(&mut src, name)?;
    let parser = Parser::new(src, &header, name, line, true);
    Ok((header, LayerStream::new(parser, 0)))
}

/// The file name used in error messages.
pub(crate) fn display_name(path: &Path) -> String {
    match path.file_name() {
        Some(n) => n.to_string_lossy().into_owned(),
        None => path.display().to_string(),
    }
}

/// Opens a file for buffered reading; returns the reader, its length and its display name.
pub(crate) fn open_file(path: &Path) -> Result<(BufReader<File>, u64, String), VectorError> {
    let name = display_name(path);
    let io = |source| VectorError::Io {
        file: name.clone(),
        source,
    };
    let file = crate::fsutil::open_regular(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    Ok((BufReader::with_capacity(BUFFER, file), len, name))
}

/// Reads a whole CLI file (ASCII or binary, detected from the header).
pub fn read(path: &Path) -> Result<VectorFile, VectorError> {
    let name = display_name(path);
    // Read whole only when asked to (large files are streamed): any size a file system holds.
    let bytes =
        crate::fsutil::read_bounded(path, u64::MAX - 1).map_err(|source| VectorError::Io {
            file: name.clone(),
            source,
        })?;
    read_bytes(&bytes, &name)
}

/// Reads a CLI file from memory; `name` is used in error messages.
pub fn read_bytes(bytes: &[u8], name: &str) -> Result<VectorFile, VectorError> {
    let src = Src::new(bytes, 0, bytes.len() as u64);
    let (header, mut layers) = open_stream(src, name)?;
    let mut out = Vec::new();
    while let Some((layer, _)) = layers.next_layer(true)? {
        out.push(layer);
    }
    Ok(VectorFile {
        header,
        layers: out,
    })
}

/// Reads a CLI file layer by layer: the header first, then one layer at a time, holding only
/// that layer (and a read buffer) in memory.
pub struct LayerReader {
    header: Header,
    stream: LayerStream<BufReader<File>>,
}

impl LayerReader {
    /// Opens the file and reads its header.
    pub fn open(path: &Path) -> Result<LayerReader, VectorError> {
        let (reader, len, name) = open_file(path)?;
        let (header, stream) = open_stream(Src::new(reader, 0, len), &name)?;
        Ok(LayerReader { header, stream })
    }

    pub fn header(&self) -> &Header {
        &self.header
    }

    /// The next layer in file order, `None` at the end. After an error, `None`.
    pub fn next_layer(&mut self) -> Result<Option<Layer>, VectorError> {
        Ok(self.stream.next_layer(true)?.map(|(layer, _)| layer))
    }
}

impl Iterator for LayerReader {
    type Item = Result<Layer, VectorError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_layer().transpose()
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// The OS error is the source, not part of the message.
    #[test]
    fn io_errors_keep_the_os_error_as_their_source() {
        let e = super::read(Path::new("/nonexistent/dir/missing.cli")).unwrap_err();
        assert_eq!(e.to_string(), "missing.cli: cannot read");
        let cause = std::error::Error::source(&e).expect("the OS error");
        assert!(cause.downcast_ref::<std::io::Error>().is_some());
        assert_eq!(
            crate::logging::chain(&e),
            format!("missing.cli: cannot read: {cause}")
        );
    }
}
