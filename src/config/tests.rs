//! Configuration parsing and validation: every refusal names the file and the key.

use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("test.toml"))
}

#[test]
fn embedded_examples_are_valid() {
    parse(DEMO_CONFIG).expect("demo.toml");
    parse(include_str!("../../config/layerwise.toml")).expect("layerwise.toml");
}

#[test]
fn unknown_key_names_file_key_and_expected() {
    let text = DEMO_CONFIG.replace("[camera]", "[camera]\nisoo = 100");
    let err = parse(&text).unwrap_err().to_string();
    assert!(err.starts_with("test.toml: line"), "{err}");
    assert!(err.contains("isoo"), "{err}");
    assert!(err.contains("expected"), "{err}");
}

#[test]
fn wrong_type_names_key() {
    let text = DEMO_CONFIG.replace("settle_ms = 0", "settle_ms = \"fast\"");
    let err = parse(&text).unwrap_err().to_string();
    assert!(
        err.contains("lights.settle_ms") || err.contains("settle_ms"),
        "{err}"
    );
    assert!(err.contains("line"), "{err}");
}

#[test]
fn pattern_without_groups_is_refused() {
    let text = r#"
[build]
name = "b"
output_dir = "/tmp/x"
[trigger]
kind = "serial"
port = "/dev/ttyUSB0"
pattern = "LAYER (\\d+)"
[camera]
kind = "mock"
"#;
    let err = parse(text).unwrap_err().to_string();
    assert!(
        err.contains("trigger.pattern") && err.contains("layer"),
        "{err}"
    );
}

#[test]
fn relay_without_commands_is_refused() {
    let text = r#"
[build]
name = "b"
output_dir = "/tmp/x"
[trigger]
kind = "mock"
[lights]
kind = "serial-relay"
port = "/dev/ttyUSB1"
commands = { front_on = "A1", front_off = "A0" }
[camera]
kind = "mock"
"#;
    let err = parse(text).unwrap_err().to_string();
    assert!(
        err.contains("lights.commands") && err.contains("side_on"),
        "{err}"
    );
}

#[test]
fn one_file_per_shot_image_quality() {
    let real = include_str!("../../config/layerwise.toml");
    for quality in ["JPEG Fine", "NEF (Raw)"] {
        let text = real.replace("\"JPEG Fine\"", &format!("\"{quality}\""));
        parse(&text).unwrap_or_else(|e| panic!("{quality}: {e}"));
    }
    for quality in ["NEF+Fine", "TIFF (RGB)"] {
        let text = real.replace("\"JPEG Fine\"", &format!("\"{quality}\""));
        let err = parse(&text).unwrap_err().to_string();
        assert!(
            err.contains("camera.settings.imagequality")
                && err.contains(quality)
                && err.contains("NEF (Raw)"),
            "{err}"
        );
    }
}

#[test]
fn grid_defaults_to_whole_plate() {
    let grid = crate::geometry::Grid::default();
    assert_eq!((grid.columns(), grid.rows()), (4400, 4400));
}

/// The demo configuration with `from` replaced by `to` (which must occur).
fn demo_with(from: &str, to: &str) -> Result<Config, ConfigError> {
    assert!(DEMO_CONFIG.contains(from), "{from}");
    parse(&DEMO_CONFIG.replacen(from, to, 1))
}

fn refused(result: Result<Config, ConfigError>, key: &str) {
    let err = result.expect_err("must be refused").to_string();
    assert!(err.contains("test.toml") && err.contains(key), "{err}");
}

#[test]
fn config_zero_backoffs_are_refused() {
    refused(
        demo_with("retry_backoff_ms = [5, 50]", "retry_backoff_ms = [0, 0]"),
        "capture.retry_backoff_ms",
    );
    let serial = DEMO_CONFIG.replacen(
        "[trigger]\nkind = \"mock\"",
        "[trigger]\nkind = \"serial\"\nport = \"/dev/ttyUSB0\"\nreopen_backoff_ms = [0, 0]",
        1,
    );
    let serial = serial.replacen("layers = 20\nfirst_layer = 1\ninterval_ms = 0\n", "", 1);
    refused(parse(&serial), "trigger.reopen_backoff_ms");
}

#[test]
fn config_huge_queue_grid_and_mock_sensor_are_refused() {
    refused(
        demo_with("queue_capacity = 16", "queue_capacity = 1000000000000"),
        "storage.queue_capacity",
    );
    refused(
        demo_with("pixel_mm = 0.25", "pixel_mm = 0.0000001"),
        "rectify",
    );
    refused(
        demo_with("width = 1472", "width = 4000000000"),
        "camera.width",
    );
}

#[test]
fn config_duplicate_views_are_refused() {
    refused(
        demo_with(
            "phases = [\"pre\", \"post\"]",
            "phases = [\"post\", \"post\"]",
        ),
        "views.phases",
    );
    refused(
        demo_with(
            "lights = [\"front\", \"side\", \"top\"]",
            "lights = [\"top\", \"side\", \"top\"]",
        ),
        "views.lights",
    );
}

#[test]
fn config_out_of_range_layers_and_thickness_are_refused() {
    refused(
        demo_with("first_layer = 1", "first_layer = 4294967295"),
        "trigger.first_layer",
    );
    refused(
        demo_with("first_layer = 1", "first_layer = 0"),
        "trigger.first_layer",
    );
    refused(
        demo_with("layer_thickness_mm = 0.03", "layer_thickness_mm = 1e308"),
        "build.layer_thickness_mm",
    );
}

#[test]
fn config_control_characters_in_the_build_name_are_refused() {
    refused(
        demo_with("name = \"demo-build\"", "name = \"demo\\u0000build\""),
        "build.name",
    );
    refused(
        demo_with("name = \"demo-build\"", "name = \"demo\\nbuild\""),
        "build.name",
    );
}

#[test]
fn a_pattern_that_does_not_compile_keeps_the_regex_error_as_its_source() {
    let text = DEMO_CONFIG.replacen(
        "[trigger]\nkind = \"mock\"",
        "[trigger]\nkind = \"serial\"\nport = \"/dev/ttyUSB0\"\npattern = \"LAYER (\"",
        1,
    );
    let text = text.replacen("layers = 20\nfirst_layer = 1\ninterval_ms = 0\n", "", 1);
    let err = parse(&text).unwrap_err();
    let ConfigError::Invalid {
        key,
        message,
        source: Some(cause),
        ..
    } = &err
    else {
        panic!("{err:?}");
    };
    assert_eq!(key, "trigger.pattern");
    assert_eq!(message, "is not a valid regular expression");
    #[allow(clippy::invalid_regex)] // the very pattern the configuration gives
    let regex = regex::Regex::new("LAYER (").unwrap_err();
    assert_eq!(cause.to_string(), regex.to_string());
    // What the binary prints: the same words as when the cause was part of the message.
    assert_eq!(
        crate::logging::chain(&err),
        format!(
            "test.toml: line 15: key `trigger.pattern`: is not a valid regular expression: {regex}"
        )
    );
}

#[test]
fn every_refusal_is_an_invalid_key_of_the_file() {
    let err = demo_with("queue_capacity = 16", "queue_capacity = 0").unwrap_err();
    let ConfigError::Invalid {
        file, key, source, ..
    } = &err
    else {
        panic!("{err:?}");
    };
    assert_eq!(
        (file.as_path(), key.as_str()),
        (Path::new("test.toml"), "storage.queue_capacity")
    );
    assert!(source.is_none());
    assert_eq!(
        err.to_string(),
        format!(
            "test.toml: line 48: key `storage.queue_capacity`: must be 1 to {MAX_QUEUE} (frames \
             wait on disk when the queue is full)"
        )
    );
    let err = demo_with("layer_thickness_mm = 0.03", "layer_thickness_mm = \"thin\"").unwrap_err();
    assert!(
        matches!(err, ConfigError::File(TomlFileError::Parse(_))),
        "{err:?}"
    );
}

#[test]
fn the_examples_round_trip_through_their_snapshot() {
    for (name, text) in [
        ("demo.toml", DEMO_CONFIG),
        (
            "layerwise.toml",
            include_str!("../../config/layerwise.toml"),
        ),
    ] {
        let config = parse(text).unwrap_or_else(|e| panic!("{name}: {e}"));
        let snapshot = toml::to_string(&config).unwrap();
        let again = parse(&snapshot).unwrap_or_else(|e| panic!("{name} snapshot: {e}"));
        assert_eq!(toml::to_string(&again).unwrap(), snapshot, "{name}");
    }
}

#[test]
fn sections_left_out_or_empty_take_the_same_defaults() {
    let minimal = "[build]\nname = \"b\"\noutput_dir = \"/tmp/x\"\n[trigger]\nkind = \"mock\"\n\
                   [camera]\nkind = \"mock\"\n";
    let empty_tables = format!(
        "{minimal}[capture]\n[views]\n[storage]\n[web]\n[series]\n[inspection]\n\
         [inspection.alarm]\n"
    );
    let left_out = parse(minimal).unwrap();
    let empty = parse(&empty_tables).unwrap();
    assert_eq!(
        toml::to_string(&left_out).unwrap(),
        toml::to_string(&empty).unwrap()
    );
    let capture = &left_out.capture;
    assert_eq!(
        (
            capture.settle_ms,
            capture.call_timeout_s,
            capture.retries,
            capture.retry_backoff_ms,
            capture.reopen_attempts
        ),
        (0, 60, 8, [100, 3000], 5)
    );
    assert_eq!(left_out.views.phases, crate::shot::Phase::ALL);
    assert_eq!(left_out.views.lights, crate::shot::Light::ALL);
    let storage = &left_out.storage;
    assert!(storage.fsync);
    assert_eq!((storage.queue_capacity, storage.min_free_gb), (64, 20.0));
    assert_eq!(storage.dicom, crate::dicom::Compression::None);
    let inspection = &left_out.inspection;
    assert!(inspection.enabled && inspection.alarm.latch);
    assert_eq!((inspection.streak_z, inspection.drift_window), (7.0, 30));
    assert_eq!(
        inspection.alarm.severity,
        inspection::AlarmSeverity::Critical
    );
}

#[test]
fn builds_dir_needs_no_output_dir_and_without_it_output_dir_is_required() {
    let line = DEMO_CONFIG
        .lines()
        .find(|l| l.starts_with("output_dir"))
        .expect("the demo names its output_dir");
    let without = DEMO_CONFIG.replacen(&format!("{line}\n"), "", 1);
    let err = parse(&without).unwrap_err().to_string();
    assert!(
        err.contains("key `build.output_dir`") && err.contains("builds_dir"),
        "{err}"
    );
    let with_builds = without.replacen("[build]\n", "[build]\nbuilds_dir = \"/srv/builds\"\n", 1);
    let config = parse(&with_builds).expect("builds_dir alone is enough");
    assert_eq!(config.build.output_dir.as_os_str(), "");
    // A configuration written back (as the daemon's snapshot) loads again.
    parse(&toml::to_string(&config).unwrap()).expect("round trip");
}
