//! Inside a module: no import circle between its files, no file over 800 lines, no String
//! errors.

use super::lexer::*;
use super::rust_files;
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The most lines a source file may have.
const MAX_LINES: usize = 800;

/// Every .rs file of src/, as (path relative to the crate, e.g. `src/rectify/warp.rs`, text).
fn library_sources() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("src"), &mut files);
    read_sorted(root, files)
}

/// `files` in path order, as (path relative to `root`, text).
fn read_sorted(root: &Path, mut files: Vec<std::path::PathBuf>) -> Vec<(String, String)> {
    files.sort();
    files
        .into_iter()
        .map(|f| {
            let rel = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            (rel, std::fs::read_to_string(&f).unwrap())
        })
        .collect()
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

/// Every .rs file of the repository outside src/ (tests, benches, examples, the mock camera,
/// the fuzz targets), as [`library_sources`] gives them; build output and hidden folders left out.
fn other_sources() -> Vec<(String, String)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    for dir in ["tests", "benches", "examples", "mock_camera", "fuzz"] {
        let dir = root.join(dir);
        if dir.is_dir() {
            rust_files(&dir, &mut files);
        }
    }
    files.retain(|f| {
        !f.strip_prefix(root).unwrap().components().any(|c| {
            let c = c.as_os_str().to_string_lossy();
            c == "target" || c.starts_with('.')
        })
    });
    read_sorted(root, files)
}

#[test]
fn no_test_bench_or_example_file_is_over_800_lines() {
    let sources = other_sources();
    assert!(
        sources.iter().any(|(f, _)| f.starts_with("tests/it/")),
        "the integration tests were not found"
    );
    let long = long_files(&sources);
    assert!(
        long.is_empty(),
        "files over {MAX_LINES} lines: split each at a natural cut (a test module directory \
         whose mod.rs holds what its files share):\n{}",
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
