//! `register images` (camera → build plate, paper §3.1), `register points` (camera → build plate
//! from clicked points alone) and `register ct` (CT → build, §3.2).

use anyhow::{bail, Result};
use clap::{Args, Subcommand, ValueEnum};
use layerwise::calibrate::{
    register_images, DistortionChoice, ImageRegistration, RegistrationImage, RegistrationOptions,
};
use std::path::PathBuf;

#[derive(Subcommand)]
pub enum RegisterCommand {
    /// Register a post-build CT volume to the laser vectors (paper §3.2) and write ct.toml
    /// (CT physical mm → build mm) with the Table 2 error figures.
    Ct(CtArgs),
    /// Refine the camera → build-plate homography against the laser vectors (paper §3.1) and
    /// write the calibration the daemon reads.
    Images(ImagesArgs),
    /// A calibration from point correspondences alone (no vector file to refine against):
    /// the homography through at least four `u v x y` lines, each point's residual reported.
    Points(PointsArgs),
}

#[derive(Args)]
pub struct PointsArgs {
    /// Lines `u v x y` (image pixel column and row, build mm), at least 4 (more show residuals).
    #[arg(long)]
    points: PathBuf,
    /// Where to write calibration.toml.
    #[arg(long)]
    out: PathBuf,
    /// The laser scan vector file: the expected error is also reported at its parts' centres
    /// and between them.
    #[arg(long)]
    vectors: Option<PathBuf>,
    #[command(flatten)]
    spread: SpreadArgs,
}

/// Where the calibration's expected error is reported and when it warns.
#[derive(Args)]
pub struct SpreadArgs {
    /// The configuration whose plate ([rectify] grid) the corners are taken from (default: the
    /// whole 275 x 275 mm plate).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Warn when the calibration's expected error anywhere on the plate exceeds this, mm.
    #[arg(long, default_value_t = layerwise::calibrate::spread::DEFAULT_MAX_ERROR_MM, value_parser = super::values::max_error_mm)]
    max_error_mm: f64,
}

impl SpreadArgs {
    fn plate(&self) -> Result<layerwise::geometry::Grid> {
        Ok(match &self.config {
            Some(path) => layerwise::config::Config::load(path)?.rectify,
            None => layerwise::geometry::Grid::default(),
        })
    }
}

impl PointsArgs {
    fn run(self) -> Result<()> {
        let parts = match &self.vectors {
            Some(path) => layerwise::vectors::info(path)?
                .parts
                .iter()
                .filter_map(|p| {
                    let b = p.bbox?;
                    Some(layerwise::calibrate::PartCentre {
                        part: p.id,
                        centre: layerwise::geometry::BuildPoint::new(
                            0.5 * (b[0] + b[2]),
                            0.5 * (b[1] + b[3]),
                        ),
                    })
                })
                .collect(),
            None => Vec::new(),
        };
        let targets = layerwise::calibrate::SpreadTargets {
            plate: self.spread.plate()?,
            parts,
            max_error_mm: self.spread.max_error_mm,
        };
        let fit = layerwise::calibrate::calibrate_from_points(&self.points, &targets)?;
        println!("point   residual (mm)");
        for (line, d) in &fit.residuals {
            println!("line {line:<3} {d:>9.3}");
        }
        println!(
            "{} points: rms {:.3} mm, max {:.3} mm{}",
            fit.residuals.len(),
            fit.rms_mm,
            fit.max_mm,
            if fit.residuals.len() == 4 {
                " (4 points fix the homography exactly: add points to see how well it fits)"
            } else {
                ""
            }
        );
        if let Some(spread) = &fit.spread {
            print!("{spread}");
        }
        layerwise::fsutil::write_atomic(&self.out, fit.calibration.to_toml().as_bytes(), false)?;
        println!("wrote {}", self.out.display());
        Ok(())
    }
}

impl RegisterCommand {
    pub fn run(self) -> Result<()> {
        match self {
            RegisterCommand::Ct(args) => args.run(),
            RegisterCommand::Images(args) => args.run(),
            RegisterCommand::Points(args) => args.run(),
        }
    }
}

#[derive(Args)]
pub struct CtArgs {
    /// The laser scan vector file (CLI).
    #[arg(long)]
    vectors: PathBuf,
    /// A DICOM series folder, a phoenix .pcr/.vol, a VGStudio .vgi, a raw volume (with --size,
    /// --dtype, --voxel-mm) or a TIFF stack folder (with --voxel-mm).
    #[arg(long)]
    ct: PathBuf,
    /// Register to this part of the vector file only (its number in the file's $$LABEL).
    #[arg(long)]
    part: Option<i64>,
    /// Start from ≥ 3 point pairs `cx cy cz bx by bz`; default: centroids with R = I.
    #[arg(long)]
    init: Option<PathBuf>,
    /// Where to write ct.toml.
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
    #[command(flatten)]
    layout: RawLayoutArgs,
    /// A fixed threshold (physical units); default Otsu.
    #[arg(long)]
    threshold: Option<f64>,
    /// Huber loss with this k (mm), against CT reflections.
    #[arg(long)]
    huber_mm: Option<f64>,
    /// Voxel size of the vectors' signed distance volume.
    #[arg(long, default_value_t = 0.05)]
    tsdf_voxel_mm: f64,
    /// Largest CT read, in voxels (default 2 G, about 4 GB of 16-bit voxels): a bigger scan is
    /// refused from its header unless this lifts the cap (the machine needs the memory).
    #[arg(long, default_value_t = layerwise::ct::volume::MAX_VOXELS)]
    max_voxels: usize,
    /// The resampled series' layer numbers (with --build: the build's configuration decides).
    #[command(flatten)]
    numbering: super::numbering::NumberingArgs,
}

/// How to read a CT file that does not say it itself (raw volumes, TIFF stacks).
#[derive(Args)]
pub struct RawLayoutArgs {
    /// Voxel size in mm (raw volumes and TIFF stacks).
    #[arg(long)]
    voxel_mm: Option<f64>,
    /// Raw volumes: X,Y,Z voxels.
    #[arg(long)]
    size: Option<String>,
    /// Raw volumes: u8, u16 or f32.
    #[arg(long)]
    dtype: Option<String>,
}

impl RawLayoutArgs {
    /// The CT at `path` with this layout, as ct.toml records it (the path made absolute).
    pub fn source(self, path: &std::path::Path) -> Result<layerwise::ct::CtSource> {
        match (&self.size, &self.dtype, self.voxel_mm) {
            (Some(_), Some(_), None) => bail!("a raw volume needs --voxel-mm"),
            (Some(_), None, _) | (None, Some(_), _) => {
                bail!("--size and --dtype go together (a raw volume)")
            }
            _ => {}
        }
        Ok(layerwise::ct::CtSource {
            path: std::fs::canonicalize(path)
                .unwrap_or(path.to_path_buf())
                .display()
                .to_string(),
            voxel_mm: self.voxel_mm,
            size: self.size,
            dtype: self.dtype,
        })
    }
}

impl CtArgs {
    fn run(self) -> Result<()> {
        use layerwise::ct;
        // The small file first: a bad point is refused before the CT is read.
        let init = match &self.init {
            Some(points) => ct::InitialTransform::Points(ct::align::read_points_file(points)?),
            None => ct::InitialTransform::Centroid,
        };
        let recorded = self.layout.source(&self.ct)?;
        let volume = recorded.read_capped(self.max_voxels)?;
        let mut params = ct::CtParams::default();
        if let Some(v) = self.threshold {
            params.threshold = ct::surface::Threshold::Value(v);
        }
        params.huber_k_mm = self.huber_mm;
        let out = self.out.clone();
        let numbering = match &self.build {
            Some(build) => layerwise::series::BuildRecord::open(build)?
                .config
                .build
                .numbering(),
            None => self.numbering.numbering(),
        };
        let (ply, resampled) = (self.surface_ply.clone(), self.resample_dicom.clone());
        let request = ct::CtRequest {
            numbering,
            source: recorded,
            vectors: self.vectors,
            part: self.part,
            init,
            out: self.out,
            surface_ply: self.surface_ply,
            resample_dicom: self.resample_dicom,
            build: self.build,
            tsdf_voxel_mm: self.tsdf_voxel_mm,
            params,
        };
        let started = std::time::Instant::now();
        let outcome = ct::register_ct(&request, &volume)?;
        print!("{}", outcome.registration.to_toml_string());
        for free in &outcome.free_rotations {
            println!("WARNING: {free}");
        }
        println!(
            "wrote {} in {:.1} s",
            out.display(),
            started.elapsed().as_secs_f64()
        );
        if let Some(ply) = ply {
            println!(
                "wrote the CT surface coloured by distance to {}",
                ply.display()
            );
        }
        if let Some(dir) = resampled {
            println!(
                "wrote the CT resampled onto the build grid to {}",
                dir.display()
            );
        }
        Ok(())
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Lens {
    /// A homography only.
    None,
    /// Radial k1, k2 about the image center, fitted with the homography.
    Radial,
}

#[derive(Args)]
pub struct ImagesArgs {
    /// The laser scan vector file (CLI).
    #[arg(long)]
    vectors: PathBuf,
    /// The printer layer each image shows (from 1: the number in L00150_post_top.jpg); one for
    /// all images or one per --image, in order.
    #[arg(long, required = true, value_parser = super::values::layer)]
    layer: Vec<u32>,
    #[command(flatten)]
    numbering: super::numbering::NumberingArgs,
    /// Post-scan frame(s) from the camera pose to calibrate; several are fitted jointly.
    #[arg(long, required = true)]
    image: Vec<PathBuf>,
    /// Start points: lines `u v x y` (image px, build mm), at least 4.
    #[arg(long)]
    init: PathBuf,
    /// Where to write calibration.toml.
    #[arg(long)]
    out: PathBuf,
    /// Also draw the contours through the start (red) and result (blue) on the first image,
    /// with each part enlarged below it and a legend.
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Lens model fitted with the homography.
    #[arg(long, value_enum, default_value = "none")]
    distortion: Lens,
    /// Focal length in pixels for --distortion radial (default 1.25 x image width).
    #[arg(long)]
    focal_px: Option<f64>,
    /// Pyramid levels (default from the exemplar size).
    #[arg(long, value_parser = super::values::pyramid_levels)]
    levels: Option<usize>,
    /// Std filter window of the exemplar, pixels (odd).
    #[arg(long, default_value_t = 11)]
    std_window: usize,
    #[command(flatten)]
    spread: SpreadArgs,
}

impl ImagesArgs {
    fn run(self) -> Result<()> {
        let layers = match (self.layer.len(), self.image.len()) {
            (1, n) => vec![self.layer[0]; n],
            (a, b) if a == b => self.layer,
            (a, b) => bail!("{a} --layer for {b} --image: give one, or one per image"),
        };
        let mut options = RegistrationOptions {
            std_window: self.std_window,
            plate: self.spread.plate()?,
            max_error_mm: self.spread.max_error_mm,
            ..RegistrationOptions::default()
        };
        options.lm.levels = self.levels;
        let out = self.out.clone();
        let request = ImageRegistration {
            vectors: self.vectors,
            numbering: self.numbering.numbering(),
            images: self
                .image
                .into_iter()
                .zip(layers)
                .map(|(path, layer)| RegistrationImage { path, layer })
                .collect(),
            init_points: self.init,
            out: Some(self.out),
            overlay: self.overlay,
            distortion: match self.distortion {
                Lens::None => DistortionChoice::None,
                Lens::Radial => DistortionChoice::Radial {
                    focal_px: self.focal_px,
                },
            },
            options,
        };
        let report = register_images(&request)?;
        print!("{report}");
        println!("wrote {} in {:.2} s", out.display(), report.seconds);
        Ok(())
    }
}
