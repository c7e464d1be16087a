//! Fuzzes the CLI reader: any input must give a file or an error, never a panic or a huge
//! allocation; and whatever reads must write as ASCII and read back with the same layers.
//! Run with `cargo fuzz run read_cli` (nightly); seed the corpus with shared/data/cli/*.cli.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(file) = layerwise::vectors::read_bytes(data, "fuzz") {
        let mut out = Vec::new();
        if layerwise::vectors::write_ascii(&file, &mut out).is_ok() {
            let back = layerwise::vectors::read_bytes(&out, "fuzz-ascii")
                .expect("what was read must read back after write_ascii");
            assert_eq!(back.layers.len(), file.layers.len());
        }
    }
});
