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
