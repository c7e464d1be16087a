//! The calibration report across the plate (issue 27): `register points` prints the expected
//! error at the plate corners, the parts and between them, warns when the worst exceeds
//! `--max-error-mm`, and writes the figures into the calibration's `fit` table.

use crate::common;
use std::path::Path;

use layerwise::geometry::Homography;
use layerwise::rectify::calibration::Calibration;

/// About 0.2-0.3 mm per pixel over a 1472 x 982 frame, viewed obliquely (build_from_image).
fn truth() -> Homography {
    Homography::from_matrix([
        [0.21, 0.013, -150.0],
        [-0.004, -0.25, 120.0],
        [1.1e-5, -6.0e-5, 1.0],
    ])
}

/// Points at build `at`, each clicked up to 0.4 px off.
fn points_text(at: &[(f64, f64)]) -> String {
    let inv = truth().inverse().expect("invertible");
    let mut s = String::from("# u v x y\n");
    for (i, &(x, y)) in at.iter().enumerate() {
        let (u, v) = inv.apply(x, y).expect("in view");
        let k = i as f64;
        s += &format!(
            "{:.3} {:.3} {x} {y}\n",
            u + 0.4 * (1.7 * k).sin(),
            v + 0.4 * (2.3 * k).cos()
        );
    }
    s
}

/// A vector file with two square parts, numbered 1 and 2, on one layer.
fn two_parts(path: &Path) {
    let text = "$$HEADERSTART\n$$ASCII\n$$UNITS/1\n$$LAYERS/1\n$$HEADEREND\n$$GEOMETRYSTART\n\
                $$LAYER/0.03\n\
                $$POLYLINE/1,1,5,-40,-10,-20,-10,-20,10,-40,10,-40,-10\n\
                $$POLYLINE/2,1,5,20,-10,40,-10,40,10,20,10,20,-10\n\
                $$GEOMETRYEND\n";
    std::fs::write(path, text).expect("vectors");
}

fn register_points(dir: &Path, name: &str, at: &[(f64, f64)]) -> (String, Calibration) {
    let points = dir.join(format!("{name}.txt"));
    std::fs::write(&points, points_text(at)).expect("points");
    let out = dir.join(format!("{name}.toml"));
    let vectors = dir.join("parts.cli");
    two_parts(&vectors);
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
        .args(["register", "points", "--points"])
        .arg(&points)
        .arg("--out")
        .arg(&out)
        .arg("--vectors")
        .arg(&vectors)
        .args(["--max-error-mm", "0.5"])
        .output()
        .expect("runs");
    common::assert_success(&run);
    let stdout = String::from_utf8_lossy(&run.stdout).to_string();
    eprintln!("{name}:\n{stdout}");
    (
        stdout,
        Calibration::load(&out).expect("the calibration loads"),
    )
}

/// The error figure printed on the row that starts with `place`.
fn row_error(stdout: &str, place: &str) -> f64 {
    let line = stdout
        .lines()
        .find(|l| l.trim_start().starts_with(place))
        .unwrap_or_else(|| panic!("no row {place:?} in\n{stdout}"));
    let fields: Vec<&str> = line[line.find(place).unwrap() + place.len()..]
        .split_whitespace()
        .collect();
    fields[2].parse().unwrap_or_else(|_| panic!("{line}"))
}

#[test]
fn four_clustered_clicks_warn_about_the_corners_and_spread_ones_do_not() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Issue 27: four clicks on the parts near the middle of the plate.
    let (clustered, cal) = register_points(
        dir.path(),
        "clustered",
        &[(-40.0, -10.0), (40.0, -10.0), (40.0, 10.0), (-40.0, 10.0)],
    );
    assert!(clustered.contains("place") && clustered.contains("error mm"));
    for corner in [
        "corner -x +y",
        "corner +x +y",
        "corner -x -y",
        "corner +x -y",
    ] {
        let e = row_error(&clustered, corner);
        assert!(e > 0.5, "{corner}: {e} mm\n{clustered}");
    }
    for part in ["part 1", "part 2", "between 1 and 2"] {
        let e = row_error(&clustered, part);
        assert!(e < 0.5, "{part}: {e} mm\n{clustered}");
    }
    let warn = clustered
        .lines()
        .find(|l| l.starts_with("WARN"))
        .unwrap_or_else(|| panic!("no WARN line in\n{clustered}"));
    assert!(
        warn.contains("0.50 mm") && warn.contains("near the plate corners"),
        "{warn}"
    );
    let spread = cal
        .fit
        .as_ref()
        .and_then(|f| f.get("spread"))
        .and_then(|s| s.as_table())
        .expect("fit.spread");
    assert_eq!(spread["max_error_mm"].as_float(), Some(0.5));
    assert_eq!(spread["exceeds_limit"].as_bool(), Some(true));
    assert!(spread["worst_mm"].as_float().expect("worst") > 0.5);

    // Four clicks near the plate corners: within the limit everywhere.
    let (spread_out, cal) = register_points(
        dir.path(),
        "spread",
        &[
            (-130.0, -125.0),
            (125.0, -130.0),
            (130.0, 128.0),
            (-128.0, 130.0),
        ],
    );
    assert!(spread_out.contains("error mm"), "{spread_out}");
    assert!(!spread_out.contains("WARN"), "{spread_out}");
    for corner in [
        "corner -x +y",
        "corner +x +y",
        "corner -x -y",
        "corner +x -y",
    ] {
        let e = row_error(&spread_out, corner);
        assert!(e < 0.5, "{corner}: {e} mm\n{spread_out}");
    }
    let fit = cal.fit.expect("fit");
    assert_eq!(fit["spread"]["exceeds_limit"].as_bool(), Some(false));
}

/// The limit is the user's: the clustered clicks pass a 5 mm limit; a calibration written
/// before the report (no `spread` in `fit`) still loads.
#[test]
fn the_limit_is_the_users_and_old_calibrations_load() {
    let dir = tempfile::tempdir().expect("tempdir");
    let points = dir.path().join("p.txt");
    std::fs::write(
        &points,
        points_text(&[(-40.0, -10.0), (40.0, -10.0), (40.0, 10.0), (-40.0, 10.0)]),
    )
    .expect("points");
    let out = dir.path().join("c.toml");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
        .args(["register", "points", "--max-error-mm", "50", "--points"])
        .arg(&points)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    common::assert_success(&run);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        !stdout.contains("WARN") && stdout.contains("within the limit 50.00 mm"),
        "{stdout}"
    );
    let old = dir.path().join("old.toml");
    std::fs::write(
        &old,
        "homography = [[0.21, 0.013, -150.0], [-0.004, -0.25, 120.0], [1.1e-5, -6.0e-5, 1.0]]\n\
         [fit]\nmethod = \"points (DLT)\"\nrms_mm = 0.0\n",
    )
    .expect("old");
    Calibration::load(&old).expect("an old calibration loads");
    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
        .args(["register", "points", "--max-error-mm", "0", "--points"])
        .arg(&points)
        .arg("--out")
        .arg(&out)
        .output()
        .expect("runs");
    assert_eq!(bad.status.code(), Some(2), "{bad:?}");
}
