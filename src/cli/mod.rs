//! The command line: one `#[derive(Args)]` struct per command, each turned into the library's
//! request and run; reports print through their `Display`. Errors get their context here, at the
//! binary's edge, and are printed once with their causes.

mod alarm;
mod build;
mod daemon;
mod files;
mod flaws;
mod inspect;
mod learn;
mod learn_compare;
mod lifecycle;
mod numbering;
mod register;
// The push to archives (PACS).
mod push;
mod serve;
mod values;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "layerwise",
    version,
    about = "Layer-wise imaging of powder bed fusion builds, registered to the laser vectors and CT"
)]
pub struct Cli {
    /// More log detail.
    #[arg(short, long, global = true)]
    pub verbose: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
    /// Run the acquisition daemon (what the systemd service runs).
    Run(daemon::RunArgs),
    /// Validate a configuration file without touching any hardware.
    CheckConfig(daemon::CheckConfigArgs),
    /// Before a build: detect the camera, read its settings, take one test shot per light.
    Check(daemon::CheckArgs),
    /// Where a build stands: layer, frames, missing frames, processing, disk.
    Status(daemon::StatusArgs),
    /// Start, end and list builds without editing the configuration (`[build] builds_dir`).
    Build {
        #[command(subcommand)]
        command: lifecycle::BuildCommand,
    },
    /// Laser scan vector files (CLI, ASCII or binary).
    Vectors {
        #[command(subcommand)]
        command: files::VectorsCommand,
    },
    /// Rectify one camera frame to the top-down build grid through a calibration.
    Rectify(files::RectifyArgs),
    /// Plan the camera: magnification, resolution, depth of field (paper eq. 1-4) and the
    /// Scheimpflug lens tilt that puts the plane of focus on the plate.
    Optics(files::OpticsArgs),
    /// Export a build as series of one study on one grid (DICOM, or NRRD for 3D Slicer / napari).
    Export(build::ExportArgs),
    /// Where a build point is: its layer, its pixel in each rectified view and in each original frame.
    Locate(build::LocateArgs),
    /// Internal flaws of a registered CT (pores, lack of fusion) in the build frame and its
    /// layers; with --build, labelled patches of every view of those layers.
    Flaws(flaws::FlawsArgs),
    /// DICOM series of a build.
    Dicom {
        #[command(subcommand)]
        command: files::DicomCommand,
    },
    /// Registration of build images and of a CT to the laser vectors.
    Register {
        #[command(subcommand)]
        command: register::RegisterCommand,
    },
    /// Push a build's (or an export folder's) DICOM instances to a PACS: STOW-RS or C-STORE.
    Push(push::PushArgs),
    /// Serve the operator page of a build directory, e.g. a finished build.
    Serve(serve::ServeArgs),
    /// A whole simulated build: mock trigger, mock lights, mock camera, the real storage path.
    Demo(daemon::DemoArgs),
    /// Inspect a stored build (or a folder of frames) for streaks, short feed, super-elevation,
    /// fusion against the vectors and drift, as the daemon does live.
    Inspect(inspect::InspectArgs),
    /// The inspection alarm: acknowledge it (`alarm ack --build DIR`) or show it.
    Alarm(alarm::AlarmArgs),
    /// A defect model: train it on labelled pictures, CT flaws or operator verdicts, evaluate
    /// it, run it on pictures (docs/learning.md).
    Learn {
        #[command(subcommand)]
        command: learn::LearnCommand,
    },
}

impl Command {
    pub fn run(self) -> Result<()> {
        match self {
            Command::Run(args) => args.run(),
            Command::CheckConfig(args) => args.run(),
            Command::Check(args) => args.run(),
            Command::Status(args) => args.run(),
            Command::Build { command } => command.run(),
            Command::Vectors { command } => command.run(),
            Command::Rectify(args) => args.run(),
            Command::Optics(args) => args.run(),
            Command::Export(args) => args.run(),
            Command::Locate(args) => args.run(),
            Command::Flaws(args) => args.run(),
            Command::Dicom { command } => command.run(),
            Command::Register { command } => command.run(),
            Command::Serve(args) => args.run(),
            Command::Demo(args) => args.run(),
            Command::Push(args) => args.run(),
            Command::Inspect(args) => args.run(),
            Command::Alarm(args) => args.run(),
            Command::Learn { command } => command.run(),
        }
    }
}

/// An error with its causes: `message: cause: cause`. Library errors write their own message
/// only and keep the cause as their source, so each is said once.
pub fn report(error: &anyhow::Error) -> String {
    format!("{error:#}")
}

#[cfg(test)]
mod tests {
    use super::Cli;
    use clap::CommandFactory;

    /// Every command and every option and argument of every command has a help line.
    #[test]
    fn every_option_has_a_help_line() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            let path = format!("{path} {}", cmd.get_name());
            if cmd.get_about().is_none() && path.trim() != "layerwise" {
                missing.push(format!("{path} (the command)"));
            }
            for arg in cmd.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                if arg.get_help().is_none() && arg.get_long_help().is_none() {
                    missing.push(format!("{path} --{id}"));
                }
            }
            for sub in cmd.get_subcommands() {
                walk(sub, &path, missing);
            }
        }
        let mut missing = Vec::new();
        walk(&Cli::command(), "", &mut missing);
        assert!(missing.is_empty(), "no help line: {missing:#?}");
    }
}
