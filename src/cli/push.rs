//! `layerwise push`: pushes (or completes the push of) a finished build or an export folder to
//! archives, idempotently: what the push log says is stored is not sent again. `layerwise push
//! forget` drops a destination (a mistaken one) from the build's push state.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use layerwise::build_dir::pushlog;
use layerwise::clock::{Clock, SystemClock};
use layerwise::config::Config;
use layerwise::logging::Escaped;
use layerwise::pacs::{Destination, Queue};
use std::path::PathBuf;

#[derive(Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub struct PushArgs {
    #[command(subcommand)]
    command: Option<PushCommand>,
    /// The build directory (the daemon's build.output_dir) or an export folder.
    #[arg(long, required = true)]
    build: Option<PathBuf>,
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

#[derive(Subcommand)]
enum PushCommand {
    /// Forget a destination (one given by mistake, or retired): its push log moves to
    /// pacs/forgotten/, so `status` no longer counts its instances as pending.
    Forget(ForgetArgs),
}

#[derive(Args)]
struct ForgetArgs {
    /// The build directory or export folder.
    #[arg(long)]
    build: PathBuf,
    /// The destination as `status` names it (its push log pacs/NAME.jsonl), or the URL it was
    /// pushed to.
    #[arg(long)]
    to: String,
}

impl PushArgs {
    pub fn run(self) -> Result<()> {
        match self.command {
            Some(PushCommand::Forget(args)) => args.run(),
            None => self.push(),
        }
    }

    fn push(self) -> Result<()> {
        let build = self.build.clone().context("--build DIR is required")?;
        if !build.is_dir() {
            bail!(
                "{}: no such directory: pass a build directory or an export folder",
                build.display()
            );
        }
        let config_path = self.config.clone().or_else(|| {
            let snapshot = build.join(layerwise::build_dir::CONFIG_SNAPSHOT);
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
        let instances = pushlog::instances(&build).len();
        if instances == 0 {
            bail!("{}: no DICOM instances (*.dcm) to push", build.display());
        }
        let clock = SystemClock::new();
        let mut rejected = 0;
        for destination in destinations {
            let name = destination.name.clone();
            let mut queue = Queue::open(&build, destination)?;
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
                        build.display()
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
                build.join(pushlog::PACS_DIR).display()
            );
        }
        Ok(())
    }
}

impl ForgetArgs {
    fn run(self) -> Result<()> {
        if !self.build.is_dir() {
            bail!(
                "{}: no such directory: pass a build directory or an export folder",
                self.build.display()
            );
        }
        let known = pushlog::log_names(&self.build);
        // The name `status` shows, else the name a URL's push log was given.
        let name = if known.contains(&self.to) {
            self.to.clone()
        } else {
            Destination::resolve(&self.to, &[])
                .ok()
                .map(|d| d.name)
                .filter(|n| known.contains(n))
                .with_context(|| {
                    format!(
                        "{}: no push log for {}; its destinations: {}",
                        self.build.display(),
                        self.to,
                        if known.is_empty() {
                            "none".to_string()
                        } else {
                            known.join(", ")
                        }
                    )
                })?
        };
        let summary = pushlog::summaries(&self.build)
            .into_iter()
            .find(|s| s.destination == name);
        let kept = pushlog::forget(&self.build, &name, chrono::Utc::now())?;
        println!(
            "forgot {name}{}; its log is kept in {}",
            summary
                .map(|s| format!(" ({} pushed, {} pending)", s.pushed, s.pending))
                .unwrap_or_default(),
            kept.display()
        );
        let snapshot = self.build.join(layerwise::build_dir::CONFIG_SNAPSHOT);
        let configured = Config::load(&snapshot).map(|c| c.pacs).unwrap_or_default();
        if configured.iter().any(|d| d.name == name) {
            println!(
                "note: {name} is still a [[pacs]] destination of the build's configuration: a \
                 daemon running it, or `layerwise push --build`, pushes to it again; remove it \
                 from the configuration first"
            );
        }
        Ok(())
    }
}
