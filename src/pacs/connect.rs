//! A connection to a destination's archive, by its kind.

use super::destination::{Destination, Target};
use super::instance::Sender;
use super::{cstore, stow};

impl Destination {
    /// A connection to the archive.
    pub fn connect(&self) -> Box<dyn Sender> {
        match &self.target {
            Target::Stow { .. } => Box::new(stow::StowClient::new(self)),
            Target::CStore { .. } => Box::new(cstore::CStoreClient::new(self)),
        }
    }
}
