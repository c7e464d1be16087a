//! Issue 30, "check-config is as strict as run": what check-config called valid and `run` then
//! failed every frame with, hung on or wrote as nonsense. Each configuration is refused by
//! check-config (naming the file and the key) and by `run` before any frame, under the memory
//! and time limits of `common::bounded`.

use crate::common::{config_refused, config_with, layerwise, refused, section};

/// The finding: check-config called these valid (a newline, NUL or backslash written into
/// PatientID; 5,000 characters cut to 64 silently). Both check-config and run refuse each.
#[test]
fn config_build_id_with_newline_nul_backslash_or_5000_characters_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let long = "x".repeat(5000);
    for (i, id) in ["part\none", "part\u{0}one", "part\\one", long.as_str()]
        .into_iter()
        .enumerate()
    {
        config_refused(dir.path(), &format!("id{i}.toml"), "build.id", |t| {
            section(t, "build").insert("id".into(), id.into());
        });
    }
}

/// A name of 100,000 characters, and a right-to-left override that reversed PatientName in a
/// viewer.
#[test]
fn config_build_name_of_100000_characters_or_with_a_right_to_left_override_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let long = "n".repeat(100_000);
    config_refused(dir.path(), "long-name.toml", "build.name", |t| {
        section(t, "build").insert("name".into(), long.into());
    });
    config_refused(dir.path(), "rlo.toml", "build.name", |t| {
        section(t, "build").insert("name".into(), "part\u{202e}gpj.exe".into());
    });
}

#[test]
fn config_mock_camera_of_16384_by_16384_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "square.toml", "camera.width", |t| {
        let camera = section(t, "camera");
        camera.insert("width".into(), 16384i64.into());
        camera.insert("height".into(), 16384i64.into());
    });
}

/// One `[[pacs]]` destination (STOW-RS at `url`) named `name`.
fn pacs_table(name: &str, url: &str) -> toml::Value {
    let mut table = toml::Table::new();
    table.insert("name".into(), name.into());
    table.insert("url".into(), url.into());
    toml::Value::Table(table)
}

/// The finding: PACS URLs that are not URLs, or hold CR/LF (run hung at start).
#[test]
fn config_pacs_url_that_is_not_a_url_or_holds_cr_lf_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let urls = [
        "archive.example/dicom-web",
        "http://127.0.0.1:9/dicom-web\r\nX-Injected: 1",
    ];
    for (i, url) in urls.into_iter().enumerate() {
        config_refused(dir.path(), &format!("url{i}.toml"), "pacs[0].url", |t| {
            t.insert("pacs".into(), vec![pacs_table("archive", url)].into());
        });
    }
}

/// The finding: 1,000 PACS destinations (run aborted at 1.35 GB).
#[test]
fn config_1000_pacs_destinations_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let destinations: Vec<toml::Value> = (0..1000)
        .map(|i| pacs_table(&format!("archive{i}"), "http://127.0.0.1:9/dicom-web"))
        .collect();
    let err = {
        let path = config_with(dir.path(), "many.toml", |t| {
            t.insert("pacs".into(), destinations.clone().into());
        });
        refused(
            layerwise().arg("check-config").arg(&path),
            &["many.toml", "pacs", "1000"],
        )
    };
    assert!(err.contains("at most 16"), "{err}");
    config_refused(dir.path(), "many-run.toml", "pacs", |t| {
        t.insert("pacs".into(), destinations.into());
    });
}

/// The finding: `storage.dicom = "jpeg-ls"` on a binary without the feature was valid, and
/// every slice then failed. Run by tests/run.sh with `--no-default-features`.
#[cfg(not(feature = "jpegls"))]
#[test]
fn config_jpeg_ls_on_a_binary_without_the_feature_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "jpegls.toml", "storage.dicom", |t| {
        section(t, "storage").insert("dicom".into(), "jpeg-ls".into());
    });
}

/// The same configuration on a binary with the feature is valid.
#[cfg(feature = "jpegls")]
#[test]
fn config_jpeg_ls_on_a_binary_with_the_feature_passes_check_config() {
    let dir = tempfile::tempdir().unwrap();
    let path = config_with(dir.path(), "jpegls.toml", |t| {
        section(t, "storage").insert("dicom".into(), "jpeg-ls".into());
    });
    let out = crate::common::bounded(layerwise().arg("check-config").arg(&path));
    assert!(out.status.success(), "{}", crate::common::report(&out));
}
