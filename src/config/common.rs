//! Defaults and checks several sections share.

use super::error::Invalid;
use std::path::PathBuf;

/// Serial line speed of the trigger and the light relay when none is given.
pub(super) fn default_baud() -> u32 {
    9600
}

/// GPIO character device of the trigger and the lights when none is given.
pub(super) fn default_gpio_chip() -> PathBuf {
    PathBuf::from("/dev/gpiochip0")
}

/// A back-off `[first, max]` in ms under `key`: both positive, first ≤ max (a zero back-off
/// spins).
pub(super) fn check_backoff(key: &str, [first, max]: [u64; 2]) -> Result<(), Invalid> {
    if first == 0 || max < first {
        return Err(Invalid::new(
            key,
            format!("[{first}, {max}]: {key} needs 0 < first ≤ max, e.g. [250, 5000]"),
        ));
    }
    Ok(())
}
