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
