//! The daemon's commands: `run`, `check-config`, `status` and `demo`. This is the composition
//! root: it picks the simulated machine (`sim`) where the configuration says `kind = "mock"` and
//! the real hardware elsewhere; the library's daemon sees only the traits.

use super::runtime;
use anyhow::{Context, Result};
use clap::Args;
use layerwise::acquisition::{self, RunOptions, RunSummary};
use layerwise::clock::{SharedClock, SystemClock};
use layerwise::config::{CameraConfig, Config, TriggerConfig, DEMO_CONFIG};
use layerwise::hardware::Machine;
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
        config.check_backends(&self.config)?;
        let mut options = RunOptions::new();
        options.notify_systemd = true;
        options.drain_at_end = true;
        let summary = run_daemon(&config, options)?;
        println!(
            "stopped ({}): {} frames stored, {} missing",
            summary.stop_reason, summary.stored, summary.missing
        );
        Ok(())
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

/// Opens the machine and runs the daemon on it.
fn run_daemon(config: &Config, options: RunOptions) -> Result<RunSummary> {
    let machine = open_machine(config, options.clock.clone())?;
    Ok(runtime()?.block_on(acquisition::run(config, machine, options))?)
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
        config.check_backends(&self.config)?;
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
        config.check_backends(&self.file)?;
        println!(
            "{}: valid ({} views per layer, output in {})",
            self.file.display(),
            config.views.all().len(),
            config.build.output_dir.display()
        );
        Ok(())
    }
}

#[derive(Args)]
pub struct StatusArgs {
    /// The build directory (the daemon's build.output_dir).
    #[arg(long)]
    build: PathBuf,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Warn when less than this much would be left free.
    #[arg(long, default_value_t = 20.0)]
    min_free_gb: f64,
}

impl StatusArgs {
    pub fn run(self) -> Result<()> {
        let report =
            layerwise::build_dir::status::report(&self.build, (self.min_free_gb * 1e9) as u64)?;
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print!("{report}");
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct DemoArgs {
    /// Number of layers to simulate.
    #[arg(long, default_value_t = 20)]
    layers: u32,
    /// The build directory to write (run again on it to resume).
    #[arg(long, default_value = "demo-build")]
    out: PathBuf,
    /// Anomalies for the mock camera to render, comma-separated `kind@layer[..last][/key=value…]`:
    /// streak (y, from, to, w, c), short-feed (x, c), elevation (part, w, c), no-fusion (part),
    /// wide-fusion (part, d), spatter (n, r, x, y); e.g. `streak@40,short-feed@75,elevation@90..95`.
    #[arg(long, default_value = "")]
    inject: String,
}

impl DemoArgs {
    pub fn run(self) -> Result<()> {
        let (layers, out) = (self.layers, self.out.as_path());
        let inject = layerwise::config::inspection::parse_injections(&self.inject)
            .map_err(|e| anyhow::anyhow!("--inject: {e}"))?;
        let mut config = demo_config(layers, out)?;
        if let CameraConfig::Mock(mock) = &mut config.camera {
            mock.inject = inject;
        }
        let started = std::time::Instant::now();
        let mut options = RunOptions::new();
        options.clock = SystemClock::shared();
        options.drain_at_end = true;
        let summary = run_daemon(&config, options)?;
        println!(
            "demo build of {layers} layers in {:.1} s: {} frames stored, {} missing, {} already there; see {}",
            started.elapsed().as_secs_f64(),
            summary.stored,
            summary.missing,
            summary.skipped,
            out.display()
        );
        println!("status: layerwise status --build {}", out.display());
        Ok(())
    }
}

/// The embedded demo configuration for `layers` layers in `out`, with the simulated camera's
/// true homography written as the calibration, so the demo writes rectified DICOM series like a
/// calibrated machine does.
fn demo_config(layers: u32, out: &Path) -> Result<Config> {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("<embedded demo.toml>"))?;
    config.build.output_dir = out.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    if let CameraConfig::Mock(mock) = &config.camera {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        let truth = mock_camera::Homography::oblique_view(mock.width, mock.height);
        let mut fit = toml::Table::new();
        fit.insert(
            "source".into(),
            "ground truth of the simulated camera (mock_camera::Homography::oblique_view)".into(),
        );
        let calibration = layerwise::rectify::Calibration {
            build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
            distortion: None,
            grid: Some(config.rectify),
            fit: Some(fit),
        };
        let path = out.join("calibration.toml");
        layerwise::fsutil::write_atomic(&path, calibration.to_toml().as_bytes(), true)?;
        config.calibration.file = Some(path);
        // The parts the mock camera prints, as the build's vector file: the inspection checks
        // each layer's fusion against it.
        let vectors = out.join("demo-vectors.cli");
        layerwise::sim::inject::write_demo_vectors(&vectors, layers.max(1))
            .with_context(|| format!("cannot write {}", vectors.display()))?;
        config.build.vectors = Some(vectors);
    }
    Ok(config)
}
