//! Checks that run after the classical ones, in turn, on the same layer: a trained model joins
//! here ([`Inspector::add_check`](super::Inspector::add_check)). Each sees the layer's views
//! reduced to cells, the powder bed and what was found before it, and returns findings of its
//! own; they are grouped and tracked across layers with the rest.

use super::cells::Cells;
use super::mask::Mask;
use super::stats::Found;
use crate::geometry::Grid;
use crate::shot::View;
use std::collections::BTreeMap;

/// What a check sees of one layer.
pub struct LayerInput<'a> {
    pub layer: u32,
    /// The inspection grid the cells are on.
    pub grid: &'a Grid,
    pub views: &'a BTreeMap<View, Cells>,
    /// The powder bed of the pre-scan view (when it was inspected).
    pub bed: Option<&'a Mask>,
    /// The findings of the checks before this one, by view.
    pub found: &'a [(View, Found)],
}

/// One more check of a layer.
pub trait Check: Send {
    /// Its name, for the log.
    fn name(&self) -> &str;
    /// The findings on this layer, each with the view it was seen in.
    fn check(&mut self, input: &LayerInput<'_>) -> Vec<(View, Found)>;
}
