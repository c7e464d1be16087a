//! Summary of a CLI file, computed by streaming.

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use serde::Serialize;

use super::{Format, Header, Layer, LayerReader, VectorError, VectorFile};

/// One part: a `$$LABEL` and/or a part id used by the geometry.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PartInfo {
    pub id: i64,
    /// The `$$LABEL` text, "" when the header has none for this id.
    pub label: String,
    pub polylines: u64,
    pub points: u64,
    /// Hatch segments.
    pub hatches: u64,
    /// `[x_min, y_min, x_max, y_max]` in mm over the part's polylines and hatches; `None`
    /// for a labelled part without geometry.
    pub bbox: Option<[f64; 4]>,
}

/// Summary statistics of a CLI file. Lengths are in millimetres.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Info {
    pub format: Format,
    /// Millimetres per file unit.
    pub units: f64,
    pub layers: usize,
    /// Lowest and highest layer z over all layers (empty ones included).
    pub z_min: Option<f64>,
    pub z_max: Option<f64>,
    /// Median of the z steps between consecutive layers, rounded to 1 nm.
    pub layer_thickness: Option<f64>,
    pub polylines: u64,
    /// Polyline points.
    pub points: u64,
    /// Hatch segments (not hatch commands).
    pub hatches: u64,
    pub parts: Vec<PartInfo>,
    /// Layers without polylines or hatches.
    pub empty_layers: usize,
    /// Marking parameter commands ($$POWER, $$SPEED, $$FOCUS).
    pub parameters: u64,
    /// Extent of the geometry in the layout of `$$DIMENSION` (x1,y1,z1,x2,y2,z2), z over the
    /// layers that have geometry; `None` without geometry.
    pub bbox_mm: Option<[f64; 6]>,
    pub declared_layers: Option<u32>,
    pub declared_dimension_mm: Option<[f64; 6]>,
}

/// Summarises a file, streaming it one layer at a time.
pub fn info(path: &Path) -> Result<Info, VectorError> {
    let mut reader = LayerReader::open(path)?;
    let mut acc = Accumulator::new(reader.header());
    while let Some(layer) = reader.next_layer()? {
        acc.add(&layer);
    }
    Ok(acc.finish())
}

impl Info {
    /// The extent [x_min, y_min, x_max, y_max] of part `id`, when it has geometry.
    pub fn part_bbox(&self, id: i64) -> Option<[f64; 4]> {
        self.parts.iter().find(|p| p.id == id).and_then(|p| p.bbox)
    }

    /// Summarises a file already in memory (the same figures as [`info`]).
    pub fn of(file: &VectorFile) -> Info {
        let mut acc = Accumulator::new(&file.header);
        for layer in &file.layers {
            acc.add(layer);
        }
        acc.finish()
    }

    /// The summary as JSON (keys: format, units, layers, z_min, z_max, layer_thickness,
    /// polylines, points, hatches, parts, empty_layers, parameters, bbox_mm, declared_layers,
    /// declared_dimension_mm).
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self)
            .unwrap_or_else(|e| format!("{{\"error\": {:?}}}", e.to_string()))
    }
}

/// Running x/y bounds: `[x_min, y_min, x_max, y_max]`, `None` before the first point.
#[derive(Default)]
struct Extent(Option<(f64, f64, f64, f64)>);

impl Extent {
    fn add(&mut self, x: f64, y: f64) {
        self.0 = Some(match self.0 {
            Some((x1, y1, x2, y2)) => (x1.min(x), y1.min(y), x2.max(x), y2.max(y)),
            None => (x, y, x, y),
        });
    }

    fn merge(&mut self, o: &Extent) {
        if let Some((x1, y1, x2, y2)) = o.0 {
            self.add(x1, y1);
            self.add(x2, y2);
        }
    }

    fn bbox(&self) -> Option<[f64; 4]> {
        self.0.map(|(x1, y1, x2, y2)| [x1, y1, x2, y2])
    }
}

#[derive(Default)]
struct PartAcc {
    label: Option<String>,
    polylines: u64,
    points: u64,
    hatches: u64,
    extent: Extent,
}

struct Accumulator {
    header: Header,
    z: Vec<f64>,
    geometry_z: Option<(f64, f64)>,
    polylines: u64,
    points: u64,
    hatches: u64,
    empty_layers: usize,
    parameters: u64,
    parts: BTreeMap<i64, PartAcc>,
}

impl Accumulator {
    fn new(header: &Header) -> Accumulator {
        let mut parts: BTreeMap<i64, PartAcc> = BTreeMap::new();
        for (id, label) in &header.labels {
            parts.entry(*id).or_default().label = Some(label.clone());
        }
        Accumulator {
            header: Header {
                user_data: Vec::new(),
                ..header.clone()
            },
            z: Vec::new(),
            geometry_z: None,
            polylines: 0,
            points: 0,
            hatches: 0,
            empty_layers: 0,
            parameters: 0,
            parts,
        }
    }

    fn add(&mut self, layer: &Layer) {
        self.z.push(layer.z_mm);
        self.parameters += layer.parameters.len() as u64;
        if layer.is_empty() {
            self.empty_layers += 1;
        } else {
            let z = layer.z_mm;
            self.geometry_z = Some(match self.geometry_z {
                Some((lo, hi)) => (lo.min(z), hi.max(z)),
                None => (z, z),
            });
        }
        for p in &layer.polylines {
            let part = self.parts.entry(p.part).or_default();
            part.polylines += 1;
            part.points += p.points.len() as u64;
            for &[x, y] in &p.points {
                part.extent.add(x, y);
            }
            self.polylines += 1;
            self.points += p.points.len() as u64;
        }
        for h in &layer.hatches {
            let part = self.parts.entry(h.part).or_default();
            part.hatches += h.segments.len() as u64;
            for &[sx, sy, ex, ey] in &h.segments {
                part.extent.add(sx, sy);
                part.extent.add(ex, ey);
            }
            self.hatches += h.segments.len() as u64;
        }
    }

    fn finish(self) -> Info {
        let mut steps: Vec<f64> = self
            .z
            .iter()
            .zip(self.z.iter().skip(1))
            .map(|(a, b)| b - a)
            .collect();
        steps.sort_by(f64::total_cmp);
        let layer_thickness = match steps.len() {
            0 => None,
            n if n % 2 == 1 => steps.get(n / 2).copied(),
            n => match (steps.get(n / 2 - 1), steps.get(n / 2)) {
                (Some(a), Some(b)) => Some((a + b) / 2.0),
                _ => None,
            },
        };
        // A derived figure: drop the float noise of subtracting scaled z values.
        let layer_thickness = layer_thickness.map(|t| (t * 1e9).round() / 1e9);
        let mut all = Extent::default();
        for p in self.parts.values() {
            all.merge(&p.extent);
        }
        let bbox_mm = match (all.bbox(), self.geometry_z) {
            (Some([x1, y1, x2, y2]), Some((z1, z2))) => Some([x1, y1, z1, x2, y2, z2]),
            _ => None,
        };
        Info {
            format: self.header.format,
            units: self.header.units_mm,
            layers: self.z.len(),
            z_min: self.z.iter().copied().reduce(f64::min),
            z_max: self.z.iter().copied().reduce(f64::max),
            layer_thickness,
            polylines: self.polylines,
            points: self.points,
            hatches: self.hatches,
            parts: self
                .parts
                .into_iter()
                .map(|(id, p)| PartInfo {
                    id,
                    label: p.label.unwrap_or_default(),
                    polylines: p.polylines,
                    points: p.points,
                    hatches: p.hatches,
                    bbox: p.extent.bbox(),
                })
                .collect(),
            empty_layers: self.empty_layers,
            parameters: self.parameters,
            bbox_mm,
            declared_layers: self.header.layers_declared,
            declared_dimension_mm: self.header.dimension_mm,
        }
    }
}

/// A length for people: at most 6 decimals, trailing zeros dropped.
fn mm(v: f64) -> String {
    let s = format!("{v:.6}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        &s
    };
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

fn range(lo: f64, hi: f64) -> String {
    format!("{} … {}", mm(lo), mm(hi))
}

impl fmt::Display for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let format = match self.format {
            Format::Ascii => "ASCII",
            Format::Binary => "binary",
        };
        writeln!(f, "format: {format}, units: {} mm", mm(self.units))?;
        write!(f, "layers: {}", self.layers)?;
        if let Some(d) = self.declared_layers {
            write!(f, " (declared {d})")?;
        }
        if self.empty_layers > 0 {
            write!(f, ", {} empty", self.empty_layers)?;
        }
        writeln!(f)?;
        if let (Some(lo), Some(hi)) = (self.z_min, self.z_max) {
            write!(f, "z: {} mm", range(lo, hi))?;
            if let Some(t) = self.layer_thickness {
                write!(f, ", layer thickness {} mm", mm(t))?;
            }
            writeln!(f)?;
        }
        writeln!(
            f,
            "geometry: {} polylines, {} points, {} hatch segments, {} marking parameters",
            self.polylines, self.points, self.hatches, self.parameters
        )?;
        if let Some([x1, y1, z1, x2, y2, z2]) = self.bbox_mm {
            writeln!(
                f,
                "extent: x {}, y {}, z {} mm",
                range(x1, x2),
                range(y1, y2),
                range(z1, z2)
            )?;
        }
        if let Some([x1, y1, z1, x2, y2, z2]) = self.declared_dimension_mm {
            writeln!(
                f,
                "declared dimension: x {}, y {}, z {} mm",
                range(x1, x2),
                range(y1, y2),
                range(z1, z2)
            )?;
        }
        for p in &self.parts {
            write!(
                f,
                "part {} {:?}: {} polylines, {} points, {} hatch segments",
                p.id, p.label, p.polylines, p.points, p.hatches
            )?;
            if let Some([x1, y1, x2, y2]) = p.bbox {
                write!(f, ", x {}, y {} mm", range(x1, x2), range(y1, y2))?;
            }
            writeln!(f)?;
        }
        Ok(())
    }
}
