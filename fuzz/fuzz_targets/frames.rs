//! Camera frames: JPEG (and NEF when built with the `nef` feature), decoded as the daemon and
//! `rectify` do, luma only and in colour.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = layerwise::rectify::decode_frame_luma(data);
    let _ = layerwise::rectify::decode_frame(data);
});
