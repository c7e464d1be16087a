//! Writing CLI files.

use std::fmt::Write as _;
use std::io::{self, BufWriter, Write};

use super::{Format, Header, MarkingParameter, VectorFile};

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}

fn check_units(header: &Header) -> io::Result<f64> {
    let u = header.units_mm;
    if u.is_finite() && u > 0.0 {
        Ok(u)
    } else {
        Err(invalid(format!("units must be a positive number, not {u}")))
    }
}

/// Header text is one line per command: line breaks inside values become spaces.
fn one_line(s: &str) -> String {
    s.replace(['\r', '\n'], " ")
}

fn write_header(w: &mut impl Write, file: &VectorFile, format: Format) -> io::Result<()> {
    let h = &file.header;
    w.write_all(b"$$HEADERSTART\n")?;
    w.write_all(match format {
        Format::Ascii => b"$$ASCII\n",
        Format::Binary => b"$$BINARY\n",
    })?;
    writeln!(w, "$$UNITS/{}", h.units_mm)?;
    if let Some(v) = &h.version {
        writeln!(w, "$$VERSION/{}", one_line(v))?;
    }
    for (id, label) in &h.labels {
        writeln!(w, "$$LABEL/{id},{}", one_line(label))?;
    }
    if let Some(d) = &h.date {
        writeln!(w, "$$DATE/{}", one_line(d))?;
    }
    if let Some([x1, y1, z1, x2, y2, z2]) = h.dimension_mm {
        writeln!(w, "$$DIMENSION/{x1},{y1},{z1},{x2},{y2},{z2}")?;
    }
    writeln!(w, "$$LAYERS/{}", file.layers.len())?;
    for (uid, data) in &h.user_data {
        write!(
            w,
            "$$USERDATA/{},{},",
            one_line(uid).replace(',', "_"),
            data.len()
        )?;
        w.write_all(data)?;
        w.write_all(b"\n")?;
    }
    w.write_all(b"$$HEADEREND")
}

/// Formats numbers in file units with enough decimals for 1 nm, trailing zeros dropped.
struct Num {
    decimals: usize,
    text: String,
}

impl Num {
    fn new(units: f64) -> Num {
        // 1e-9 mm expressed in units needs ceil(9 + log10(units)) decimals.
        let d = (9.0 + units.log10()).ceil();
        Num {
            decimals: if d.is_finite() {
                d.clamp(0.0, 15.0) as usize
            } else {
                9
            },
            text: String::new(),
        }
    }

    fn write(&mut self, w: &mut impl Write, v: f64) -> io::Result<()> {
        if !v.is_finite() {
            return Err(invalid(format!("cannot write the non-finite value {v}")));
        }
        self.text.clear();
        // Writing to a String cannot fail.
        let _ = write!(self.text, "{:.*}", self.decimals, v);
        let mut s = self.text.as_str();
        if s.contains('.') {
            s = s.trim_end_matches('0').trim_end_matches('.');
        }
        if s == "-0" {
            s = "0";
        }
        w.write_all(s.as_bytes())
    }
}

/// Writes the file as ASCII CLI (CLI+ marking parameters included), coordinates divided by the
/// header's units and written with a resolution of 1 nm. `$$LAYERS` is the number of layers
/// written; `$$DIMENSION` is copied from the header (millimetres).
pub fn write_ascii(file: &VectorFile, out: &mut impl Write) -> io::Result<()> {
    let units = check_units(&file.header)?;
    let mut w = BufWriter::with_capacity(1 << 16, out);
    write_header(&mut w, file, Format::Ascii)?;
    w.write_all(b"\n$$GEOMETRYSTART\n")?;
    let mut num = Num::new(units);
    for layer in &file.layers {
        w.write_all(b"$$LAYER/")?;
        num.write(&mut w, layer.z_mm / units)?;
        w.write_all(b"\n")?;
        for p in &layer.parameters {
            let (word, v) = match p {
                MarkingParameter::Power(v) => ("POWER", v),
                MarkingParameter::Speed(v) => ("SPEED", v),
                MarkingParameter::Focus(v) => ("FOCUS", v),
            };
            if !v.is_finite() {
                return Err(invalid(format!("cannot write the non-finite ${word} {v}")));
            }
            writeln!(w, "$${word}/{v}")?;
        }
        for p in &layer.polylines {
            write!(
                w,
                "$$POLYLINE/{},{},{}",
                p.part,
                p.direction.code(),
                p.points.len()
            )?;
            for &[x, y] in &p.points {
                w.write_all(b",")?;
                num.write(&mut w, x / units)?;
                w.write_all(b",")?;
                num.write(&mut w, y / units)?;
            }
            w.write_all(b"\n")?;
        }
        for h in &layer.hatches {
            write!(w, "$$HATCHES/{},{}", h.part, h.segments.len())?;
            for seg in &h.segments {
                for &v in seg {
                    w.write_all(b",")?;
                    num.write(&mut w, v / units)?;
                }
            }
            w.write_all(b"\n")?;
        }
    }
    w.write_all(b"$$GEOMETRYEND\n")?;
    w.flush()
}

fn f32_bytes(v: f64, units: f64) -> io::Result<[u8; 4]> {
    let f = (v / units) as f32;
    if f.is_finite() {
        Ok(f.to_le_bytes())
    } else {
        Err(invalid(format!(
            "cannot write {v} mm as a 32-bit float in units of {units} mm"
        )))
    }
}

fn i32_field(v: i64, what: &str) -> io::Result<[u8; 4]> {
    i32::try_from(v)
        .map(i32::to_le_bytes)
        .map_err(|_| invalid(format!("{what} {v} does not fit a 32-bit integer")))
}

fn count(n: usize, what: &str) -> io::Result<[u8; 4]> {
    i32::try_from(n)
        .map(i32::to_le_bytes)
        .map_err(|_| invalid(format!("{n} {what} do not fit one binary command")))
}

/// Writes the file as binary CLI with long commands only (127 layer, 130 polyline, 132 hatches,
/// f32 coordinates divided by the header's units). The geometry follows `$$HEADEREND` directly,
/// as in the real files. Binary CLI has no marking parameters: they are not written.
pub fn write_binary(file: &VectorFile, out: &mut impl Write) -> io::Result<()> {
    let units = check_units(&file.header)?;
    let mut w = BufWriter::with_capacity(1 << 16, out);
    write_header(&mut w, file, Format::Binary)?;
    for layer in &file.layers {
        w.write_all(&127u16.to_le_bytes())?;
        w.write_all(&f32_bytes(layer.z_mm, units)?)?;
        for p in &layer.polylines {
            w.write_all(&130u16.to_le_bytes())?;
            w.write_all(&i32_field(p.part, "part id")?)?;
            w.write_all(&(p.direction.code() as i32).to_le_bytes())?;
            w.write_all(&count(p.points.len(), "points")?)?;
            for &[x, y] in &p.points {
                w.write_all(&f32_bytes(x, units)?)?;
                w.write_all(&f32_bytes(y, units)?)?;
            }
        }
        for h in &layer.hatches {
            w.write_all(&132u16.to_le_bytes())?;
            w.write_all(&i32_field(h.part, "part id")?)?;
            w.write_all(&count(h.segments.len(), "hatches")?)?;
            for seg in &h.segments {
                for &v in seg {
                    w.write_all(&f32_bytes(v, units)?)?;
                }
            }
        }
    }
    w.flush()
}
