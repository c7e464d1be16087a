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

/// Text from a log or a remote answer as a terminal may print it: control characters (escape
/// sequences that retitle or clear a terminal) shown escaped; with `lines`, line breaks kept.
pub fn printable_text(text: &str, lines: bool) -> String {
    text.chars()
        .flat_map(|c| {
            let escaped: Vec<char> = if c.is_control() && !(lines && c == '\n') {
                c.escape_default().collect()
            } else {
                vec![c]
            };
            escaped
        })
        .collect()
}

/// One line of text from a log, as a terminal may print it ([`printable_text`]).
pub fn printable(text: &str) -> String {
    printable_text(text, false)
}

#[cfg(test)]
mod tests {
    #[derive(Debug, thiserror::Error)]
    #[error("cannot read {0}")]
    struct Read(&'static str, #[source] std::io::Error);

    #[test]
    fn the_chain_says_each_cause_once() {
        let e = Read("a.toml", std::io::Error::other("permission denied"));
        assert_eq!(super::chain(&e), "cannot read a.toml: permission denied");
    }
}
