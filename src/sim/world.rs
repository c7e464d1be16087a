//! The simulated plate's lamps, shared by the mock lights and the mock camera.

use crate::shot::Light;
use std::collections::BTreeSet;
use std::sync::{Arc, Mutex};

/// The simulated plate's lamps: the mock lights switch them, the mock camera sees them.
#[derive(Clone, Debug, Default)]
pub struct MockWorld {
    lit: Arc<Mutex<BTreeSet<Light>>>,
}

impl MockWorld {
    pub fn new() -> MockWorld {
        MockWorld::default()
    }
    pub fn set_light(&self, light: Light, on: bool) {
        if let Ok(mut lit) = self.lit.lock() {
            if on {
                lit.insert(light);
            } else {
                lit.remove(&light);
            }
        }
    }
    pub fn all_lights_off(&self) {
        if let Ok(mut lit) = self.lit.lock() {
            lit.clear();
        }
    }
    /// The lamps on now.
    pub fn lit(&self) -> BTreeSet<Light> {
        self.lit.lock().map(|l| l.clone()).unwrap_or_default()
    }
}
