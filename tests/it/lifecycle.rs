//! The build lifecycle through the binary: `layerwise build start|stop|list` switch the running
//! daemon (`[build] builds_dir`) from build to build without editing the configuration or
//! restarting the service.

use crate::common::*;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn build(config: &Path, args: &[&str]) -> std::process::Command {
    let mut command = layerwise();
    command
        .arg("build")
        .arg(args[0])
        .arg("--config")
        .arg(config)
        .args(&args[1..]);
    command
}

/// The folder the last `build start` printed.
fn started_dir(stdout: &str) -> PathBuf {
    let line = stdout
        .lines()
        .find(|l| l.starts_with("started build"))
        .unwrap_or_else(|| panic!("{stdout}"));
    PathBuf::from(line.rsplit("records into ").next().unwrap())
}

/// Waits until the daemon's status.json in `dir` says `state`.
fn wait_for_state(dir: &Path, state: &str) -> serde_json::Value {
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let path = dir.join("status.json");
        if path.exists() {
            let status = read_json(&path);
            if status["state"] == state {
                return status;
            }
        }
        assert!(Instant::now() < deadline, "{} never {state}", dir.display());
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn operators_start_switch_and_end_builds_while_the_daemon_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let builds = tmp.path().join("builds");
    let mut config = demo_config(&tmp.path().join("unused"), 99_999);
    if let layerwise::config::TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.interval_ms = 100;
    }
    config.web.listen = String::new();
    config.build.builds_dir = Some(builds.clone());
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let vectors = tmp.path().join("part-b.cli");
    std::fs::write(
        &vectors,
        "$$HEADERSTART\n$$ASCII\n$$UNITS/1\n$$HEADEREND\n$$GEOMETRYSTART\n$$LAYER/0.03\n$$POLYLINE/1,1,4,0,0,10,0,10,10,0,0\n$$GEOMETRYEND\n",
    )
    .unwrap();

    // No build yet: the daemon waits, listing says so.
    let listed = build(&config_path, &["list"]).stdout_ok();
    let mut child = run_command(&config_path)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    assert!(listed.contains("no builds in"), "{listed}");
    std::thread::sleep(Duration::from_millis(1500));
    assert!(!std::fs::read_dir(&builds)
        .unwrap()
        .flatten()
        .any(|e| e.path().is_dir()));
    assert!(
        child.try_wait().unwrap().is_none(),
        "the idle daemon must not exit"
    );

    // Build A: the daemon records into its folder.
    let out = build(
        &config_path,
        &["start", "--name", "part A", "--layers", "500"],
    )
    .stdout_ok();
    let a = started_dir(&out);
    assert!(a.starts_with(&builds), "{out}");
    wait_for_originals(&a, 6, Duration::from_secs(60));
    let manifest = read_json(&a.join("build.json"));
    assert_eq!(manifest["name"], "part A");
    assert_eq!(manifest["layers_expected"], 500);

    // Build B (a second later, so the folders differ): A ends cleanly, B records.
    std::thread::sleep(Duration::from_millis(1100));
    let out = build(
        &config_path,
        &[
            "start",
            "--name",
            "part B",
            "--vectors",
            vectors.to_str().unwrap(),
        ],
    )
    .stdout_ok();
    assert!(out.contains("ended build \"part A\""), "{out}");
    let b = started_dir(&out);
    let status_a = wait_for_state(&a, "stopped");
    wait_for_originals(&b, 6, Duration::from_secs(60));
    let snapshot = std::fs::read_to_string(b.join("config.toml")).unwrap();
    assert!(snapshot.contains("part-b.cli"), "{snapshot}");
    // A's journal holds every frame on disk, nothing missing, and its stop says why.
    let replay_a = replay(&a);
    assert_eq!(replay_a.frames.len(), originals(&a).len());
    assert!(replay_a.missing.is_empty(), "{status_a}");
    let journal = std::fs::read_to_string(a.join("journal.jsonl")).unwrap();
    assert!(
        journal.contains("the next build was started (part B)"),
        "{journal}"
    );

    // End B: the daemon goes idle (no more frames), and says so when stopped.
    let out = build(&config_path, &["stop"]).stdout_ok();
    assert!(out.contains("ended build \"part B\""), "{out}");
    wait_for_state(&b, "stopped");
    let frames_b = originals(&b).len();
    std::thread::sleep(Duration::from_millis(1000));
    assert_eq!(originals(&b).len(), frames_b);
    assert_eq!(replay(&b).frames.len(), frames_b);
    assert!(build(&config_path, &["stop"])
        .stdout_ok()
        .contains("no build was running"));

    let list = build(&config_path, &["list", "--json"]).json_ok();
    let list = list.as_array().unwrap();
    assert_eq!(list.len(), 2, "{list:?}");
    assert_eq!(list[0]["name"], "part A");
    assert_eq!(list[1]["name"], "part B");
    assert_eq!(list[1]["frames"], frames_b);
    assert!(list
        .iter()
        .all(|b| b["current"] == false && b["state"] == "stopped"));
    // `status` with the configuration lists the builds, then reports the last one.
    let status = layerwise()
        .args(["status", "--config"])
        .arg(&config_path)
        .stdout_ok();
    let b_name = b.file_name().unwrap().to_string_lossy().into_owned();
    let a_name = a.file_name().unwrap().to_string_lossy().into_owned();
    assert!(
        status.contains("builds in") && status.contains(&a_name) && status.contains(&b_name),
        "{status}"
    );
    let json = layerwise()
        .args(["status", "--json", "--config"])
        .arg(&config_path)
        .json_ok();
    assert_eq!(json["build_dir"], b.to_str().unwrap(), "{json}");
    let text = build(&config_path, &["list"]).stdout_ok();
    assert_eq!(text.lines().count(), 2, "{text}");

    let out = terminate(child);
    assert!(out.status.success(), "{}", report(&out));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("stopped (the next build was started (part B))")
            && stdout.contains("stopped (the build was ended (layerwise build stop))")
            && stdout.ends_with("stopped (no build open)\n"),
        "{stdout}"
    );
}

#[test]
fn build_commands_need_builds_dir_and_refuse_bad_names() {
    let tmp = tempfile::tempdir().unwrap();
    let mut config = demo_config(&tmp.path().join("b"), 3);
    let config_path = tmp.path().join("layerwise.toml");
    write_config(&config, &config_path);
    let e = build(&config_path, &["start", "--name", "x"]).fails();
    assert!(e.contains("no [build] builds_dir: set it"), "{e}");

    config.build.builds_dir = Some(tmp.path().join("builds"));
    write_config(&config, &config_path);
    let e = build(&config_path, &["start", "--name", "a\nb"]).fails();
    assert!(e.contains("contains a control character"), "{e}");
    let e = build(
        &config_path,
        &["start", "--name", "x", "--vectors", "/nonexistent.cli"],
    )
    .fails();
    assert!(e.contains("--vectors /nonexistent.cli"), "{e}");
    // A damaged order file: named, with what to do.
    std::fs::create_dir_all(tmp.path().join("builds")).unwrap();
    std::fs::write(tmp.path().join("builds/current-build.toml"), "name = 3").unwrap();
    let e = build(&config_path, &["list"]).fails();
    assert!(
        e.contains("current-build.toml: not a build order") && e.contains("layerwise build start"),
        "{e}"
    );
}
