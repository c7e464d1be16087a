//! The sRGB transfer curve, for the pictures of linear (raw) frames (`frame.rs`, `raw.rs`).

/// The sRGB transfer curve: linear 0..1 to encoded 0..1.
pub(crate) fn srgb_encode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
