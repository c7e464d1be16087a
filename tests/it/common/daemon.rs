//! The daemon in the test's own process, on the simulated machine (`layerwise::sim`): the one
//! place that knows how `acquisition::run` is called (a blocking call on the test's thread; it
//! returns when the mock trigger ends or `options.shutdown` is requested).

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
    let (mut machine, simulation) = layerwise::sim::open(config, options.clock.clone())?;
    adjust(&mut machine, &simulation);
    layerwise::acquisition::run(config, machine, options)
}
