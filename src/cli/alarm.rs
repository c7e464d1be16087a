//! `layerwise alarm`: the inspection alarm of a build: acknowledge it (the running daemon switches
//! the stack light off within a second) or show where it stands.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use layerwise::build_dir::alarm::{self, AlarmState};
use std::path::PathBuf;

#[derive(Args)]
pub struct AlarmArgs {
    #[command(subcommand)]
    command: AlarmCommand,
}

#[derive(Subcommand)]
enum AlarmCommand {
    /// Acknowledge the raised alarm: the daemon switches the stack light off and journals who did
    /// it; the next flag at the alarm's severity raises it again.
    Ack {
        /// The build directory (the daemon's build.output_dir).
        #[arg(long)]
        build: PathBuf,
        /// Who acknowledges (default: $USER).
        #[arg(long)]
        by: Option<String>,
        /// What was checked or decided, kept with the acknowledgement.
        #[arg(long)]
        note: Option<String>,
    },
    /// Show the alarm: raised since which layer, or acknowledged by whom and when.
    Show {
        /// The build directory.
        #[arg(long)]
        build: PathBuf,
    },
}

impl AlarmArgs {
    pub fn run(self) -> Result<()> {
        match self.command {
            AlarmCommand::Ack { build, by, note } => {
                let by = by
                    .or_else(|| std::env::var("USER").ok())
                    .filter(|b| !b.trim().is_empty())
                    .unwrap_or_else(|| "an operator".into());
                let state =
                    alarm::acknowledge(&build, &by, note.as_deref(), chrono::Utc::now(), None)?;
                println!("alarm {state}");
                Ok(())
            }
            AlarmCommand::Show { build } => {
                layerwise::build_dir::require_build(&build)?;
                let events = alarm::history(&build)
                    .with_context(|| format!("the alarm of {}", build.display()))?;
                println!("alarm {}", AlarmState::replay(&events));
                Ok(())
            }
        }
    }
}
