//! After the build: locating one point of the build frame in every modality (and, with the
//! raster and CT modules, exporting them all as one study).

use crate::acquisition::processing::FrameProcessor;
use crate::acquisition::series::{series_dir, LayerHeights, SeriesSettings};
use crate::acquisition::status;
use crate::config::Config;
use crate::rectify::{Calibration, Grid, Rectifier};
use crate::registration::ct::vectors_field::{apply, invert_affine, invert_rigid};
use crate::view::{Shot, View};
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(
        "{0}: not a layerwise build directory ({1} missing); pass the daemon's build.output_dir"
    )]
    NotABuild(PathBuf, &'static str),
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    #[error("{0}")]
    Invalid(String),
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
}

/// Everything known about a build after the fact: its configuration, calibration and grid.
pub struct BuildRecord {
    pub dir: PathBuf,
    pub config: Config,
    pub calibration: Option<Calibration>,
    pub grid: Grid,
    pub heights: LayerHeights,
}

impl BuildRecord {
    pub fn open(dir: &Path) -> Result<BuildRecord, ExportError> {
        let config_path = dir.join(status::CONFIG_SNAPSHOT);
        if !config_path.exists() {
            return Err(ExportError::NotABuild(
                dir.to_path_buf(),
                status::CONFIG_SNAPSHOT,
            ));
        }
        let config = Config::load(&config_path)?;
        let calibration_path = dir.join(status::CALIBRATION_COPY);
        let calibration = if calibration_path.exists() {
            Some(Calibration::load(&calibration_path)?)
        } else {
            None
        };
        let settings = SeriesSettings::from_config(&config).map_err(ExportError::Invalid)?;
        Ok(BuildRecord {
            dir: dir.to_path_buf(),
            config,
            calibration,
            grid: settings.grid,
            heights: settings.heights,
        })
    }
}

/// Where a build point is in one view.
#[derive(Clone, Debug, Serialize)]
pub struct ViewLocation {
    pub view: String,
    /// Pixel (row, column) in the rectified series, when the point is on its grid.
    pub rectified_pixel: Option<[f64; 2]>,
    pub dicom: Option<PathBuf>,
    /// Pixel (u, v) in the original camera frame (through the homography and distortion).
    pub image_pixel: Option<[f64; 2]>,
    pub original: Option<PathBuf>,
}

/// Where a build point is in the registered CT.
#[derive(Clone, Debug, Serialize)]
pub struct CtLocation {
    /// CT physical mm (DICOM patient coordinates of the CT, or voxel index x voxel size).
    pub ct_mm: [f64; 3],
    /// Fractional voxel index (i, j, k), when the CT volume could be read.
    pub voxel: Option<[f64; 3]>,
}

#[derive(Clone, Debug, Serialize)]
pub struct Location {
    /// The point in the build frame, mm.
    pub build_mm: [f64; 3],
    pub ct: Option<CtLocation>,
    pub layer: Option<u32>,
    pub layer_z_mm: Option<f64>,
    pub views: Vec<ViewLocation>,
}

/// The CT transform of a ct.toml and, when its source can be read, the CT's index geometry.
pub struct CtFrame {
    pub ct_to_build: [[f64; 4]; 4],
    pub mm_to_index: Option<[[f64; 4]; 4]>,
}

impl CtFrame {
    pub fn open(ct_toml: &Path) -> Result<CtFrame, ExportError> {
        let registration = crate::registration::ct::CtRegistration::read_toml(ct_toml)
            .map_err(|e| ExportError::Invalid(e.to_string()))?;
        let mm_to_index = registration
            .source
            .as_ref()
            .and_then(|s| s.read().ok())
            .and_then(|v| invert_affine(&v.index_to_mm));
        Ok(CtFrame {
            ct_to_build: registration.transform,
            mm_to_index,
        })
    }

    /// CT mm → build mm.
    pub fn to_build(&self, ct_mm: [f64; 3]) -> [f64; 3] {
        apply(&self.ct_to_build, ct_mm)
    }

    /// Build mm → CT mm and voxel.
    pub fn locate(&self, build_mm: [f64; 3]) -> CtLocation {
        let ct_mm = apply(&invert_rigid(&self.ct_to_build), build_mm);
        CtLocation {
            ct_mm,
            voxel: self.mm_to_index.map(|m| apply(&m, ct_mm)),
        }
    }
}

/// Where `point` (build mm) is in the layer stack, the rectified views and the original frames.
pub fn locate(record: &BuildRecord, point: [f64; 3]) -> Result<Location, ExportError> {
    let layer = record.heights.layer_at(point[2]);
    let rectifier = match &record.calibration {
        Some(c) => Some(
            Rectifier::new(
                c.homography,
                record.grid,
                c.distortion,
                Default::default(),
                0,
            )
            .map_err(|e| ExportError::Invalid(format!("calibration: {e}")))?,
        ),
        None => None,
    };
    let (row, col) = record.grid.pixel_of(point[0], point[1]);
    let on_grid = row >= -0.5
        && col >= -0.5
        && row <= record.grid.rows() as f64 - 0.5
        && col <= record.grid.columns() as f64 - 0.5;
    let views = record
        .config
        .views
        .all()
        .into_iter()
        .map(|view: View| {
            let shot = layer.map(|layer| Shot {
                layer,
                phase: view.phase,
                light: view.light,
            });
            let dicom = shot
                .map(|s| series_dir(&record.dir, view).join(format!("L{:05}.dcm", s.layer)))
                .filter(|p| p.exists());
            let original = shot.and_then(|s| find_original(&record.dir, &s));
            ViewLocation {
                view: view.to_string(),
                rectified_pixel: on_grid.then_some([row, col]),
                dicom,
                image_pixel: rectifier
                    .as_ref()
                    .and_then(|r| r.image_point(point[0], point[1]))
                    .map(|(u, v)| [u, v]),
                original,
            }
        })
        .collect();
    Ok(Location {
        ct: None,
        build_mm: point,
        layer,
        layer_z_mm: layer.map(|k| record.heights.z(k)),
        views,
    })
}

fn find_original(dir: &Path, shot: &Shot) -> Option<PathBuf> {
    ["jpg", "jpeg", "nef", "png", "tif"]
        .iter()
        .map(|ext| dir.join(format!("raw/{}.{ext}", shot.stem())))
        .find(|p| p.exists())
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.build_mm;
        writeln!(f, "build point   ({x}, {y}, {z}) mm")?;
        match (self.layer, self.layer_z_mm) {
            (Some(k), Some(zk)) => writeln!(f, "layer         {k} (top at z = {zk} mm)")?,
            _ => writeln!(f, "layer         none: z is outside the build")?,
        }
        if let Some(ct) = &self.ct {
            let [a, b, c] = ct.ct_mm;
            write!(f, "ct            ({a:.3}, {b:.3}, {c:.3}) mm")?;
            match ct.voxel {
                Some([i, j, k]) => writeln!(f, ", voxel ({i:.1}, {j:.1}, {k:.1})")?,
                None => writeln!(f)?,
            }
        }
        for v in &self.views {
            let rect = v
                .rectified_pixel
                .map_or("off the grid".to_string(), |[r, c]| {
                    format!("row {r:.1}, column {c:.1}")
                });
            let img = v.image_pixel.map_or("not in view".to_string(), |[u, v]| {
                format!("u {u:.1}, v {v:.1}")
            });
            writeln!(
                f,
                "{:<10}    rectified {rect}{}",
                v.view,
                v.dicom
                    .as_ref()
                    .map(|p| format!(" in {}", p.display()))
                    .unwrap_or_default()
            )?;
            writeln!(
                f,
                "              original  {img}{}",
                v.original
                    .as_ref()
                    .map(|p| format!(" in {}", p.display()))
                    .unwrap_or_default()
            )?;
        }
        Ok(())
    }
}

/// Draws the point in each view, side by side: the rectified view (re-rectified from the original,
/// the same pixels as its DICOM slice) and the original frame, cropped around the point, with a
/// green marker (the paper's Fig. 9).
pub fn mark(record: &BuildRecord, location: &Location, out: &Path) -> Result<(), ExportError> {
    const HALF: i64 = 80;
    let calibration = record
        .calibration
        .as_ref()
        .ok_or_else(|| ExportError::Invalid("the build has no calibration.toml".into()))?;
    let rectifier = Rectifier::new(
        calibration.homography,
        record.grid,
        calibration.distortion,
        Default::default(),
        0,
    )
    .map_err(|e| ExportError::Invalid(format!("calibration: {e}")))?;
    let mut tiles: Vec<image::RgbImage> = Vec::new();
    let rgb = |gray: image::GrayImage| image::DynamicImage::ImageLuma8(gray).to_rgb8();
    // First the laser vectors of the layer (contours blue, hatches red), as in the paper's Fig. 9.
    if let (Some(path), Some(k), Some([r, c])) = (
        &record.config.build.vectors,
        location.layer,
        location.views.first().and_then(|v| v.rectified_pixel),
    ) {
        let file = crate::vectors::read(path).map_err(|e| ExportError::Invalid(e.to_string()))?;
        if let Some(layer) = file.layers.get(k as usize - 1) {
            let picture = crate::raster::rgb(
                layer,
                &record.grid,
                &crate::raster::RasterOptions::default(),
            )
            .map_err(|e| ExportError::Invalid(e.to_string()))?;
            tiles.push(crop_with_marker(&picture, r, c, HALF));
        }
    }
    for v in &location.views {
        let Some(original) = &v.original else {
            continue;
        };
        let bytes = std::fs::read(original).map_err(|e| ExportError::Io {
            path: original.clone(),
            message: e.to_string(),
        })?;
        let luma = crate::rectify::decode_frame_luma(&bytes).map_err(|e| ExportError::Io {
            path: original.clone(),
            message: e.to_string(),
        })?;
        if let Some([r, c]) = v.rectified_pixel {
            let rect = luma.rectified(&rectifier).to_display8();
            tiles.push(crop_with_marker(&rgb(rect), r, c, HALF));
        }
        if let Some([u, vv]) = v.image_pixel {
            tiles.push(crop_with_marker(&rgb(luma.to_display8()), vv, u, HALF));
        }
    }
    if tiles.is_empty() {
        return Err(ExportError::Invalid(
            "nothing to draw: no frame of that layer holds the point".into(),
        ));
    }
    let side = (2 * HALF + 1) as u32;
    let mut sheet = image::RgbImage::from_pixel(
        side * tiles.len() as u32 + 4 * (tiles.len() as u32 - 1),
        side,
        image::Rgb([255, 255, 255]),
    );
    for (i, tile) in tiles.iter().enumerate() {
        image::imageops::replace(&mut sheet, tile, (i as u32 * (side + 4)) as i64, 0);
    }
    sheet.save(out).map_err(|e| ExportError::Io {
        path: out.to_path_buf(),
        message: e.to_string(),
    })
}

/// A (2·half + 1)² crop centred on (row, col) with a green cross; outside the image is black.
fn crop_with_marker(img: &image::RgbImage, row: f64, col: f64, half: i64) -> image::RgbImage {
    let (r0, c0) = (row.round() as i64, col.round() as i64);
    let side = (2 * half + 1) as u32;
    let mut tile = image::RgbImage::new(side, side);
    for dy in -half..=half {
        for dx in -half..=half {
            let (r, c) = (r0 + dy, c0 + dx);
            if r >= 0 && c >= 0 && (r as u32) < img.height() && (c as u32) < img.width() {
                tile.put_pixel(
                    (dx + half) as u32,
                    (dy + half) as u32,
                    *img.get_pixel(c as u32, r as u32),
                );
            }
        }
    }
    for d in -6i64..=6 {
        if d.abs() < 2 {
            continue;
        }
        for t in [-1i64, 0, 1] {
            tile.put_pixel(
                (half + d) as u32,
                (half + t) as u32,
                image::Rgb([0, 255, 0]),
            );
            tile.put_pixel(
                (half + t) as u32,
                (half + d) as u32,
                image::Rgb([0, 255, 0]),
            );
        }
    }
    tile
}

/// What `layerwise export` writes.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, clap::ValueEnum,
)]
#[serde(rename_all = "lowercase")]
pub enum ExportFormat {
    Dicom,
    Nrrd,
}

#[derive(Clone, Debug)]
pub struct ExportRequest {
    pub build: PathBuf,
    pub out: PathBuf,
    /// Crop every series to this part's bounding box (from the build's vector file) plus a margin.
    pub part: Option<i64>,
    pub margin_mm: f64,
    pub format: ExportFormat,
    pub progress: bool,
    /// The CT registration (ct.toml from `layerwise register ct`): the CT is resampled into the study.
    pub ct: Option<PathBuf>,
}

#[derive(Clone, Debug, Serialize)]
pub struct ExportSummary {
    pub out: PathBuf,
    pub grid: [f64; 5],
    pub rows: usize,
    pub columns: usize,
    /// Series name and slice count.
    pub series: Vec<(String, usize)>,
    pub written: usize,
    pub unchanged: usize,
}

/// The originals of a build, per view, in layer order.
fn originals_by_view(
    dir: &Path,
) -> Result<std::collections::BTreeMap<View, Vec<(Shot, PathBuf)>>, ExportError> {
    let raw = dir.join("raw");
    let entries = std::fs::read_dir(&raw).map_err(|e| ExportError::Io {
        path: raw.clone(),
        message: e.to_string(),
    })?;
    let mut out: std::collections::BTreeMap<View, Vec<(Shot, PathBuf)>> = Default::default();
    for entry in entries.flatten() {
        let path = entry.path();
        let (Some(stem), Some(ext)) = (path.file_stem(), path.extension()) else {
            continue;
        };
        if ext == "json" || stem.to_string_lossy().starts_with('.') {
            continue;
        }
        if let Some(shot) = Shot::from_stem(&stem.to_string_lossy()) {
            out.entry(shot.view()).or_default().push((shot, path));
        }
    }
    for shots in out.values_mut() {
        shots.sort();
    }
    Ok(out)
}

/// Exports the build's image views (and, as they become available, the rasterized vectors and the
/// registered CT) as series of one study on one grid. Re-running rewrites nothing that is already
/// there: series and instance UIDs are derived, so the files would be identical.
pub fn export(request: &ExportRequest) -> Result<ExportSummary, ExportError> {
    let record = BuildRecord::open(&request.build)?;
    let calibration = record.calibration.clone().ok_or_else(|| {
        ExportError::Invalid(format!(
            "{}: no calibration.toml: the views cannot be rectified",
            request.build.display()
        ))
    })?;
    let manifest: status::BuildManifest = std::fs::read(request.build.join(status::MANIFEST))
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .ok_or(ExportError::NotABuild(
            request.build.clone(),
            status::MANIFEST,
        ))?;
    let mut settings = SeriesSettings::from_config(&record.config).map_err(ExportError::Invalid)?;
    let label = match request.part {
        Some(part) => {
            let vectors = record.config.build.vectors.as_ref().ok_or_else(|| {
                ExportError::Invalid(
                    "--part needs the build's vector file (build.vectors in its configuration)"
                        .into(),
                )
            })?;
            let info =
                crate::vectors::info(vectors).map_err(|e| ExportError::Invalid(e.to_string()))?;
            let bbox = info
                .parts
                .iter()
                .find(|p| p.id == part)
                .and_then(|p| p.bbox)
                .ok_or_else(|| {
                    ExportError::Invalid(format!(
                        "{}: no part {part} with geometry",
                        vectors.display()
                    ))
                })?;
            settings.grid = record.config.rectify.around(bbox, request.margin_mm);
            format!("part {part}")
        }
        None => "export".to_string(),
    };
    settings.compression = crate::dicom::Compression::Deflate;
    let grid = settings.grid;
    let heights = settings.heights.clone();
    let views = record.config.views.all();
    let live =
        crate::acquisition::series::LiveSeries::new(&manifest, &views, &calibration, settings)
            .map_err(ExportError::Invalid)?
            .relabelled(&request.out, &label, 10);
    let originals = originals_by_view(&request.build)?;
    let total: usize = originals.values().map(Vec::len).sum();
    let bar = if request.progress {
        indicatif::ProgressBar::new(total as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{msg:>12} [{bar:40}] {pos}/{len} frames, {eta} left",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut summary = ExportSummary {
        out: request.out.clone(),
        grid: [
            grid.x_min,
            grid.x_max,
            grid.y_min,
            grid.y_max,
            grid.pixel_mm,
        ],
        rows: grid.rows(),
        columns: grid.columns(),
        series: Vec::new(),
        written: 0,
        unchanged: 0,
    };
    for view in &views {
        let shots = originals.get(view).map(Vec::as_slice).unwrap_or_default();
        bar.set_message(view.to_string());
        let mut volume: Vec<u16> = Vec::new();
        let mut zs = Vec::new();
        for (shot, path) in shots {
            let io = |message: String| ExportError::Io {
                path: path.clone(),
                message,
            };
            match request.format {
                ExportFormat::Dicom => {
                    // Already exported: nothing to read or write (the UIDs make it identical).
                    if live.slice_path(&request.build, *shot).exists() {
                        summary.unchanged += 1;
                    } else {
                        live.process(&request.build, *shot, path).map_err(io)?;
                        summary.written += 1;
                    }
                }
                ExportFormat::Nrrd => {
                    let bytes = std::fs::read(path).map_err(|e| io(e.to_string()))?;
                    let luma = live
                        .rectified_luma(&bytes)
                        .map_err(|message| ExportError::Io {
                            path: path.clone(),
                            message,
                        })?;
                    volume.extend(luma.into_u16());
                    zs.push(heights.z(shot.layer));
                }
            }
            bar.inc(1);
        }
        let name = if label == "export" {
            view.to_string()
        } else {
            format!("{view}_{}", label.replace(' ', "_"))
        };
        if request.format == ExportFormat::Nrrd && !zs.is_empty() {
            let path = request.out.join(format!("{name}.nrrd"));
            write_nrrd(&path, NrrdVoxels::Gray16(&volume), grid, &zs)?;
            summary.written += 1;
        }
        summary.series.push((name, shots.len()));
    }
    bar.finish_and_clear();
    if let Some(ct) = &request.ct {
        let slices = export_ct(
            ct, &live, grid, &heights, &originals, &record, &label, request,
        )?;
        summary.written += slices;
        summary.series.push((
            if label == "export" {
                "ct".into()
            } else {
                format!("ct_{}", label.replace(' ', "_"))
            },
            slices,
        ));
    }
    if let Some(vectors) = &record.config.build.vectors {
        let slices = export_vectors(vectors, &live, grid, &label, request, &mut summary)?;
        summary.series.push((
            if label == "export" {
                "vectors".into()
            } else {
                format!("vectors_{}", label.replace(' ', "_"))
            },
            slices,
        ));
    }
    Ok(summary)
}

/// A 3D NRRD (raw, little endian) in the build frame: for 3D Slicer or napari without DICOM.
/// Slices must be equally spaced in z (layers of one thickness).
/// Voxels of an NRRD volume: grey 16-bit, or RGB for the vectors' colours.
enum NrrdVoxels<'a> {
    Gray16(&'a [u16]),
    Rgb8(&'a [u8]),
}

fn write_nrrd(path: &Path, voxels: NrrdVoxels, grid: Grid, zs: &[f64]) -> Result<(), ExportError> {
    let rgb = matches!(voxels, NrrdVoxels::Rgb8(_));
    let dz = if zs.len() > 1 {
        (zs[zs.len() - 1] - zs[0]) / (zs.len() - 1) as f64
    } else {
        1.0
    };
    let p = grid.pixel_mm;
    let header = format!(
        "NRRD0004\n# layerwise: build frame of docs/frames.md, mm\ntype: {}\ndimension: {}\nspace dimension: 3\nsizes: {}{} {} {}\nspace directions: {}({p},0,0) (0,{},0) (0,0,{dz})\nkinds: {}domain domain domain\nendian: little\nencoding: raw\nspace origin: ({},{},{})\nspace units: \"mm\" \"mm\" \"mm\"\n\n",
        if rgb { "uint8" } else { "uint16" },
        if rgb { 4 } else { 3 },
        if rgb { "3 " } else { "" },
        grid.columns(),
        grid.rows(),
        zs.len(),
        if rgb { "none " } else { "" },
        -p,
        if rgb { "RGB-color " } else { "" },
        grid.x_min + p / 2.0,
        grid.y_max - p / 2.0,
        zs[0]
    );
    let mut bytes = header.into_bytes();
    match voxels {
        NrrdVoxels::Gray16(volume) => {
            bytes.reserve(volume.len() * 2);
            for v in volume {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        NrrdVoxels::Rgb8(volume) => bytes.extend_from_slice(volume),
    }
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| ExportError::Io {
            path: dir.to_path_buf(),
            message: e.to_string(),
        })?;
    }
    crate::acquisition::storage::write_atomic(path, &bytes, true).map_err(|e| ExportError::Io {
        path: path.to_path_buf(),
        message: e.source.to_string(),
    })
}

/// Label values of the vectors series: the CT Image IOD is MONOCHROME2 only, so the Fig. 9 colours
/// become grey levels (the NRRD export keeps them as RGB).
pub const LABEL_FUSED: u16 = 1000;
pub const LABEL_HATCH: u16 = 2000;
pub const LABEL_CONTOUR: u16 = 3000;

/// The rasterized vectors, one slice per layer at its z: contours, hatches, fused area.
fn export_vectors(
    path: &Path,
    live: &crate::acquisition::series::LiveSeries,
    grid: Grid,
    label: &str,
    request: &ExportRequest,
    summary: &mut ExportSummary,
) -> Result<usize, ExportError> {
    use crate::raster::{self, RasterOptions, RGB_CONTOUR, RGB_HATCH};
    let file = crate::vectors::read(path).map_err(|e| ExportError::Invalid(e.to_string()))?;
    let options = RasterOptions {
        part: request.part,
        ..RasterOptions::default()
    };
    let name = if label == "export" {
        "vectors".to_string()
    } else {
        format!("vectors {label}")
    };
    let series = crate::dicom::Series::named(live.study(), 9, &name);
    let dir = request.out.join(name.replace(' ', "_"));
    let (rows, cols) = (grid.rows(), grid.columns());
    let mut rgb_volume: Vec<u8> = Vec::new();
    let mut zs = Vec::new();
    let mut slices = 0;
    for (k, layer) in file.layers.iter().enumerate() {
        let layer_number = k as u32 + 1;
        let rgb = raster::rgb(layer, &grid, &options)
            .map_err(|e| ExportError::Invalid(format!("{}: layer {k}: {e}", path.display())))?;
        slices += 1;
        match request.format {
            ExportFormat::Nrrd => {
                rgb_volume.extend_from_slice(rgb.as_raw());
                zs.push(layer.z_mm);
            }
            ExportFormat::Dicom => {
                let target = dir.join(format!("L{layer_number:05}.dcm"));
                if target.exists() {
                    summary.unchanged += 1;
                    continue;
                }
                let pixels: Vec<u16> = rgb
                    .pixels()
                    .map(|p| match p {
                        p if *p == RGB_CONTOUR => LABEL_CONTOUR,
                        p if *p == RGB_HATCH => LABEL_HATCH,
                        p if p.0 != [0, 0, 0] => LABEL_FUSED,
                        _ => 0,
                    })
                    .collect();
                let thickness = if k > 0 {
                    layer.z_mm - file.layers[k - 1].z_mm
                } else {
                    layer.z_mm
                };
                let slice = crate::dicom::Slice {
                    layer: layer_number,
                    plane: crate::dicom::Plane {
                        origin: [grid.x_min + grid.pixel_mm / 2.0, grid.y_max - grid.pixel_mm / 2.0, layer.z_mm],
                        pixel_mm: grid.pixel_mm,
                        rows,
                        columns: cols,
                        thickness_mm: if thickness > 0.0 { thickness } else { 0.03 },
                    },
                    pixels: &pixels,
                    acquired: None,
                    window: (1500.0, 3000.0),
                    derivation: "laser scan vectors rasterized: 3000 contour, 2000 hatch, 1000 fused area, 0 powder",
                };
                crate::dicom::write_slice(
                    &target,
                    live.study(),
                    &series,
                    &slice,
                    crate::dicom::Compression::Deflate,
                )
                .map_err(|e| ExportError::Io {
                    path: target.clone(),
                    message: e.to_string(),
                })?;
                summary.written += 1;
            }
        }
    }
    if request.format == ExportFormat::Nrrd && !zs.is_empty() {
        let out = request.out.join(format!("{}.nrrd", name.replace(' ', "_")));
        write_nrrd(&out, NrrdVoxels::Rgb8(&rgb_volume), grid, &zs)?;
        summary.written += 1;
    }
    Ok(slices)
}

/// The registered CT resampled onto the export grid, one slice per layer (the vector file's layers,
/// else the layers the build photographed), in the build's study.
#[allow(clippy::too_many_arguments)]
fn export_ct(
    ct_toml: &Path,
    live: &crate::acquisition::series::LiveSeries,
    grid: Grid,
    heights: &LayerHeights,
    originals: &std::collections::BTreeMap<View, Vec<(Shot, PathBuf)>>,
    record: &BuildRecord,
    label: &str,
    request: &ExportRequest,
) -> Result<usize, ExportError> {
    use crate::registration::ct;
    let registration =
        ct::CtRegistration::read_toml(ct_toml).map_err(|e| ExportError::Invalid(e.to_string()))?;
    let source = registration.source.as_ref().ok_or_else(|| {
        ExportError::Invalid(format!(
            "{}: records no CT source; register again with this layerwise",
            ct_toml.display()
        ))
    })?;
    let volume = source
        .read()
        .map_err(|e| ExportError::Invalid(e.to_string()))?;
    let planes: Vec<(u32, f64, f64)> = match &record.config.build.vectors {
        Some(path) => {
            let file =
                crate::vectors::read(path).map_err(|e| ExportError::Invalid(e.to_string()))?;
            ct::vectors_field::layer_planes(&file)
        }
        None => {
            let layers: std::collections::BTreeSet<u32> =
                originals.values().flatten().map(|(s, _)| s.layer).collect();
            layers
                .into_iter()
                .map(|k| (k, heights.z(k), heights.thickness(k)))
                .collect()
        }
    };
    let name = if label == "export" {
        "ct".to_string()
    } else {
        format!("ct {label}")
    };
    if request.format == ExportFormat::Nrrd {
        let slices =
            ct::vectors_field::resample_slices(&volume, &registration.transform, grid, &planes)
                .map_err(ExportError::Invalid)?;
        let zs: Vec<f64> = slices.iter().map(|s| s.z_mm).collect();
        let voxels: Vec<u16> = slices
            .iter()
            .flat_map(|s| s.pixels.iter().copied())
            .collect();
        if !zs.is_empty() {
            let path = request.out.join(format!("{}.nrrd", name.replace(' ', "_")));
            write_nrrd(&path, NrrdVoxels::Gray16(&voxels), grid, &zs)?;
        }
        return Ok(zs.len());
    }
    let series = crate::dicom::Series::named(live.study(), 8, &name);
    let dir = request.out.join(name.replace(' ', "_"));
    ct::vectors_field::resample_to_dicom(
        &volume,
        &registration.transform,
        grid,
        &planes,
        live.study(),
        &series,
        &dir,
    )
    .map_err(ExportError::Invalid)
}
