//! The links of README.md and docs/*.md: every relative link (and picture) names a file that
//! exists, and every `#anchor` a heading of the file it points into, as GitHub makes anchors
//! from headings. The checker is tested on planted links.

use crate::common;

/// GitHub's anchor of a heading: lower case, punctuation other than `-` and `_` dropped, spaces
/// made hyphens.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter(|c| c.is_alphanumeric() || matches!(c, ' ' | '-' | '_'))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// The anchors of a markdown text's headings (outside code blocks).
fn anchors(text: &str) -> Vec<String> {
    let mut in_block = false;
    let mut out = Vec::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
        } else if !in_block && line.starts_with('#') {
            out.push(anchor(line.trim_start_matches('#')));
        }
    }
    out
}

/// The targets of the inline links and pictures of a markdown text (outside code blocks and
/// code spans), with their line numbers.
fn links(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let (mut in_block, mut in_span) = (false, false);
    for (n, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            in_block = !in_block;
            continue;
        }
        if in_block {
            continue;
        }
        // Code spans (which may run on to the next line of a paragraph) are dropped first:
        // `[a](b)` in backticks is not a link.
        in_span &= !line.trim().is_empty();
        let mut plain = String::new();
        for c in line.chars() {
            if c == '`' {
                in_span = !in_span;
                plain.push(' ');
            } else if !in_span {
                plain.push(c);
            }
        }
        let mut rest = plain.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            out.push((n + 1, after[..end].to_string()));
            rest = &after[end..];
        }
    }
    out
}

/// The broken links of the markdown file `name` (its path from the repository's root) whose
/// text is `text`, as `NAME:LINE: TARGET: why`.
fn broken_links(name: &str, text: &str) -> Vec<String> {
    let path = common::repo_root().join(name);
    let mut broken = Vec::new();
    for (line, target) in links(text) {
        if target.contains("://") || target.starts_with("mailto:") {
            continue;
        }
        let (file, fragment) = match target.split_once('#') {
            Some((f, a)) => (f, Some(a)),
            None => (target.as_str(), None),
        };
        let linked = path.parent().unwrap().join(file);
        let why = if !file.is_empty() && !linked.exists() {
            Some("no such file".to_string())
        } else {
            fragment.and_then(|a| {
                let into = if file.is_empty() {
                    text.to_string()
                } else if file.ends_with(".md") {
                    std::fs::read_to_string(&linked).unwrap()
                } else {
                    return None;
                };
                (!anchors(&into).iter().any(|h| h == a)).then(|| "no such heading".to_string())
            })
        };
        if let Some(why) = why {
            broken.push(format!("{name}:{line}: {target}: {why}"));
        }
    }
    broken
}

#[test]
fn every_relative_link_of_the_docs_resolves() {
    let mut broken = Vec::new();
    let mut count = 0;
    for (name, text) in common::markdown_docs() {
        count += links(&text).len();
        broken.extend(broken_links(&name, &text));
    }
    assert!(count > 50, "only {count} links found");
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn the_link_checker_finds_planted_broken_links() {
    let text = "# Top\n\n## The page: API (v2)\n\
        [ok](#the-page-api-v2) [ok](frames.md#rectified-grid) ![ok](live-page.png)\n\
        [gone](no-such.md) [bad anchor](#the-page) [bad](frames.md#no-heading)\n\
        `[not a link](nowhere.md)` [web](https://example.org/x#y)\n\
        ```sh\n[in a block](nowhere.md)\n# not a heading\n```\n";
    assert_eq!(
        broken_links("docs/planted.md", text),
        [
            "docs/planted.md:5: no-such.md: no such file",
            "docs/planted.md:5: #the-page: no such heading",
            "docs/planted.md:5: frames.md#no-heading: no such heading",
        ]
    );
    assert_eq!(
        anchor(" Processing (`storage.dicom = deflate`)"),
        "processing-storagedicom--deflate"
    );
}
