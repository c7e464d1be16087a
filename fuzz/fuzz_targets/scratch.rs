//! A scratch folder per fuzzing process, for the readers that take a path.

use std::path::PathBuf;
use std::sync::OnceLock;

/// `<tmp>/layerwise-fuzz-<pid>/<name>`, created once.
pub fn dir(name: &str) -> PathBuf {
    static ROOT: OnceLock<PathBuf> = OnceLock::new();
    let root = ROOT.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("layerwise-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("scratch folder");
        d
    });
    let d = root.join(name);
    std::fs::create_dir_all(&d).expect("scratch folder");
    d
}

/// Writes `data` to `dir(folder)/file` and returns the path.
pub fn file(folder: &str, file: &str, data: &[u8]) -> PathBuf {
    let path = dir(folder).join(file);
    std::fs::write(&path, data).expect("scratch file");
    path
}
