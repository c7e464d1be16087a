//! ASCII geometry: `$$LAYER/z`, `$$POLYLINE/id,dir,n,x1,y1,…`, `$$HATCHES/id,n,sx,sy,ex,ey,…`
//! and the CLI+ marking parameters.
//!
//! The text is read a line at a time into a reused buffer and tokenised in place. Parameters are
//! separated by commas and/or whitespace, and may continue on following lines: a command's
//! parameters end where its announced count is satisfied. `// … //` comments are skipped.

use std::io::BufRead;

use super::command::{Command, Pos};
use super::header::shown;
use super::number::{parse_f64, parse_i64, parse_u64};
use super::source::Src;
use super::{Direction, Hatches, MarkingParameter, Polyline, VectorError};

#[derive(Clone, Copy, PartialEq, Eq)]
enum Cmd {
    Layer,
    Polyline,
    Hatches,
    Power,
    Speed,
    Focus,
    GeometryStart,
    GeometryEnd,
    Other,
}

impl Cmd {
    fn classify(name: &[u8]) -> Cmd {
        let is = |s: &str| name.eq_ignore_ascii_case(s.as_bytes());
        if is("LAYER") {
            Cmd::Layer
        } else if is("POLYLINE") {
            Cmd::Polyline
        } else if is("HATCHES") {
            Cmd::Hatches
        } else if is("POWER") {
            Cmd::Power
        } else if is("SPEED") {
            Cmd::Speed
        } else if is("FOCUS") {
            Cmd::Focus
        } else if is("GEOMETRYSTART") {
            Cmd::GeometryStart
        } else if is("GEOMETRYEND") {
            Cmd::GeometryEnd
        } else {
            Cmd::Other
        }
    }
}

enum Tok {
    Cmd(Cmd),
    Field,
    Eof,
}

fn is_sep(b: u8) -> bool {
    b == b',' || b.is_ascii_whitespace()
}

pub(crate) struct AsciiParser<R> {
    src: Src<R>,
    units: f64,
    name: String,
    buf: Vec<u8>,
    cur: usize,
    /// 1-based line number of `buf`.
    line: u64,
    /// `buf` ended with a newline, so the next line read has the next number.
    newline_pending: bool,
    /// File offset of `buf[0]`.
    line_start: u64,
    tok_start: usize,
    tok_end: usize,
    tok_line: u64,
    tok_offset: u64,
    done: bool,
}

impl<R: BufRead> AsciiParser<R> {
    /// `line` is the line number of the data at the source's position.
    pub(crate) fn new(src: Src<R>, units: f64, name: &str, line: u64) -> Self {
        AsciiParser {
            line_start: src.pos(),
            src,
            units,
            name: name.to_string(),
            buf: Vec::new(),
            cur: 0,
            line,
            newline_pending: false,
            tok_start: 0,
            tok_end: 0,
            tok_line: line,
            tok_offset: 0,
            done: false,
        }
    }

    pub(crate) fn error(&self, line: u64, message: String) -> VectorError {
        VectorError::AtLine {
            file: self.name.clone(),
            line,
            message,
        }
    }

    fn err_tok(&self, message: String) -> VectorError {
        self.error(self.tok_line, message)
    }

    fn read_line(&mut self) -> Result<bool, VectorError> {
        if self.newline_pending {
            self.line += 1;
        }
        self.buf.clear();
        self.cur = 0;
        self.line_start = self.src.pos();
        let n = self
            .src
            .read_line(&mut self.buf)
            .map_err(|source| VectorError::Io {
                file: self.name.clone(),
                source,
            })?;
        self.newline_pending = self.buf.last() == Some(&b'\n');
        Ok(n > 0)
    }

    fn tok_bytes(&self) -> &[u8] {
        self.buf.get(self.tok_start..self.tok_end).unwrap_or(&[])
    }

    /// What the last token was, for an error message.
    fn found(&self, tok: &Tok) -> String {
        match tok {
            Tok::Eof => "end of file".to_string(),
            _ => format!("'{}'", shown(self.tok_bytes())),
        }
    }

    fn next_tok(&mut self) -> Result<Tok, VectorError> {
        loop {
            let mut i = self.cur;
            while let Some(&b) = self.buf.get(i) {
                if !is_sep(b) {
                    break;
                }
                i += 1;
            }
            self.cur = i;
            let Some(&b) = self.buf.get(i) else {
                if !self.read_line()? {
                    self.tok_start = 0;
                    self.tok_end = 0;
                    self.tok_line = self.line;
                    self.tok_offset = self.src.pos();
                    return Ok(Tok::Eof);
                }
                continue;
            };
            let next = self.buf.get(i + 1).copied();
            self.tok_start = i;
            self.tok_line = self.line;
            self.tok_offset = self.line_start + i as u64;
            if b == b'/' && next == Some(b'/') {
                self.skip_comment(i + 2)?;
                continue;
            }
            if b == b'$' && next == Some(b'$') {
                let mut j = i + 2;
                while let Some(&c) = self.buf.get(j) {
                    if !(c.is_ascii_alphanumeric() || c == b'_') {
                        break;
                    }
                    j += 1;
                }
                let cmd = Cmd::classify(self.buf.get(i + 2..j).unwrap_or(&[]));
                self.tok_end = j;
                if self.buf.get(j) == Some(&b'/') {
                    j += 1;
                }
                self.cur = j;
                return Ok(Tok::Cmd(cmd));
            }
            let mut j = i + 1;
            while let Some(&c) = self.buf.get(j) {
                if is_sep(c) || ((c == b'/' || c == b'$') && self.buf.get(j + 1) == Some(&c)) {
                    break;
                }
                j += 1;
            }
            self.tok_end = j;
            self.cur = j;
            return Ok(Tok::Field);
        }
    }

    /// Skips a comment whose text starts at `buf[from]`, possibly over several lines.
    fn skip_comment(&mut self, from: usize) -> Result<(), VectorError> {
        let start_line = self.line;
        let mut from = from;
        loop {
            let rest = self.buf.get(from..).unwrap_or(&[]);
            if let Some(k) = rest.windows(2).position(|w| w == b"//") {
                self.cur = from + k + 2;
                return Ok(());
            }
            if !self.read_line()? {
                return Err(self.error(
                    start_line,
                    "unterminated comment: '//' without a closing '//'".into(),
                ));
            }
            from = 0;
        }
    }

    /// Positions on the next field of `cmd`, or fails naming what was expected.
    fn field(
        &mut self,
        what: &str,
        cmd: &str,
        progress: Option<(u64, u64, &str)>,
    ) -> Result<(), VectorError> {
        match self.next_tok()? {
            Tok::Field => Ok(()),
            other => {
                let extra = match progress {
                    Some((n, got, unit)) => format!(" ({n} {unit} announced, {got} read)"),
                    None => String::new(),
                };
                Err(self.err_tok(format!(
                    "expected {what} in {cmd}{extra}, found {}",
                    self.found(&other)
                )))
            }
        }
    }

    fn number(
        &mut self,
        cmd: &str,
        progress: Option<(u64, u64, &str)>,
    ) -> Result<f64, VectorError> {
        self.field("a number", cmd, progress)?;
        match parse_f64(self.tok_bytes()) {
            Some(v) => Ok(v),
            None => Err(self.err_tok(format!(
                "expected a number in {cmd}, found {}",
                self.found(&Tok::Field)
            ))),
        }
    }

    fn integer<T>(
        &mut self,
        what: &str,
        cmd: &str,
        parse: impl Fn(&[u8]) -> Option<T>,
    ) -> Result<T, VectorError> {
        self.field(what, cmd, None)?;
        match parse(self.tok_bytes()) {
            Some(v) => Ok(v),
            None => Err(self.err_tok(format!(
                "expected {what} in {cmd}, found {}",
                self.found(&Tok::Field)
            ))),
        }
    }

    /// At most one element per 4 remaining bytes can follow ("x,y," at the shortest).
    fn capacity(&self, n: u64, bytes_each: u64) -> usize {
        let left = self.src.remaining() + self.buf.len() as u64;
        n.min(left / bytes_each) as usize
    }

    fn polyline(&mut self, store: bool) -> Result<Polyline, VectorError> {
        const CMD: &str = "$$POLYLINE";
        let part = self.integer("a part id", CMD, parse_i64)?;
        let direction = self.integer("a direction (0, 1 or 2)", CMD, |s| {
            parse_u64(s).and_then(Direction::from_code)
        })?;
        let n = self.integer("a point count", CMD, parse_u64)?;
        let mut points = Vec::new();
        if store {
            points.reserve(self.capacity(n, 4));
            for k in 0..n {
                let x = self.number(CMD, Some((n, k, "points")))?;
                let y = self.number(CMD, Some((n, k, "points")))?;
                points.push([x * self.units, y * self.units]);
            }
        } else {
            for k in 0..n {
                self.field("a number", CMD, Some((n, k, "points")))?;
                self.field("a number", CMD, Some((n, k, "points")))?;
            }
        }
        Ok(Polyline {
            part,
            direction,
            points,
        })
    }

    fn hatches(&mut self, store: bool) -> Result<Hatches, VectorError> {
        const CMD: &str = "$$HATCHES";
        let part = self.integer("a part id", CMD, parse_i64)?;
        let n = self.integer("a hatch count", CMD, parse_u64)?;
        let mut segments = Vec::new();
        let u = self.units;
        if store {
            segments.reserve(self.capacity(n, 8));
            for k in 0..n {
                let p = Some((n, k, "hatches"));
                let sx = self.number(CMD, p)?;
                let sy = self.number(CMD, p)?;
                let ex = self.number(CMD, p)?;
                let ey = self.number(CMD, p)?;
                segments.push([sx * u, sy * u, ex * u, ey * u]);
            }
        } else {
            for k in 0..n {
                for _ in 0..4 {
                    self.field("a number", CMD, Some((n, k, "hatches")))?;
                }
            }
        }
        Ok(Hatches { part, segments })
    }

    /// The next geometry command, `None` after `$$GEOMETRYEND` or at the end of the data.
    /// With `store` false, coordinates are counted but neither parsed nor kept.
    pub(crate) fn next_command(
        &mut self,
        store: bool,
    ) -> Result<Option<(Command, Pos)>, VectorError> {
        loop {
            if self.done {
                return Ok(None);
            }
            let tok = self.next_tok()?;
            let cmd = match tok {
                Tok::Eof => {
                    self.done = true;
                    return Ok(None);
                }
                Tok::Field => {
                    return Err(self.err_tok(format!(
                        "expected a command such as $$LAYER or $$POLYLINE, found {}",
                        self.found(&tok)
                    )))
                }
                Tok::Cmd(c) => c,
            };
            let mut pos = Pos {
                offset: self.tok_offset,
                line: self.tok_line,
                what: "",
            };
            let command = match cmd {
                Cmd::GeometryStart => continue,
                Cmd::GeometryEnd => {
                    self.done = true;
                    return Ok(None);
                }
                Cmd::Layer => {
                    pos.what = "$$LAYER";
                    Command::Layer(self.number("$$LAYER", None)? * self.units)
                }
                Cmd::Polyline => {
                    pos.what = "$$POLYLINE";
                    Command::Polyline(self.polyline(store)?)
                }
                Cmd::Hatches => {
                    pos.what = "$$HATCHES";
                    Command::Hatches(self.hatches(store)?)
                }
                Cmd::Power => {
                    pos.what = "$$POWER";
                    Command::Parameter(MarkingParameter::Power(self.number("$$POWER", None)?))
                }
                Cmd::Speed => {
                    pos.what = "$$SPEED";
                    Command::Parameter(MarkingParameter::Speed(self.number("$$SPEED", None)?))
                }
                Cmd::Focus => {
                    pos.what = "$$FOCUS";
                    Command::Parameter(MarkingParameter::Focus(self.number("$$FOCUS", None)?))
                }
                Cmd::Other => {
                    return Err(self.err_tok(format!(
                        "unknown command {} (expected $$LAYER, $$POLYLINE, $$HATCHES, $$POWER, $$SPEED, $$FOCUS or $$GEOMETRYEND)",
                        self.found(&tok)
                    )))
                }
            };
            return Ok(Some((command, pos)));
        }
    }
}
