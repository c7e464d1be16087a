//! One geometry command as the ASCII and binary parsers give it to the layer stream
//! (`stream.rs`), with where it starts in the file.

use super::{Hatches, MarkingParameter, Polyline};

/// One geometry command, coordinates already in millimetres.
pub(crate) enum Command {
    Layer(f64),
    Polyline(Polyline),
    Hatches(Hatches),
    Parameter(MarkingParameter),
}

/// Where a command starts: byte offset always, line for ASCII; `what` names the command.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Pos {
    pub(crate) offset: u64,
    pub(crate) line: u64,
    pub(crate) what: &'static str,
}
