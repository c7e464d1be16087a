//! The real data the tests read (shared/ beside the checkout) and what the binary says about it.

use std::path::Path;

/// Keys every `layerwise vectors info --json` summary has.
pub const VECTORS_INFO_KEYS: [&str; 12] = [
    "format",
    "units",
    "layers",
    "z_min",
    "z_max",
    "layer_thickness",
    "polylines",
    "points",
    "hatches",
    "parts",
    "declared_layers",
    "declared_dimension_mm",
];

/// The four real CLI files of shared/data/cli.
pub const REAL_CLI_FILES: [&str; 4] = [
    "s_Cylinder_ex.cli",
    "s_MiniCooper_ex.cli",
    "frustrum_ASCII.cli",
    "Box_support_solid_ascii_with_params.cli",
];

/// The folder of the real CLI files: `$LAYERWISE_SHARED_DATA` when that variable is set, else
/// `<CARGO_MANIFEST_DIR>/../shared/data/cli`.
pub fn shared_cli_dir() -> std::path::PathBuf {
    match std::env::var_os("LAYERWISE_SHARED_DATA") {
        Some(d) => std::path::PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/cli"),
    }
}

/// A real CLI file from shared/data/cli: `$LAYERWISE_SHARED_DATA/<name>` when that variable is
/// set, else `<CARGO_MANIFEST_DIR>/../shared/data/cli/<name>`. Fails when the file is missing.
pub fn shared_cli(name: &str) -> std::path::PathBuf {
    let path = shared_cli_dir().join(name);
    assert!(
        path.is_file(),
        "test data {} is missing: put shared/ beside the checkout or set LAYERWISE_SHARED_DATA",
        path.display()
    );
    path
}

/// A class folder of the real powder-bed frames, `shared/data/real/pblm/<class>` (beside
/// `$LAYERWISE_SHARED_DATA`'s cli folder when that is set); its pictures in name order. Fails
/// when the folder is missing.
pub fn shared_pblm(class: &str) -> Vec<std::path::PathBuf> {
    let dir = shared_cli_dir().join("../real/pblm").join(class);
    let mut pictures: Vec<std::path::PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| {
            panic!(
                "test data {} is missing ({e}): put shared/ beside the checkout or set LAYERWISE_SHARED_DATA",
                dir.display()
            )
        })
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "jpg"))
        .collect();
    pictures.sort();
    pictures
}
