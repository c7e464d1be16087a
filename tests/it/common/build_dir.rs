//! Reading what a build wrote: the journal, the originals and their sidecars, JSON files.

use layerwise::build_dir::journal::{Journal, Record};
use std::collections::BTreeMap;
use std::path::Path;

/// All journal records of a build.
pub fn records(dir: &Path) -> Vec<Record> {
    let text = std::fs::read_to_string(dir.join("journal.jsonl")).expect("journal");
    text.lines()
        .map(|l| serde_json::from_str(l).expect("journal line"))
        .collect()
}

/// Frame records per file name: more than one would be a duplicate.
pub fn frame_records(dir: &Path) -> BTreeMap<String, usize> {
    let mut out = BTreeMap::new();
    for r in records(dir) {
        if let Record::Frame { file, .. } = r {
            *out.entry(file).or_insert(0) += 1;
        }
    }
    out
}

/// Original files in raw/ (not sidecars, not temporaries).
pub fn originals(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir.join("raw")) else {
        return Vec::new();
    };
    let mut out: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".jpg") || n.ends_with(".nef"))
        .map(|n| format!("raw/{n}"))
        .collect();
    out.sort();
    out
}

pub fn temporaries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir.join("raw"))
        .expect("raw dir")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// Every original's sidecar agrees with its bytes.
pub fn assert_sidecars_match(dir: &Path) {
    for file in originals(dir) {
        let data = std::fs::read(dir.join(&file)).expect("original");
        let sidecar = read_json(&dir.join(&file).with_extension("json"));
        assert_eq!(
            sidecar["sha256"],
            layerwise::fsutil::sha256_hex(&data),
            "{file}"
        );
        assert_eq!(sidecar["bytes"], data.len() as u64, "{file}");
    }
}

pub fn replay(dir: &Path) -> layerwise::build_dir::journal::Replay {
    Journal::read(&dir.join("journal.jsonl")).expect("journal replays")
}

/// Every expected original name for layers 1..=layers.
pub fn expected_originals(layers: u32) -> Vec<String> {
    let mut out = Vec::new();
    for layer in 1..=layers {
        for phase in ["pre", "post"] {
            for light in ["front", "side", "top"] {
                out.push(format!("raw/L{layer:05}_{phase}_{light}.jpg"));
            }
        }
    }
    out.sort();
    out
}

/// Waits until `dir/raw` holds at least `at_least` originals, failing after `timeout`.
pub fn wait_for_originals(dir: &Path, at_least: usize, timeout: std::time::Duration) {
    let deadline = std::time::Instant::now() + timeout;
    while originals(dir).len() < at_least {
        assert!(
            std::time::Instant::now() < deadline,
            "only {} frames after {timeout:?}: {:?}",
            originals(dir).len(),
            originals(dir)
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// A JSON file (a sidecar, a manifest, status.json) parsed.
pub fn read_json(path: &Path) -> serde_json::Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}
