//! The daemon's side of the build lifecycle (`build_dir::lifecycle`): the configuration of the
//! build an operator started, and a watch that ends a run when the order changes.

use crate::build_dir::lifecycle::{self, BuildOrder, LifecycleError};
use crate::config::Config;
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

/// Completes when the order in `builds_dir` is no longer `now` (a build started or ended), with
/// the reason; an unreadable order file is logged once and waited out (the running build goes
/// on).
pub async fn changed(builds_dir: PathBuf, now: Next) -> String {
    let mut warned = false;
    loop {
        tokio::time::sleep(POLL).await;
        match next(&builds_dir) {
            Ok(next) if next == now => warned = false,
            Ok(Next::Wait) => return "the build was ended (layerwise build stop)".into(),
            Ok(Next::Record(order)) => {
                return format!("the next build was started ({})", order.name)
            }
            Err(e) if !warned => {
                tracing::warn!(error = %e, "cannot read the build order; going on as before");
                warned = true;
            }
            Err(_) => {}
        }
    }
}

/// Between builds: waits until a build is started (true) or SIGTERM/SIGINT arrives (false),
/// telling systemd that the daemon is ready and idle, and pinging its watchdog.
pub async fn wait_for_build(builds_dir: &Path, notify_systemd: bool) -> Result<bool, String> {
    use sd_notify::NotifyState;
    let signal = |kind| {
        tokio::signal::unix::signal(kind).map_err(|e| format!("cannot watch signal {kind:?}: {e}"))
    };
    let mut sigterm = signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut sigint = signal(tokio::signal::unix::SignalKind::interrupt())?;
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
    let mut tick = tokio::time::interval(POLL);
    loop {
        tokio::select! {
            _ = sigterm.recv() => return Ok(false),
            _ = sigint.recv() => return Ok(false),
            _ = tick.tick() => {
                if notify_systemd {
                    let _ = sd_notify::notify(false, &[NotifyState::Watchdog]);
                }
                match next(builds_dir) {
                    Ok(Next::Record(_)) => return Ok(true),
                    Ok(Next::Wait) => {}
                    Err(e) => return Err(e.to_string()),
                }
            }
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
