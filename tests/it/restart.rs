//! A restart after a `kill -9` through the binary (issue 30, "Nothing hidden from the
//! operator"): the layers the kill left processed but not inspected are inspected, the run
//! says so, and the temporary slices it left in `dicom/` are removed.

use crate::common;
use std::path::Path;
use std::time::{Duration, Instant};

/// The mock printer's script: `layers`, then (when `wait`) a long pause as between layers.
fn write_script(path: &Path, layers: std::ops::RangeInclusive<u32>, wait: bool) {
    let mut script: String = layers
        .map(|n| format!("LAYER {n} PRE\nLAYER {n} POST\n"))
        .collect();
    if wait {
        script.push_str("WAIT 120000\n");
    }
    std::fs::write(path, script).expect("script");
}

/// The layers `inspection.jsonl` holds a record of, in file order.
fn inspected_layers(dir: &Path) -> Vec<u64> {
    let text = std::fs::read_to_string(dir.join("inspection.jsonl")).unwrap_or_default();
    text.lines()
        .map(|line| {
            let record: serde_json::Value = serde_json::from_str(line).expect("a record");
            record["layer"].as_u64().expect("its layer")
        })
        .collect()
}

/// Every `.tmp` file in the build directory and its folders, recursively.
fn temporaries_anywhere(dir: &Path) -> Vec<String> {
    let mut found = Vec::new();
    for entry in std::fs::read_dir(dir).expect("a folder") {
        let entry = entry.expect("an entry");
        let path = entry.path();
        if entry.file_type().expect("its type").is_dir() {
            found.extend(temporaries_anywhere(&path));
        } else if path.to_string_lossy().ends_with(".tmp") {
            found.push(path.display().to_string());
        }
    }
    found
}

#[test]
fn a_restart_after_kill_9_inspects_every_layer_and_removes_its_temporaries() {
    use layerwise::config::TriggerConfig;
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path().join("build");
    let layers = 10;
    let mut config = common::calibrated_config(&dir, layers, layerwise::dicom::Compression::None);
    let script = tmp.path().join("printer.txt");
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.script = Some(script.clone());
    }
    let path = tmp.path().join("layerwise.toml");
    common::write_config(&config, &path);

    // The first run captures six layers, then the printer pauses and the daemon is killed.
    write_script(&script, 1..=6, true);
    let mut child = common::spawn_build(&path, std::process::Stdio::null());
    let deadline = Instant::now() + Duration::from_secs(120);
    while inspected_layers(&dir).len() < 6 {
        assert!(Instant::now() < deadline, "six layers never inspected");
        std::thread::sleep(Duration::from_millis(50));
    }
    child.kill().expect("kill -9");
    child.wait().expect("the daemon ends");
    // As when the kill comes after the slices of layers 5 and 6 but before their records, in the
    // middle of writing a slice of layer 6 (the killed daemon's own temporary file).
    let text = std::fs::read_to_string(dir.join("inspection.jsonl")).expect("records");
    let kept: String = text.lines().take(4).map(|l| format!("{l}\n")).collect();
    std::fs::write(dir.join("inspection.jsonl"), kept).expect("records cut");
    let series = std::fs::read_dir(dir.join("dicom"))
        .expect("dicom/")
        .next()
        .expect("a series folder")
        .expect("its entry")
        .path();
    let temporary = format!(".L00006.dcm.{}.3.tmp", child.id());
    std::fs::write(series.join(&temporary), b"half a slice").expect("temporary");
    assert_eq!(inspected_layers(&dir), [1, 2, 3, 4]);

    // The restart finishes the build: layers 5 and 6 are inspected before the new ones.
    write_script(&script, 7..=layers, false);
    let out = common::run_build(&path);
    let log = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        inspected_layers(&dir),
        (1..=u64::from(layers)).collect::<Vec<_>>(),
        "{log}"
    );
    assert!(
        log.contains("2 layers were processed before the stop but never inspected (layers 5 to 6)"),
        "{log}"
    );
    assert!(log.contains(&temporary), "{log}");
    assert_eq!(temporaries_anywhere(&dir), Vec::<String>::new(), "{log}");
}
