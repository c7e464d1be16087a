//! The page's request path: bytes a client sends on one connection, answered by
//! `layerwise::web::harness` (hyper's parser, the limits, the routes, the build's files) of a
//! small build made once per process (a journal, a frame, a link out of the build, a FIFO).
#![no_main]

#[allow(dead_code)] // `file`: this target reads no file of its own
#[path = "scratch.rs"]
mod scratch;

use layerwise::web::harness::Harness;
use libfuzzer_sys::fuzz_target;
use std::ffi::{c_char, c_int, CString};
use std::sync::OnceLock;

extern "C" {
    fn mkfifo(path: *const c_char, mode: u32) -> c_int;
}

fn page() -> &'static Harness {
    static PAGE: OnceLock<Harness> = OnceLock::new();
    PAGE.get_or_init(|| {
        let dir = scratch::dir("web_request");
        let raw = dir.join("raw");
        std::fs::create_dir_all(&raw).expect("scratch raw/");
        let _ = std::os::unix::fs::symlink("/etc/passwd", raw.join("L00001_post_side.jpg"));
        let fifo = raw
            .join("L00001_pre_top.jpg")
            .into_os_string()
            .into_encoded_bytes();
        let fifo = CString::new(fifo).expect("a path without NUL");
        // SAFETY: a NUL-terminated path; an existing FIFO (EEXIST) is fine.
        unsafe { mkfifo(fifo.as_ptr(), 0o600) };
        Harness::new(&dir, &layerwise::config::WebConfig::default())
            .expect("the page of a scratch build")
    })
}

fuzz_target!(|data: &[u8]| {
    let _ = page().answer(data);
});
