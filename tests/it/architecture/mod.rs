//! The layering of docs/architecture.md, checked on the source: every `crate::…` path in a
//! library module may name only modules of lower layers, and the top-level modules form no
//! circle. The binary (src/main.rs, src/cli/) sits above everything and is not checked here.
//!
//! Inside a module too: its files form no import circle (a file's `use`s and paths, `super::`,
//! `self::` and `crate::` alike, resolved through mod.rs's re-exports to the file that defines
//! the item; unit tests left out), no file of src/ (nor of the tests, benches, examples, mock
//! camera and fuzz targets) is over 800 lines, and the library returns no
//! `Result<_, String>`. Each checker is tested on small sources written here.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

mod files;
mod lexer;

/// The layers of docs/architecture.md, bottom first. A module may use any module of a lower
/// layer, none of its own or a higher one.
const LAYERS: &[&[&str]] = &[
    &[
        "alloc", "fsutil", "clock", "shutdown", "geometry", "logging",
    ],
    &["shot", "vectors", "dicom", "optics"],
    &["build_dir", "config", "raster"],
    &["rectify", "tsdf"],
    &["calibrate", "ct", "series"],
    &[
        "export", "flaws", "learn", "locate", "hardware", "inspect", "pacs", "plant",
    ],
    &["acquisition", "web"],
    &["sim"],
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|layer| layer.contains(&module))
}

pub(super) fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The top-level module a library file belongs to (`src/ct/volume/raw.rs` → `ct`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel
        .components()
        .next()?
        .as_os_str()
        .to_string_lossy()
        .into_owned();
    let name = first.strip_suffix(".rs").unwrap_or(&first).to_string();
    (!matches!(name.as_str(), "main" | "cli" | "lib")).then_some(name)
}

/// Every top-level module named by a `crate::NAME` path in `text`, with its line number; also
/// the names inside `use crate::{a, b::c}` groups. Comment lines are skipped.
fn crate_references(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        let mut rest = code;
        while let Some(i) = rest.find("crate::") {
            let after = &rest[i + "crate::".len()..];
            if let Some(group) = after.strip_prefix('{') {
                let end = group.find('}').unwrap_or(group.len());
                for item in group[..end].split(',') {
                    let name: String = item
                        .trim()
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if !name.is_empty() {
                        out.push((n + 1, name));
                    }
                }
            } else {
                let name: String = after
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    out.push((n + 1, name));
                }
            }
            rest = after;
        }
    }
    out
}

/// Module → the modules it names, with one place each.
fn dependencies() -> BTreeMap<String, BTreeMap<String, String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let mut deps: BTreeMap<String, BTreeMap<String, String>> = BTreeMap::new();
    for file in files {
        let Some(module) = module_of(&src, &file) else {
            continue;
        };
        let text = std::fs::read_to_string(&file).unwrap();
        let entry = deps.entry(module.clone()).or_default();
        for (line, used) in crate_references(&text) {
            if used != module {
                entry
                    .entry(used)
                    .or_insert_with(|| format!("{}:{line}", file.display()));
            }
        }
    }
    deps
}

#[test]
fn every_library_module_is_in_a_layer() {
    let unknown: Vec<String> = dependencies()
        .keys()
        .filter(|m| layer_of(m).is_none())
        .cloned()
        .collect();
    assert!(
        unknown.is_empty(),
        "modules missing from docs/architecture.md and LAYERS: {unknown:?}"
    );
}

#[test]
fn imports_only_go_down_the_layers() {
    let mut broken = Vec::new();
    for (module, used) in dependencies() {
        let Some(own) = layer_of(&module) else {
            continue;
        };
        for (target, place) in used {
            match layer_of(&target) {
                Some(layer) if layer < own => {}
                Some(layer) => broken.push(format!(
                    "{place}: {module} (layer {own}) uses {target} (layer {layer})"
                )),
                None => broken.push(format!("{place}: {module} uses unknown module {target}")),
            }
        }
    }
    assert!(
        broken.is_empty(),
        "imports that break the layering of docs/architecture.md:\n{}",
        broken.join("\n")
    );
}

#[test]
fn top_level_modules_form_no_circle() {
    let deps = dependencies();
    // Depth-first search for a back edge.
    fn visit(
        node: &str,
        deps: &BTreeMap<String, BTreeMap<String, String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut circle = path[i..].to_vec();
            circle.push(node.to_string());
            return Some(circle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in deps.get(node).into_iter().flat_map(|d| d.keys()) {
            if let Some(circle) = visit(next, deps, path, done) {
                return Some(circle);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    for module in deps.keys() {
        let circle = visit(module, &deps, &mut Vec::new(), &mut done);
        assert!(
            circle.is_none(),
            "import circle: {}",
            circle.unwrap().join(" -> ")
        );
    }
}

#[test]
fn the_checker_sees_grouped_and_inline_paths() {
    let refs = crate_references(
        "use crate::{geometry::Grid, shot};\n// crate::sim\nlet x = crate::dicom::new_uid();",
    );
    let names: Vec<&str> = refs.iter().map(|(_, n)| n.as_str()).collect();
    assert_eq!(names, ["geometry", "shot", "dicom"]);
}
