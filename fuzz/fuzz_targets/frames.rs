//! Camera frames: JPEG and NEF, decoded as the daemon and `rectify` do, luma only and in colour.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // libfuzzer-sys aborts on any panic, even one caught: the NEF decoder (rawler) panics on
    // some damaged files and `rectify::raw` catches that and returns an error, so the default
    // hook is put back (it prints). A panic that escapes the library still aborts the run.
    static DEFAULT_HOOK: std::sync::Once = std::sync::Once::new();
    DEFAULT_HOOK.call_once(|| drop(std::panic::take_hook()));
    let _ = layerwise::rectify::decode_frame_luma(data);
    let _ = layerwise::rectify::decode_frame(data);
});
