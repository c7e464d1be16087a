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
