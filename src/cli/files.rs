//! Commands on single files: vector files, one frame through a calibration, DICOM series, and
//! the optics planner.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum VectorsCommand {
    /// Rasterize one layer onto the build grid (docs/frames.md): the fused-area mask, the
    /// anti-aliased coverage, the RGB picture (contours blue, hatches red) or the exemplar.
    Raster(RasterArgs),
    /// Format, units, layers, z range, parts and counts of a CLI file.
    Info(VectorsInfoArgs),
}

impl VectorsCommand {
    pub fn run(self) -> Result<()> {
        match self {
            VectorsCommand::Raster(args) => args.run(),
            VectorsCommand::Info(args) => args.run(),
        }
    }
}

#[derive(Args)]
pub struct RasterArgs {
    /// The vector file (CLI, ASCII or binary).
    file: PathBuf,
    /// The printer layer (from 1, as in the frames' names); see --layer-match.
    #[arg(long)]
    layer: u32,
    #[command(flatten)]
    numbering: super::numbering::NumberingArgs,
    /// mask | coverage | rgb | exemplar
    #[arg(long, default_value = "mask")]
    kind: String,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
    /// Only this part, on a grid around it (2 mm margin, 62.5 µm).
    #[arg(long)]
    part: Option<i64>,
    /// On a grid around the file's geometry (2 mm margin, 62.5 µm) instead of the whole plate.
    #[arg(long, conflicts_with_all = ["config", "build"])]
    extent: bool,
    /// The configuration whose [rectify] grid to draw on (default: the built-in plate grid).
    #[arg(long, conflicts_with = "build")]
    config: Option<PathBuf>,
    /// A build directory: draw on its [rectify] grid, as its rectified views are.
    #[arg(long)]
    build: Option<PathBuf>,
}

impl RasterArgs {
    fn run(self) -> Result<()> {
        use layerwise::raster;
        let RasterArgs {
            file,
            layer,
            kind,
            out,
            part,
            numbering,
            extent,
            config,
            build,
        } = self;
        let kind: raster::RasterKind = kind.parse()?;
        let vectors = layerwise::vectors::read(&file)?;
        let map = layerwise::vectors::LayerMap::of_file(&vectors, numbering.numbering());
        let Some(position) = map.position(layer) else {
            anyhow::bail!(
                "{}: no vectors for printer layer {layer}: the file has {}",
                file.display(),
                map.describe()
            );
        };
        let grid = match (&config, &build) {
            _ if extent || part.is_some() => raster::default_grid(&vectors, part)?,
            (Some(path), _) => layerwise::config::Config::load(path)?.rectify,
            (None, Some(dir)) => layerwise::series::BuildRecord::open(dir)?.config.rectify,
            (None, None) => layerwise::geometry::Grid::default(),
        };
        raster::render_to_png(&vectors, position, kind, &grid, part, &out)?;
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
        Ok(())
    }
}

#[derive(Args)]
pub struct VectorsInfoArgs {
    /// The vector file (CLI, ASCII or binary).
    file: PathBuf,
    /// One JSON object for scripts.
    #[arg(long)]
    json: bool,
}

impl VectorsInfoArgs {
    fn run(self) -> Result<()> {
        let info = layerwise::vectors::info(&self.file)?;
        if self.json {
            println!("{}", info.to_json());
        } else {
            print!("{info}");
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct RectifyArgs {
    /// calibration.toml from `layerwise register images`.
    #[arg(long)]
    calibration: PathBuf,
    /// The camera frame (JPEG, or NEF with the `nef` feature).
    #[arg(long)]
    image: PathBuf,
    /// OUT.png keeps colour; OUT.dcm holds luma as a CT Image slice.
    #[arg(long)]
    out: PathBuf,
    /// The layer (DICOM InstanceNumber; z = layer x layer thickness).
    #[arg(long, default_value_t = 1, value_parser = super::values::layer)]
    layer: u32,
    /// Layer thickness in mm, for the slice's z.
    #[arg(long, default_value_t = 0.03, value_parser = super::values::layer_thickness_mm)]
    layer_thickness_mm: f64,
    /// The configuration whose [rectify] grid to use (default: the built-in plate grid).
    #[arg(long, conflicts_with = "build")]
    config: Option<PathBuf>,
    /// A build directory: its configuration's [rectify] grid, as its series use.
    #[arg(long)]
    build: Option<PathBuf>,
}

impl RectifyArgs {
    pub fn run(self) -> Result<()> {
        let started = std::time::Instant::now();
        let config = match (&self.config, &self.build) {
            (Some(path), _) => Some(layerwise::config::Config::load(path)?),
            (None, Some(dir)) => Some(layerwise::series::BuildRecord::open(dir)?.config),
            (None, None) => None,
        };
        let grid = config.map(|c| c.rectify).unwrap_or_default();
        let grid = layerwise::rectify::rectify_file(
            &self.calibration,
            &self.image,
            &self.out,
            self.layer,
            self.layer_thickness_mm,
            grid,
        )?;
        println!(
            "{} -> {} ({} x {} px at {} mm) in {:.0} ms",
            self.image.display(),
            self.out.display(),
            grid.columns(),
            grid.rows(),
            grid.pixel_mm,
            started.elapsed().as_secs_f64() * 1e3
        );
        Ok(())
    }
}

#[derive(Args)]
pub struct OpticsArgs {
    /// Lens focal length.
    #[arg(long, default_value_t = 45.0)]
    focal_mm: f64,
    /// Aperture (f-number).
    #[arg(long, default_value_t = 32.0)]
    f_number: f64,
    /// Sensor pixel pitch.
    #[arg(long, default_value_t = 4.88)]
    pixel_um: f64,
    /// Sensor size in pixels, WIDTHxHEIGHT.
    #[arg(long, default_value = "7360x4912")]
    sensor: String,
    /// Object distance from the lens to the plate's center, along the optical axis.
    #[arg(long)]
    distance_mm: f64,
    /// Optical axis off the plate normal.
    #[arg(long, default_value_t = 30.0)]
    angle_deg: f64,
    /// Side of the square build plate.
    #[arg(long, default_value_t = 275.0)]
    plate_mm: f64,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Draw the paper's Fig. 3 and 4 (without and with tilt).
    #[arg(long)]
    plot: Option<PathBuf>,
}

impl OpticsArgs {
    pub fn run(self) -> Result<()> {
        use layerwise::optics;
        let input = optics::OpticsInput {
            focal_mm: self.focal_mm,
            f_number: self.f_number,
            pixel_um: self.pixel_um,
            sensor_px: optics::parse_sensor(&self.sensor)?,
            distance_mm: self.distance_mm,
            angle_deg: self.angle_deg,
            plate_mm: self.plate_mm,
        };
        let report = optics::plan(&input)?;
        if let Some(path) = &self.plot {
            layerwise::fsutil::write_atomic(
                path,
                optics::plot_svg(&input, &report).as_bytes(),
                false,
            )
            .with_context(|| format!("cannot write the plot {}", path.display()))?;
        }
        if self.json {
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            println!("{}", report.to_string().trim_end());
        }
        Ok(())
    }
}

#[derive(Subcommand)]
pub enum DicomCommand {
    /// Series, slices, z range and geometry of the DICOM files below DIR.
    Info {
        /// The folder to search (e.g. a build's dicom/).
        dir: PathBuf,
        /// One JSON array instead of text.
        #[arg(long)]
        json: bool,
    },
}

impl DicomCommand {
    pub fn run(self) -> Result<()> {
        let DicomCommand::Info { dir, json } = self;
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
        let unsound = series.iter().filter(|s| !s.problems.is_empty()).count();
        if unsound > 0 {
            anyhow::bail!(
                "{unsound} of {} series have problems (PROBLEM above): their geometry or pixels \
                 cannot be trusted; fix or re-export them",
                series.len()
            );
        }
        Ok(())
    }
}
