//! The flags that pair printer layers with a vector file's layers (docs/frames.md).

use clap::Args;
use layerwise::vectors::{LayerMatch, LayerNumbering};

#[derive(Args, Clone, Copy, Debug)]
pub struct NumberingArgs {
    /// How printer layers pair with the vector file's layers: geometry (layer 1 is the file's
    /// first layer with geometry), position (layer n is the file's n-th layer) or z
    /// (z = n x --layer-thickness-mm).
    #[arg(long, default_value = "geometry", value_name = "RULE")]
    pub layer_match: LayerMatch,
    /// Printer layers before the vector file's first (geometry, position); may be negative.
    #[arg(
        long,
        default_value_t = 0,
        allow_hyphen_values = true,
        value_name = "N"
    )]
    pub layer_offset: i64,
    /// Nominal layer thickness for --layer-match z.
    #[arg(long = "layer-thickness-mm", default_value_t = 0.03, value_name = "MM")]
    pub thickness_mm: f64,
}

impl NumberingArgs {
    pub fn numbering(self) -> LayerNumbering {
        LayerNumbering {
            rule: self.layer_match,
            offset: self.layer_offset,
            thickness_mm: self.thickness_mm,
        }
    }
}
