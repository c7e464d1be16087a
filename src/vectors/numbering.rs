//! Printer layer numbers ↔ layers of a vector file: the one numbering (docs/frames.md).
//!
//! Everything a user types or reads (file names `L00150_post_top.jpg`, the journal, DICOM
//! InstanceNumber, `--layer` of every command) is the printer's layer number, counted from 1.
//! A vector file counts its layers by position, and often starts with empty layers (the real
//! `Box_support_solid_ascii_with_params.cli` has 101 empty layers below its first geometry at
//! z = 3.03 mm). [`LayerMap`] is the explicit match between the two, chosen by
//! [`LayerNumbering`]:
//!
//! - `geometry` (default): printer layer 1 is the file's first layer with geometry, and the
//!   layers after it follow in file order (empty ones included: the printer still recoats them);
//!   `offset` shifts the match: printer layer `n` is position `first + n − 1 − offset`.
//! - `position`: printer layer `n` is the n-th layer of the file (position `n − 1 − offset`),
//!   empty or not: the rule before the numbering was made explicit.
//! - `z`: printer layer `n` is the file's layer whose z is `n × layer thickness` (nearest, within
//!   half a layer); for files that start elsewhere or skip heights.

use serde::{Deserialize, Serialize};

/// How printer layers are matched to a vector file's layers (`[build] layer_match`,
/// `layer_offset`; `--layer-match`, `--layer-offset`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LayerMatch {
    /// Layer 1 is the first layer with geometry.
    #[default]
    Geometry,
    /// Layer n is the n-th layer of the file.
    Position,
    /// Layer n is the layer at z = n × thickness.
    Z,
}

/// A layer match rule that is not `geometry`, `position` or `z`.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("layer match `{0}`: expected geometry, position or z")]
pub struct UnknownLayerMatch(pub String);

impl std::str::FromStr for LayerMatch {
    type Err = UnknownLayerMatch;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "geometry" => Ok(LayerMatch::Geometry),
            "position" => Ok(LayerMatch::Position),
            "z" => Ok(LayerMatch::Z),
            other => Err(UnknownLayerMatch(other.to_string())),
        }
    }
}

impl std::fmt::Display for LayerMatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            LayerMatch::Geometry => "geometry",
            LayerMatch::Position => "position",
            LayerMatch::Z => "z",
        })
    }
}

/// The rule plus its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerNumbering {
    pub rule: LayerMatch,
    /// Printer layers before the file's first (geometry, position): layer `offset + 1` is the
    /// file's first; may be negative.
    pub offset: i64,
    /// Nominal layer thickness, mm (for `z`).
    pub thickness_mm: f64,
}

impl Default for LayerNumbering {
    fn default() -> Self {
        LayerNumbering {
            rule: LayerMatch::Geometry,
            offset: 0,
            thickness_mm: 0.03,
        }
    }
}

/// What is known of one layer of the file: its z and whether it holds geometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LayerSummary {
    pub z_mm: f64,
    pub has_geometry: bool,
}

/// The match of printer layers to the positions of one file's layers.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerMap {
    numbering: LayerNumbering,
    /// Position (0-based) in the file of printer layer 1, for geometry/position (may be < 0).
    base: i64,
    /// z of each layer of the file, for `z`.
    z_mm: Vec<f64>,
}

impl LayerMap {
    pub fn new(layers: &[LayerSummary], numbering: LayerNumbering) -> LayerMap {
        let first = match numbering.rule {
            LayerMatch::Geometry => layers.iter().position(|l| l.has_geometry).unwrap_or(0),
            _ => 0,
        };
        LayerMap {
            numbering,
            base: first as i64 - numbering.offset,
            z_mm: layers.iter().map(|l| l.z_mm).collect(),
        }
    }

    pub fn of_file(file: &super::VectorFile, numbering: LayerNumbering) -> LayerMap {
        let summary: Vec<LayerSummary> = file
            .layers
            .iter()
            .map(|l| LayerSummary {
                z_mm: l.z_mm,
                has_geometry: !l.is_empty(),
            })
            .collect();
        LayerMap::new(&summary, numbering)
    }

    pub fn numbering(&self) -> LayerNumbering {
        self.numbering
    }

    /// Number of layers in the file.
    pub fn len(&self) -> usize {
        self.z_mm.len()
    }

    pub fn is_empty(&self) -> bool {
        self.z_mm.is_empty()
    }

    /// The file position of printer layer `layer` (from 1), if the file has it.
    pub fn position(&self, layer: u32) -> Option<usize> {
        if layer == 0 {
            return None;
        }
        let k = match self.numbering.rule {
            LayerMatch::Geometry | LayerMatch::Position => self.base + i64::from(layer) - 1,
            LayerMatch::Z => {
                let t = self.numbering.thickness_mm;
                let z = f64::from(layer) * t;
                let k = self.z_mm.partition_point(|&zk| zk < z);
                let best = [k.checked_sub(1), Some(k)]
                    .into_iter()
                    .flatten()
                    .filter(|&k| k < self.z_mm.len())
                    .min_by(|&a, &b| {
                        (self.z_mm[a] - z)
                            .abs()
                            .total_cmp(&(self.z_mm[b] - z).abs())
                    })?;
                return ((self.z_mm[best] - z).abs() <= 0.5 * t + 1e-9).then_some(best);
            }
        };
        usize::try_from(k).ok().filter(|&k| k < self.z_mm.len())
    }

    /// The printer layer (from 1) of file position `position`, if any printer layer maps there.
    pub fn layer(&self, position: usize) -> Option<u32> {
        let z = *self.z_mm.get(position)?;
        let n = match self.numbering.rule {
            LayerMatch::Geometry | LayerMatch::Position => position as i64 - self.base + 1,
            LayerMatch::Z => (z / self.numbering.thickness_mm).round() as i64,
        };
        let n = u32::try_from(n).ok().filter(|&n| n >= 1)?;
        (self.position(n) == Some(position)).then_some(n)
    }

    /// The printer layers this file covers, first and last, if any.
    pub fn range(&self) -> Option<(u32, u32)> {
        let first = (0..self.len()).find_map(|k| self.layer(k))?;
        let last = (0..self.len()).rev().find_map(|k| self.layer(k))?;
        Some((first, last))
    }

    /// The z of printer layer `layer` from the file, if the file has it.
    pub fn z_mm(&self, layer: u32) -> Option<f64> {
        self.position(layer).map(|k| self.z_mm[k])
    }

    /// "layers 1 to 910 (file positions 101 to 1010, matched by geometry)" for messages.
    pub fn describe(&self) -> String {
        match self.range() {
            None => format!(
                "no printer layer (matched by {}, offset {})",
                self.numbering.rule, self.numbering.offset
            ),
            Some((a, b)) => format!(
                "printer layers {a} to {b} (file positions {} to {}, matched by {}{})",
                self.position(a).unwrap_or(0),
                self.position(b).unwrap_or(0),
                self.numbering.rule,
                if self.numbering.offset != 0 {
                    format!(", offset {}", self.numbering.offset)
                } else {
                    String::new()
                }
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(empty: usize, full: usize, t: f64) -> Vec<LayerSummary> {
        (0..empty + full)
            .map(|k| LayerSummary {
                z_mm: t * k as f64,
                has_geometry: k >= empty,
            })
            .collect()
    }

    #[test]
    fn geometry_skips_leading_empty_layers() {
        // As the real Box_support file: 101 empty layers from z = 0, geometry from z = 3.03.
        let map = LayerMap::new(&file(101, 910, 0.03), LayerNumbering::default());
        assert_eq!(map.position(1), Some(101));
        assert_eq!(map.position(910), Some(1010));
        assert_eq!(map.position(911), None);
        assert_eq!(map.position(0), None);
        assert_eq!(map.layer(101), Some(1));
        assert_eq!(map.layer(100), None);
        assert_eq!(map.range(), Some((1, 910)));
        assert!((map.z_mm(1).unwrap() - 3.03).abs() < 1e-9);
    }

    #[test]
    fn offset_and_position_rules() {
        let layers = file(3, 5, 0.05);
        let shifted = LayerMap::new(
            &layers,
            LayerNumbering {
                offset: 10,
                ..LayerNumbering::default()
            },
        );
        // Layer 11 is the first with geometry; 8 to 10 are the empty layers before it.
        assert_eq!(shifted.position(11), Some(3));
        assert_eq!(shifted.position(10), Some(2));
        assert_eq!(shifted.position(8), Some(0));
        assert_eq!(shifted.position(7), None);
        assert_eq!(shifted.layer(7), Some(15));
        let position = LayerMap::new(
            &layers,
            LayerNumbering {
                rule: LayerMatch::Position,
                ..LayerNumbering::default()
            },
        );
        assert_eq!(position.position(1), Some(0));
        assert_eq!(position.range(), Some((1, 8)));
        let negative = LayerMap::new(
            &layers,
            LayerNumbering {
                rule: LayerMatch::Position,
                offset: -2,
                thickness_mm: 0.05,
            },
        );
        assert_eq!(negative.position(1), Some(2));
        assert_eq!(negative.layer(1), None);
    }

    #[test]
    fn z_rule_matches_heights_within_half_a_layer() {
        // Layers at z = 0.1, 0.2, 0.4 (0.3 missing): printer layer 3 has no vectors.
        let layers: Vec<LayerSummary> = [0.1, 0.2, 0.4]
            .iter()
            .map(|&z| LayerSummary {
                z_mm: z,
                has_geometry: true,
            })
            .collect();
        let map = LayerMap::new(
            &layers,
            LayerNumbering {
                rule: LayerMatch::Z,
                offset: 0,
                thickness_mm: 0.1,
            },
        );
        assert_eq!(map.position(1), Some(0));
        assert_eq!(map.position(2), Some(1));
        assert_eq!(map.position(3), None);
        assert_eq!(map.position(4), Some(2));
        assert_eq!(map.layer(2), Some(4));
        assert_eq!(map.position(u32::MAX), None);
    }

    #[test]
    fn huge_layer_numbers_do_not_overflow() {
        let map = LayerMap::new(&file(0, 3, 0.03), LayerNumbering::default());
        assert_eq!(map.position(u32::MAX), None);
        assert_eq!("z".parse::<LayerMatch>(), Ok(LayerMatch::Z));
        assert!("nth".parse::<LayerMatch>().is_err());
    }
}
