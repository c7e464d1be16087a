//! `layerwise alarm`: the inspection alarm of a build: acknowledge it (the running daemon switches
//! the stack light off within a second) or show where it stands.

use anyhow::{bail, Result};
use clap::{Args, Subcommand};
use layerwise::build_dir::alarm::{AlarmEvent, AlarmLog, AlarmState};
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
                let path = build.join(layerwise::build_dir::ALARM);
                let state = AlarmState::replay(&AlarmLog::read(&path)?);
                if !state.is_raised() {
                    bail!(
                        "{}: the alarm is not raised (it is {state}); nothing to acknowledge",
                        build.display()
                    );
                }
                for (flag, text, most) in [("--by", &by, 100), ("--note", &note, 2000)] {
                    let chars = text.as_deref().map_or(0, |t| t.chars().count());
                    if chars > most {
                        bail!("{flag}: {chars} characters; at most {most}");
                    }
                    if let Some(c) = text
                        .as_deref()
                        .and_then(|t| t.chars().find(|&c| layerwise::logging::is_hidden_char(c)))
                    {
                        bail!(
                            "{flag}: holds the control or bidirectional character {}; write \
                             plain text (it is shown to every operator)",
                            c.escape_unicode()
                        );
                    }
                }
                let by = by
                    .or_else(|| std::env::var("USER").ok())
                    .filter(|b| !b.trim().is_empty())
                    .unwrap_or_else(|| "an operator".into());
                AlarmLog::append_only(&path)?.append(&AlarmEvent::Acknowledged {
                    at: chrono::Utc::now(),
                    by,
                    note,
                })?;
                println!("alarm {}", AlarmState::replay(&AlarmLog::read(&path)?));
                Ok(())
            }
            AlarmCommand::Show { build } => {
                let events = AlarmLog::read(&build.join(layerwise::build_dir::ALARM))?;
                println!("alarm {}", AlarmState::replay(&events));
                Ok(())
            }
        }
    }
}
