//! Issue 30, "Files the daemon and the commands trust": every file of a build directory and every
//! file a configuration names is opened as a regular file (non-blocking: a FIFO is refused, never
//! waited on), with a cap that fits its kind (`/dev/zero` or a sparse 3 GB file is refused, never
//! read whole); a journal record's `file` is a name to check, never a path to follow; the build
//! order cannot send the daemon out of `builds_dir`. Each command is run as a user runs it, under
//! the memory and time limits of `common::bounded`.

use crate::common::{bounded, demo_config, layerwise, mkfifo, refused, report, write_config, Run};
use std::path::{Path, PathBuf};
use std::process::Command;

/// A finished demo build of 2 layers (calibrated, inspected, its series written), made by the
/// binary in `dir/name`.
fn demo_build(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(name);
    let done = layerwise()
        .args(["demo", "--layers", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(done.status.success(), "{}", report(&done));
    out
}

/// A copy of `build` at `to` (`cp -a`: the series, the journal, the originals).
fn copy_build(build: &Path, to: &Path) {
    let out = Command::new("cp")
        .arg("-a")
        .arg(build)
        .arg(to)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", report(&out));
}

/// What replaces a file of the build.
#[derive(Clone, Copy, Debug)]
enum Hostile {
    /// A FIFO nothing writes to: a blocking open or read hangs.
    Fifo,
    /// A link to `/dev/zero`: a whole read never ends.
    DevZero,
    /// A 3 GB sparse file of zeros: a whole read takes 3 GB.
    Sparse,
}

impl Hostile {
    fn plant(self, path: &Path) {
        let _ = std::fs::remove_file(path);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        match self {
            Hostile::Fifo => mkfifo(path),
            Hostile::DevZero => std::os::unix::fs::symlink("/dev/zero", path).unwrap(),
            Hostile::Sparse => std::fs::File::create(path)
                .unwrap()
                .set_len(3 << 30)
                .unwrap(),
        }
    }
}

/// The push log of `push --to PUSH_URL` (named after the URL).
const PUSH_URL: &str = "http://127.0.0.1:9/dicom-web";
const PUSH_LOG: &str = "pacs/127.0.0.1_9_dicom-web.jsonl";

/// The commands an operator runs on a build, by name, with the files each must refuse by name.
fn commands(build: &Path, scratch: &Path) -> Vec<(&'static str, Command, &'static [&'static str])> {
    let on = |args: &[&str]| {
        let mut c = layerwise();
        c.args(args).arg("--build").arg(build);
        c
    };
    let mut export = on(&["export"]);
    export.arg("--out").arg(scratch.join("export"));
    let mut push = on(&["push"]);
    push.args(["--to", PUSH_URL]);
    let mut demo = layerwise();
    demo.args(["demo", "--layers", "2", "--out"]).arg(build);
    vec![
        ("status", on(&["status"]), &["journal.jsonl"][..]),
        ("alarm show", on(&["alarm", "show"]), &["alarm.jsonl"]),
        ("alarm ack", on(&["alarm", "ack"]), &["alarm.jsonl"]),
        ("push", push, &[PUSH_LOG]),
        ("export", export, &["build.json", "raw/L00002_post_top.jpg"]),
        (
            "inspect",
            on(&["inspect"]),
            &["journal.jsonl", "raw/L00002_post_top.jpg"],
        ),
        (
            "resumed demo",
            demo,
            &[
                "journal.jsonl",
                "build.json",
                "alarm.jsonl",
                "inspection.jsonl",
            ],
        ),
    ]
}

/// The finding: the build directory's own files (journal, status.json, build.json, alarm.jsonl,
/// inspection.jsonl, push logs) and its frames as a FIFO hung `status`, `alarm show/ack`,
/// `push`, `export`, `inspect` and a resumed demo; as `/dev/zero` they aborted at 2.2 GB. Each
/// now ends (exit 0 or 1, no abort, no hang) under 2 GiB, and a command that needs the file
/// refuses it by name. (`status` reading status.json and build.json is `status`'s own report,
/// left out here.)
#[test]
fn build_directory_files_as_fifo_dev_zero_or_sparse_never_hang_or_abort_a_command() {
    let dir = tempfile::tempdir().unwrap();
    let template = demo_build(dir.path(), "template");
    let files = [
        "journal.jsonl",
        "status.json",
        "build.json",
        "alarm.jsonl",
        "inspection.jsonl",
        PUSH_LOG,
        "raw/L00002_post_top.jpg",
    ];
    for (i, file) in files.iter().enumerate() {
        for (j, hostile) in [Hostile::Fifo, Hostile::DevZero, Hostile::Sparse]
            .into_iter()
            .enumerate()
        {
            let case = dir.path().join(format!("case{i}-{j}"));
            std::fs::create_dir(&case).unwrap();
            let build = case.join("build");
            copy_build(&template, &build);
            hostile.plant(&build.join(file));
            for (name, mut command, needs) in commands(&build, &case) {
                if name == "status" && matches!(*file, "status.json" | "build.json") {
                    continue;
                }
                let out = bounded(&mut command);
                let stderr = String::from_utf8_lossy(&out.stderr);
                let what = format!("{name} with {file} as {hostile:?}");
                assert!(
                    matches!(out.status.code(), Some(0 | 1)),
                    "{what}: {}",
                    report(&out)
                );
                assert!(!stderr.contains("panicked"), "{what}: {stderr}");
                if needs.contains(file) {
                    let base = Path::new(file).file_name().unwrap().to_str().unwrap();
                    assert!(
                        stderr.contains(base),
                        "{what}: the file is not named: {stderr}"
                    );
                }
            }
        }
    }
}

/// The finding: `calibration.file` or a PACS `secret_file` = `/dev/zero` took `run` to 2 GB while
/// check-config called them valid. Both refuse it, naming the key, before any frame.
#[test]
fn calibration_file_or_secret_file_of_dev_zero_is_refused_by_check_config_and_run() {
    let dir = tempfile::tempdir().unwrap();
    for (name, edit) in [
        ("calibration.toml", "calibration"),
        ("secret.toml", "secret_file"),
    ] {
        let build = dir.path().join(format!("build-{edit}"));
        let mut config = demo_config(&build, 2);
        if edit == "calibration" {
            config.calibration.file = Some("/dev/zero".into());
        } else {
            config.pacs = vec![toml::from_str(
                "name = \"archive\"\nurl = \"http://127.0.0.1:9/dicom-web\"\nauth = \"bearer\"\n\
                 secret_file = \"/dev/zero\"\n",
            )
            .unwrap()];
        }
        let path = dir.path().join(name);
        write_config(&config, &path);
        for command in ["check-config", "run"] {
            let mut c = layerwise();
            if command == "run" {
                c.args(["run", "--config"]);
            } else {
                c.arg(command);
            }
            refused(c.arg(&path), &["/dev/zero", edit]);
        }
        assert!(
            crate::common::originals(&build).is_empty(),
            "{name}: frames were captured"
        );
    }
}

/// The finding: a FIFO named `*.tif` in a TIFF-stack folder hung `register ct`.
#[test]
fn fifo_named_tif_in_a_tiff_stack_is_refused_by_register_ct() {
    let dir = tempfile::tempdir().unwrap();
    let stack = dir.path().join("stack");
    std::fs::create_dir(&stack).unwrap();
    let slice = image::GrayImage::from_fn(16, 16, |x, y| image::Luma([(x * y) as u8]));
    slice.save(stack.join("s0000.tif")).unwrap();
    slice.save(stack.join("s0001.tif")).unwrap();
    mkfifo(&stack.join("s0002.tif"));
    let vectors = dir.path().join("part.cli");
    let mut text = Vec::new();
    layerwise::vectors::write_ascii(&layerwise::vectors::synth::generate(3, 6, 8), &mut text)
        .unwrap();
    std::fs::write(&vectors, text).unwrap();
    refused(
        layerwise()
            .args(["register", "ct", "--voxel-mm", "0.05", "--vectors"])
            .arg(&vectors)
            .arg("--ct")
            .arg(&stack)
            .arg("--out")
            .arg(dir.path().join("ct.toml")),
        &["s0002.tif", "FIFO"],
    );
}

/// The finding: a 3 GB sparse `.dcm` was read whole by `push`. It is refused by its size (and
/// logged as rejected with the reason), the other instances pushed as usual.
#[test]
fn sparse_3_gb_dcm_is_not_read_whole_by_push() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("export");
    std::fs::create_dir(&folder).unwrap();
    std::fs::File::create(folder.join("huge.dcm"))
        .unwrap()
        .set_len(3 << 30)
        .unwrap();
    let out = bounded(
        layerwise()
            .args(["push", "--to", PUSH_URL, "--build"])
            .arg(&folder),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{}", report(&out));
    assert!(
        stdout.contains("huge.dcm") && stdout.contains("larger than"),
        "{stdout}\n{stderr}"
    );
}

/// The finding: a journal record's `file` was trusted: a record naming another build's JPEG
/// (wrong SHA-256 and size) was rectified into the series. Originals are taken only from raw/ by
/// their own name, checked against their sidecar: the resumed daemon journals the record as a
/// failure and writes no slice from it; `inspect` refuses the journal; an original replaced in
/// raw/ is refused against its sidecar.
#[test]
fn journal_record_naming_another_builds_frame_is_not_trusted() {
    let dir = tempfile::tempdir().unwrap();
    let other = demo_build(dir.path(), "other");
    let build = demo_build(dir.path(), "build");
    // Layer 2 post top, unprocessed, its record pointing at the other build's frame.
    let journal = build.join("journal.jsonl");
    let text = std::fs::read_to_string(&journal).unwrap();
    let foreign = other.join("raw/L00001_post_top.jpg");
    let mut lines: Vec<String> = Vec::new();
    for line in text.lines() {
        let mut record: serde_json::Value = serde_json::from_str(line).unwrap();
        let is = |kind: &str| record["kind"] == kind;
        let shot = record["layer"] == 2 && record["phase"] == "post" && record["light"] == "top";
        if shot && is("processed") {
            continue;
        }
        if shot && is("frame") {
            record["file"] = foreign.to_str().unwrap().into();
        }
        lines.push(record.to_string());
    }
    std::fs::write(&journal, lines.join("\n") + "\n").unwrap();
    let slice = build.join("dicom/post_top/L00002.dcm");
    std::fs::remove_file(&slice).unwrap();
    refused(
        layerwise().args(["inspect", "--build"]).arg(&build),
        &["journal", "L00001_post_top.jpg", "raw/L00002_post_top."],
    );
    // The resumed daemon processes its backlog: the record is a failure, not a slice.
    let out = bounded(
        layerwise()
            .args(["demo", "--layers", "2", "--out"])
            .arg(&build),
    );
    assert!(out.status.success(), "{}", report(&out));
    assert!(
        !slice.exists(),
        "a slice was written from another build's frame"
    );
    let failed = std::fs::read_to_string(&journal)
        .unwrap()
        .lines()
        .filter(|l| l.contains("processing_failed") && l.contains("raw/L00002_post_top."))
        .count();
    assert_eq!(failed, 1, "the refusal is journaled once");
    // `status` tells the failure as one, not as a frame waiting for processing.
    let status = layerwise()
        .args(["status", "--json", "--build"])
        .arg(&build)
        .json_ok();
    assert_eq!(status["waiting_for_processing"], 0, "{status}");
    let failures = status["processing_failed"].as_array().unwrap();
    assert_eq!(failures.len(), 1, "{status}");
    let failure = failures[0].as_str().unwrap();
    assert!(failure.starts_with("L00002_post_top: "), "{failure}");
    let text = layerwise()
        .args(["status", "--build"])
        .arg(&build)
        .stdout_ok();
    assert!(text.contains("failed     1 frames' processing"), "{text}");
    // An original replaced in raw/ (its sidecar says otherwise) is refused by name.
    std::fs::copy(&foreign, build.join("raw/L00002_pre_top.jpg")).unwrap();
    refused(
        layerwise()
            .args(["export", "--build"])
            .arg(&build)
            .arg("--out")
            .arg(dir.path().join("export")),
        &["L00002_pre_top.jpg", "sidecar"],
    );
}

/// The finding: `current-build.toml` with `folder = "/"` made `run` write raw/, the journal and
/// the configuration into `/`. Such an order (and `..`, a hidden folder, a link out of
/// builds_dir) is refused: the daemon writes nothing outside builds_dir.
#[test]
fn current_build_folder_outside_builds_dir_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let builds = dir.path().join("builds");
    std::fs::create_dir(&builds).unwrap();
    let outside = dir.path().join("outside");
    std::fs::create_dir(&outside).unwrap();
    std::os::unix::fs::symlink(&outside, builds.join("link")).unwrap();
    let mut config = demo_config(&dir.path().join("unused"), 2);
    config.build.builds_dir = Some(builds.clone());
    let path = dir.path().join("config.toml");
    write_config(&config, &path);
    for folder in ["/", "..", "../outside", ".hidden", "link", "a/b"] {
        std::fs::write(
            builds.join("current-build.toml"),
            format!(
                "name = \"part\"\nfolder = \"{folder}\"\nstarted_at = \"2026-01-01T00:00:00Z\"\n"
            ),
        )
        .unwrap();
        refused(
            layerwise().args(["run", "--config"]).arg(&path),
            &["current-build.toml", "inside builds_dir"],
        );
        refused(
            layerwise().args(["build", "list", "--config"]).arg(&path),
            &["current-build.toml", "inside builds_dir"],
        );
    }
    assert_eq!(std::fs::read_dir(&outside).unwrap().count(), 0);
    assert!(!Path::new("/raw").exists() && !Path::new("/journal.jsonl").exists());
}

/// The finding: files a configuration names (the page's token, the mock printer's script, the
/// vector file) as a FIFO hung `run` and as `/dev/zero` read without end. check-config and
/// `run` refuse each by its key and its path, promptly, before any frame.
#[test]
fn token_file_script_and_vectors_as_fifo_or_dev_zero_are_refused_by_check_config_and_run() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("named.fifo");
    mkfifo(&fifo);
    let keys = ["web.token_file", "trigger.script", "build.vectors"];
    for (i, key) in keys.into_iter().enumerate() {
        for (j, path) in [fifo.as_path(), Path::new("/dev/zero")]
            .into_iter()
            .enumerate()
        {
            let build = dir.path().join(format!("build-{i}-{j}"));
            let mut config = demo_config(&build, 2);
            match key {
                "web.token_file" => config.web.token_file = Some(path.into()),
                "build.vectors" => config.build.vectors = Some(path.into()),
                _ => match &mut config.trigger {
                    layerwise::config::TriggerConfig::Mock(mock) => mock.script = Some(path.into()),
                    _ => unreachable!("the demo's trigger is the mock"),
                },
            }
            let file = dir.path().join(format!("config-{i}-{j}.toml"));
            write_config(&config, &file);
            // The configuration names the file as written (relative to its folder): the message
            // names it the same way.
            let shown = path.file_name().unwrap().to_string_lossy().into_owned();
            let started = std::time::Instant::now();
            refused(
                layerwise().arg("check-config").arg(&file),
                &[key, shown.as_str()],
            );
            refused(
                layerwise().args(["run", "--config"]).arg(&file),
                &[key, shown.as_str()],
            );
            assert!(
                started.elapsed() < std::time::Duration::from_secs(10),
                "{key} = {shown}: {:?}",
                started.elapsed()
            );
            assert!(
                crate::common::originals(&build).is_empty(),
                "{key} = {shown}: frames were captured"
            );
        }
    }
}

/// The finding, for `status`'s own report: status.json or build.json as a FIFO hung `status`,
/// as `/dev/zero` it aborted at 2.2 GB. Each is refused by name as damaged, promptly, while the
/// rest of the build (its frames) is still shown; `status` exits 1 and `--json` lists it.
#[test]
fn status_with_status_json_or_build_json_as_fifo_or_dev_zero_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let template = demo_build(dir.path(), "template");
    for (i, file) in ["status.json", "build.json"].into_iter().enumerate() {
        for (j, hostile) in [Hostile::Fifo, Hostile::DevZero, Hostile::Sparse]
            .into_iter()
            .enumerate()
        {
            let build = dir.path().join(format!("case{i}-{j}"));
            copy_build(&template, &build);
            hostile.plant(&build.join(file));
            let what = format!("status with {file} as {hostile:?}");
            let started = std::time::Instant::now();
            let out = bounded(layerwise().args(["status", "--build"]).arg(&build));
            assert!(
                started.elapsed() < std::time::Duration::from_secs(10),
                "{what}: {:?}",
                started.elapsed()
            );
            assert_eq!(out.status.code(), Some(1), "{what}: {}", report(&out));
            let shown = String::from_utf8_lossy(&out.stdout);
            let damaged = shown
                .lines()
                .find(|l| l.starts_with("DAMAGED") && l.contains(file))
                .unwrap_or_else(|| panic!("{what}: {file} is not named damaged: {shown}"));
            assert!(damaged.contains("cannot"), "{what}: {damaged}");
            assert!(shown.contains("frames     12 stored"), "{what}: {shown}");
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert!(
                stderr.contains("cannot be read") && !stderr.contains("panicked"),
                "{what}: {stderr}"
            );
            let out = bounded(
                layerwise()
                    .args(["status", "--json", "--build"])
                    .arg(&build),
            );
            assert_eq!(out.status.code(), Some(1), "{what}: {}", report(&out));
            let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            let named = json["damaged"].as_array().is_some_and(|d| {
                d.iter()
                    .any(|d| d.as_str().is_some_and(|d| d.contains(file)))
            });
            assert!(named, "{what}: {json:#}");
        }
    }
}
