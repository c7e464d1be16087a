//! `layerwise serve`: the operator page for any build directory.

use anyhow::{Context, Result};
use clap::Args;
use layerwise::config::WebConfig;
use layerwise::shutdown::{self, Shutdown};
use layerwise::web::WebServer;
use std::path::PathBuf;

#[derive(Args)]
pub struct ServeArgs {
    /// The build directory (a finished build, or one a daemon is writing).
    #[arg(long)]
    build: PathBuf,
    /// host:port to listen on (port 0: any free port, printed).
    #[arg(long, default_value = "127.0.0.1:8040")]
    listen: String,
    /// A file holding the bearer token requests must carry (required beyond loopback).
    #[arg(long)]
    token_file: Option<PathBuf>,
    /// Let the calibration page save new points files (and calibrations) in the build directory.
    #[arg(long)]
    calibration_page: bool,
    /// Seconds a connection may sit idle (nothing read or written, no request being answered)
    /// before it is closed, as `[web] idle_timeout_s`.
    #[arg(long, default_value_t = WebConfig::default().idle_timeout_s)]
    idle_timeout_s: u64,
    /// Serve Prometheus metrics of the build at /metrics (docs/metrics.md).
    #[arg(long)]
    metrics: bool,
}

impl ServeArgs {
    pub fn run(self) -> Result<()> {
        anyhow::ensure!(
            self.build.join(layerwise::build_dir::JOURNAL).is_file(),
            "{}: not a layerwise build directory (no {}); pass the daemon's build.output_dir",
            self.build.display(),
            layerwise::build_dir::JOURNAL
        );
        let config = WebConfig {
            listen: self.listen.clone(),
            token_file: self.token_file.clone(),
            calibration_page: self.calibration_page,
            idle_timeout_s: self.idle_timeout_s,
            ..WebConfig::default()
        };
        config.validate().map_err(|invalid| {
            let flag = invalid.key["web.".len()..].replace('_', "-");
            anyhow::anyhow!("--{flag}: {}", invalid.message)
        })?;
        let addr = config
            .address()
            .map_err(|invalid| anyhow::anyhow!("--listen: {}", invalid.message))?
            .context("--listen must name an address")?;
        let process = Shutdown::new();
        let _signals =
            shutdown::watch_signals(&process).context("cannot watch SIGTERM and SIGINT")?;
        if self.metrics {
            layerwise::plant::metrics::install(None);
        }
        let server = WebServer::start(&self.build, &config, addr, &process)?;
        println!(
            "serving {} at http://{}/ (Ctrl-C stops)",
            self.build.display(),
            server.addr
        );
        // Until SIGINT or SIGTERM: the receiver is ready (disconnected) once they came.
        let _ = process.receiver().recv();
        server.join();
        Ok(())
    }
}

/// Starts the page of the daemon's build when `[web] listen` is set, until `shutdown` is
/// requested. A page that cannot start (port taken, token unreadable) is logged, never a reason
/// not to capture.
pub fn start_for_daemon(
    config: &layerwise::config::Config,
    shutdown: &Shutdown,
) -> Option<WebServer> {
    let addr = config.web.address().ok()??;
    match WebServer::start(&config.build.output_dir, &config.web, addr, shutdown) {
        Ok(server) => {
            tracing::info!(url = %format!("http://{}/", server.addr), "operator page");
            Some(server)
        }
        Err(e) => {
            tracing::warn!(error = %layerwise::logging::Chain(&e), "no operator page; capture goes on");
            None
        }
    }
}
