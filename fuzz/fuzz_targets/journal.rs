//! The build directory's readers (issue 30), each given the same bytes as its file: the journal
//! replay (`journal.jsonl`), `layerwise status`'s report (status.json, build.json and the logs
//! with it), alarm.jsonl, inspection.jsonl, current-build.toml, a push log; and ct.toml.
#![no_main]

#[path = "scratch.rs"]
mod scratch;

#[path = "build_dir_readers.rs"]
mod build_dir_readers;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    build_dir_readers::read_all(&scratch::dir("journal"), data);
    let ct = scratch::file("journal", "ct.toml", data);
    let _ = layerwise::ct::CtRegistration::read_toml(&ct);
});
