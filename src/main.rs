//! The `layerwise` command: parses arguments and calls the library.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use layerwise::acquisition::{self, status, RunOptions};
use layerwise::config::{Config, TriggerConfig, DEMO_CONFIG};
use layerwise::calibrate::{
    register_images, DistortionChoice, ImageRegistration, RegistrationImage, RegistrationOptions,
};
use std::path::{Path, PathBuf};

#[derive(Parser)]
#[command(
    name = "layerwise",
    version,
    about = "Layer-wise imaging of powder bed fusion builds, registered to the laser vectors and CT"
)]
struct Cli {
    /// More log detail.
    #[arg(short, long, global = true)]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the acquisition daemon (what the systemd service runs).
    Run {
        #[arg(long, default_value = "/etc/layerwise/layerwise.toml")]
        config: PathBuf,
    },
    /// Validate a configuration file without touching any hardware.
    CheckConfig { file: PathBuf },
    /// Where a build stands: layer, frames, missing frames, processing, disk.
    Status {
        #[arg(long)]
        build: PathBuf,
        /// One JSON object instead of text.
        #[arg(long)]
        json: bool,
        /// Warn when less than this much would be left free.
        #[arg(long, default_value_t = 20.0)]
        min_free_gb: f64,
    },
    /// Laser scan vector files (CLI, ASCII or binary).
    Vectors {
        #[command(subcommand)]
        command: VectorsCommand,
    },
    /// Rectify one camera frame to the top-down build grid through a calibration.
    Rectify {
        #[arg(long)]
        calibration: PathBuf,
        #[arg(long)]
        image: PathBuf,
        /// OUT.png keeps colour; OUT.dcm holds luma as a CT Image slice.
        #[arg(long)]
        out: PathBuf,
        /// The layer (DICOM InstanceNumber; z = layer x layer thickness).
        #[arg(long, default_value_t = 1)]
        layer: u32,
        #[arg(long, default_value_t = 0.03)]
        layer_thickness_mm: f64,
    },
    /// Plan the camera: magnification, resolution, depth of field (paper eq. 1-4) and the
    /// Scheimpflug lens tilt that puts the plane of focus on the plate.
    Optics {
        #[arg(long, default_value_t = 45.0)]
        focal_mm: f64,
        #[arg(long, default_value_t = 32.0)]
        f_number: f64,
        #[arg(long, default_value_t = 4.88)]
        pixel_um: f64,
        #[arg(long, default_value = "7360x4912")]
        sensor: String,
        /// Object distance from the lens to the plate's center, along the optical axis.
        #[arg(long)]
        distance_mm: f64,
        /// Optical axis off the plate normal.
        #[arg(long, default_value_t = 30.0)]
        angle_deg: f64,
        #[arg(long, default_value_t = 275.0)]
        plate_mm: f64,
        #[arg(long)]
        json: bool,
        /// Draw the paper's Fig. 3 and 4 (without and with tilt).
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Export a build as series of one study on one grid (DICOM, or NRRD for 3D Slicer / napari).
    Export {
        #[arg(long)]
        build: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// Crop every series to this part (needs the build's vector file) plus --margin-mm.
        #[arg(long)]
        part: Option<i64>,
        #[arg(long, default_value_t = 5.0)]
        margin_mm: f64,
        #[arg(long, value_enum, default_value = "dicom")]
        format: layerwise::export::ExportFormat,
        /// ct.toml from `layerwise register ct`: the CT joins the study, resampled onto the grid.
        #[arg(long)]
        ct: Option<PathBuf>,
    },
    /// Where a build point is: its layer, its pixel in each rectified view and in each original frame.
    Locate {
        #[arg(long)]
        build: PathBuf,
        /// x,y,z in build mm.
        #[arg(
            long,
            value_delimiter = ',',
            allow_hyphen_values = true,
            required_unless_present = "ct_point"
        )]
        point: Vec<f64>,
        /// x,y,z in CT mm (needs --ct).
        #[arg(
            long,
            value_delimiter = ',',
            allow_hyphen_values = true,
            conflicts_with = "point",
            requires = "ct"
        )]
        ct_point: Vec<f64>,
        /// ct.toml from `layerwise register ct`: also where the point is in the CT.
        #[arg(long)]
        ct: Option<PathBuf>,
        #[arg(long)]
        json: bool,
        /// Draw the point in each view, side by side.
        #[arg(long)]
        mark: Option<PathBuf>,
    },
    /// DICOM series of a build.
    Dicom {
        #[command(subcommand)]
        command: DicomCommand,
    },
    /// Registration of build images (and, later, CT) to the laser vectors.
    Register {
        #[command(subcommand)]
        command: RegisterCommand,
    },
    /// A whole simulated build: mock trigger, mock lights, mock camera, the real storage path.
    Demo {
        #[arg(long, default_value_t = 20)]
        layers: u32,
        #[arg(long, default_value = "demo-build")]
        out: PathBuf,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum Lens {
    /// A homography only.
    None,
    /// Radial k1, k2 about the image center, fitted with the homography.
    Radial,
}

#[derive(Subcommand)]
enum RegisterCommand {
    /// Register a post-build CT volume to the laser vectors (paper §3.2) and write ct.toml
    /// (CT physical mm → build mm) with the Table 2 error figures.
    Ct {
        #[arg(long)]
        vectors: PathBuf,
        /// A DICOM series folder, a phoenix .pcr/.vol, a VGStudio .vgi, a raw volume (with --size,
        /// --dtype, --voxel-mm) or a TIFF stack folder (with --voxel-mm).
        #[arg(long)]
        ct: PathBuf,
        #[arg(long)]
        part: Option<i64>,
        /// Start from ≥ 3 point pairs `cx cy cz bx by bz`; default: centroids with R = I.
        #[arg(long)]
        init: Option<PathBuf>,
        #[arg(long)]
        out: PathBuf,
        /// The CT surface points coloured by signed distance (blue subtractive, red additive).
        #[arg(long)]
        surface_ply: Option<PathBuf>,
        /// The CT resampled onto the build grid as a DICOM series.
        #[arg(long)]
        resample_dicom: Option<PathBuf>,
        /// The build whose study the resampled series joins.
        #[arg(long)]
        build: Option<PathBuf>,
        #[arg(long)]
        voxel_mm: Option<f64>,
        /// Raw volumes: X,Y,Z voxels.
        #[arg(long)]
        size: Option<String>,
        /// Raw volumes: u8, u16 or f32.
        #[arg(long)]
        dtype: Option<String>,
        /// A fixed threshold (physical units); default Otsu.
        #[arg(long)]
        threshold: Option<f64>,
        /// Huber loss with this k (mm), against CT reflections.
        #[arg(long)]
        huber_mm: Option<f64>,
        /// Voxel size of the vectors' signed distance volume.
        #[arg(long, default_value_t = 0.05)]
        tsdf_voxel_mm: f64,
    },
    /// Refine the camera → build-plate homography against the laser vectors (paper §3.1) and
    /// write the calibration the daemon reads.
    Images {
        /// The laser scan vector file (CLI).
        #[arg(long)]
        vectors: PathBuf,
        /// Layer shown by the image (0-based index in the file); one for all images or one per
        /// --image, in order.
        #[arg(long, required = true)]
        layer: Vec<usize>,
        /// Post-scan frame(s) from the camera pose to calibrate; several are fitted jointly.
        #[arg(long, required = true)]
        image: Vec<PathBuf>,
        /// Start points: lines `u v x y` (image px, build mm), at least 4.
        #[arg(long)]
        init: PathBuf,
        /// Where to write calibration.toml.
        #[arg(long)]
        out: PathBuf,
        /// Also draw the contours through the start (red) and result (blue) on the first image.
        #[arg(long)]
        overlay: Option<PathBuf>,
        #[arg(long, value_enum, default_value = "none")]
        distortion: Lens,
        /// Focal length in pixels for --distortion radial (default 1.25 x image width).
        #[arg(long)]
        focal_px: Option<f64>,
        /// Pyramid levels (default from the exemplar size).
        #[arg(long)]
        levels: Option<usize>,
        /// Std filter window of the exemplar, pixels (odd).
        #[arg(long, default_value_t = 11)]
        std_window: usize,
    },
}

#[derive(Subcommand)]
enum VectorsCommand {
    /// Rasterize one layer onto the build grid (docs/frames.md): the fused-area mask, the
    /// anti-aliased coverage, the RGB picture (contours blue, hatches red) or the exemplar.
    Raster {
        file: PathBuf,
        /// Layer index in the file, from 0.
        #[arg(long)]
        layer: usize,
        /// mask | coverage | rgb | exemplar
        #[arg(long, default_value = "mask")]
        kind: String,
        #[arg(long)]
        out: PathBuf,
        /// Only this part, on a grid around it (2 mm margin, 62.5 µm).
        #[arg(long)]
        part: Option<i64>,
    },
    /// Format, units, layers, z range, parts and counts of a CLI file.
    Info {
        file: PathBuf,
        /// One JSON object for scripts.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum DicomCommand {
    /// Series, slices, z range and geometry of the DICOM files below DIR.
    Info {
        dir: PathBuf,
        #[arg(long)]
        json: bool,
    },
}

fn main() {
    // Like other command-line tools: `layerwise dicom info DIR | head` ends quietly.
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    layerwise::logging::init(cli.verbose);
    if let Err(e) = dispatch(cli.command) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

fn dispatch(command: Command) -> Result<()> {
    match command {
        Command::Run { config } => {
            let config = Config::load(&config)?;
            let mut options = RunOptions::new();
            options.notify_systemd = true;
            options.drain_at_end = true;
            let summary = runtime()?.block_on(acquisition::run(&config, options))?;
            println!(
                "stopped ({}): {} frames stored, {} missing",
                summary.stop_reason, summary.stored, summary.missing
            );
        }
        Command::CheckConfig { file } => {
            let config = Config::load(&file)?;
            println!(
                "{}: valid ({} views per layer, output in {})",
                file.display(),
                config.views.all().len(),
                config.build.output_dir.display()
            );
        }
        Command::Status {
            build,
            json,
            min_free_gb,
        } => {
            let report = status::report(&build, (min_free_gb * 1e9) as u64)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{report}");
            }
        }
        Command::Register {
            command:
                RegisterCommand::Ct {
                    vectors,
                    ct,
                    part,
                    init,
                    out,
                    surface_ply,
                    resample_dicom,
                    build,
                    voxel_mm,
                    size,
                    dtype,
                    threshold,
                    huber_mm,
                    tsdf_voxel_mm,
                },
        } => {
            use layerwise::ct;
            let (size_arg, dtype_arg) = (size.clone(), dtype.clone());
            let source = match (size, dtype) {
                (Some(size), Some(dtype)) => {
                    let voxel =
                        voxel_mm.ok_or_else(|| anyhow::anyhow!("a raw volume needs --voxel-mm"))?;
                    ct::volume::VolumeSource::Raw(
                        ct.clone(),
                        ct::volume::RawSpec::from_args(&size, voxel, &dtype)?,
                    )
                }
                (None, None) => ct::volume::VolumeSource::detect(&ct, voxel_mm)?,
                _ => anyhow::bail!("--size and --dtype go together (a raw volume)"),
            };
            let volume = ct::volume::read_volume(&source)?;
            let mut params = ct::CtParams::default();
            if let Some(v) = threshold {
                params.threshold = ct::surface::Threshold::Value(v);
            }
            params.huber_k_mm = huber_mm;
            let init = match init {
                Some(points) => ct::InitialTransform::Points(ct::align::read_points_file(&points)?),
                None => ct::InitialTransform::Centroid,
            };
            let recorded = ct::CtSource {
                path: std::fs::canonicalize(&ct)
                    .unwrap_or(ct.clone())
                    .display()
                    .to_string(),
                voxel_mm,
                size: size_arg,
                dtype: dtype_arg,
            };
            let request = ct::vectors_field::CtRequest {
                source: recorded,
                vectors,
                part,
                init,
                out: out.clone(),
                surface_ply,
                resample_dicom,
                build,
                tsdf_voxel_mm,
                params,
            };
            let started = std::time::Instant::now();
            let result =
                ct::vectors_field::register_ct(&request, &volume).map_err(anyhow::Error::msg)?;
            print!("{}", result.to_toml_string());
            println!(
                "wrote {} in {:.1} s",
                out.display(),
                started.elapsed().as_secs_f64()
            );
        }
        Command::Register {
            command:
                RegisterCommand::Images {
                    vectors,
                    layer,
                    image,
                    init,
                    out,
                    overlay,
                    distortion,
                    focal_px,
                    levels,
                    std_window,
                },
        } => {
            let layers = match (layer.len(), image.len()) {
                (1, n) => vec![layer[0]; n],
                (a, b) if a == b => layer,
                (a, b) => anyhow::bail!("{a} --layer for {b} --image: give one, or one per image"),
            };
            let mut options = RegistrationOptions {
                std_window,
                ..RegistrationOptions::default()
            };
            options.lm.levels = levels;
            let request = ImageRegistration {
                vectors,
                images: image
                    .into_iter()
                    .zip(layers)
                    .map(|(path, layer)| RegistrationImage { path, layer })
                    .collect(),
                init_points: init,
                out: Some(out.clone()),
                overlay,
                distortion: match distortion {
                    Lens::None => DistortionChoice::None,
                    Lens::Radial => DistortionChoice::Radial { focal_px },
                },
                options,
            };
            let report = register_images(&request)?;
            for l in &report.levels {
                println!(
                    "level {} ({}x{}): {} iterations, cost {:.4e} -> {:.4e}, last step {:.1e} px, {}",
                    l.level,
                    l.width,
                    l.height,
                    l.iterations,
                    l.initial_cost,
                    l.final_cost,
                    l.last_step_px,
                    l.termination.name()
                );
            }
            for i in &report.images {
                println!(
                    "{} (layer {}): correlation {:.4} (start {:.4})",
                    i.name, i.layer, i.fit.correlation, i.fit.initial_correlation
                );
            }
            let h = report.calibration.homography;
            println!("homography = {h:?}");
            if let Some(d) = report.calibration.distortion {
                println!("distortion: k1 = {:.6}, k2 = {:.6}", d.k1, d.k2);
            }
            println!("wrote {} in {:.2} s", out.display(), report.seconds);
        }
        Command::Demo { layers, out } => demo(layers, &out)?,
        Command::Export {
            build,
            out,
            part,
            margin_mm,
            format,
            ct,
        } => {
            let request = layerwise::export::ExportRequest {
                build,
                out,
                part,
                margin_mm,
                format,
                ct,
                progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
            };
            let summary = layerwise::export::export(&request)?;
            for (name, slices) in &summary.series {
                println!("{name:<24} {slices} slices");
            }
            println!(
                "{} x {} px at {} mm; {} written, {} already there, in {}",
                summary.columns,
                summary.rows,
                summary.grid[4],
                summary.written,
                summary.unchanged,
                summary.out.display()
            );
        }
        Command::Locate {
            build,
            point,
            ct_point,
            ct,
            json,
            mark,
        } => {
            let three = |v: Vec<f64>, flag: &str| -> Result<[f64; 3]> {
                v.try_into()
                    .map_err(|_| anyhow::anyhow!("{flag} takes x,y,z in mm"))
            };
            let frame = ct
                .as_deref()
                .map(layerwise::export::CtFrame::open)
                .transpose()?;
            let point = match &frame {
                Some(frame) if !ct_point.is_empty() => {
                    frame.to_build(three(ct_point, "--ct-point")?)
                }
                _ => three(point, "--point")?,
            };
            let record = layerwise::export::BuildRecord::open(&build)?;
            let mut location = layerwise::export::locate(&record, point)?;
            location.ct = frame.map(|f| f.locate(point));
            if let Some(out) = mark {
                layerwise::export::mark(&record, &location, &out)?;
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&location)?);
            } else {
                print!("{location}");
            }
        }
        Command::Optics {
            focal_mm,
            f_number,
            pixel_um,
            sensor,
            distance_mm,
            angle_deg,
            plate_mm,
            json,
            plot,
        } => {
            use layerwise::optics;
            let input = optics::OpticsInput {
                focal_mm,
                f_number,
                pixel_um,
                sensor_px: optics::parse_sensor(&sensor)?,
                distance_mm,
                angle_deg,
                plate_mm,
            };
            let report = optics::plan(&input)?;
            if let Some(path) = plot {
                std::fs::write(&path, optics::plot_svg(&input, &report))
                    .with_context(|| format!("cannot write {}", path.display()))?;
            }
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                println!("{}", report.to_string().trim_end());
            }
        }
        Command::Rectify {
            calibration,
            image,
            out,
            layer,
            layer_thickness_mm,
        } => {
            let started = std::time::Instant::now();
            let grid = layerwise::rectify::rectify_file(
                &calibration,
                &image,
                &out,
                layer,
                layer_thickness_mm,
            )?;
            println!(
                "{} -> {} ({} x {} px at {} mm) in {:.0} ms",
                image.display(),
                out.display(),
                grid.columns(),
                grid.rows(),
                grid.pixel_mm,
                started.elapsed().as_secs_f64() * 1e3
            );
        }
        Command::Dicom {
            command: DicomCommand::Info { dir, json },
        } => {
            let series = layerwise::dicom::series_info(&dir)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&series)?);
            } else {
                if series.is_empty() {
                    println!("no DICOM files below {}", dir.display());
                }
                for s in &series {
                    print!("{s}");
                }
            }
        }
        Command::Vectors {
            command:
                VectorsCommand::Raster {
                    file,
                    layer,
                    kind,
                    out,
                    part,
                },
        } => {
            use layerwise::raster;
            let kind: raster::RasterKind = kind.parse()?;
            let vectors = layerwise::vectors::read(&file)?;
            if layer >= vectors.layers.len() {
                anyhow::bail!(
                    "{}: no layer {layer}: the file has layers 0 to {}",
                    file.display(),
                    vectors.layers.len().saturating_sub(1)
                );
            }
            let grid = raster::default_grid(&vectors, part)?;
            raster::render_to_png(&vectors, layer, kind, &grid, part, &out)?;
            println!(
                "{} layer {layer} -> {} ({} x {} px at {} mm, x {} … {}, y {} … {})",
                file.display(),
                out.display(),
                grid.columns(),
                grid.rows(),
                grid.pixel_mm,
                grid.x_min,
                grid.x_max,
                grid.y_min,
                grid.y_max
            );
        }
        Command::Vectors {
            command: VectorsCommand::Info { file, json },
        } => {
            let info = layerwise::vectors::info(&file)?;
            if json {
                println!("{}", info.to_json());
            } else {
                print!("{info}");
            }
        }
    }
    Ok(())
}

fn demo(layers: u32, out: &Path) -> Result<()> {
    let mut config = Config::parse(DEMO_CONFIG, Path::new("<embedded demo.toml>"))?;
    config.build.output_dir = out.to_path_buf();
    config.build.layers = Some(layers);
    if let TriggerConfig::Mock(mock) = &mut config.trigger {
        mock.layers = layers;
    }
    // The simulated camera's true homography stands in for a calibration, so the demo writes
    // rectified DICOM series like a calibrated machine does.
    if let layerwise::config::CameraConfig::Mock(mock) = &config.camera {
        std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
        let truth = mock_camera::Homography::oblique_view(mock.width, mock.height);
        let mut fit = toml::Table::new();
        fit.insert(
            "source".into(),
            "ground truth of the simulated camera (mock_camera::Homography::oblique_view)".into(),
        );
        let calibration = layerwise::rectify::Calibration {
            homography: truth.m,
            distortion: None,
            grid: Some(config.rectify),
            fit: Some(fit),
        };
        let path = out.join("calibration.toml");
        std::fs::write(&path, calibration.to_toml())
            .with_context(|| format!("cannot write {}", path.display()))?;
        config.calibration.file = Some(path);
    }
    let started = std::time::Instant::now();
    let mut options = RunOptions::new();
    options.drain_at_end = true;
    let summary = runtime()?.block_on(acquisition::run(&config, options))?;
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
