//! Every `layerwise` command line in the code blocks of README.md and docs/*.md, checked against
//! the binary: the subcommand path exists, every flag is one of that subcommand's, every value
//! parses (`common::check_command`: clap reads the line, then prints help instead of running it).
//! The blocks the tests run as written are in tutorial.rs; these are the rest, from the
//! operator's and the engineer's guides and the reference, which cannot all run here (a service,
//! a camera, an archive). The checker is tested on planted lines.

use crate::common::{self, DocCommand};

#[test]
fn every_layerwise_command_in_the_docs_parses() {
    let mut refused = Vec::new();
    let mut checked = Vec::new();
    for (name, text) in common::markdown_docs() {
        let (bad, count) = common::refused_commands(&name, &text);
        refused.extend(bad);
        checked.push((name, count));
    }
    assert!(
        refused.is_empty(),
        "refused by the binary:\n{}",
        refused.join("\n")
    );
    // The extractor must keep finding the commands: the README's tour and the guides have many.
    let count = |file: &str| checked.iter().find(|(n, _)| n == file).map_or(0, |c| c.1);
    for (file, at_least) in [
        ("README.md", 12),
        ("docs/operator-guide.md", 12),
        ("docs/tutorial.md", 15),
    ] {
        assert!(count(file) >= at_least, "{file}: {checked:?}");
    }
}

const PLANTED: &str = r#"# Planted

```sh
layerwise status --build demo-build --json   # fine
layerwise demo --layers 3 \
  --out x --no-such-flag
cargo run --release -- dicom info demo-build/dicom && layerwise alarm ack --build b --bye ana
layerwise dicom inventory demo-build/dicom
layerwise demo --layers N
# layerwise status --bogus: a comment, not a command
ls raw | layerwise vectors info demo-vectors.cli --json > info.json
sudo -u layerwise layerwise build list --config '/etc/layerwise/layerwise.toml'
cargo run --release --example inspect_real
```

```toml
token_file = "/etc/layerwise/web.token"
```

```console
$ layerwise status --jsn
layerwise status --not-a-command: output, not a command
```
"#;

#[test]
fn the_extractor_finds_the_planted_commands() {
    let found = common::layerwise_commands(PLANTED);
    let line = |line: usize, args: &str| DocCommand {
        line,
        args: args.split(' ').map(String::from).collect(),
    };
    assert_eq!(
        found,
        vec![
            line(4, "status --build demo-build --json"),
            line(5, "demo --layers 3 --out x --no-such-flag"),
            line(7, "dicom info demo-build/dicom"),
            line(7, "alarm ack --build b --bye ana"),
            line(8, "dicom inventory demo-build/dicom"),
            line(9, "demo --layers N"),
            line(11, "vectors info demo-vectors.cli --json"),
            line(12, "build list --config /etc/layerwise/layerwise.toml"),
            line(21, "status --jsn"),
        ]
    );
}

#[test]
fn the_checker_refuses_the_planted_bad_lines() {
    let (refused, count) = common::refused_commands("planted.md", PLANTED);
    assert_eq!(count, 9);
    let lines: Vec<&str> = refused
        .iter()
        .map(|r| r.split(": ").next().unwrap())
        .collect();
    assert_eq!(
        lines,
        [
            "planted.md:5",
            "planted.md:7",
            "planted.md:8",
            "planted.md:9",
            "planted.md:21"
        ],
        "{refused:#?}"
    );
    let all = refused.join("\n");
    for what in [
        "'--no-such-flag'",
        "'--bye'",
        "'inventory'",
        "invalid value 'N'",
        "'--jsn'",
    ] {
        assert!(all.contains(what), "{what} not named:\n{all}");
    }
}
