//! The journal replay (`journal.jsonl`) and ct.toml.
#![no_main]

#[path = "scratch.rs"]
mod scratch;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let journal = scratch::file("journal", "journal.jsonl", data);
    let _ = layerwise::build_dir::journal::Journal::read(&journal);
    let ct = scratch::file("journal", "ct.toml", data);
    let _ = layerwise::ct::CtRegistration::read_toml(&ct);
});
