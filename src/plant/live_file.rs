//! The daemon's live metrics for its page process. The page runs as a process of its own
//! (docs/architecture.md), so the histograms and counters the daemon's threads update are
//! written, as the Prometheus text of their families, to a file of the daemon's (in its private
//! /tmp under the shipped unit) after each plant event; the page adds that text to the build's
//! state at each scrape. A write never makes capture wait: the events reach the writer through
//! the sink's bounded channel like any consumer's.

use super::metrics::{encode, LiveMetrics};
use super::sink::PlantFeed;
use crate::shutdown::Shutdown;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tracing::warn;

/// The file this daemon process keeps its live metrics in.
pub fn live_file() -> PathBuf {
    std::env::temp_dir().join(format!("layerwise-{}-metrics.prom", std::process::id()))
}

/// Writes `live` to `path` now and after each event of `feed` (events that came meanwhile
/// folded into one write), until every sink is gone or `shutdown` is requested; then removes
/// the file.
async fn keep(live: &LiveMetrics, path: &Path, mut feed: PlantFeed, shutdown: Shutdown) {
    let mut warned = false;
    let mut write = |live: &LiveMetrics| {
        let text = encode(None, Some(live), chrono::Utc::now());
        if let Err(e) = crate::fsutil::write_atomic(path, text.as_bytes(), false) {
            if !warned {
                warned = true;
                warn!(file = %path.display(), error = %crate::logging::Chain(&e), "the page's /metrics lacks the daemon's live metrics");
            }
        }
    };
    write(live);
    loop {
        tokio::select! {
            event = feed.events.recv() => match event {
                Some(_) => {
                    while feed.events.try_recv().is_ok() {}
                    write(live);
                }
                None => break,
            },
            _ = shutdown.requested() => break,
        }
    }
    let _ = std::fs::remove_file(path);
}

/// Starts [`keep`] on a thread of its own (`plant-metrics`), until `shutdown` is requested.
pub fn start(
    live: Arc<LiveMetrics>,
    path: PathBuf,
    feed: PlantFeed,
    shutdown: Shutdown,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    let runtime = tokio::runtime::Builder::new_current_thread().build()?;
    std::thread::Builder::new()
        .name("plant-metrics".into())
        .spawn(move || runtime.block_on(keep(&live, &path, feed, shutdown)))
}
