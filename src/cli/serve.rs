//! `layerwise serve`: the operator page for any build directory; also the daemon's page process
//! (started and supervised by `run` and `demo`, see `layerwise::web::supervisor`).

use anyhow::{Context, Result};
use clap::Args;
use layerwise::clock::SharedClock;
use layerwise::config::WebConfig;
use layerwise::shutdown::{self, Shutdown};
use layerwise::web::supervisor::{PageCommand, PageProcess, LISTEN_FD};
use layerwise::web::{process, WebError, WebServer};
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
    /// A name besides 127.0.0.1, [::1] and localhost the page answers to without a token (one a
    /// reverse proxy sends as Host), as `[web] allowed_hosts`; repeatable.
    #[arg(long = "allowed-host", value_name = "NAME")]
    allowed_hosts: Vec<String>,
    /// Seconds a connection may sit idle (nothing read or written, no request being answered)
    /// before it is closed, as `[web] idle_timeout_s`.
    #[arg(long, default_value_t = WebConfig::default().idle_timeout_s)]
    idle_timeout_s: u64,
    /// Seconds a client has to send a request's headers (from its connection's start or the
    /// previous answer's end), as `[web] header_timeout_s`.
    #[arg(long, default_value_t = WebConfig::default().header_timeout_s)]
    header_timeout_s: u64,
    /// Seconds a client has to send a request's body (from its headers), as
    /// `[web] body_timeout_s`.
    #[arg(long, default_value_t = WebConfig::default().body_timeout_s)]
    body_timeout_s: u64,
    /// Connections open at once, as `[web] max_connections` (beyond it, one waiting for a request
    /// makes room).
    #[arg(long, default_value_t = WebConfig::default().max_connections)]
    max_connections: usize,
    /// Bound this process's address space to this many MiB, as `[web] memory_mb` bounds the
    /// daemon's page process (by default: unbounded).
    #[arg(long)]
    memory_mb: Option<u64>,
    /// The daemon's page process: serve on the listening socket at this descriptor.
    #[arg(long, hide = true, requires = "web_config")]
    listen_fd: Option<i32>,
    /// The daemon's page process: the daemon's `[web]` section, as TOML.
    #[arg(long, hide = true, requires = "listen_fd")]
    web_config: Option<String>,
    /// The daemon's page process: serve /metrics with the daemon's live metrics from this file.
    #[arg(long, hide = true, requires = "listen_fd")]
    live_metrics: Option<PathBuf>,
    /// Serve Prometheus metrics of the build at /metrics (docs/metrics.md).
    #[arg(long)]
    metrics: bool,
}

impl ServeArgs {
    pub fn run(self) -> Result<()> {
        if let (Some(fd), Some(web)) = (self.listen_fd, &self.web_config) {
            if let Some(path) = &self.live_metrics {
                layerwise::plant::metrics::install_from_file(path.clone());
            }
            return serve_for_daemon(&self.build, fd, web);
        }
        layerwise::build_dir::require_build(&self.build)?;
        let mut config = WebConfig {
            listen: self.listen.clone(),
            token_file: self.token_file.clone(),
            calibration_page: self.calibration_page,
            allowed_hosts: self.allowed_hosts.clone(),
            idle_timeout_s: self.idle_timeout_s,
            header_timeout_s: self.header_timeout_s,
            body_timeout_s: self.body_timeout_s,
            max_connections: self.max_connections,
            ..WebConfig::default()
        };
        if let Some(mb) = self.memory_mb {
            config.memory_mb = mb;
        }
        process::prepare_page_process();
        if self.memory_mb.is_some() {
            limit_memory(config.memory_mb);
        }
        let process = Shutdown::new();
        let _signals =
            shutdown::watch_signals(&process).context("cannot watch SIGTERM and SIGINT")?;
        if self.metrics {
            layerwise::plant::metrics::install(None);
        }
        let server = start_page(&self.build, &config, &process)?;
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

/// The daemon's page process: its `[web]` section, on the socket the daemon bound, bounded in
/// memory, the kernel's first choice when memory runs out; until SIGTERM.
fn serve_for_daemon(build: &std::path::Path, fd: i32, web: &str) -> Result<()> {
    let config: WebConfig = toml::from_str(web).context("--web-config")?;
    config
        .validate()
        .map_err(|invalid| anyhow::anyhow!("--web-config: {}", invalid.message))?;
    process::prepare_page_process();
    limit_memory(config.memory_mb);
    process::prefer_for_oom_kill();
    process::name_page_process();
    anyhow::ensure!(
        fd == LISTEN_FD,
        "--listen-fd {fd}: the daemon hands down {LISTEN_FD}"
    );
    // SAFETY: the daemon hands its listening socket down as this descriptor (supervisor::spawn);
    // nothing else in this process owns it.
    let listener = unsafe { <std::net::TcpListener as std::os::fd::FromRawFd>::from_raw_fd(fd) };
    listener
        .local_addr()
        .with_context(|| format!("--listen-fd {fd} is not a listening socket"))?;
    let process = Shutdown::new();
    let _signals = shutdown::watch_signals(&process).context("cannot watch SIGTERM and SIGINT")?;
    let server = WebServer::start_listening(build, &config, listener, &process)?;
    let _ = process.receiver().recv();
    server.join();
    Ok(())
}

fn limit_memory(mb: u64) {
    if let Err(errno) = process::limit_memory(mb) {
        tracing::warn!(
            errno,
            memory_mb = mb,
            "the page's memory is not bounded (prlimit refused)"
        );
    }
}

/// Starts the page of `build` as `serve` and `demo --listen` do, until `shutdown` is requested:
/// an address that is taken (or not one) is an error naming `--listen`.
pub fn start_page(
    build: &std::path::Path,
    config: &WebConfig,
    shutdown: &Shutdown,
) -> Result<WebServer> {
    config.validate().map_err(|invalid| {
        let flag = invalid.key["web.".len()..].replace('_', "-");
        anyhow::anyhow!("--{flag}: {}", invalid.message)
    })?;
    let addr = config
        .address()
        .map_err(|invalid| anyhow::anyhow!("--listen: {}", invalid.message))?
        .context("--listen must name an address")?;
    WebServer::start(build, config, addr, shutdown).map_err(|e| match e {
        WebError::Listen { addr, source } => anyhow::Error::new(source).context(format!(
            "cannot listen on {addr}: give --listen a free address (port 0: any free port)"
        )),
        other => other.into(),
    })
}

/// Starts the page of the daemon's build when `[web] listen` is set, in a process of its own
/// (`layerwise serve` on the daemon's socket, restarted if it ends), until `shutdown` is
/// requested. A page that cannot start (port taken, token unreadable) is logged, never a reason
/// not to capture.
pub fn start_for_daemon(
    config: &layerwise::config::Config,
    clock: SharedClock,
    shutdown: &Shutdown,
) -> Option<PageProcess> {
    let addr = config.web.address().ok()??;
    let started = page_command(config).and_then(|command| {
        Ok(PageProcess::start(
            &config.web,
            addr,
            command,
            clock,
            shutdown,
        )?)
    });
    match started {
        Ok(page) => {
            tracing::info!(url = %format!("http://{}/", page.addr), "operator page");
            Some(page)
        }
        Err(e) => {
            tracing::warn!(error = %format!("{e:#}"), "no operator page; capture goes on");
            None
        }
    }
}

/// This very program (`/proc/self/exe`: the binary running, even if replaced on disk since) as
/// `serve` of the configuration's build on the daemon's socket.
fn page_command(config: &layerwise::config::Config) -> Result<PageCommand> {
    let own = PathBuf::from("/proc/self/exe");
    let program = if own.exists() {
        own
    } else {
        std::env::current_exe().context("cannot find this program to start the page with")?
    };
    let web = toml::to_string(&config.web).context("cannot write the [web] section")?;
    let mut args: Vec<std::ffi::OsString> = vec![
        "serve".into(),
        "--build".into(),
        config.build.output_dir.clone().into(),
        "--listen-fd".into(),
        LISTEN_FD.to_string().into(),
        "--web-config".into(),
        web.into(),
    ];
    if config.metrics.enabled {
        args.push("--live-metrics".into());
        args.push(layerwise::plant::live_file().into());
    }
    Ok(PageCommand {
        program,
        name: "layerwise".into(),
        args,
    })
}
