//! After the build: the vectors, the six views and the registered CT exported as one study on one
//! grid (part crops), DICOM or NRRD.

use crate::ct::CtError;
use crate::dicom::DicomError;
use crate::fsutil::WriteError;
use crate::raster::RasterError;
use crate::rectify::Grid;
use crate::series::{BuildRecord, LayerHeights, SeriesError, SeriesSettings};
use crate::shot::{Shot, View};
use crate::vectors::VectorError;
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(
        "{0}: not a layerwise build directory ({1} missing); pass the daemon's build.output_dir"
    )]
    NotABuild(PathBuf, &'static str),
    #[error(transparent)]
    Manifest(#[from] crate::build_dir::manifest::ManifestError),
    #[error(transparent)]
    Series(#[from] SeriesError),
    #[error(transparent)]
    Vectors(#[from] VectorError),
    #[error(transparent)]
    Ct(#[from] CtError),
    #[error(transparent)]
    Write(#[from] WriteError),
    #[error("{file}: layer {layer}: cannot draw the vectors")]
    Raster {
        file: PathBuf,
        layer: usize,
        #[source]
        source: RasterError,
    },
    #[error("{path}: cannot export the frame")]
    Frame {
        path: PathBuf,
        #[source]
        source: SeriesError,
    },
    #[error("{path}: cannot write the slice")]
    Dicom {
        path: PathBuf,
        #[source]
        source: DicomError,
    },
    #[error("cannot {action} {path}")]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("{0}")]
    Invalid(String),
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

impl std::fmt::Display for ExportSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (name, slices) in &self.series {
            writeln!(f, "{name:<24} {slices} slices")?;
        }
        writeln!(
            f,
            "{} x {} px at {} mm; {} written, {} already there, in {}",
            self.columns,
            self.rows,
            self.grid[4],
            self.written,
            self.unchanged,
            self.out.display()
        )
    }
}

/// Per view, in layer order, the shots with the take shown and its original.
type Originals = std::collections::BTreeMap<View, Vec<(Shot, u32, PathBuf)>>;

/// The originals of a build, per view, in layer order: per shot the take `take` picks (the
/// first, or the last retake).
fn originals_by_view(dir: &Path, take: crate::shot::SeriesTake) -> Result<Originals, ExportError> {
    let raw = dir.join(crate::build_dir::RAW_DIR);
    let entries = std::fs::read_dir(&raw).map_err(|source| ExportError::Io {
        path: raw.clone(),
        action: "list",
        source,
    })?;
    let mut picked: std::collections::BTreeMap<Shot, (u32, PathBuf)> = Default::default();
    for entry in entries.flatten() {
        let path = entry.path();
        let (Some(stem), Some(ext)) = (path.file_stem(), path.extension()) else {
            continue;
        };
        if ext == "json" || stem.to_string_lossy().starts_with('.') {
            continue;
        }
        let Some((shot, n)) = Shot::from_take_stem(&stem.to_string_lossy()) else {
            continue;
        };
        let wanted = match take {
            crate::shot::SeriesTake::First => n == 1,
            crate::shot::SeriesTake::Last => picked.get(&shot).is_none_or(|(m, _)| n > *m),
        };
        if wanted {
            picked.insert(shot, (n, path));
        }
    }
    let mut out = Originals::default();
    for (shot, (n, path)) in picked {
        out.entry(shot.view()).or_default().push((shot, n, path));
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
    let manifest = crate::build_dir::BuildManifest::read(&request.build).map_err(|e| match e {
        crate::build_dir::manifest::ManifestError::Read { source, .. }
            if source.kind() == std::io::ErrorKind::NotFound =>
        {
            ExportError::NotABuild(request.build.clone(), crate::build_dir::MANIFEST)
        }
        other => other.into(),
    })?;
    let mut settings = SeriesSettings::from_config(&record.config)?;
    let label = match request.part {
        Some(part) => {
            let vectors = record.config.build.vectors.as_ref().ok_or_else(|| {
                ExportError::Invalid(
                    "--part needs the build's vector file (build.vectors in its configuration)"
                        .into(),
                )
            })?;
            let info = crate::vectors::info(vectors)?;
            let bbox = info.part_bbox(part).ok_or_else(|| {
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
    let live = crate::series::LiveSeries::new(&manifest, &views, &calibration, settings)?
        .relabelled(&request.out, &label, 10);
    let originals = originals_by_view(&request.build, record.config.series.take)?;
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
        for (shot, take, path) in shots {
            let frame = |source: SeriesError| ExportError::Frame {
                path: path.clone(),
                source,
            };
            match request.format {
                ExportFormat::Dicom => {
                    // Already exported from the same take: nothing to read or write (the UIDs
                    // make it identical).
                    let target = live.slice_path(&request.build, *shot);
                    if crate::dicom::slice_take(&target) == Some(*take) {
                        summary.unchanged += 1;
                    } else {
                        live.write_original(&request.build, *shot, *take, path)
                            .map_err(frame)?;
                        summary.written += 1;
                    }
                }
                ExportFormat::Nrrd => {
                    let bytes = crate::build_dir::original::read(path)
                        .map_err(|e| frame(e.into()))?
                        .bytes;
                    let luma = live.rectified_luma(&bytes).map_err(frame)?;
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
        let slices = export_vectors(
            vectors,
            &live,
            grid,
            &label,
            request,
            record.config.build.numbering(),
            &mut summary,
        )?;
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
        "NRRD0004\n# layerwise: build frame of docs/frames.md, mm\ntype: {}\ndimension: {}\nspace dimension: 3\nsizes: {}{} {} {}\nspace directions: {}({p},0,0) (0,{},0) (0,0,{dz})\nkinds: {}domain domain domain\nendian: little\nencoding: gzip\nspace origin: ({},{},{})\nspace units: \"mm\" \"mm\" \"mm\"\n\n",
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
    // gzip (NRRD's `encoding: gzip`, read by 3D Slicer, ITK, pynrrd): the mostly empty plate
    // compresses many times over (a 48 MB view of the demo was raw before).
    let mut gz = flate2::write::GzEncoder::new(header.into_bytes(), flate2::Compression::fast());
    let io = |source| ExportError::Io {
        path: path.to_path_buf(),
        action: "write",
        source,
    };
    match voxels {
        NrrdVoxels::Gray16(volume) => {
            let mut le = Vec::with_capacity(volume.len() * 2);
            for v in volume {
                le.extend_from_slice(&v.to_le_bytes());
            }
            std::io::Write::write_all(&mut gz, &le).map_err(io)?;
        }
        NrrdVoxels::Rgb8(volume) => std::io::Write::write_all(&mut gz, volume).map_err(io)?,
    }
    let bytes = gz.finish().map_err(io)?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| ExportError::Io {
            path: dir.to_path_buf(),
            action: "create",
            source,
        })?;
    }
    Ok(crate::fsutil::write_atomic(path, &bytes, true)?)
}

/// Label values of the vectors series: the CT Image IOD is MONOCHROME2 only, so the Fig. 9 colours
/// become grey levels (the NRRD export keeps them as RGB).
pub const LABEL_FUSED: u16 = 1000;
pub const LABEL_HATCH: u16 = 2000;
pub const LABEL_CONTOUR: u16 = 3000;

/// The rasterized vectors, one slice per layer at its z: contours, hatches, fused area.
fn export_vectors(
    path: &Path,
    live: &crate::series::LiveSeries,
    grid: Grid,
    label: &str,
    request: &ExportRequest,
    numbering: crate::vectors::LayerNumbering,
    summary: &mut ExportSummary,
) -> Result<usize, ExportError> {
    use crate::raster::{self, RasterOptions, RGB_CONTOUR, RGB_HATCH};
    let file = crate::vectors::read(path)?;
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
    let map = crate::vectors::LayerMap::of_file(&file, numbering);
    for (k, layer) in file.layers.iter().enumerate() {
        let Some(layer_number) = map.layer(k) else {
            continue;
        };
        let rgb = raster::rgb(layer, &grid, &options).map_err(|source| ExportError::Raster {
            file: path.to_path_buf(),
            layer: k,
            source,
        })?;
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
                    pixels: (&pixels).into(),
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
                .map_err(|source| ExportError::Dicom {
                    path: target.clone(),
                    source,
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
    live: &crate::series::LiveSeries,
    grid: Grid,
    heights: &LayerHeights,
    originals: &Originals,
    record: &BuildRecord,
    label: &str,
    request: &ExportRequest,
) -> Result<usize, ExportError> {
    use crate::ct;
    let registration = ct::CtRegistration::read_toml(ct_toml)?;
    let source = registration.source.as_ref().ok_or_else(|| {
        ExportError::Invalid(format!(
            "{}: records no CT source; register again with this layerwise",
            ct_toml.display()
        ))
    })?;
    let volume = source.read()?;
    let planes: Vec<(u32, f64, f64)> = match &record.config.build.vectors {
        Some(path) => {
            let file = crate::vectors::read(path)?;
            let map = crate::vectors::LayerMap::of_file(&file, record.config.build.numbering());
            ct::resample::layer_planes(&file, &map)
        }
        None => {
            let layers: std::collections::BTreeSet<u32> = originals
                .values()
                .flatten()
                .map(|(s, _, _)| s.layer)
                .collect();
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
            ct::resample::resample_slices(&volume, &registration.build_from_ct, grid, &planes)?;
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
    ct::resample::resample_to_dicom(
        &volume,
        &registration.build_from_ct,
        grid,
        &planes,
        live.study(),
        &series,
        &dir,
    )
    .map_err(ExportError::from)
}
