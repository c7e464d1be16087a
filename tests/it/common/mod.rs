//! Shared helpers for the integration tests: configurations derived from the embedded demo.
#![allow(dead_code)]

pub mod pty;

use layerwise::build_dir::journal::{Journal, Record};
use layerwise::config::{CameraConfig, Config, MockFaultConfig, TriggerConfig, DEMO_CONFIG};

/// Runs the daemon on the simulated machine the configuration describes.
pub async fn run(
    config: &Config,
    options: layerwise::acquisition::RunOptions,
) -> Result<layerwise::acquisition::RunSummary, layerwise::acquisition::AcquisitionError> {
    run_with(config, options, |_, _| {}).await
}

/// As [`run`], letting the test change the machine (a scripted camera, its own trigger) and see
/// the simulation (the mock lights' log) before the daemon starts.
pub async fn run_with(
    config: &Config,
    options: layerwise::acquisition::RunOptions,
    adjust: impl FnOnce(&mut layerwise::hardware::Machine, &layerwise::sim::Simulation),
) -> Result<layerwise::acquisition::RunSummary, layerwise::acquisition::AcquisitionError> {
    let (mut machine, simulation) = layerwise::sim::open(config, options.clock.clone())?;
    adjust(&mut machine, &simulation);
    layerwise::acquisition::run(config, machine, options).await
}
use std::collections::BTreeMap;
use std::path::Path;

/// The demo configuration writing into `dir`, `layers` layers, a small sensor for speed.
pub fn demo_config(dir: &Path, layers: u32) -> Config {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml"))
        .expect("the embedded demo config is valid");
    config.build.output_dir = dir.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = 320;
        mock.height = 214;
    }
    // A test's build is a few MB: it must not pause its series on a CI disk with little room
    // (tests/disk.rs sets its own limits).
    config.storage.min_free_gb = 0.0;
    config
}

pub fn add_fault(
    config: &mut Config,
    fault: &str,
    layer: u32,
    phase: &str,
    light: &str,
    times: u32,
    millis: u64,
) {
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.faults.push(MockFaultConfig {
            layer,
            phase: phase.parse().expect("phase"),
            light: light.parse().expect("light"),
            fault: fault.to_string(),
            times,
            millis,
        });
    }
}

pub fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime")
}

/// All journal records of a build.
pub fn records(dir: &Path) -> Vec<Record> {
    let text = std::fs::read_to_string(dir.join("journal.jsonl")).expect("journal");
    text.lines()
        .map(|l| serde_json::from_str(l).expect("journal line"))
        .collect()
}

/// Frame records per file name: more than one would be a duplicate.
pub fn frame_records(dir: &Path) -> BTreeMap<String, usize> {
    let mut out = BTreeMap::new();
    for r in records(dir) {
        if let Record::Frame { file, .. } = r {
            *out.entry(file).or_insert(0) += 1;
        }
    }
    out
}

/// Original files in raw/ (not sidecars, not temporaries).
pub fn originals(dir: &Path) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir(dir.join("raw")) else {
        return Vec::new();
    };
    let mut out: Vec<String> = entries
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".jpg") || n.ends_with(".nef"))
        .map(|n| format!("raw/{n}"))
        .collect();
    out.sort();
    out
}

pub fn temporaries(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir.join("raw"))
        .expect("raw dir")
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

/// Every original's sidecar agrees with its bytes.
pub fn assert_sidecars_match(dir: &Path) {
    for file in originals(dir) {
        let data = std::fs::read(dir.join(&file)).expect("original");
        let sidecar = read_json(&dir.join(&file).with_extension("json"));
        assert_eq!(
            sidecar["sha256"],
            layerwise::fsutil::sha256_hex(&data),
            "{file}"
        );
        assert_eq!(sidecar["bytes"], data.len() as u64, "{file}");
    }
}

pub fn replay(dir: &Path) -> layerwise::build_dir::journal::Replay {
    Journal::read(&dir.join("journal.jsonl")).expect("journal replays")
}

/// Every expected original name for layers 1..=layers.
pub fn expected_originals(layers: u32) -> Vec<String> {
    let mut out = Vec::new();
    for layer in 1..=layers {
        for phase in ["pre", "post"] {
            for light in ["front", "side", "top"] {
                out.push(format!("raw/L{layer:05}_{phase}_{light}.jpg"));
            }
        }
    }
    out.sort();
    out
}

/// Writes a configuration as TOML for the binary.
pub fn write_config(config: &Config, path: &Path) {
    let text = toml::to_string(config).expect("config serialises");
    std::fs::write(path, text).expect("config written");
}

pub fn layerwise() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
}

/// Keys every `layerwise vectors info --json` summary has.
pub const VECTORS_INFO_KEYS: [&str; 12] = [
    "format",
    "units",
    "layers",
    "z_min",
    "z_max",
    "layer_thickness",
    "polylines",
    "points",
    "hatches",
    "parts",
    "declared_layers",
    "declared_dimension_mm",
];

/// The four real CLI files of shared/data/cli.
pub const REAL_CLI_FILES: [&str; 4] = [
    "s_Cylinder_ex.cli",
    "s_MiniCooper_ex.cli",
    "frustrum_ASCII.cli",
    "Box_support_solid_ascii_with_params.cli",
];

/// The folder of the real CLI files: `$LAYERWISE_SHARED_DATA` when that variable is set, else
/// `<CARGO_MANIFEST_DIR>/../shared/data/cli`.
pub fn shared_cli_dir() -> std::path::PathBuf {
    match std::env::var_os("LAYERWISE_SHARED_DATA") {
        Some(d) => std::path::PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/cli"),
    }
}

/// A real CLI file from shared/data/cli: `$LAYERWISE_SHARED_DATA/<name>` when that variable is
/// set, else `<CARGO_MANIFEST_DIR>/../shared/data/cli/<name>`. Fails when the file is missing.
pub fn shared_cli(name: &str) -> std::path::PathBuf {
    let path = shared_cli_dir().join(name);
    assert!(
        path.is_file(),
        "test data {} is missing: put shared/ beside the checkout or set LAYERWISE_SHARED_DATA",
        path.display()
    );
    path
}

/// A calibrated mock build: the mock camera's true homography as the calibration.
pub fn calibrated_config(
    dir: &Path,
    layers: u32,
    compression: layerwise::dicom::Compression,
) -> Config {
    let mut config = demo_config(dir, layers);
    config.rectify = plate_grid();
    config.storage.dicom = compression;
    let CameraConfig::Mock(mock) = &config.camera else {
        unreachable!("demo camera is the mock")
    };
    let truth = mock_camera::Homography::oblique_view(mock.width, mock.height);
    std::fs::create_dir_all(dir).unwrap();
    config.calibration.file = Some(write_true_calibration(dir, &truth));
    config
}

/// The whole 275 mm plate at 0.5 mm: 550 x 550 pixels, small enough for tests.
pub fn plate_grid() -> layerwise::rectify::Grid {
    layerwise::rectify::Grid {
        x_min: -137.5,
        x_max: 137.5,
        y_min: -137.5,
        y_max: 137.5,
        pixel_mm: 0.5,
    }
}

/// `dir/calibration.toml` holding the mock camera's true homography onto [`plate_grid`].
pub fn write_true_calibration(dir: &Path, truth: &mock_camera::Homography) -> std::path::PathBuf {
    let calibration = layerwise::rectify::Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(plate_grid()),
        fit: None,
    };
    let path = dir.join("calibration.toml");
    std::fs::write(&path, calibration.to_toml()).unwrap();
    path
}

/// A small oblique picture of the demo plate at layer 1 (top light, after the scan), a
/// calibration file holding its true homography, and a configuration whose [rectify] grid is
/// the plate at 0.5 mm: a 550×550 grid.
pub struct SmallView {
    pub renderer: mock_camera::Renderer,
    pub parts: Vec<mock_camera::Shape>,
    pub calibration: std::path::PathBuf,
    pub config: std::path::PathBuf,
}

impl SmallView {
    pub fn new(dir: &Path) -> Self {
        let (w, h) = (320, 214);
        let truth = mock_camera::Homography::oblique_view(w, h);
        let mut config = demo_config(&dir.join("build"), 1);
        config.rectify = plate_grid();
        let config_path = dir.join("small-view.toml");
        write_config(&config, &config_path);
        SmallView {
            calibration: write_true_calibration(dir, &truth),
            config: config_path,
            renderer: mock_camera::Renderer::new(w, h, truth),
            parts: mock_camera::demo_parts(1),
        }
    }

    fn scene(&self) -> mock_camera::Scene<'_> {
        mock_camera::Scene {
            layer: 1,
            fused: &self.parts,
            scanned: true,
            illumination: mock_camera::Illumination::Top,
        }
    }

    pub fn picture(&self) -> image::RgbImage {
        self.renderer.render(&self.scene())
    }

    pub fn jpeg(&self) -> Vec<u8> {
        self.renderer.render_jpeg(&self.scene(), 95)
    }

    /// `layerwise rectify` of one frame with this calibration.
    pub fn rectify(&self, image: &Path, out: &Path) -> std::process::Output {
        self.rectify_command(image, out).output().unwrap()
    }

    /// The `layerwise rectify` command of [`SmallView::rectify`], not started.
    pub fn rectify_command(&self, image: &Path, out: &Path) -> std::process::Command {
        let mut command = layerwise();
        command
            .arg("rectify")
            .arg("--calibration")
            .arg(&self.calibration)
            .arg("--config")
            .arg(&self.config)
            .arg("--image")
            .arg(image)
            .arg("--out")
            .arg(out);
        command
    }
}

/// What a finished command said, for failure messages: its exit code, stdout and stderr.
pub fn report(out: &std::process::Output) -> String {
    format!(
        "exit {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status.code(),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

/// Checks that a command exited 0, showing its output if not.
pub fn assert_success(out: &std::process::Output) {
    assert!(out.status.success(), "{}", report(out));
}

/// Checks that a command exited 1 (a refusal, not a crash or a success) and returns its stderr.
pub fn assert_exit_1(out: &std::process::Output) -> String {
    assert_eq!(out.status.code(), Some(1), "{}", report(out));
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Running a command to its end and checking how it ended; failures name the command line.
pub trait Run {
    /// Runs to the end, checks it exited 0 and returns the output.
    fn succeeds(&mut self) -> std::process::Output;
    /// Runs to the end, checks it exited 0 and returns its stdout as text.
    fn stdout_ok(&mut self) -> String {
        String::from_utf8_lossy(&self.succeeds().stdout).into_owned()
    }
    /// Runs to the end, checks it exited 0 and returns its stdout parsed as JSON.
    fn json_ok(&mut self) -> serde_json::Value {
        let out = self.succeeds();
        serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("stdout is not JSON ({e}): {}", report(&out)))
    }
    /// Runs to the end, checks it exited 1 and returns its stderr.
    fn fails(&mut self) -> String;
}

fn output_of(command: &mut std::process::Command) -> std::process::Output {
    command
        .output()
        .unwrap_or_else(|e| panic!("{command:?} did not start: {e}"))
}

impl Run for std::process::Command {
    fn succeeds(&mut self) -> std::process::Output {
        let out = output_of(self);
        assert!(out.status.success(), "{self:?}: {}", report(&out));
        out
    }

    fn fails(&mut self) -> String {
        let out = output_of(self);
        assert_eq!(out.status.code(), Some(1), "{self:?}: {}", report(&out));
        String::from_utf8_lossy(&out.stderr).into_owned()
    }
}

/// `layerwise run --config FILE`, not started.
pub fn run_command(config_path: &Path) -> std::process::Command {
    let mut command = layerwise();
    command.arg("run").arg("--config").arg(config_path);
    command
}

/// Runs `layerwise run --config FILE` to its end and checks it succeeded.
pub fn run_build(config_path: &Path) -> std::process::Output {
    run_command(config_path).succeeds()
}

/// Starts `layerwise run --config FILE` in the background, its stderr going to `stderr`.
pub fn spawn_build(config_path: &Path, stderr: std::process::Stdio) -> std::process::Child {
    run_command(config_path)
        .stderr(stderr)
        .spawn()
        .expect("layerwise run starts")
}

/// Sends SIGTERM to a running `layerwise` and waits for it to end.
pub fn terminate(child: std::process::Child) -> std::process::Output {
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    child.wait_with_output().unwrap()
}

/// Waits until `dir/raw` holds at least `at_least` originals, failing after `timeout`.
pub fn wait_for_originals(dir: &Path, at_least: usize, timeout: std::time::Duration) {
    let deadline = std::time::Instant::now() + timeout;
    while originals(dir).len() < at_least {
        assert!(
            std::time::Instant::now() < deadline,
            "only {} frames after {timeout:?}: {:?}",
            originals(dir).len(),
            originals(dir)
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// A JSON file (a sidecar, a manifest, status.json) parsed.
pub fn read_json(path: &Path) -> serde_json::Value {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A small deterministic generator (xorshift64*) for the robustness tests that mutate inputs.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// A number in 0..n (0 when n is 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// `status --json` of a build, polled until `ready` accepts it.
pub fn status_until(
    build: &std::path::Path,
    what: &str,
    ready: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        let out = layerwise()
            .args(["status", "--json", "--build"])
            .arg(build)
            .output()
            .unwrap();
        if out.status.success() {
            let status: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
            if ready(&status) {
                return status;
            }
        }
        assert!(
            std::time::Instant::now() < deadline,
            "status never showed {what}"
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}
