//! The daemon's side of the build lifecycle (`build_dir::lifecycle`): the configuration of the
//! build an operator started, a watch that ends a run when the order changes, and the wait
//! between builds.

use crate::build_dir::lifecycle::{self, BuildOrder, LifecycleError};
use crate::clock::SharedClock;
use crate::config::Config;
use crate::logging::Chain;
use crate::shutdown::{Shutdown, StopReason};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// How often the daemon looks at the order file.
pub const POLL: Duration = Duration::from_secs(1);

/// The configuration for recording `order`: its folder, name, id, vectors and layers over the
/// configuration's defaults.
pub fn config_for(config: &Config, builds_dir: &Path, order: &BuildOrder) -> Config {
    let mut config = config.clone();
    config.build.output_dir = order.dir(builds_dir);
    config.build.name = order.name.clone();
    config.build.id = order.id.clone();
    if let Some(vectors) = &order.vectors {
        config.build.vectors = Some(vectors.clone());
    }
    if order.layers.is_some() {
        config.build.layers = order.layers;
    }
    config
}

/// What the daemon should do now.
#[derive(Clone, Debug, PartialEq)]
pub enum Next {
    /// Record into this build.
    Record(BuildOrder),
    /// No build is open: wait for `layerwise build start`.
    Wait,
}

/// The order in force.
pub fn next(builds_dir: &Path) -> Result<Next, LifecycleError> {
    Ok(match lifecycle::current(builds_dir)? {
        Some(order) if order.is_open() => Next::Record(order),
        _ => Next::Wait,
    })
}

/// Watches the order in `builds_dir` every [`POLL`] on `clock` from a thread of its own, and
/// requests `shutdown` (`StopReason::BuildStopped`) when it is no longer `now` (a build started
/// or ended). An unreadable order file is logged once and waited out (the running build goes on).
/// The thread ends with the shutdown, whoever requested it.
pub fn watch_order(
    builds_dir: PathBuf,
    now: Next,
    clock: SharedClock,
    shutdown: Shutdown,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name("build-order".into())
        .spawn(move || {
            let mut warned = false;
            while shutdown.wait(&clock.after(POLL)).is_none() {
                let next = match next(&builds_dir) {
                    Ok(next) if next == now => {
                        warned = false;
                        continue;
                    }
                    Ok(Next::Wait) => None,
                    Ok(Next::Record(order)) => Some(order.name),
                    Err(e) => {
                        if !warned {
                            tracing::warn!(error = %Chain(&e), "cannot read the build order; going on as before");
                            warned = true;
                        }
                        continue;
                    }
                };
                let reason = StopReason::BuildStopped { next };
                tracing::info!(reason = %reason, "finishing the frame in hand, then stopping");
                shutdown.request(reason);
            }
        })
}

/// Between builds: waits until a build is started (true) or `shutdown` is requested (false),
/// telling systemd that the daemon is ready and idle, and pinging its watchdog.
pub fn wait_for_build(
    builds_dir: &Path,
    notify_systemd: bool,
    clock: &SharedClock,
    shutdown: &Shutdown,
) -> Result<bool, LifecycleError> {
    use sd_notify::NotifyState;
    tracing::info!(
        builds_dir = %builds_dir.display(),
        "no build is open: waiting for `layerwise build start`"
    );
    if notify_systemd {
        let _ = sd_notify::notify(
            false,
            &[
                NotifyState::Ready,
                NotifyState::Status("idle: no build open (layerwise build start)"),
            ],
        );
    }
    loop {
        if notify_systemd {
            let _ = sd_notify::notify(false, &[NotifyState::Watchdog]);
        }
        if let Next::Record(_) = next(builds_dir)? {
            return Ok(true);
        }
        if shutdown.wait(&clock.after(POLL)).is_some() {
            return Ok(false);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::build_dir::lifecycle::StartRequest;
    use chrono::TimeZone;

    #[test]
    fn an_order_names_the_folder_and_overrides_name_vectors_and_layers() {
        let tmp = tempfile::tempdir().unwrap();
        let config = Config::parse(crate::config::DEMO_CONFIG, Path::new("demo.toml")).unwrap();
        assert_eq!(next(tmp.path()).unwrap(), Next::Wait);
        let at = chrono::Utc.with_ymd_and_hms(2026, 12, 2, 1, 0, 0).unwrap();
        let order = lifecycle::start(
            tmp.path(),
            StartRequest {
                name: "part A".into(),
                vectors: Some("/x/a.cli".into()),
                layers: Some(12),
                ..StartRequest::default()
            },
            at,
        )
        .unwrap();
        assert_eq!(next(tmp.path()).unwrap(), Next::Record(order.clone()));
        let c = config_for(&config, tmp.path(), &order);
        assert_eq!(
            c.build.output_dir,
            tmp.path().join("20261202-010000-part-A")
        );
        assert_eq!(c.build.name, "part A");
        assert_eq!(c.build.vectors.as_deref(), Some(Path::new("/x/a.cli")));
        assert_eq!(c.build.layers, Some(12));
        lifecycle::stop(tmp.path(), at).unwrap();
        assert_eq!(next(tmp.path()).unwrap(), Next::Wait);
    }
}
