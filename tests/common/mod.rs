//! Shared helpers for the integration tests: configurations derived from the embedded demo.
#![allow(dead_code)]

use layerwise::acquisition::journal::{Journal, Record};
use layerwise::config::{CameraConfig, Config, MockFaultConfig, TriggerConfig, DEMO_CONFIG};
use std::collections::BTreeMap;
use std::path::Path;

/// The demo configuration writing into `dir`, `layers` layers, a small sensor for speed.
pub fn demo_config(dir: &Path, layers: u32) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml"))
        .expect("the embedded demo config is valid");
    config.build.output_dir = dir.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = 320;
        mock.height = 214;
    }
    config
}

pub fn add_fault(
    config: &mut Config,
    fault: &str,
    layer: u32,
    phase: &str,
    light: &str,
    times: u32,
    millis: u64,
) {
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.faults.push(MockFaultConfig {
            layer,
            phase: phase.parse().expect("phase"),
            light: light.parse().expect("light"),
            fault: fault.to_string(),
            times,
            millis,
        });
    }
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

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
        .filter(|n| n.ends_with(".jpg"))
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
        let sidecar_path = dir.join(file.replace(".jpg", ".json"));
        let sidecar: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&sidecar_path).expect("sidecar"))
                .expect("sidecar json");
        assert_eq!(
            sidecar["sha256"],
            layerwise::acquisition::storage::sha256_hex(&data),
            "{file}"
        );
        assert_eq!(sidecar["bytes"], data.len() as u64, "{file}");
    }
}

pub fn replay(dir: &Path) -> layerwise::acquisition::journal::Replay {
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

/// Writes a configuration as TOML for the binary.
pub fn write_config(config: &Config, path: &Path) {
    let text = toml::to_string(config).expect("config serialises");
    std::fs::write(path, text).expect("config written");
}

pub fn layerwise() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
}

/// The four real CLI files of shared/data/cli.
pub const REAL_CLI_FILES: [&str; 4] = [
    "s_Cylinder_ex.cli",
    "s_MiniCooper_ex.cli",
    "frustrum_ASCII.cli",
    "Box_support_solid_ascii_with_params.cli",
];

/// A real CLI file from shared/data/cli: `$LAYERWISE_SHARED_DATA/<name>` when that variable is
/// set, else `<CARGO_MANIFEST_DIR>/../shared/data/cli/<name>`. Fails when the file is missing.
pub fn shared_cli(name: &str) -> std::path::PathBuf {
    let dir = match std::env::var_os("LAYERWISE_SHARED_DATA") {
        Some(d) => std::path::PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/cli"),
    };
    let path = dir.join(name);
    assert!(
        path.is_file(),
        "test data {} is missing: put shared/ beside the checkout or set LAYERWISE_SHARED_DATA",
        path.display()
    );
    path
}
