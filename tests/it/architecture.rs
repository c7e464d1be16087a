//! The layering of docs/architecture.md, checked on the source: every `crate::…` path in a
//! library module may name only modules of lower layers, and the top-level modules form no
//! circle. The binary (src/main.rs, src/cli/) sits above everything and is not checked here.
//!
//! Inside a module too: its files form no import circle (a file's `use`s and paths, `super::`,
//! `self::` and `crate::` alike, resolved through mod.rs's re-exports to the file that defines
//! the item; unit tests left out), no file of src/ is over 800 lines, and the library returns no
//! `Result<_, String>`. Each checker is tested on small sources written here.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The layers of docs/architecture.md, bottom first. A module may use any module of a lower
/// layer, none of its own or a higher one.
const LAYERS: &[&[&str]] = &[
    &["fsutil", "clock", "shutdown", "geometry", "logging"],
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

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
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

// ---------------------------------------------------------------------------------------------
// Inside a module: no import circle between its files, no file over 800 lines, no String errors.

/// The most lines a file of src/ may have.
const MAX_LINES: usize = 800;

/// Every .rs file of src/, as (path relative to the crate, e.g. `src/rectify/warp.rs`, text).
fn library_sources() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let rel = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            (rel, std::fs::read_to_string(&f).unwrap())
        })
        .collect()
}

/// `text` with its comments and its string and character literals blanked (newlines kept, so
/// line numbers stay right): what is left is code.
fn code_only(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let blank = |out: &mut String, s: &[char]| {
        out.extend(s.iter().map(|&ch| if ch == '\n' { '\n' } else { ' ' }));
    };
    let ident = |ch: char| ch.is_alphanumeric() || ch == '_';
    let mut i = 0;
    while i < c.len() {
        let start = i;
        if c[i] == '/' && c.get(i + 1) == Some(&'/') {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if c[i] == '/' && c.get(i + 1) == Some(&'*') {
            let mut depth = 0;
            while i < c.len() {
                if c[i] == '/' && c.get(i + 1) == Some(&'*') {
                    depth += 1;
                    i += 2;
                } else if c[i] == '*' && c.get(i + 1) == Some(&'/') {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if (c[i] == 'r' || (c[i] == 'b' && c.get(i + 1) == Some(&'r')))
            && (i == 0 || !ident(c[i - 1]))
            && {
                let mut j = i + if c[i] == 'b' { 2 } else { 1 };
                while c.get(j) == Some(&'#') {
                    j += 1;
                }
                c.get(j) == Some(&'"')
            }
        {
            // A raw string: r"…", r#"…"#, br"…".
            i += if c[i] == 'b' { 2 } else { 1 };
            let mut hashes = 0;
            while c.get(i) == Some(&'#') {
                hashes += 1;
                i += 1;
            }
            i += 1;
            while i < c.len() {
                if c[i] == '"' && (1..=hashes).all(|k| c.get(i + k) == Some(&'#')) {
                    i += 1 + hashes;
                    break;
                }
                i += 1;
            }
        } else if c[i] == '"' {
            i += 1;
            while i < c.len() && c[i] != '"' {
                i += if c[i] == '\\' { 2 } else { 1 };
            }
            i += 1;
        } else if c[i] == '\'' && c.get(i + 1) == Some(&'\\') {
            // An escaped character literal: '\n', '\'', '\u{1F600}'.
            i += 3;
            while i < c.len() && c[i] != '\'' {
                i += 1;
            }
            i += 1;
        } else if c[i] == '\'' && c.get(i + 2) == Some(&'\'') {
            i += 3;
        } else {
            out.push(c[i]);
            i += 1;
            continue;
        }
        let end = i.min(c.len());
        // Keep the quotes' places as spaces too: only newlines survive.
        blank(&mut out, &c[start..end]);
        i = end;
    }
    out
}

/// `code` (from [`code_only`]) without the items under `#[cfg(test)]`: unit-test modules and
/// test-only functions and imports do not make the library's structure.
fn without_tests(code: &str) -> String {
    const ATTR: &str = "#[cfg(test)]";
    let mut out: Vec<char> = code.chars().collect();
    let text: String = out.iter().collect();
    let mut from = 0;
    while let Some(at) = text[from..].find(ATTR).map(|i| i + from) {
        // Char index of `at` (the text is mostly ASCII; count to be exact).
        let start = text[..at].chars().count();
        let mut i = start + ATTR.chars().count();
        let mut depth = 0i32;
        let mut end = out.len();
        while i < out.len() {
            match out[i] {
                '(' | '[' => depth += 1,
                ')' | ']' => depth -= 1,
                ';' if depth == 0 => {
                    end = i + 1;
                    break;
                }
                '{' if depth == 0 => {
                    let mut braces = 0;
                    while i < out.len() {
                        match out[i] {
                            '{' => braces += 1,
                            '}' => {
                                braces -= 1;
                                if braces == 0 {
                                    break;
                                }
                            }
                            _ => {}
                        }
                        i += 1;
                    }
                    end = (i + 1).min(out.len());
                    break;
                }
                _ => {}
            }
            i += 1;
        }
        for ch in &mut out[start..end] {
            if *ch != '\n' {
                *ch = ' ';
            }
        }
        from = at + ATTR.len();
    }
    out.into_iter().collect()
}

#[derive(Clone, Debug, PartialEq)]
enum Token {
    Ident(String),
    /// `::`
    Path,
    /// `->`
    Arrow,
    Punct(char),
}

/// The tokens of code-only text, each with its line (1-based). Numbers are skipped.
fn tokens(code: &str) -> Vec<(usize, Token)> {
    let c: Vec<char> = code.chars().collect();
    let mut out = Vec::new();
    let (mut i, mut line) = (0, 1);
    while i < c.len() {
        let ch = c[i];
        if ch == '\n' {
            line += 1;
            i += 1;
        } else if ch.is_whitespace() {
            i += 1;
        } else if ch.is_alphabetic() || ch == '_' {
            let start = i;
            while i < c.len() && (c[i].is_alphanumeric() || c[i] == '_') {
                i += 1;
            }
            let word: String = c[start..i].iter().collect();
            // A raw identifier: r#type.
            if word == "r" && c.get(i) == Some(&'#') {
                i += 1;
                continue;
            }
            out.push((line, Token::Ident(word)));
        } else if ch.is_ascii_digit() {
            // 1_000, 0x1f, 2.5e-3f64; not the `..` of a range.
            while i < c.len()
                && (c[i].is_alphanumeric()
                    || c[i] == '_'
                    || (c[i] == '.' && c.get(i + 1).is_some_and(|d| d.is_ascii_digit())))
            {
                i += 1;
            }
        } else if ch == ':' && c.get(i + 1) == Some(&':') {
            out.push((line, Token::Path));
            i += 2;
        } else if ch == '-' && c.get(i + 1) == Some(&'>') {
            out.push((line, Token::Arrow));
            i += 2;
        } else {
            out.push((line, Token::Punct(ch)));
            i += 1;
        }
    }
    out
}

fn is_ident(t: Option<&(usize, Token)>, word: &str) -> bool {
    matches!(t, Some((_, Token::Ident(w))) if w == word)
}

/// One path a file names, as written: its segments and its line.
#[derive(Debug)]
struct Named {
    line: usize,
    segments: Vec<String>,
    /// The module the path is written in (a file's module, or an inline `mod` inside it).
    scope: Vec<String>,
    kind: NameKind,
}

#[derive(Debug, PartialEq)]
enum NameKind {
    /// A path in code, or a private `use`: the file depends on what it names.
    Use,
    /// `pub use` (any visibility): the module re-exports it; a dependency only when the file's
    /// own code names the re-exported item too.
    Reexport { bound: String },
    /// `pub use path::*`.
    GlobReexport,
}

/// What one library file holds for the import graph.
#[derive(Debug, Default)]
struct Parsed {
    named: Vec<Named>,
    /// Inline or file modules declared (`mod x;`, `mod x { … }`), per scope.
    declared: Vec<(Vec<String>, String)>,
    /// Items defined, per scope (fn, struct, enum, trait, type, const, static, union, macro).
    defined: Vec<(Vec<String>, String)>,
    /// Every identifier of the code outside `use` declarations.
    idents: BTreeSet<String>,
}

/// Parses one use tree starting at `toks[*i]`, appending each leaf (segments, bound name or
/// `None` for a glob) to `out`.
fn use_tree(
    toks: &[(usize, Token)],
    i: &mut usize,
    prefix: Vec<String>,
    out: &mut Vec<(Vec<String>, Option<String>)>,
) {
    let mut path = prefix;
    loop {
        match toks.get(*i).map(|t| &t.1) {
            Some(Token::Ident(w)) => {
                path.push(w.clone());
                *i += 1;
                if toks.get(*i).map(|t| &t.1) == Some(&Token::Path) {
                    *i += 1;
                    continue;
                }
                let mut bound = path.last().cloned();
                if bound.as_deref() == Some("self") {
                    path.pop();
                    bound = path.last().cloned();
                }
                if is_ident(toks.get(*i), "as") {
                    if let Some((_, Token::Ident(alias))) = toks.get(*i + 1) {
                        bound = Some(alias.clone());
                    }
                    *i += 2;
                }
                out.push((path, bound));
                return;
            }
            Some(Token::Punct('*')) => {
                *i += 1;
                out.push((path, None));
                return;
            }
            Some(Token::Punct('{')) => {
                *i += 1;
                loop {
                    match toks.get(*i).map(|t| &t.1) {
                        Some(Token::Punct('}')) | None => {
                            *i += 1;
                            return;
                        }
                        Some(Token::Punct(',')) => *i += 1,
                        _ => use_tree(toks, i, path.clone(), out),
                    }
                }
            }
            Some(Token::Path) => *i += 1, // `use ::std::…`
            _ => return,
        }
    }
}

const ITEM_KEYWORDS: &[&str] = &[
    "fn", "struct", "enum", "trait", "type", "const", "static", "union", "mod",
];

/// The paths, declarations and definitions of one library file whose module is `module`.
fn parse(module: &[String], text: &str) -> Parsed {
    let code = without_tests(&code_only(text));
    let toks = tokens(&code);
    let mut parsed = Parsed::default();
    // Inline modules: (path, brace depth at which it closes).
    let mut scopes: Vec<(Vec<String>, i32)> = vec![(module.to_vec(), -1)];
    let mut depth = 0;
    let mut i = 0;
    while i < toks.len() {
        let scope = scopes.last().unwrap().0.clone();
        let (line, tok) = (&toks[i].0, &toks[i].1);
        match tok {
            Token::Punct('{') => depth += 1,
            Token::Punct('}') => {
                depth -= 1;
                if scopes.len() > 1 && scopes.last().unwrap().1 == depth {
                    scopes.pop();
                }
            }
            Token::Ident(w)
                if w == "use" && toks.get(i + 1).map(|t| &t.1) != Some(&Token::Punct('<')) =>
            {
                // Visibility: `pub use` or `pub(…) use`.
                let public = is_ident(i.checked_sub(1).and_then(|k| toks.get(k)), "pub")
                    || (toks.get(i.wrapping_sub(1)).map(|t| &t.1) == Some(&Token::Punct(')'))
                        && (2..9).any(|back| {
                            is_ident(i.checked_sub(back).and_then(|k| toks.get(k)), "pub")
                        }));
                let mut j = i + 1;
                let mut leaves = Vec::new();
                use_tree(&toks, &mut j, Vec::new(), &mut leaves);
                for (segments, bound) in leaves {
                    let kind = match (public, bound) {
                        (false, _) => NameKind::Use,
                        (true, Some(bound)) => NameKind::Reexport { bound },
                        (true, None) => NameKind::GlobReexport,
                    };
                    parsed.named.push(Named {
                        line: *line,
                        segments,
                        scope: scope.clone(),
                        kind,
                    });
                }
                while j < toks.len() && toks[j].1 != Token::Punct(';') {
                    j += 1;
                }
                i = j + 1;
                continue;
            }
            Token::Ident(w) if ITEM_KEYWORDS.contains(&w.as_str()) || w == "macro_rules" => {
                let mut k = i + 1;
                if w == "macro_rules" {
                    k += 1; // the `!`
                }
                if is_ident(toks.get(k), "fn") {
                    k += 1; // `const fn`
                }
                if let Some((_, Token::Ident(name))) = toks.get(k) {
                    if w == "mod" {
                        parsed.declared.push((scope.clone(), name.clone()));
                        if toks.get(k + 1).map(|t| &t.1) == Some(&Token::Punct('{')) {
                            let mut inner = scope.clone();
                            inner.push(name.clone());
                            scopes.push((inner, depth));
                            depth += 1;
                            i = k + 2;
                            continue;
                        }
                    } else {
                        parsed.defined.push((scope.clone(), name.clone()));
                    }
                    i = k + 1;
                    continue;
                }
            }
            Token::Ident(w) => {
                // Not a field or a method (`.name`, `name: value`): those name no item.
                let member = i > 0 && toks[i - 1].1 == Token::Punct('.');
                let field = toks.get(i + 1).map(|t| &t.1) == Some(&Token::Punct(':'));
                if !member && !field {
                    parsed.idents.insert(w.clone());
                }
                // A path: `crate::…`, `super::…`, `self::…`, or one starting with a name that
                // may be a child module (resolved later); not the tail of a longer path.
                let after_path = i > 0 && toks[i - 1].1 == Token::Path;
                if !after_path && toks.get(i + 1).map(|t| &t.1) == Some(&Token::Path) {
                    let mut segments = vec![w.clone()];
                    let mut j = i + 1;
                    while toks.get(j).map(|t| &t.1) == Some(&Token::Path) {
                        match toks.get(j + 1) {
                            Some((_, Token::Ident(next))) => {
                                segments.push(next.clone());
                                j += 2;
                            }
                            _ => break,
                        }
                    }
                    for s in &segments[1..] {
                        parsed.idents.insert(s.clone());
                    }
                    parsed.named.push(Named {
                        line: *line,
                        segments,
                        scope,
                        kind: NameKind::Use,
                    });
                    i = j;
                    continue;
                }
            }
            _ => {}
        }
        i += 1;
    }
    parsed
}

/// The module path of a library file: `src/ct/volume/raw.rs` → [ct, volume, raw],
/// `src/rectify/mod.rs` → [rectify]; `None` for lib.rs, main.rs and the binary's src/cli/.
fn module_path(file: &str) -> Option<Vec<String>> {
    let rel = file.strip_prefix("src/")?.strip_suffix(".rs")?;
    let mut parts: Vec<String> = rel.split('/').map(str::to_string).collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    let first = parts.first()?;
    (!matches!(first.as_str(), "lib" | "main" | "cli")).then_some(parts)
}

/// The import graph between the files of each top-level module.
struct FileGraph {
    files: Vec<String>,
    /// File index → (file index it uses → the line of the first use and the path as written).
    edges: Vec<BTreeMap<usize, (usize, String)>>,
}

#[derive(Default)]
struct ModuleInfo {
    file: usize,
    children: BTreeSet<String>,
    defined: BTreeSet<String>,
    reexports: BTreeMap<String, Vec<String>>,
    glob_reexports: Vec<Vec<String>>,
}

impl FileGraph {
    fn new(sources: &[(String, String)]) -> FileGraph {
        // Parse every library file; keep those declared by their parent (a `#[cfg(test)] mod
        // tests;` file is test code, as is everything below it).
        let mut candidates: Vec<(String, Vec<String>, Parsed)> = sources
            .iter()
            .filter_map(|(file, text)| {
                let module = module_path(file)?;
                let parsed = parse(&module, text);
                Some((file.clone(), module, parsed))
            })
            .collect();
        candidates.sort_by_key(|c| c.1.len());
        let mut modules: BTreeMap<Vec<String>, ModuleInfo> = BTreeMap::new();
        let mut files = Vec::new();
        let mut parsed_files = Vec::new();
        for (file, module, parsed) in candidates {
            let declared = module.len() == 1
                || modules
                    .get(&module[..module.len() - 1])
                    .is_some_and(|parent| parent.children.contains(&module[module.len() - 1]));
            if !declared {
                continue;
            }
            let index = files.len();
            files.push(file);
            modules.entry(module.clone()).or_default().file = index;
            for (scope, name) in &parsed.declared {
                modules
                    .entry(scope.clone())
                    .or_default()
                    .children
                    .insert(name.clone());
                let mut inner = scope.clone();
                inner.push(name.clone());
                // Inline modules live in this file (a file module gets its own entry later).
                modules.entry(inner).or_insert_with(|| ModuleInfo {
                    file: index,
                    ..Default::default()
                });
            }
            for (scope, name) in &parsed.defined {
                modules
                    .entry(scope.clone())
                    .or_default()
                    .defined
                    .insert(name.clone());
            }
            parsed_files.push((module, parsed));
        }
        // Re-exports, made absolute.
        for (_, parsed) in &parsed_files {
            for named in &parsed.named {
                let Some(target) = absolute(&named.segments, &named.scope, &modules) else {
                    continue;
                };
                let info = modules.entry(named.scope.clone()).or_default();
                match &named.kind {
                    NameKind::Reexport { bound } => {
                        info.reexports.insert(bound.clone(), target);
                    }
                    NameKind::GlobReexport => info.glob_reexports.push(target),
                    NameKind::Use => {}
                }
            }
        }
        let mut edges = vec![BTreeMap::new(); files.len()];
        for (index, (module, parsed)) in parsed_files.iter().enumerate() {
            for named in &parsed.named {
                let uses = match &named.kind {
                    NameKind::Use => true,
                    NameKind::Reexport { bound } => parsed.idents.contains(bound),
                    NameKind::GlobReexport => false,
                };
                if !uses {
                    continue;
                }
                let Some(target) = absolute(&named.segments, &named.scope, &modules) else {
                    continue;
                };
                let Some((to, _)) = resolve(&target, &modules, 0) else {
                    continue;
                };
                let same_module = module_path(&files[to]).is_some_and(|m| m[0] == module[0]);
                if to != index && same_module {
                    edges[index]
                        .entry(to)
                        .or_insert_with(|| (named.line, named.segments.join("::")));
                }
            }
        }
        FileGraph { files, edges }
    }

    /// The circles: every group of files that reach each other through imports (a strongly
    /// connected component of more than one file), each with the imports inside it.
    fn circles(&self) -> Vec<Vec<String>> {
        let n = self.files.len();
        // Tarjan's algorithm.
        struct State {
            index: Vec<Option<usize>>,
            low: Vec<usize>,
            on_stack: Vec<bool>,
            stack: Vec<usize>,
            next: usize,
            groups: Vec<Vec<usize>>,
        }
        fn connect(v: usize, g: &FileGraph, s: &mut State) {
            s.index[v] = Some(s.next);
            s.low[v] = s.next;
            s.next += 1;
            s.stack.push(v);
            s.on_stack[v] = true;
            for &w in g.edges[v].keys() {
                match s.index[w] {
                    None => {
                        connect(w, g, s);
                        s.low[v] = s.low[v].min(s.low[w]);
                    }
                    Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                    Some(_) => {}
                }
            }
            if Some(s.low[v]) == s.index[v] {
                let mut group = Vec::new();
                loop {
                    let w = s.stack.pop().unwrap();
                    s.on_stack[w] = false;
                    group.push(w);
                    if w == v {
                        break;
                    }
                }
                if group.len() > 1 {
                    group.sort();
                    s.groups.push(group);
                }
            }
        }
        let mut s = State {
            index: vec![None; n],
            low: vec![0; n],
            on_stack: vec![false; n],
            stack: Vec::new(),
            next: 0,
            groups: Vec::new(),
        };
        for v in 0..n {
            if s.index[v].is_none() {
                connect(v, self, &mut s);
            }
        }
        s.groups.sort();
        s.groups
            .iter()
            .map(|group| {
                let mut uses = Vec::new();
                for &a in group {
                    for (&b, (line, path)) in &self.edges[a] {
                        if group.contains(&b) {
                            uses.push((&self.files[a], *line, &self.files[b], path));
                        }
                    }
                }
                uses.sort();
                uses.into_iter()
                    .map(|(a, line, b, path)| format!("{a}:{line}: uses {b} (`{path}`)"))
                    .collect()
            })
            .collect()
    }
}

/// `segments` as written in `scope`, made absolute (`crate::…`); `None` for a path that leaves
/// the crate or names nothing of it (an extern crate, a local item, a type's associated item).
fn absolute(
    segments: &[String],
    scope: &[String],
    modules: &BTreeMap<Vec<String>, ModuleInfo>,
) -> Option<Vec<String>> {
    let first = segments.first()?;
    let mut out: Vec<String> = match first.as_str() {
        "crate" => return Some(segments[1..].to_vec()),
        "self" => scope.to_vec(),
        "super" => {
            let mut base = scope.to_vec();
            let mut k = 0;
            while segments.get(k).is_some_and(|s| s == "super") {
                base.pop()?;
                k += 1;
            }
            base.extend(segments[k..].iter().cloned());
            return Some(base);
        }
        name if modules
            .get(scope)
            .is_some_and(|m| m.children.contains(name)) =>
        {
            let mut base = scope.to_vec();
            base.push(name.to_string());
            base
        }
        _ => return None,
    };
    out.extend(segments[1..].iter().cloned());
    Some(out)
}

/// The file that defines what the absolute path names, following re-exports; `true` when it
/// is certain (defined there, or a module itself), `false` when only the module's file is known.
fn resolve(
    path: &[String],
    modules: &BTreeMap<Vec<String>, ModuleInfo>,
    depth: usize,
) -> Option<(usize, bool)> {
    if depth > 16 {
        return None;
    }
    let mut k = 0;
    while k < path.len() && modules.contains_key(&path[..=k]) {
        k += 1;
    }
    if k == 0 {
        return None;
    }
    let info = &modules[&path[..k]];
    let Some(name) = path.get(k) else {
        return Some((info.file, true));
    };
    if let Some(target) = info.reexports.get(name) {
        let mut next = target.clone();
        next.extend(path[k + 1..].iter().cloned());
        if let Some(found) = resolve(&next, modules, depth + 1) {
            return Some(found);
        }
    }
    if info.defined.contains(name) {
        return Some((info.file, true));
    }
    for glob in &info.glob_reexports {
        let mut next = glob.clone();
        next.extend(path[k..].iter().cloned());
        if let Some((file, true)) = resolve(&next, modules, depth + 1) {
            return Some((file, true));
        }
    }
    Some((info.file, false))
}

/// Files of `sources` over [`MAX_LINES`], each named with the first line over the limit.
fn long_files(sources: &[(String, String)]) -> Vec<String> {
    sources
        .iter()
        .filter(|(_, text)| text.lines().count() > MAX_LINES)
        .map(|(file, text)| {
            format!(
                "{file}:{}: {} lines, over the limit of {MAX_LINES}",
                MAX_LINES + 1,
                text.lines().count()
            )
        })
        .collect()
}

/// Every `Result<_, String>` of `sources` outside the binary (src/main.rs, src/cli/), with its
/// file and line.
fn string_errors(sources: &[(String, String)]) -> Vec<String> {
    let mut out = Vec::new();
    for (file, text) in sources {
        if file == "src/main.rs" || file.starts_with("src/cli/") {
            continue;
        }
        let toks = tokens(&code_only(text));
        for (i, (line, tok)) in toks.iter().enumerate() {
            if *tok != Token::Ident("Result".into()) {
                continue;
            }
            // `Result<…>` or `Result::<…>`.
            let mut j = i + 1;
            if toks.get(j).map(|t| &t.1) == Some(&Token::Path) {
                j += 1;
            }
            if toks.get(j).map(|t| &t.1) != Some(&Token::Punct('<')) {
                continue;
            }
            // The generic arguments, split at the top-level commas.
            let mut args: Vec<Vec<&Token>> = vec![Vec::new()];
            let mut depth = 0;
            for (_, t) in &toks[j + 1..] {
                match t {
                    Token::Punct('<' | '(' | '[') => depth += 1,
                    Token::Punct('>' | ')' | ']') if depth == 0 => break,
                    Token::Punct('>' | ')' | ']') => depth -= 1,
                    Token::Punct(',') if depth == 0 => {
                        args.push(Vec::new());
                        continue;
                    }
                    _ => {}
                }
                args.last_mut().unwrap().push(t);
            }
            let error: Vec<String> = args
                .get(1)
                .into_iter()
                .flatten()
                .map(|t| match t {
                    Token::Ident(w) => w.clone(),
                    Token::Path => "::".into(),
                    Token::Arrow => "->".into(),
                    Token::Punct(c) => c.to_string(),
                })
                .collect();
            let error = error.concat();
            if matches!(
                error.as_str(),
                "String" | "std::string::String" | "alloc::string::String"
            ) {
                let shown: String = text.lines().nth(line - 1).unwrap_or("").trim().into();
                out.push(format!("{file}:{line}: {shown}"));
            }
        }
    }
    out
}

#[test]
fn no_import_circle_between_the_files_of_a_module() {
    let circles = FileGraph::new(&library_sources()).circles();
    assert!(
        circles.is_empty(),
        "{} import circle(s) between the files of a module: each group below uses itself \
         through these imports. Move what the files share (the types, the error) into a file \
         that uses none of them, and leave mod.rs declaring and re-exporting its files:\n\n{}",
        circles.len(),
        circles
            .iter()
            .map(|c| c.join("\n"))
            .collect::<Vec<_>>()
            .join("\n\n")
    );
}

#[test]
fn no_library_file_is_over_800_lines() {
    let long = long_files(&library_sources());
    assert!(
        long.is_empty(),
        "files over {MAX_LINES} lines: split each into files by topic (a module directory \
         whose mod.rs declares and re-exports them):\n{}",
        long.join("\n")
    );
}

#[test]
fn the_library_returns_no_string_errors() {
    let found = string_errors(&library_sources());
    assert!(
        found.is_empty(),
        "`Result<_, String>` in the library: a caller cannot tell one failure from another. \
         Return the module's error type (a thiserror enum with a variant for this case); \
         only the binary (src/main.rs, src/cli/) turns errors into text:\n{}",
        found.join("\n")
    );
}

fn sources(files: &[(&str, &str)]) -> Vec<(String, String)> {
    files
        .iter()
        .map(|(f, t)| (f.to_string(), t.to_string()))
        .collect()
}

#[test]
fn the_circle_checker_catches_a_circle_through_super_crate_and_self() {
    // a → b by `super::b`, b → c by `crate::m::c`, c → a through mod.rs's re-export.
    let circle = sources(&[
        (
            "src/m/mod.rs",
            "mod a;\nmod b;\nmod c;\npub use a::A;\npub use b::B;\n",
        ),
        ("src/m/a.rs", "use super::b::B;\npub struct A(B);\n"),
        (
            "src/m/b.rs",
            "pub struct B;\nfn f() { crate::m::c::go(); }\n",
        ),
        (
            "src/m/c.rs",
            "pub fn go() { let _ = super::A(super::B); }\n",
        ),
    ]);
    let found = FileGraph::new(&circle).circles();
    assert_eq!(found.len(), 1, "{found:#?}");
    let text = found[0].join("\n");
    assert!(
        text.contains("src/m/a.rs:1: uses src/m/b.rs (`super::b::B`)"),
        "{text}"
    );
    assert!(
        text.contains("src/m/b.rs:2: uses src/m/c.rs (`crate::m::c::go`)"),
        "{text}"
    );
    // `super::A` goes through mod.rs's re-export to a.rs.
    assert!(
        text.contains("src/m/c.rs:1: uses src/m/a.rs (`super::A`)"),
        "{text}"
    );
    assert!(!text.contains("mod.rs"), "mod.rs only re-exports: {text}");
    // `self::` in mod.rs's code, and a child that uses what mod.rs defines.
    let through_self = sources(&[
        (
            "src/m/mod.rs",
            "mod a;\npub struct Grid;\nfn f() { self::a::warp(); }\n",
        ),
        (
            "src/m/a.rs",
            "pub fn warp() -> crate::m::Grid { super::Grid }\n",
        ),
    ]);
    assert_eq!(
        FileGraph::new(&through_self).circles(),
        [[
            "src/m/a.rs:1: uses src/m/mod.rs (`crate::m::Grid`)",
            "src/m/mod.rs:3: uses src/m/a.rs (`self::a::warp`)",
        ]]
    );
}

#[test]
fn the_circle_checker_counts_mod_rs_code_but_not_its_declarations_or_tests() {
    // mod.rs defining the error its children use is no circle while it only declares and
    // re-exports them; its own code calling a child makes one.
    let base = [
        (
            "src/m/a.rs",
            "use super::Error;\npub fn parse() -> Error { Error }\n",
        ),
        (
            "src/m/b.rs",
            "use crate::m::Error;\n#[cfg(test)]\nmod tests { use super::super::a::parse; }\n",
        ),
    ];
    let quiet = "mod a;\nmod b;\npub use a::parse;\n// a::parse()\npub struct Error;\n";
    let mut files = sources(&base);
    files.push(("src/m/mod.rs".into(), quiet.into()));
    assert_eq!(FileGraph::new(&files).circles(), Vec::<Vec<String>>::new());
    let calling = "mod a;\nmod b;\npub use a::parse;\npub struct Error;\nfn go() { parse(); }\n";
    let mut files = sources(&base);
    files.push(("src/m/mod.rs".into(), calling.into()));
    let found = FileGraph::new(&files).circles();
    assert_eq!(
        found,
        [[
            "src/m/a.rs:1: uses src/m/mod.rs (`super::Error`)",
            "src/m/mod.rs:3: uses src/m/a.rs (`a::parse`)",
        ]],
    );
    // Another top-level module's files are not this check's business (the layering is).
    let across = sources(&[
        ("src/m/mod.rs", "mod a;\n"),
        ("src/m/a.rs", "use crate::n::B;\n"),
        ("src/n/mod.rs", "mod b;\npub use b::B;\n"),
        (
            "src/n/b.rs",
            "pub struct B;\nfn f() { crate::m::a::g(); }\n",
        ),
    ]);
    assert!(FileGraph::new(&across).circles().is_empty());
}

#[test]
fn the_line_checker_names_the_first_line_over_the_limit() {
    let long = "fn f() {}\n".repeat(MAX_LINES + 1);
    let files = sources(&[("src/a.rs", &long), ("src/b.rs", &"\n".repeat(MAX_LINES))]);
    assert_eq!(
        long_files(&files),
        [format!(
            "src/a.rs:{}: {} lines, over the limit of {MAX_LINES}",
            MAX_LINES + 1,
            MAX_LINES + 1
        )]
    );
}

#[test]
fn the_string_error_checker_finds_result_string_and_nothing_else() {
    let library = r##"fn a() -> Result<(), String> {}
fn b() -> std::io::Result<String> {}
fn c() -> Result<String, Error> {}
// fn d() -> Result<(), String>
fn e() -> Result<Vec<Box<dyn Fn(u8) -> u8>>, std::string::String> {}
const S: &str = "Result<(), String>";
fn f() { let x = Result::<u8, String>::Ok(1); }
fn g() -> Result<(), (String, String)> {}
fn h(c: char) -> bool { c == '"' || c == '\'' || c == '{' }
fn i<'a>(s: &'a str) -> Result<&'a str, String> { Ok(r#""}"#) }
"##;
    let files = sources(&[
        ("src/m/a.rs", library),
        ("src/main.rs", "fn main() -> Result<(), String> {}\n"),
        ("src/cli/x.rs", "fn x() -> Result<(), String> {}\n"),
    ]);
    assert_eq!(
        string_errors(&files),
        [
            "src/m/a.rs:1: fn a() -> Result<(), String> {}",
            "src/m/a.rs:5: fn e() -> Result<Vec<Box<dyn Fn(u8) -> u8>>, std::string::String> {}",
            "src/m/a.rs:7: fn f() { let x = Result::<u8, String>::Ok(1); }",
            r##"src/m/a.rs:10: fn i<'a>(s: &'a str) -> Result<&'a str, String> { Ok(r#""}"#) }"##,
        ]
    );
}
