//! The daemon in the test's own process, on the simulated machine (`layerwise::sim`): the one
//! place that knows how `acquisition::run` is called (today an async function, run here on a
//! tokio runtime of its own), so a change of that API changes only this file.

use layerwise::acquisition::{AcquisitionError, RunOptions, RunSummary};
use layerwise::config::Config;

/// Runs the daemon to its end on the simulated machine the configuration describes.
pub fn run_daemon(config: &Config, options: RunOptions) -> Result<RunSummary, AcquisitionError> {
    run_daemon_with(config, options, |_, _| {})
}

/// As [`run_daemon`], letting the test change the machine (a scripted camera, its own trigger)
/// and see the simulation (the mock lights' log) before the daemon starts.
pub fn run_daemon_with(
    config: &Config,
    options: RunOptions,
    adjust: impl FnOnce(&mut layerwise::hardware::Machine, &layerwise::sim::Simulation),
) -> Result<RunSummary, AcquisitionError> {
    runtime().block_on(run_with(config, options, adjust))
}

async fn run_with(
    config: &Config,
    options: RunOptions,
    adjust: impl FnOnce(&mut layerwise::hardware::Machine, &layerwise::sim::Simulation),
) -> Result<RunSummary, AcquisitionError> {
    let (mut machine, simulation) = layerwise::sim::open(config, options.clock.clone())?;
    adjust(&mut machine, &simulation);
    layerwise::acquisition::run(config, machine, options).await
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}
