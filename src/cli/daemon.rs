//! The daemon's commands: `run`, `check-config`, `status` and `demo`. This is the composition
//! root: it picks the simulated machine (`sim`) where the configuration says `kind = "mock"` and
//! the real hardware elsewhere; the library's daemon sees only the traits.

use anyhow::{Context, Result};
use clap::Args;
use layerwise::acquisition::{self, RunOptions, RunSummary};
use layerwise::clock::{SharedClock, SystemClock};
use layerwise::config::{CameraConfig, Config, TriggerConfig, DEMO_CONFIG};
use layerwise::hardware::Machine;
use layerwise::pacs::live::{PushPlan, Pusher};
use layerwise::pacs::Destination;
use layerwise::shutdown::{self, Shutdown, StopReason};
use std::path::{Path, PathBuf};

#[derive(Args)]
pub struct RunArgs {
    /// The configuration file (config/layerwise.toml documents every key).
    #[arg(long, default_value = "/etc/layerwise/layerwise.toml")]
    config: PathBuf,
}

impl RunArgs {
    pub fn run(self) -> Result<()> {
        let config = Config::load(&self.config)?;
        // What check-config checks, before anything touches the hardware.
        acquisition::preflight(&config, &self.config)?;
        // SIGTERM (systemd's stop) and SIGINT end the process's shutdown, and every run with it.
        let process = Shutdown::new();
        let _signals =
            shutdown::watch_signals(&process).context("cannot watch SIGTERM and SIGINT")?;
        let plant = PlantRunning::start(&config);
        let result = match config.build.builds_dir.clone() {
            None => run_daemon(&config, service_options(&process, &plant.sink)).map(|summary| {
                print_stopped(&summary);
            }),
            Some(builds) => run_builds(&config, &builds, &process, &plant.sink),
        };
        plant.stop(&process);
        result
    }
}

/// The plant interfaces (`[metrics]`, `[mqtt]`) for the whole process: they go on
/// across builds and stop once every run has ended.
struct PlantRunning {
    plant: layerwise::plant::Plant,
    sink: layerwise::plant::PlantSink,
    stop: Shutdown,
}

impl PlantRunning {
    fn start(config: &Config) -> PlantRunning {
        let stop = Shutdown::new();
        let plant = layerwise::plant::Plant::start(config, &stop);
        PlantRunning {
            sink: plant.sink(),
            plant,
            stop,
        }
    }

    /// Stops them with the process's reason (or as after a build that ended).
    fn stop(self, process: &Shutdown) {
        self.stop
            .request(process.reason().unwrap_or(StopReason::TriggerEnded));
        drop(self.sink);
        self.plant.join();
    }
}

/// The service's options: systemd told, the frames taken processed when a build ends, stopped
/// by `process` (a child of it: the run also ends on its own), the plant interfaces told.
fn service_options(process: &Shutdown, plant: &layerwise::plant::PlantSink) -> RunOptions {
    let mut options = RunOptions::new();
    options.notify_systemd = true;
    options.drain_at_end = true;
    options.shutdown = process.child();
    options.plant = plant.clone();
    options
}

fn print_stopped(summary: &RunSummary) {
    let reason = summary
        .stop_reason
        .as_ref()
        .map_or_else(String::new, ToString::to_string);
    println!(
        "stopped ({reason}): {} frames stored, {} missing",
        summary.stored, summary.missing
    );
}

/// The daemon with `[build] builds_dir`: records into the build an operator started
/// (`layerwise build start`), switches when the next one starts, waits while none is open.
fn run_builds(
    config: &Config,
    builds: &Path,
    process: &Shutdown,
    plant: &layerwise::plant::PlantSink,
) -> Result<()> {
    use layerwise::acquisition::lifecycle::{self, Next};
    std::fs::create_dir_all(builds)
        .with_context(|| format!("cannot create [build] builds_dir {}", builds.display()))?;
    let clock = SystemClock::shared();
    loop {
        let next = lifecycle::next(builds)?;
        match &next {
            Next::Wait => {
                if !lifecycle::wait_for_build(builds, true, &clock, process)? {
                    println!("stopped (no build open)");
                    return Ok(());
                }
            }
            Next::Record(order) => {
                let build_config = lifecycle::config_for(config, builds, order);
                let options = service_options(process, plant);
                // The order's change ends this run (the frames taken are processed first).
                let watch = lifecycle::watch_order(
                    builds.to_path_buf(),
                    next.clone(),
                    clock.clone(),
                    options.shutdown.clone(),
                )
                .context("cannot start the build order's watch")?;
                let summary = run_daemon(&build_config, options);
                // Every run ends with its shutdown requested: the watch ends too.
                let _ = watch.join();
                let summary = summary?;
                print_stopped(&summary);
                if !summary.stopped_on_request() {
                    return Ok(());
                }
            }
        }
    }
}

/// The machine the configuration describes: the real hardware, or the simulated machine where a
/// part says `kind = "mock"`.
fn open_machine(config: &Config, clock: SharedClock) -> Result<Machine> {
    Ok(if config.is_simulated() {
        layerwise::sim::open(config, clock)?.0
    } else {
        layerwise::hardware::open(config, clock)?
    })
}

/// Opens the machine and runs the daemon on it, with the page and the push to every `[[pacs]]`
/// beside it (threads of their own: capture and processing never wait for a page or an
/// archive). Those two outlive the capture loop: they stop once the run has returned (its frames
/// processed), with its reason.
fn run_daemon(config: &Config, mut options: RunOptions) -> Result<RunSummary> {
    let machine = open_machine(config, options.clock.clone())?;
    let after_run = Shutdown::new();
    let page = super::serve::start_for_daemon(config, options.clock.clone(), &after_run);
    let pusher = start_pusher(config, &options, &after_run)?;
    if let Some(pusher) = &pusher {
        // Each instance written is pushed at once (the poll stays as the fallback).
        let waker = pusher.waker();
        options.on_instance = Some(std::sync::Arc::new(move || waker.wake()));
    }
    let result = acquisition::run(config, machine, options);
    let reason = match &result {
        Ok(summary) => summary
            .stop_reason
            .clone()
            .unwrap_or(StopReason::TriggerEnded),
        Err(e) => StopReason::failure_of(e),
    };
    let next_build_starts = matches!(reason, StopReason::BuildStopped { .. });
    after_run.request(reason);
    if let Some(page) = page {
        page.join();
    }
    if let Some(pusher) = pusher {
        if next_build_starts {
            // The next build starts now; this one's push goes on beside it for its grace (its
            // queue is on disk: `layerwise push --build DIR` completes it after a restart).
            std::thread::spawn(move || pusher.join());
        } else {
            pusher.join();
        }
    }
    Ok(result?)
}

/// How long the push goes on after the build stops, to send what is still pending.
const PUSH_GRACE: std::time::Duration = std::time::Duration::from_secs(60);

fn start_pusher(
    config: &Config,
    options: &RunOptions,
    shutdown: &Shutdown,
) -> Result<Option<Pusher>> {
    if config.pacs.is_empty() {
        return Ok(None);
    }
    let destinations = config
        .pacs
        .iter()
        .map(Destination::from_config)
        .collect::<Result<Vec<_>, _>>()?;
    let dir = &config.build.output_dir;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let plan = PushPlan {
        poll: std::time::Duration::from_millis(500),
        shutdown: shutdown.clone(),
        grace: PUSH_GRACE,
    };
    Ok(Some(Pusher::start(
        dir,
        destinations,
        options.clock.clone(),
        plan,
    )?))
}

#[derive(Args)]
pub struct CheckArgs {
    /// The configuration file the daemon will run with.
    #[arg(long, default_value = "/etc/layerwise/layerwise.toml")]
    config: PathBuf,
    /// Keep the test shots here (`check_{light}.{ext}`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
}

impl CheckArgs {
    pub fn run(self) -> Result<()> {
        let config = Config::load(&self.config)?;
        acquisition::preflight(&config, &self.config)?;
        if let Some(out) = &self.out {
            std::fs::create_dir_all(out)
                .with_context(|| format!("cannot create {}", out.display()))?;
        }
        let clock = SystemClock::shared();
        let machine = open_machine(&config, clock.clone())?;
        let report = layerwise::acquisition::check::check_machine(
            &config,
            machine,
            clock,
            self.out.as_deref(),
        )?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{report}");
        }
        if !report.ok() {
            anyhow::bail!("a test shot failed (see above): fix it before the build");
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct CheckConfigArgs {
    /// The configuration file to check.
    file: PathBuf,
}

impl CheckConfigArgs {
    pub fn run(self) -> Result<()> {
        let config = Config::load(&self.file)?;
        // Every check `run` makes before touching the hardware, every file it names read.
        acquisition::preflight(&config, &self.file)?;
        let output = match &config.build.builds_dir {
            Some(builds) => format!("builds in {}", builds.display()),
            None => format!("output in {}", config.build.output_dir.display()),
        };
        if let Some(model) = &config.inspection.model {
            let live = layerwise::learn::live::LiveModel::open(model, &config.rectify)
                .context("[inspection.model] file")?;
            let h = &live.model.header;
            println!(
                "{}: model {:?} (validation accuracy {:.3}, macro recall {:.3}) runs on every layer",
                model.file.display(),
                h.classes,
                h.validation.accuracy,
                h.validation.macro_recall
            );
        }
        println!(
            "{}: valid ({} views per layer, {output})",
            self.file.display(),
            config.views.all().len(),
        );
        Ok(())
    }
}

#[derive(Args)]
pub struct StatusArgs {
    /// The build directory (the daemon's build.output_dir); by default the configuration's
    /// build (with `[build] builds_dir`: the builds, and the current or last one).
    #[arg(long)]
    build: Option<PathBuf>,
    /// The daemon's configuration, when --build is not given.
    #[arg(long, default_value = "/etc/layerwise/layerwise.toml")]
    config: PathBuf,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Warn when less than this much would be left free; by default the build's own
    /// `storage.min_free_gb` (from its config.toml snapshot).
    #[arg(long)]
    min_free_gb: Option<f64>,
}

impl StatusArgs {
    pub fn run(self) -> Result<()> {
        let build = match self.build {
            Some(build) => build,
            None => match self.configured_build()? {
                Some(build) => build,
                None => return Ok(()),
            },
        };
        let mut settings = build_report_settings(&build);
        match self.min_free_gb {
            Some(gb) if gb.is_finite() && gb >= 0.0 => settings.min_free_bytes = (gb * 1e9) as u64,
            Some(gb) => anyhow::bail!("--min-free-gb {gb}: expected a number of GB, 0 or more"),
            None => {}
        }
        let report = layerwise::build_dir::status::report(&build, settings)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            // PACS answers, alarm notes and reasons reach the terminal escaped.
            print!(
                "{}",
                layerwise::logging::printable_text(&report.to_string(), true)
            );
        }
        if !report.damaged.is_empty() {
            anyhow::bail!(
                "{} of the build's files cannot be read ({}): what they hold may be missing \
                 above; keep a copy, then repair or remove the damaged line or file",
                report.damaged.len(),
                if self.json {
                    "\"damaged\""
                } else {
                    "DAMAGED above"
                }
            );
        }
        Ok(())
    }
}

/// What the status report takes from the build's configuration snapshot (`storage.min_free_gb`,
/// `[series] take`); the defaults when there is none, or it cannot be read.
fn build_report_settings(build: &std::path::Path) -> layerwise::build_dir::status::ReportSettings {
    let snapshot = build.join(layerwise::build_dir::CONFIG_SNAPSHOT);
    let config = Config::load(&snapshot)
        .inspect_err(|e| {
            if snapshot.exists() {
                eprintln!(
                    "warning: {}; using the default storage.min_free_gb and [series] take",
                    layerwise::logging::Chain(e)
                );
            }
        })
        .ok();
    layerwise::series::report_settings(config.as_ref())
}

impl StatusArgs {
    /// The configuration's build: `build.output_dir`, or with `builds_dir` the current build
    /// (else the last one), after the list of builds (in text mode). None when there is none.
    fn configured_build(&self) -> Result<Option<PathBuf>> {
        use layerwise::build_dir::lifecycle;
        let config = Config::load(&self.config)?;
        let Some(builds) = &config.build.builds_dir else {
            return Ok(Some(config.build.output_dir));
        };
        let list = lifecycle::list(builds)?;
        if !self.json {
            println!("builds in {} (layerwise build list):", builds.display());
            for b in &list {
                let mark = if b.current { "*" } else { " " };
                println!("{mark} {}  {} frames, {}", b.folder, b.frames, b.state);
            }
        }
        let current = list.iter().find(|b| b.current).or(list.last());
        match current {
            Some(b) => {
                if !self.json {
                    println!();
                }
                Ok(Some(builds.join(&b.folder)))
            }
            None if self.json => anyhow::bail!(
                "no builds in {} yet: start one with `layerwise build start --name NAME`",
                builds.display()
            ),
            None => {
                println!("  none yet: start one with `layerwise build start --name NAME`");
                Ok(None)
            }
        }
    }
}

#[derive(Args)]
pub struct DemoArgs {
    /// Number of layers to simulate (1 to 99999).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=99_999))]
    layers: u32,
    /// The build directory to write (run again on it to resume).
    #[arg(long, default_value = "demo-build")]
    out: PathBuf,
    /// Serve the operator page at this host:port while the demo runs (e.g. 127.0.0.1:8040).
    #[arg(long)]
    listen: Option<String>,
    /// Time between layer signals in ms (0: as fast as the machine goes).
    #[arg(long, default_value_t = 0)]
    interval_ms: u64,
    /// Anomalies for the mock camera to render, comma-separated `kind@layer[..last][/key=value…]`:
    /// streak (y, from, to, w, c), short-feed (x, c), elevation (part, w, c), no-fusion (part),
    /// wide-fusion (part, d), spatter (n, r, x, y), drift (part, c: the post-scan grey level
    /// ramps to c over the layers); e.g. `streak@40,short-feed@75,elevation@90..95,drift@100..110`.
    #[arg(long, default_value = "")]
    inject: String,
    /// Lack-of-fusion pores in the box's CT in place of its two small ones (1 to 500; 20 layers
    /// or more): flat voids 1.1 to 1.9 mm across spread over the box's layers and positions (from
    /// --pore-seed), each seen by the camera as unfused powder in the post-scan frames of the
    /// layers it spans: CT-labelled patches to train on (`flaws`, then `learn train`).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=500))]
    pores: Option<u32>,
    /// Seed of the places and sizes of the --pores pores.
    #[arg(long, default_value_t = 1, requires = "pores")]
    pore_seed: u64,
}

impl DemoArgs {
    pub fn run(self) -> Result<()> {
        let (layers, out) = (self.layers, self.out.as_path());
        let inject =
            layerwise::config::inspection::parse_injections(&self.inject).context("--inject")?;
        let pores = self.pores.map(|n| (n, self.pore_seed));
        if pores.is_some() && layers < layerwise::sim::demo::DEMO_CT_MIN_LAYERS {
            anyhow::bail!(
                "--pores needs --layers {} or more: the box must be tall enough for pores with material around them",
                layerwise::sim::demo::DEMO_CT_MIN_LAYERS
            );
        }
        let mut config = demo_config(layers, out, pores)?;
        if let CameraConfig::Mock(mock) = &mut config.camera {
            mock.inject = inject;
        }
        if let TriggerConfig::Mock(mock) = &mut config.trigger {
            mock.interval_ms = self.interval_ms;
        }
        let process = Shutdown::new();
        let _signals =
            shutdown::watch_signals(&process).context("cannot watch SIGTERM and SIGINT")?;
        // With --listen the demo serves its page itself: a busy port is an error before the
        // build starts (as `serve`), and the page stays after the last layer until Ctrl-C.
        let page = match self.listen {
            Some(listen) => {
                let mut web = config.web.clone();
                web.listen = listen;
                let page = super::serve::start_page(out, &web, &process)?;
                println!("operator page: http://{}/", page.addr);
                Some(page)
            }
            None => None,
        };
        config.web.listen = String::new();
        let started = std::time::Instant::now();
        let plant = PlantRunning::start(&config);
        let mut options = RunOptions::new();
        options.clock = SystemClock::shared();
        options.drain_at_end = true;
        options.shutdown = process.child();
        options.plant = plant.sink.clone();
        let summary = run_daemon(&config, options);
        plant.stop(&process);
        let summary = summary?;
        println!(
            "demo build of {layers} layers in {:.1} s: {} frames stored, {} missing, {} already there; see {}",
            started.elapsed().as_secs_f64(),
            summary.stored,
            summary.missing,
            summary.skipped,
            out.display()
        );
        println!(
            "status: {} --build {}",
            own_command("status"),
            out.display()
        );
        if let Some(page) = page {
            if !process.is_requested() {
                println!(
                    "the page stays at http://{}/ until Ctrl-C (or SIGTERM)",
                    page.addr
                );
                let _ = process.receiver().recv();
            }
            page.join();
        }
        Ok(())
    }
}

/// How to run this program's `command` from where it was started: `layerwise status` when this
/// executable is the one on the PATH, `cargo run [--release] -- status` under `cargo run`, else
/// the executable's full path (a copy in target/ run by hand).
fn own_command(command: &str) -> String {
    let Ok(exe) = std::env::current_exe() else {
        return format!("layerwise {command}");
    };
    let on_path = std::env::var_os("PATH").is_some_and(|path| {
        std::env::split_paths(&path)
            .any(|dir| std::fs::canonicalize(dir.join("layerwise")).is_ok_and(|found| found == exe))
    });
    if on_path {
        return format!("layerwise {command}");
    }
    // Under `cargo run` cargo itself is the parent.
    let parent = std::fs::read_to_string(format!(
        "/proc/{}/comm",
        std::os::unix::process::parent_id()
    ));
    if parent.is_ok_and(|name| name.trim() == "cargo") {
        let release = exe.components().any(|c| c.as_os_str() == "release");
        return format!(
            "cargo run {}-- {command}",
            if release { "--release " } else { "" }
        );
    }
    format!("{} {command}", exe.display())
}

/// The embedded demo configuration for `layers` layers in `out`, with the simulated camera's
/// true homography written as the calibration, so the demo writes rectified DICOM series like a
/// calibrated machine does. The build directory also gets the parts' vector file (the build's
/// `vectors`) and a points file of four clicks, to try `register images` on (docs/tutorial.md).
fn demo_config(layers: u32, out: &Path, pores: Option<(u32, u64)>) -> Result<Config> {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("<embedded demo.toml>"))?;
    config.build.output_dir = out.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    if let CameraConfig::Mock(mock) = &mut config.camera {
        use layerwise::sim::demo;
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        // The parts the mock camera prints, as the build's vector file: the inspection checks
        // each layer's fusion against it, and the tutorial (docs/tutorial.md) registers to it.
        let vectors_path = std::fs::canonicalize(out)
            .with_context(|| format!("cannot resolve {}", out.display()))?
            .join(demo::DEMO_VECTORS);
        layerwise::sim::inject::write_demo_vectors(&vectors_path, layers.max(1))
            .with_context(|| format!("cannot write {}", vectors_path.display()))?;
        config.build.vectors = Some(vectors_path);
        layerwise::fsutil::write_atomic(
            &out.join(demo::DEMO_POINTS),
            demo::demo_points(mock.width, mock.height).as_bytes(),
            true,
        )?;
        // A CT of the box with two pores (or --pores), for `register ct`, `flaws` and
        // `locate --ct`; the camera sees the --pores ones.
        match demo::write_demo_ct(out, layers, pores)? {
            Some(ct) if pores.is_some() => mock.unfused = ct.unfused_spots(),
            Some(_) => {}
            None if pores.is_some() => anyhow::bail!(
                "--pores {}: that many pores do not fit apart in the box of {layers} layers; give more layers or fewer pores",
                pores.map_or(0, |p| p.0)
            ),
            None => tracing::info!(
                "no demo CT: it needs at least {} layers (the box must be tall enough for pores)",
                demo::DEMO_CT_MIN_LAYERS
            ),
        }
        let truth = mock_camera::Homography::oblique_view(mock.width, mock.height);
        let mut fit = toml::Table::new();
        fit.insert(
            "source".into(),
            "ground truth of the simulated camera (mock_camera::Homography::oblique_view)".into(),
        );
        let calibration = layerwise::rectify::Calibration {
            build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
            distortion: None,
            grid: None,
            fit: Some(fit),
        };
        let path = out.join("calibration.toml");
        layerwise::fsutil::write_atomic(&path, calibration.to_toml().as_bytes(), true)?;
        config.calibration.file = Some(path);
    }
    Ok(config)
}
