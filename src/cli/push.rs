//! `layerwise push`: pushes (or completes the push of) a finished build or an export folder to
//! archives, idempotently: what the push log says is stored is not sent again.

use anyhow::{bail, Context, Result};
use clap::Args;
use layerwise::build_dir::pushlog;
use layerwise::clock::{Clock, SystemClock};
use layerwise::config::Config;
use layerwise::logging::Escaped;
use layerwise::pacs::{Destination, Queue};
use std::path::PathBuf;

#[derive(Args)]
pub struct PushArgs {
    /// The build directory (the daemon's build.output_dir) or an export folder.
    #[arg(long)]
    build: PathBuf,
    /// A [[pacs]] name of the configuration, or a URL: http(s)://host:port/dicom-web (STOW-RS)
    /// or dicom://CALLED_AE@host:port (C-STORE). Without it: every configured destination.
    #[arg(long)]
    to: Option<String>,
    /// The configuration holding the [[pacs]] destinations; by default the one the build ran
    /// with (config.toml in the build directory).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Send again the instances the archive rejected before.
    #[arg(long)]
    retry_rejected: bool,
    /// Stop after this many seconds per destination (1 to 86400), what is left staying pending
    /// for the next push; without it the push goes on while the archive answers (each instance
    /// within its destination's deadline_s).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=86_400))]
    deadline_s: Option<u64>,
}

impl PushArgs {
    pub fn run(self) -> Result<()> {
        if !self.build.is_dir() {
            bail!(
                "{}: no such directory: pass a build directory or an export folder",
                self.build.display()
            );
        }
        let config_path = self.config.clone().or_else(|| {
            let snapshot = self.build.join(layerwise::build_dir::CONFIG_SNAPSHOT);
            snapshot.exists().then_some(snapshot)
        });
        let configured = match &config_path {
            Some(path) => Config::load(path)?.pacs,
            None => Vec::new(),
        };
        let destinations: Vec<Destination> = match &self.to {
            Some(to) => vec![Destination::resolve(to, &configured)?],
            None if configured.is_empty() => {
                bail!("no destination: give --to NAME|URL, or a --config with [[pacs]] sections")
            }
            None => configured
                .iter()
                .map(Destination::from_config)
                .collect::<Result<_, _>>()?,
        };
        let instances = pushlog::instances(&self.build).len();
        if instances == 0 {
            bail!(
                "{}: no DICOM instances (*.dcm) to push",
                self.build.display()
            );
        }
        let clock = SystemClock::new();
        let mut rejected = 0;
        for destination in destinations {
            let name = destination.name.clone();
            let mut queue = Queue::open(&self.build, destination)?;
            let already = instances - queue.pending(self.retry_rejected).len();
            let started = std::time::Instant::now();
            let mut sender = queue.destination.connect();
            let until = self
                .deadline_s
                .map(|s| clock.elapsed() + std::time::Duration::from_secs(s));
            let count = queue
                .push_pending(sender.as_mut(), self.retry_rejected, &clock, until)
                .with_context(|| {
                    format!(
                        "push of {} to {name} stopped; run it again to complete it",
                        self.build.display()
                    )
                })?;
            let seconds = started.elapsed().as_secs_f64().max(1e-9);
            println!(
                "{name}: {} pushed ({:.1} MB, {:.0} instances/s, {:.1} MB/s), {} rejected, {already} already there",
                count.stored,
                count.bytes as f64 / 1e6,
                count.stored as f64 / seconds,
                count.bytes as f64 / 1e6 / seconds,
                count.rejected.len(),
            );
            for (file, reason) in &count.rejected {
                // An archive's words, escaped: nothing it says acts on the terminal.
                println!("  rejected {}: {}", Escaped(file), Escaped(reason));
            }
            rejected += count.rejected.len();
        }
        if rejected > 0 {
            bail!(
                "{rejected} instances rejected (reasons above, and in {}/); fix them, then push \
                 again with --retry-rejected",
                self.build.join(pushlog::PACS_DIR).display()
            );
        }
        Ok(())
    }
}
