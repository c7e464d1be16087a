//! What the file checks read of a source: its code without comments and literals, its tokens,
//! its `mod`, `use` and item names.

use std::collections::BTreeSet;

/// `text` with its comments and its string and character literals blanked (newlines kept, so
/// line numbers stay right): what is left is code.
pub(super) fn code_only(text: &str) -> String {
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
pub(super) fn without_tests(code: &str) -> String {
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
pub(super) enum Token {
    Ident(String),
    /// `::`
    Path,
    /// `->`
    Arrow,
    Punct(char),
}

/// The tokens of code-only text, each with its line (1-based). Numbers are skipped.
pub(super) fn tokens(code: &str) -> Vec<(usize, Token)> {
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

pub(super) fn is_ident(t: Option<&(usize, Token)>, word: &str) -> bool {
    matches!(t, Some((_, Token::Ident(w))) if w == word)
}

/// One path a file names, as written: its segments and its line.
#[derive(Debug)]
pub(super) struct Named {
    pub(super) line: usize,
    pub(super) segments: Vec<String>,
    /// The module the path is written in (a file's module, or an inline `mod` inside it).
    pub(super) scope: Vec<String>,
    pub(super) kind: NameKind,
}

#[derive(Debug, PartialEq)]
pub(super) enum NameKind {
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
pub(super) struct Parsed {
    pub(super) named: Vec<Named>,
    /// Inline or file modules declared (`mod x;`, `mod x { … }`), per scope.
    pub(super) declared: Vec<(Vec<String>, String)>,
    /// Items defined, per scope (fn, struct, enum, trait, type, const, static, union, macro).
    pub(super) defined: Vec<(Vec<String>, String)>,
    /// Every identifier of the code outside `use` declarations.
    pub(super) idents: BTreeSet<String>,
}

/// Parses one use tree starting at `toks[*i]`, appending each leaf (segments, bound name or
/// `None` for a glob) to `out`.
pub(super) fn use_tree(
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

pub(super) const ITEM_KEYWORDS: &[&str] = &[
    "fn", "struct", "enum", "trait", "type", "const", "static", "union", "mod",
];

/// The paths, declarations and definitions of one library file whose module is `module`.
pub(super) fn parse(module: &[String], text: &str) -> Parsed {
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
