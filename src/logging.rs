//! Logs through tracing: to journald when systemd started us (structured fields survive as journal
//! fields), human-readable on a terminal otherwise. `RUST_LOG` filters as usual.

use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::EnvFilter;

pub fn init(verbose: bool) {
    // -v: our own debug lines (lights, camera calls), not every dependency's.
    let default = if verbose {
        "info,layerwise=debug"
    } else {
        "info"
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    // systemd sets JOURNAL_STREAM for services whose stdout/stderr go to the journal.
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        if let Ok(journald) = tracing_journald::layer() {
            let _ = tracing_subscriber::registry()
                .with(filter)
                .with(journald.with_syslog_identifier("layerwise".into()))
                .try_init();
            return;
        }
    }
    // Colour only for a person at a terminal: never escape codes in a pipe or a log file.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// An error with its sources, each said once: `message: cause: cause`. Library errors write their
/// own message only and keep the cause as their source; this is how a log line, a journal
/// record or a page shows the whole chain (the binary prints `anyhow`'s chain the same way).
pub struct Chain<'a>(pub &'a (dyn std::error::Error + 'static));

impl std::fmt::Display for Chain<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)?;
        let mut source = self.0.source();
        while let Some(cause) = source {
            write!(f, ": {cause}")?;
            source = cause.source();
        }
        Ok(())
    }
}

/// [`Chain`] as a string (for records that keep the text).
pub fn chain(error: &(dyn std::error::Error + 'static)) -> String {
    Chain(error).to_string()
}

/// Whether a character acts on a terminal or on the order of the text around it instead of
/// showing: C0 and C1 controls (escape sequences, carriage return, newline), DEL, the line and
/// paragraph separators, and the bidirectional marks, embeddings, overrides and isolates (a
/// right-to-left override makes `gpj.exe` read `exe.jpg`).
pub fn is_hidden_char(c: char) -> bool {
    c.is_control()
        || matches!(
            c,
            '\u{061C}'
                | '\u{200E}'
                | '\u{200F}'
                | '\u{2028}'
                | '\u{2029}'
                | '\u{202A}'..='\u{202E}'
                | '\u{2066}'..='\u{2069}'
        )
}

/// Text from outside (an archive's error, an operator's note, a file name from a record) shown
/// as it is but with every [`is_hidden_char`] written out (`\u{1b}`, `\n`), so that nothing
/// printed can move the cursor, clear the screen, retitle the terminal or reorder a line.
pub struct Escaped<'a>(pub &'a str);

impl std::fmt::Display for Escaped<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        use std::fmt::Write;
        for c in self.0.chars() {
            if is_hidden_char(c) {
                match c {
                    '\n' | '\r' | '\t' => write!(f, "{}", c.escape_default())?,
                    c => write!(f, "{}", c.escape_unicode())?,
                }
            } else {
                f.write_char(c)?;
            }
        }
        Ok(())
    }
}

/// [`Escaped`] as a string.
pub fn escape(text: &str) -> String {
    Escaped(text).to_string()
}

/// Text from a log or a remote answer as a terminal may print it: every [`is_hidden_char`]
/// written out as [`Escaped`] does; with `lines`, line breaks kept.
pub fn printable_text(text: &str, lines: bool) -> String {
    if !lines {
        return escape(text);
    }
    text.split('\n').map(escape).collect::<Vec<_>>().join("\n")
}

/// A panic's message, when it has one.
pub(crate) fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    match (panic.downcast_ref::<&str>(), panic.downcast_ref::<String>()) {
        (Some(text), _) => text.to_string(),
        (_, Some(text)) => text.clone(),
        _ => "no message".into(),
    }
}

#[cfg(test)]
mod tests {
    #[derive(Debug, thiserror::Error)]
    #[error("cannot read {0}")]
    struct Read(&'static str, #[source] std::io::Error);

    #[test]
    fn escapes_leave_nothing_for_the_terminal_to_act_on() {
        let hostile = "ok\u{1b}]0;pwned\u{7}\u{1b}[2J\r\nnext\u{202e}gpj.exe\u{9b}31m";
        let shown = super::escape(hostile);
        assert!(!shown.chars().any(super::is_hidden_char), "{shown}");
        assert_eq!(
            shown,
            "ok\\u{1b}]0;pwned\\u{7}\\u{1b}[2J\\r\\nnext\\u{202e}gpj.exe\\u{9b}31m"
        );
        assert_eq!(super::escape("Grüße, 東京 ✓"), "Grüße, 東京 ✓");
    }

    #[test]
    fn the_chain_says_each_cause_once() {
        let e = Read("a.toml", std::io::Error::other("permission denied"));
        assert_eq!(super::chain(&e), "cannot read a.toml: permission denied");
    }
}
