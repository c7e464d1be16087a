//! The README and docs/*.md as the tests read them: their code blocks, the scripts between
//! `<!-- tutorial NAME -->` and `<!-- /tutorial -->` markers, and the `layerwise` command lines
//! of their shell blocks, each checked against the binary by letting its clap parser read it.

use std::path::Path;
use std::time::{Duration, Instant};

/// The repository's root (where README.md is).
pub fn repo_root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// README.md and every docs/*.md, README first, then by name: each file's path from the
/// repository's root (`docs/tutorial.md`) and its text.
pub fn markdown_docs() -> Vec<(String, String)> {
    let mut names: Vec<String> = std::fs::read_dir(repo_root().join("docs"))
        .expect("docs/")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.ends_with(".md"))
        .map(|name| format!("docs/{name}"))
        .collect();
    names.sort();
    names.insert(0, "README.md".to_string());
    names
        .into_iter()
        .map(|name| {
            let text = markdown(&name);
            (name, text)
        })
        .collect()
}

/// A markdown file's text, by its path from the repository's root.
pub fn markdown(relative: &str) -> String {
    std::fs::read_to_string(repo_root().join(relative))
        .unwrap_or_else(|e| panic!("{relative}: {e}"))
}

/// One fenced code block: its info string (`sh`, `toml`, or empty), the line number (from 1) of
/// its first line of content, and that content.
#[derive(Debug)]
pub struct CodeBlock {
    pub lang: String,
    pub first_line: usize,
    pub lines: Vec<String>,
}

/// The fenced (```) code blocks of a markdown text, in order.
pub fn code_blocks(text: &str) -> Vec<CodeBlock> {
    let mut blocks = Vec::new();
    let mut open: Option<CodeBlock> = None;
    for (n, line) in text.lines().enumerate() {
        let fence = line.trim_start().strip_prefix("```");
        match (fence, open.take()) {
            (Some(_), Some(block)) => blocks.push(block),
            (Some(info), None) => {
                open = Some(CodeBlock {
                    lang: info.trim().to_string(),
                    first_line: n + 2,
                    lines: Vec::new(),
                })
            }
            (None, Some(mut block)) => {
                block.lines.push(line.to_string());
                open = Some(block);
            }
            (None, None) => {}
        }
    }
    assert!(open.is_none(), "a code block is not closed");
    blocks
}

/// The names of the runnable regions of a markdown text, one per `<!-- tutorial NAME -->`
/// marker in order (`""` for a plain `<!-- tutorial -->`). Panics on a marker that is not closed
/// by `<!-- /tutorial -->` before the next one opens.
pub fn tutorial_names(text: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut inside = false;
    for line in text.lines().map(str::trim) {
        if line == "<!-- /tutorial -->" {
            assert!(inside, "<!-- /tutorial --> without an opening marker");
            inside = false;
        } else if let Some(name) = line
            .strip_prefix("<!-- tutorial")
            .and_then(|rest| rest.strip_suffix("-->"))
        {
            assert!(
                !inside,
                "<!-- tutorial{name}--> opens inside another region"
            );
            inside = true;
            names.push(name.trim().to_string());
        }
    }
    assert!(!inside, "a <!-- tutorial --> region is not closed");
    names
}

/// The script of the runnable regions named `name` (`""`: `<!-- tutorial -->`): the lines of
/// the code blocks between each such marker and the next `<!-- /tutorial -->`, regions in order.
/// Prose between the blocks of a region is not part of it.
pub fn tutorial_script(text: &str, name: &str) -> String {
    let mut script = Vec::new();
    let (mut inside, mut in_block) = (false, false);
    for line in text.lines() {
        let marker = line.trim();
        if marker == "<!-- /tutorial -->" {
            inside = false;
        } else if let Some(found) = marker
            .strip_prefix("<!-- tutorial")
            .and_then(|rest| rest.strip_suffix("-->"))
        {
            inside = found.trim() == name;
        } else if inside && marker.starts_with("```") {
            in_block = !in_block;
        } else if inside && in_block {
            script.push(line);
        }
    }
    assert!(!script.is_empty(), "no <!-- tutorial {name} --> region");
    script.join("\n")
}

/// A `layerwise` command line of a shell block: where it is and its arguments after `layerwise`.
#[derive(Debug, PartialEq)]
pub struct DocCommand {
    pub line: usize,
    pub args: Vec<String>,
}

/// Every `layerwise …` command (and `cargo run [--release] -- …`, the same binary) in the shell
/// code blocks (`sh`, `bash`, `shell`, `console` or untagged) of a markdown text. Continuation
/// lines are joined, comments dropped, `&&`, `||`, `;` and `|` split commands, redirections are
/// left out; `sudo` (with its options), `env`, `time` and `VAR=value` before the command are
/// skipped. In `console` blocks only `$ ` lines are commands.
pub fn layerwise_commands(text: &str) -> Vec<DocCommand> {
    let mut out = Vec::new();
    for block in code_blocks(text) {
        if !matches!(
            block.lang.as_str(),
            "" | "sh" | "bash" | "shell" | "console"
        ) {
            continue;
        }
        let mut joined = String::new();
        let mut start = block.first_line;
        for (i, line) in block.lines.iter().enumerate() {
            if joined.is_empty() {
                start = block.first_line + i;
            }
            match line.strip_suffix('\\') {
                Some(head) => {
                    joined.push_str(head);
                    joined.push(' ');
                    continue;
                }
                None => joined.push_str(line),
            }
            let logical = std::mem::take(&mut joined);
            let trimmed = logical.trim_start();
            let command = match trimmed.strip_prefix("$ ") {
                Some(rest) => rest,
                None if block.lang == "console" => continue,
                None => trimmed,
            };
            for words in split_commands(command) {
                if let Some(args) = layerwise_args(&words) {
                    out.push(DocCommand { line: start, args });
                }
            }
        }
    }
    out
}

/// A shell line as words, one list per simple command: quotes removed, a comment cut off.
fn split_commands(line: &str) -> Vec<Vec<String>> {
    let mut commands = vec![Vec::new()];
    let mut word: Option<String> = None;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '\'' | '"' => {
                let w = word.get_or_insert_with(String::new);
                for q in chars.by_ref() {
                    if q == c {
                        break;
                    }
                    w.push(q);
                }
            }
            '\\' => word.get_or_insert_with(String::new).extend(chars.next()),
            '#' if word.is_none() => break,
            ' ' | '\t' => commands.last_mut().unwrap().extend(word.take()),
            ';' | '|' | '&' => {
                commands.last_mut().unwrap().extend(word.take());
                while chars.peek().is_some_and(|n| matches!(n, '|' | '&')) {
                    chars.next();
                }
                commands.push(Vec::new());
            }
            _ => word.get_or_insert_with(String::new).push(c),
        }
    }
    commands.last_mut().unwrap().extend(word);
    commands
        .into_iter()
        .map(drop_redirections)
        .filter(|c| !c.is_empty())
        .collect()
}

/// The words of a command without its redirections (`> out.txt`, `2>/dev/null`, `<in`).
fn drop_redirections(words: Vec<String>) -> Vec<String> {
    let mut out = Vec::new();
    let mut skip_next = false;
    for w in words {
        if std::mem::take(&mut skip_next) {
            continue;
        }
        let op = w.trim_start_matches(|c: char| c.is_ascii_digit());
        if op.starts_with('>') || op.starts_with('<') {
            skip_next = op.trim_start_matches(['>', '<']).is_empty();
            continue;
        }
        out.push(w);
    }
    out
}

/// The arguments after `layerwise` (or after `cargo run … --`) of a command's words, if it runs
/// the layerwise binary.
fn layerwise_args(words: &[String]) -> Option<Vec<String>> {
    let mut i = 0;
    loop {
        let w = words.get(i)?.as_str();
        if w == "sudo" {
            i += 1;
            while let Some(opt) = words.get(i).filter(|o| o.starts_with('-')) {
                i += if matches!(opt.as_str(), "-u" | "-g") {
                    2
                } else {
                    1
                };
            }
        } else if matches!(w, "env" | "time" | "exec")
            || (w.contains('=') && !w.starts_with('-') && !w.starts_with('='))
        {
            i += 1;
        } else {
            break;
        }
    }
    let program = words[i].as_str();
    if program == "layerwise" || program.ends_with("/layerwise") {
        return Some(words[i + 1..].to_vec());
    }
    if program == "cargo" && words.get(i + 1).is_some_and(|w| w == "run") {
        let rest = &words[i + 2..];
        let other = rest
            .iter()
            .take_while(|w| *w != "--")
            .any(|w| matches!(w.as_str(), "--example" | "--bin" | "-p" | "--package"));
        let dashes = rest.iter().position(|w| w == "--");
        return match (other, dashes) {
            (false, Some(at)) => Some(rest[at + 1..].to_vec()),
            (false, None) => Some(Vec::new()),
            (true, _) => None,
        };
    }
    None
}

/// Whether the binary's argument parser accepts `layerwise ARGS`: the subcommand path exists,
/// every flag belongs to it, every value parses. `--help` is put at the end (before a bare
/// `--`), so clap reads every argument before it and then prints help instead of running
/// anything; required arguments are not checked, since help comes first. Runs in an empty
/// folder, killed after 30 s; `Err` holds clap's message.
pub fn check_command(args: &[String]) -> Result<(), String> {
    let mut argv = args.to_vec();
    let at = argv.iter().position(|a| a == "--").unwrap_or(argv.len());
    argv.insert(at, "--help".to_string());
    let dir = tempfile::tempdir().unwrap();
    let mut child = super::layerwise()
        .args(&argv)
        .current_dir(dir.path())
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("layerwise starts");
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(30) {
            child.kill().ok();
            child.wait().ok();
            return Err("did not print its help within 30 s".into());
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let out = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    if out.status.success() && stdout.contains("Usage: layerwise") {
        return Ok(());
    }
    let stderr = String::from_utf8_lossy(&out.stderr);
    let message: Vec<&str> = stderr
        .lines()
        .filter(|l| !l.trim().is_empty())
        .take(3)
        .collect();
    Err(format!(
        "exit {:?}: {}",
        out.status.code(),
        message.join(" / ")
    ))
}

/// The command lines of a markdown text the binary refuses, as `NAME:LINE: layerwise ARGS:
/// clap's message`, and how many commands were checked.
pub fn refused_commands(name: &str, text: &str) -> (Vec<String>, usize) {
    let commands = layerwise_commands(text);
    let refused = commands
        .iter()
        .filter_map(|c| {
            check_command(&c.args)
                .err()
                .map(|e| format!("{name}:{}: layerwise {}: {e}", c.line, c.args.join(" ")))
        })
        .collect();
    (refused, commands.len())
}
