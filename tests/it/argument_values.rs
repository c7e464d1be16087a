//! Arguments and values that wrote nonsense (issue 30): each is refused through the binary,
//! before anything is read or written, with the valid range and the right words. Usage errors
//! (an argument's value) exit 2 like every argument error; a file's bad value exits 1.

use crate::common;
use std::path::Path;

/// Runs `layerwise ARGS` bounded and checks it was refused with exit `code` and every `words`,
/// and wrote nothing in `dir` but what was there.
fn refused_with(dir: &Path, args: &[&str], code: i32, words: &[&str]) {
    let before = listing(dir);
    let mut command = common::layerwise();
    command.current_dir(dir).args(args);
    let out = common::bounded(&mut command);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(code),
        "{args:?}: {}",
        common::report(&out)
    );
    for w in words {
        assert!(stderr.contains(w), "{args:?}: no {w:?} in: {stderr}");
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(listing(dir), before, "{args:?} wrote something");
}

/// `register images` with dummy files (never read: the refusal comes first), `--init init`.
fn register_images<'a>(init: &'a str, more: &[&'a str]) -> Vec<&'a str> {
    let args = [
        "register",
        "images",
        "--vectors",
        "v.cli",
        "--layer",
        "1",
        "--image",
        "f.jpg",
        "--out",
        "c.toml",
        "--init",
        init,
    ];
    [&args[..], more].concat()
}

fn listing(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// [`refused_with`] once per value, as a usage error (exit 2), the arguments made by `args`.
fn each_refused<'a>(values: &[&'a str], args: impl Fn(&'a str) -> Vec<&'a str>, words: &[&str]) {
    let tmp = tempfile::tempdir().expect("tmp");
    // A CT named is never opened: a FIFO would hang a reader.
    common::mkfifo(&tmp.path().join("ct.raw"));
    for value in values {
        refused_with(tmp.path(), &args(value), 2, words);
    }
}

const RECTIFY: [&str; 7] = [
    "rectify",
    "--calibration",
    "c.toml",
    "--image",
    "f.jpg",
    "--out",
    "o.dcm",
];
const THICKNESS: [&str; 2] = ["--layer-thickness-mm", "more than 0 and at most 10 mm"];

#[test]
fn rectify_refuses_a_layer_no_printer_counts_and_a_thickness_that_is_not_one() {
    let with = |flag| move |v| [&RECTIFY[..], &[flag, v]].concat();
    each_refused(
        &["0", "4294967295"],
        with("--layer"),
        &["--layer", "layers are 1 to 99999"],
    );
    each_refused(
        &["nan", "1e308", "0"],
        with("--layer-thickness-mm"),
        &THICKNESS,
    );
}

#[test]
fn register_images_refuses_pyramid_levels_outside_1_to_12() {
    let levels = |v| register_images("p.txt", &["--levels", v]);
    each_refused(&["0", "64"], levels, &["--levels", "give 1 to 12"]);
}

#[test]
fn build_start_refuses_a_layer_count_outside_1_to_99999() {
    let layers = |v| vec!["build", "start", "--name", "b", "--layers", v];
    each_refused(
        &["0", "100000"],
        layers,
        &["--layers", "a build has 1 to 99999 layers"],
    );
}

#[test]
fn locate_refuses_a_point_that_is_not_a_finite_coordinate() {
    let point = |v| vec!["locate", "--build", "b", "--point", v];
    let words = [
        "--point",
        "a coordinate is a finite number, -1000000 to 1000000 mm",
    ];
    each_refused(&["nan,0,0", "0,1e308,0"], point, &words);
}

#[test]
fn export_refuses_a_negative_or_nan_margin() {
    let margin = |v| {
        vec![
            "export",
            "--build",
            "b",
            "--out",
            "o",
            "--part",
            "1",
            "--margin-mm",
            v,
        ]
    };
    each_refused(
        &["-5", "nan"],
        margin,
        &["--margin-mm", "a margin is 0 to 1000 mm"],
    );
}

#[test]
fn flaws_refuses_a_bad_layer_thickness_and_patch_size_before_reading_the_ct() {
    let flaws = |flag| {
        move |v| {
            vec![
                "flaws", "--ct", "ct.raw", "--out", "o", "--build", "b", flag, v,
            ]
        }
    };
    each_refused(&["0", "nan"], flaws("--layer-thickness-mm"), &THICKNESS);
    let words = ["--patch-px", "odd number of pixels up to 4095"];
    each_refused(&["0", "64"], flaws("--patch-px"), &words);
}

#[test]
fn demo_refuses_an_injection_count_that_would_exhaust_memory() {
    let tmp = tempfile::tempdir().expect("tmp");
    refused_with(
        tmp.path(),
        &["demo", "--out", "d", "--inject", "spatter@1/n=4294967295"],
        1,
        &["n = 4294967295 is out of range (1 to 1000)"],
    );
}

#[test]
fn point_files_refuse_huge_and_nan_coordinates_with_the_right_words() {
    let tmp = tempfile::tempdir().expect("tmp");
    std::fs::write(
        tmp.path().join("image.txt"),
        "0 0 0 0\n100 0 10 0\n1e308 100 10 10\n0 100 0 10\n",
    )
    .expect("points");
    refused_with(
        tmp.path(),
        &register_images("image.txt", &[]),
        1,
        &["image.txt", "line 3: u = 1e308 is out of range"],
    );
    std::fs::write(
        tmp.path().join("ct.txt"),
        "0 0 0 0 0 0\n10 0 0 10 0 0\nnan 10 0 0 10 0\n",
    )
    .expect("points");
    common::mkfifo(&tmp.path().join("ct.raw"));
    let stderr_words = ["ct.txt", "NaN is not a coordinate"];
    refused_with(
        tmp.path(),
        &[
            "register",
            "ct",
            "--vectors",
            "v.cli",
            "--ct",
            "ct.raw",
            "--init",
            "ct.txt",
            "--out",
            "ct.toml",
        ],
        1,
        &stderr_words,
    );
}
