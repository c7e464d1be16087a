//! The ASCII header shared by both encodings.
//!
//! The header is scanned byte by byte so that nothing past `$$HEADEREND` is consumed: in binary
//! files the first command id follows those bytes directly.

use std::io::BufRead;

use super::number::{parse_f64, parse_i64, parse_u64};
use super::source::Src;
use super::{Format, Header, VectorError};

/// Longest header parameter text accepted (a `$$LABEL` text, say).
const MAX_PARAM_LEN: usize = 1 << 20;
/// Longest command name read.
const MAX_NAME_LEN: usize = 64;

/// Parses the header; returns it with the 1-based line on which `$$HEADEREND` stands.
/// The source is left right after the `$$HEADEREND` bytes.
pub(crate) fn parse_header<R: BufRead>(
    src: &mut Src<R>,
    name: &str,
) -> Result<(Header, u64), VectorError> {
    let mut scan = Scan { src, name, line: 1 };
    scan.skip_bom()?;
    let mut format = None;
    let mut header = Header::new(Format::Ascii, 1.0);
    let mut started = false;
    loop {
        scan.skip_blank()?;
        let cmd_line = scan.line;
        let Some(word) = scan.command_word(started)? else {
            let msg = if started {
                "missing $$HEADEREND: the file ends inside the header"
            } else {
                "expected $$HEADERSTART, found end of file"
            };
            return Err(scan.err(cmd_line, msg.to_string()));
        };
        if !started {
            if word != "HEADERSTART" {
                return Err(scan.err(
                    cmd_line,
                    format!("expected $$HEADERSTART, found '$${word}'"),
                ));
            }
            started = true;
            continue;
        }
        match word.as_str() {
            "HEADEREND" => break,
            "HEADERSTART" => {}
            "ASCII" => format = Some(Format::Ascii),
            "BINARY" => format = Some(Format::Binary),
            "ALIGN" => header.aligned = true,
            "GEOMETRYSTART" | "GEOMETRYEND" | "LAYER" | "POLYLINE" | "HATCHES" => {
                return Err(scan.err(cmd_line, format!("expected $$HEADEREND before '$${word}'")));
            }
            "USERDATA" => {
                let entry = scan.user_data(cmd_line)?;
                header.user_data.push(entry);
            }
            _ => {
                let params = scan.params()?;
                let p = trim(&params);
                let bad = |what: &str| {
                    scan_err(
                        name,
                        cmd_line,
                        format!("expected {what} in $${word}, found '{}'", shown(p)),
                    )
                };
                match word.as_str() {
                    "UNITS" => {
                        // Real files use 0.001 to 1 mm per unit; outside 1 nm to 1 m, coordinates
                        // would overflow to infinity or vanish.
                        let u = parse_f64(p)
                            .filter(|u| *u > 0.0)
                            .ok_or_else(|| bad("a positive number"))?;
                        if !(1e-6..=1e3).contains(&u) {
                            return Err(bad("a unit of 1e-6 to 1000 mm"));
                        }
                        header.units_mm = u;
                    }
                    "VERSION" => header.version = Some(text(p)),
                    "DATE" => header.date = Some(text(p)),
                    "LAYERS" => {
                        let n = parse_u64(p)
                            .and_then(|n| u32::try_from(n).ok())
                            .ok_or_else(|| bad("a layer count"))?;
                        header.layers_declared = Some(n);
                    }
                    "LABEL" => {
                        let (id, label) = match p.iter().position(|&b| b == b',') {
                            Some(i) => (p.get(..i).unwrap_or(&[]), p.get(i + 1..).unwrap_or(&[])),
                            None => (p, &[][..]),
                        };
                        let id = parse_i64(trim(id)).ok_or_else(|| bad("a part id"))?;
                        header.labels.push((id, text(trim(label))));
                    }
                    "DIMENSION" => {
                        let mut dim = [0.0; 6];
                        let mut count = 0;
                        for field in p.split(|&b| b == b',') {
                            let v = parse_f64(trim(field)).ok_or_else(|| bad("a number"))?;
                            if let Some(slot) = dim.get_mut(count) {
                                *slot = v;
                            }
                            count += 1;
                        }
                        if count != 6 {
                            return Err(bad("6 numbers x1,y1,z1,x2,y2,z2"));
                        }
                        header.dimension_mm = Some(dim);
                    }
                    // Other header commands are not needed here; their text is skipped.
                    _ => {}
                }
            }
        }
    }
    let end_line = scan.line;
    header.format = format.ok_or_else(|| {
        scan.err(
            end_line,
            "expected $$ASCII or $$BINARY in the header".to_string(),
        )
    })?;
    Ok((header, end_line))
}

fn scan_err(name: &str, line: u64, message: String) -> VectorError {
    VectorError::AtLine {
        file: name.to_string(),
        line,
        message,
    }
}

fn trim(s: &[u8]) -> &[u8] {
    let start = s
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(s.len());
    let end = s
        .iter()
        .rposition(|b| !b.is_ascii_whitespace())
        .map_or(start, |e| e + 1);
    s.get(start..end).unwrap_or(&[])
}

fn text(s: &[u8]) -> String {
    String::from_utf8_lossy(s).into_owned()
}

/// A short, printable rendering of some input for an error message.
pub(crate) fn shown(s: &[u8]) -> String {
    let cut = s.get(..40).unwrap_or(s);
    let mut t: String = String::from_utf8_lossy(cut)
        .chars()
        .map(|c| if c.is_control() { '?' } else { c })
        .collect();
    if cut.len() < s.len() {
        t.push('…');
    }
    t
}

struct Scan<'a, R> {
    src: &'a mut Src<R>,
    name: &'a str,
    line: u64,
}

impl<R: BufRead> Scan<'_, R> {
    fn err(&self, line: u64, message: String) -> VectorError {
        scan_err(self.name, line, message)
    }

    fn io(&self, source: std::io::Error) -> VectorError {
        VectorError::Io {
            file: self.name.to_string(),
            source,
        }
    }

    fn peek(&mut self) -> Result<Option<u8>, VectorError> {
        self.src.peek().map_err(|e| self.io(e))
    }

    /// Consumes one byte already peeked, counting lines.
    fn bump(&mut self, b: u8) {
        self.src.bump();
        if b == b'\n' {
            self.line += 1;
        }
    }

    fn skip_bom(&mut self) -> Result<(), VectorError> {
        if self.peek()? == Some(0xEF) {
            let mut bom = [0u8; 3];
            if self.src.remaining() >= 3 {
                self.src.read_exact(&mut bom).map_err(|e| self.io(e))?;
            }
            if bom != [0xEF, 0xBB, 0xBF] {
                return Err(self.err(1, "expected $$HEADERSTART, found binary data".into()));
            }
        }
        Ok(())
    }

    /// Skips whitespace and `// … //` comments.
    fn skip_blank(&mut self) -> Result<(), VectorError> {
        while let Some(b) = self.peek()? {
            if b.is_ascii_whitespace() {
                self.bump(b);
            } else if b == b'/' {
                let line = self.line;
                self.bump(b);
                if self.peek()? != Some(b'/') {
                    return Err(self.err(line, "expected a header command, found '/'".into()));
                }
                self.bump(b'/');
                self.skip_comment(line)?;
            } else {
                break;
            }
        }
        Ok(())
    }

    /// Skips the rest of a comment whose opening `//` was consumed.
    fn skip_comment(&mut self, start_line: u64) -> Result<(), VectorError> {
        let mut prev = 0u8;
        while let Some(b) = self.peek()? {
            self.bump(b);
            if prev == b'/' && b == b'/' {
                return Ok(());
            }
            prev = b;
        }
        Err(self.err(
            start_line,
            "unterminated comment: '//' without a closing '//'".into(),
        ))
    }

    /// Reads `$$NAME`; `None` at the end of the data.
    fn command_word(&mut self, started: bool) -> Result<Option<String>, VectorError> {
        let line = self.line;
        let Some(b) = self.peek()? else {
            return Ok(None);
        };
        let expected = if started {
            "a header command starting with '$$'"
        } else {
            "$$HEADERSTART"
        };
        if b != b'$' {
            let found = self.snippet()?;
            return Err(self.err(line, format!("expected {expected}, found '{found}'")));
        }
        self.bump(b);
        if self.peek()? != Some(b'$') {
            let found = self.snippet()?;
            return Err(self.err(line, format!("expected {expected}, found '${found}'")));
        }
        self.bump(b'$');
        let mut word = String::new();
        while let Some(c) = self.peek()? {
            if !(c.is_ascii_alphanumeric() || c == b'_') || word.len() >= MAX_NAME_LEN {
                break;
            }
            self.bump(c);
            word.push(char::from(c.to_ascii_uppercase()));
        }
        Ok(Some(word))
    }

    /// Up to 20 bytes of what follows, for an error message.
    fn snippet(&mut self) -> Result<String, VectorError> {
        let mut s = Vec::new();
        while let Some(b) = self.peek()? {
            if b == b'\n' || s.len() >= 20 {
                break;
            }
            self.bump(b);
            s.push(b);
        }
        Ok(shown(&s))
    }

    /// Reads `/params` up to the end of the line, without comments.
    fn params(&mut self) -> Result<Vec<u8>, VectorError> {
        let line = self.line;
        if self.peek()? == Some(b'/') {
            self.bump(b'/');
        }
        let mut out = Vec::new();
        while let Some(b) = self.peek()? {
            self.bump(b);
            match b {
                b'\n' => break,
                b'/' if self.peek()? == Some(b'/') => {
                    let l = self.line;
                    self.bump(b'/');
                    self.skip_comment(l)?;
                }
                _ => {
                    if out.len() >= MAX_PARAM_LEN {
                        return Err(self.err(line, "header line too long".into()));
                    }
                    out.push(b);
                }
            }
        }
        Ok(out)
    }

    /// Reads `/uid,len,` then exactly `len` bytes of data, then skips to the end of the line.
    fn user_data(&mut self, line: u64) -> Result<(String, Vec<u8>), VectorError> {
        if self.peek()? == Some(b'/') {
            self.bump(b'/');
        }
        let uid = self.until_comma(line, "a uid")?;
        let len_text = self.until_comma(line, "a data length")?;
        let len = parse_u64(trim(&len_text)).ok_or_else(|| {
            self.err(
                line,
                format!(
                    "expected a data length in $$USERDATA, found '{}'",
                    shown(&len_text)
                ),
            )
        })?;
        let left = self.src.remaining();
        if len > left {
            return Err(self.err(
                line,
                format!("truncated $$USERDATA: {len} bytes of data announced, {left} bytes left"),
            ));
        }
        let mut data = vec![0u8; len as usize];
        self.src.read_exact(&mut data).map_err(|e| self.io(e))?;
        self.line += data.iter().filter(|&&b| b == b'\n').count() as u64;
        self.params()?;
        Ok((text(trim(&uid)), data))
    }

    fn until_comma(&mut self, line: u64, what: &str) -> Result<Vec<u8>, VectorError> {
        let mut out = Vec::new();
        loop {
            match self.peek()? {
                Some(b',') => {
                    self.bump(b',');
                    return Ok(out);
                }
                Some(b) if b != b'\n' && out.len() < MAX_PARAM_LEN => {
                    self.bump(b);
                    out.push(b);
                }
                _ => {
                    return Err(self.err(
                        line,
                        format!(
                            "expected {what} followed by ',' in $$USERDATA, found '{}'",
                            shown(&out)
                        ),
                    ))
                }
            }
        }
    }
}
