//! calibration.toml and the points file of `register images`.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(calibration) = layerwise::rectify::Calibration::parse(&text, Path::new("c.toml")) {
        // What parses must build its camera model without a panic.
        let _ = calibration.camera();
    }
    let _ = layerwise::calibrate::parse_points(&text, Path::new("points.txt"));
});
