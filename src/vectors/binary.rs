//! Binary geometry: little-endian, a u16 command id followed by its arguments.
//!
//! | id  | command        | arguments                                   |
//! |-----|----------------|---------------------------------------------|
//! | 127 | layer long     | f32 z                                       |
//! | 128 | layer short    | u16 z                                       |
//! | 129 | polyline short | u16 id, u16 dir, u16 n, 2n × i16            |
//! | 130 | polyline long  | i32 id, i32 dir, i32 n, 2n × f32            |
//! | 131 | hatches short  | u16 id, u16 n, 4n × i16                     |
//! | 132 | hatches long   | i32 id, i32 n, 4n × f32                     |
//!
//! Short coordinates are read as two's-complement i16: real files (s_Cylinder_ex.cli) put
//! negative coordinates there. Counts are checked against the bytes remaining before anything
//! is read or allocated.

use std::io::BufRead;

use super::command::{Command, Pos};
use super::source::Src;
use super::{Direction, Hatches, Polyline, VectorError};

const LAYER_LONG: u16 = 127;
const LAYER_SHORT: u16 = 128;
const POLYLINE_SHORT: u16 = 129;
const POLYLINE_LONG: u16 = 130;
const HATCHES_SHORT: u16 = 131;
const HATCHES_LONG: u16 = 132;
/// `$$` read as a little-endian u16: an ASCII `$$GEOMETRYSTART`/`$$GEOMETRYEND` in binary data.
const DOLLARS: u16 = 0x2424;

fn i16_at(r: &[u8], k: usize) -> f64 {
    let lo = r.get(k).copied().unwrap_or(0);
    let hi = r.get(k + 1).copied().unwrap_or(0);
    f64::from(i16::from_le_bytes([lo, hi]))
}

fn f32_at(r: &[u8], k: usize) -> f64 {
    let mut b = [0u8; 4];
    if let Some(s) = r.get(k..k + 4) {
        b.copy_from_slice(s);
    }
    f64::from(f32::from_le_bytes(b))
}

pub(crate) struct BinaryParser<R> {
    src: Src<R>,
    units: f64,
    name: String,
    /// Whitespace right after `$$HEADEREND` is still to be skipped.
    at_start: bool,
    done: bool,
}

impl<R: BufRead> BinaryParser<R> {
    /// `at_start`: the source stands right after the header.
    pub(crate) fn new(src: Src<R>, units: f64, name: &str, at_start: bool) -> Self {
        BinaryParser {
            src,
            units,
            name: name.to_string(),
            at_start,
            done: false,
        }
    }

    pub(crate) fn error(&self, offset: u64, message: String) -> VectorError {
        VectorError::AtByte {
            file: self.name.clone(),
            offset,
            message,
        }
    }

    fn io(&self, source: std::io::Error) -> VectorError {
        VectorError::Io {
            file: self.name.clone(),
            source,
        }
    }

    /// Checks that `bytes` follow for the fixed arguments of a command.
    fn need_args(&self, start: u64, what: &str, bytes: u64, args: &str) -> Result<(), VectorError> {
        let left = self.src.remaining();
        if left < bytes {
            return Err(self.error(
                start,
                format!("truncated {what}: {bytes} bytes of {args} expected, {left} bytes left"),
            ));
        }
        Ok(())
    }

    /// Checks that `per * n` values of `size` bytes follow.
    fn need_data(
        &self,
        start: u64,
        what: &str,
        per: u64,
        n: u64,
        size: u64,
        kind: &str,
    ) -> Result<(), VectorError> {
        let left = self.src.remaining();
        let values = per * n;
        if values.saturating_mul(size) > left {
            return Err(self.error(
                start,
                format!(
                    "truncated {what}: {per}n={values} {kind} values announced, {left} bytes left"
                ),
            ));
        }
        Ok(())
    }

    fn skip_whitespace(&mut self) -> Result<(), VectorError> {
        while let Some(b) = self.src.peek().map_err(|e| self.io(e))? {
            if !b.is_ascii_whitespace() {
                break;
            }
            self.src.bump();
        }
        Ok(())
    }

    fn direction(&self, start: u64, what: &str, code: i64) -> Result<Direction, VectorError> {
        u64::try_from(code)
            .ok()
            .and_then(Direction::from_code)
            .ok_or_else(|| {
                self.error(
                    start,
                    format!("direction {code} in {what} (expected 0, 1 or 2)"),
                )
            })
    }

    fn count(&self, start: u64, what: &str, n: i32) -> Result<u64, VectorError> {
        u64::try_from(n).map_err(|_| self.error(start, format!("negative count {n} in {what}")))
    }

    fn check_finite(&self, start: u64, what: &str, bad: Option<u64>) -> Result<(), VectorError> {
        match bad {
            None => Ok(()),
            Some(k) => Err(self.error(start, format!("{what}: value {k} is not a finite number"))),
        }
    }

    /// Reads `n` points of `N` bytes (two coordinates) into millimetres.
    fn points<const N: usize>(
        &mut self,
        start: u64,
        what: &str,
        n: u64,
        store: bool,
    ) -> Result<Vec<[f64; 2]>, VectorError> {
        if !store {
            self.src.skip(n * N as u64).map_err(|e| self.io(e))?;
            return Ok(Vec::new());
        }
        let u = self.units;
        // n * N bytes were checked to remain, so n is bounded by the data.
        let mut points = Vec::with_capacity(n as usize);
        let mut bad = None;
        let mut k = 0u64;
        self.src
            .for_each_record::<N>(n, |r| {
                let (x, y) = if N == 4 {
                    (i16_at(r, 0), i16_at(r, 2))
                } else {
                    (f32_at(r, 0), f32_at(r, 4))
                };
                if bad.is_none() && !(x.is_finite() && y.is_finite()) {
                    bad = Some(k);
                }
                points.push([x * u, y * u]);
                k += 1;
            })
            .map_err(|e| self.io(e))?;
        self.check_finite(start, what, bad)?;
        Ok(points)
    }

    /// Reads `n` hatch segments of `N` bytes (four coordinates) into millimetres.
    fn segments<const N: usize>(
        &mut self,
        start: u64,
        what: &str,
        n: u64,
        store: bool,
    ) -> Result<Vec<[f64; 4]>, VectorError> {
        if !store {
            self.src.skip(n * N as u64).map_err(|e| self.io(e))?;
            return Ok(Vec::new());
        }
        let u = self.units;
        let mut segments = Vec::with_capacity(n as usize);
        let mut bad = None;
        let mut k = 0u64;
        self.src
            .for_each_record::<N>(n, |r| {
                let s = if N == 8 {
                    [i16_at(r, 0), i16_at(r, 2), i16_at(r, 4), i16_at(r, 6)]
                } else {
                    [f32_at(r, 0), f32_at(r, 4), f32_at(r, 8), f32_at(r, 12)]
                };
                if bad.is_none() && !s.iter().all(|v| v.is_finite()) {
                    bad = Some(k);
                }
                let [sx, sy, ex, ey] = s;
                segments.push([sx * u, sy * u, ex * u, ey * u]);
                k += 1;
            })
            .map_err(|e| self.io(e))?;
        self.check_finite(start, what, bad)?;
        Ok(segments)
    }

    fn u16(&mut self) -> Result<u16, VectorError> {
        let a = self.src.read_array::<2>().map_err(|e| self.io(e))?;
        Ok(u16::from_le_bytes(a))
    }

    fn i32(&mut self) -> Result<i32, VectorError> {
        let a = self.src.read_array::<4>().map_err(|e| self.io(e))?;
        Ok(i32::from_le_bytes(a))
    }

    /// An ASCII word after `$$` in the binary data: up to 32 letters.
    fn word(&mut self) -> Result<Vec<u8>, VectorError> {
        let mut w = Vec::new();
        while let Some(b) = self.src.peek().map_err(|e| self.io(e))? {
            if !b.is_ascii_alphabetic() || w.len() >= 32 {
                break;
            }
            self.src.bump();
            w.push(b);
        }
        Ok(w)
    }

    /// The next geometry command, `None` at the end of the data (or an ASCII `$$GEOMETRYEND`).
    /// With `store` false, coordinates are skipped without decoding.
    pub(crate) fn next_command(
        &mut self,
        store: bool,
    ) -> Result<Option<(Command, Pos)>, VectorError> {
        if self.done {
            return Ok(None);
        }
        if self.at_start {
            self.skip_whitespace()?;
            self.at_start = false;
        }
        loop {
            let start = self.src.pos();
            let left = self.src.remaining();
            if left == 0 {
                self.done = true;
                return Ok(None);
            }
            if left < 2 {
                return Err(self.error(
                    start,
                    format!("truncated command id: 2 bytes expected, {left} byte left"),
                ));
            }
            let id = self.u16()?;
            let pos = |what| Pos {
                offset: start,
                line: 0,
                what,
            };
            let command = match id {
                LAYER_LONG => {
                    let what = "$$LAYER (command 127)";
                    self.need_args(start, what, 4, "f32 z")?;
                    let a = self.src.read_array::<4>().map_err(|e| self.io(e))?;
                    let z = f64::from(f32::from_le_bytes(a));
                    if !z.is_finite() {
                        return Err(self.error(start, format!("{what}: z is not a finite number")));
                    }
                    (Command::Layer(z * self.units), pos(what))
                }
                LAYER_SHORT => {
                    let what = "$$LAYER (command 128)";
                    self.need_args(start, what, 2, "u16 z")?;
                    let z = f64::from(self.u16()?);
                    (Command::Layer(z * self.units), pos(what))
                }
                POLYLINE_SHORT => {
                    let what = "$$POLYLINE (command 129)";
                    self.need_args(start, what, 6, "u16 id, dir and n")?;
                    let part = i64::from(self.u16()?);
                    let dir = self.u16()?;
                    let n = u64::from(self.u16()?);
                    self.need_data(start, what, 2, n, 2, "16-bit")?;
                    let direction = self.direction(start, what, i64::from(dir))?;
                    let points = self.points::<4>(start, what, n, store)?;
                    (
                        Command::Polyline(Polyline {
                            part,
                            direction,
                            points,
                        }),
                        pos(what),
                    )
                }
                POLYLINE_LONG => {
                    let what = "$$POLYLINE (command 130)";
                    self.need_args(start, what, 12, "i32 id, dir and n")?;
                    let part = i64::from(self.i32()?);
                    let dir = self.i32()?;
                    let n = self.i32()?;
                    let n = self.count(start, what, n)?;
                    self.need_data(start, what, 2, n, 4, "f32")?;
                    let direction = self.direction(start, what, i64::from(dir))?;
                    let points = self.points::<8>(start, what, n, store)?;
                    (
                        Command::Polyline(Polyline {
                            part,
                            direction,
                            points,
                        }),
                        pos(what),
                    )
                }
                HATCHES_SHORT => {
                    let what = "$$HATCHES (command 131)";
                    self.need_args(start, what, 4, "u16 id and n")?;
                    let part = i64::from(self.u16()?);
                    let n = u64::from(self.u16()?);
                    self.need_data(start, what, 4, n, 2, "16-bit")?;
                    let segments = self.segments::<8>(start, what, n, store)?;
                    (Command::Hatches(Hatches { part, segments }), pos(what))
                }
                HATCHES_LONG => {
                    let what = "$$HATCHES (command 132)";
                    self.need_args(start, what, 8, "i32 id and n")?;
                    let part = i64::from(self.i32()?);
                    let n = self.i32()?;
                    let n = self.count(start, what, n)?;
                    self.need_data(start, what, 4, n, 4, "f32")?;
                    let segments = self.segments::<16>(start, what, n, store)?;
                    (Command::Hatches(Hatches { part, segments }), pos(what))
                }
                DOLLARS => {
                    let w = self.word()?;
                    if w.eq_ignore_ascii_case(b"GEOMETRYEND") {
                        self.done = true;
                        return Ok(None);
                    }
                    if w.eq_ignore_ascii_case(b"GEOMETRYSTART") {
                        self.skip_whitespace()?;
                        continue;
                    }
                    return Err(self.error(
                        start,
                        format!(
                            "unknown command '$${}' in binary data (expected a command id 127 to 132)",
                            String::from_utf8_lossy(&w)
                        ),
                    ));
                }
                other => {
                    return Err(self.error(
                        start,
                        format!("unknown command id {other} (expected 127 to 132)"),
                    ))
                }
            };
            return Ok(Some(command));
        }
    }
}
