//! `layerwise build start|stop|list`: the next build without editing the configuration or
//! restarting the service (`[build] builds_dir`, build_dir::lifecycle).

use anyhow::{anyhow, Context, Result};
use clap::{Args, Subcommand};
use layerwise::build_dir::lifecycle::{self, StartRequest};
use layerwise::config::Config;
use std::path::{Path, PathBuf};

#[derive(Subcommand)]
pub enum BuildCommand {
    /// Start the next build: the running daemon ends the current one and records into a new
    /// folder under `[build] builds_dir`, named `YYYYMMDD-HHMMSS-NAME`.
    Start(StartArgs),
    /// End the current build: the daemon finishes the frame in hand and waits for the next.
    Stop(ConfigArg),
    /// The builds under `[build] builds_dir`, oldest first, the current one marked.
    List(ListArgs),
}

#[derive(Args)]
pub struct ConfigArg {
    /// The daemon's configuration file (its `[build] builds_dir` holds the builds).
    #[arg(long, default_value = "/etc/layerwise/layerwise.toml")]
    config: PathBuf,
}

impl ConfigArg {
    fn builds_dir(&self) -> Result<PathBuf> {
        let config = Config::load(&self.config)?;
        config.build.builds_dir.clone().ok_or_else(|| {
            anyhow!(
                "{}: no [build] builds_dir: set it (e.g. builds_dir = \"/var/lib/layerwise/builds\") \
                 and restart the service once, so that builds can be started without editing the configuration",
                self.config.display()
            )
        })
    }
}

#[derive(Args)]
pub struct StartArgs {
    #[command(flatten)]
    config: ConfigArg,
    /// The build's name (DICOM PatientName; part of its folder name).
    #[arg(long)]
    name: String,
    /// Its short id (DICOM PatientID); the name by default.
    #[arg(long)]
    id: Option<String>,
    /// Its laser scan vector file (CLI); the configuration's `build.vectors` by default.
    #[arg(long)]
    vectors: Option<PathBuf>,
    /// Layers it will have, for the disk forecast; the configuration's by default.
    #[arg(long, value_parser = super::values::layer_count)]
    layers: Option<u32>,
}

#[derive(Args)]
pub struct ListArgs {
    #[command(flatten)]
    config: ConfigArg,
    /// One JSON array instead of text.
    #[arg(long)]
    json: bool,
}

impl BuildCommand {
    pub fn run(self) -> Result<()> {
        match self {
            BuildCommand::Start(args) => {
                let builds = args.config.builds_dir()?;
                let vectors = match args.vectors {
                    Some(v) => Some(resolve_vectors(&v)?),
                    None => None,
                };
                let before = lifecycle::current(&builds)?.filter(|o| o.is_open());
                let order = lifecycle::start(
                    &builds,
                    StartRequest {
                        name: args.name,
                        id: args.id,
                        vectors,
                        layers: args.layers,
                    },
                    chrono::Utc::now(),
                )?;
                if let Some(before) = before {
                    println!("ended build {:?} ({})", before.name, before.folder);
                }
                println!(
                    "started build {:?}: the daemon records into {}",
                    order.name,
                    order.dir(&builds).display()
                );
                Ok(())
            }
            BuildCommand::Stop(config) => {
                let builds = config.builds_dir()?;
                match lifecycle::stop(&builds, chrono::Utc::now())? {
                    Some(order) => println!(
                        "ended build {:?}: the daemon waits for `layerwise build start`; see {}",
                        order.name,
                        order.dir(&builds).display()
                    ),
                    None => println!("no build was running"),
                }
                Ok(())
            }
            BuildCommand::List(args) => {
                let builds = args.config.builds_dir()?;
                let list = lifecycle::list(&builds)?;
                if args.json {
                    println!("{}", serde_json::to_string_pretty(&list)?);
                    return Ok(());
                }
                if list.is_empty() {
                    println!("no builds in {} yet", builds.display());
                }
                for b in &list {
                    println!(
                        "{} {:<40} {:<24} {:>5} layers {:>6} frames {:>4} missing  {}",
                        if b.current { "*" } else { " " },
                        b.folder,
                        b.name.as_deref().unwrap_or("-"),
                        b.layers_seen,
                        b.frames,
                        b.frames_missing,
                        b.state
                    );
                }
                Ok(())
            }
        }
    }
}

/// The vector file as an absolute path (the daemon runs elsewhere), checked to exist.
fn resolve_vectors(path: &Path) -> Result<PathBuf> {
    let meta = std::fs::metadata(path)
        .with_context(|| format!("--vectors {} (give the build's CLI file)", path.display()))?;
    if !meta.is_file() {
        anyhow::bail!("--vectors {}: not a regular file", path.display());
    }
    Ok(std::fs::canonicalize(path)?)
}
