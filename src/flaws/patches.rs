//! Patches of the build's views at the flaws: for every flaw and every layer it spans, a square
//! of the rectified view of every view (16-bit PNG) centred on the flaw's section, on the
//! build's rectified grid lattice (docs/frames.md: the patch's pixels are pixels of the series),
//! or of the views of one phase only (`PatchOptions::phase`);
//! flaw-free controls from the same part and layers; labels.json (COCO), labels.csv and a
//! contact sheet (the CT section beside each view of the layer, the paper's Fig. 9).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use image::{GrayImage, ImageBuffer, Luma, Rgb, RgbImage};
use rayon::prelude::*;
use serde::Serialize;

use super::{write_err, CtLabels, Flaw, FlawTable, FlawsError, Result};
use crate::ct::Volume;
use crate::geometry::Grid;
use crate::raster::sheet;
use crate::rectify::{FrameLuma, Gray16Image, Rectifier};
use crate::series::BuildRecord;
use crate::shot::{Phase, Shot, View};

pub const LABELS_JSON: &str = "labels.json";
pub const LABELS_CSV: &str = "labels.csv";
pub const CONTACT_SHEET: &str = "contact_sheet.png";
/// 8-bit frames are stored in the 16-bit patches times this (exactly reversible).
pub const GAMMA8_SCALE: u16 = 257;

/// How the patches are cut.
#[derive(Debug, Clone)]
pub struct PatchOptions {
    /// Side of a patch in pixels of the build's rectified grid (odd: the flaw is the centre pixel).
    pub patch_px: usize,
    /// One flaw-free control per flaw patch.
    pub controls: bool,
    /// Rows (flaw x layer) on the contact sheet at most.
    pub sheet_rows: usize,
    /// Only the views of this phase (`None`: every view of the build). A flaw of a layer shows
    /// in its post-scan views; the pre-scan views show the fresh powder that covers it.
    pub phase: Option<Phase>,
}

impl Default for PatchOptions {
    fn default() -> Self {
        Self {
            patch_px: 65,
            controls: true,
            sheet_rows: 48,
            phase: None,
        }
    }
}

/// The CT for the controls (the part's material) and the sheet's CT sections.
pub struct CtContext<'a> {
    pub volume: &'a Volume,
    pub labels: &'a CtLabels,
    pub void_level: f64,
    pub material_level: f64,
}

/// What [`cut_patches`] wrote.
#[derive(Debug, Clone, Default, Serialize)]
pub struct PatchSummary {
    pub flaw_patches: usize,
    pub control_patches: usize,
    /// (flaw or control, layer, view) with no original on disk.
    pub missing_frames: usize,
    /// Flaw sections for which no flaw-free control was found in the part.
    pub controls_not_found: usize,
    pub sheet: Option<PathBuf>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum JobKind {
    Flaw,
    Control,
}

/// One patch position: a flaw's section or its control, in one layer.
#[derive(Debug, Clone)]
struct Job {
    kind: JobKind,
    flaw: u32,
    layer: u32,
    grid: Grid,
}

impl Job {
    fn stem(&self, view: View) -> String {
        let (dir, letter) = match self.kind {
            JobKind::Flaw => ("patches", 'F'),
            JobKind::Control => ("controls", 'C'),
        };
        format!("{dir}/{letter}{:04}_L{:05}_{view}", self.flaw, self.layer)
    }
}

/// The `px` x `px` grid on `grid`'s lattice whose centre pixel holds `center` (build mm).
pub fn patch_grid(grid: &Grid, center: [f64; 2], px: usize) -> Grid {
    grid.patch_around(center, px)
}

fn overlaps(g: &Grid, bbox: [f64; 4]) -> bool {
    bbox[0] < g.x_max && bbox[2] > g.x_min && bbox[1] < g.y_max && bbox[3] > g.y_min
}

/// Flaw patches for every section of `flaws`, and a control after each when asked and found.
fn plan(
    record: &BuildRecord,
    flaws: &[Flaw],
    all: &[Flaw],
    options: &PatchOptions,
    ct: Option<&CtContext>,
) -> (Vec<Job>, usize) {
    let px = options.patch_px;
    let mut jobs = Vec::new();
    let mut used: BTreeSet<(u32, i64, i64)> = BTreeSet::new();
    let mut not_found = 0;
    for flaw in flaws {
        for s in &flaw.sections {
            jobs.push(Job {
                kind: JobKind::Flaw,
                flaw: flaw.id,
                layer: s.layer,
                grid: patch_grid(&record.grid, s.center_mm, px),
            });
            let Some(ct) = ct.filter(|_| options.controls) else {
                continue;
            };
            let z = record.heights.z(s.layer) - 0.5 * record.heights.thickness(s.layer);
            let step = px as f64 * record.grid.pixel_mm;
            let found = control_offsets().find_map(|(i, j)| {
                let c = [
                    s.center_mm[0] + i as f64 * step,
                    s.center_mm[1] + j as f64 * step,
                ];
                let g = patch_grid(&record.grid, c, px);
                let key = (s.layer, (g.x_min * 1e6) as i64, (g.y_max * 1e6) as i64);
                let (cx, cy) = g.center_of((px / 2) as f64, (px / 2) as f64);
                let clean = all.iter().all(|f| {
                    !overlaps(
                        &g,
                        [
                            f.bbox_min_mm[0],
                            f.bbox_min_mm[1],
                            f.bbox_max_mm[0],
                            f.bbox_max_mm[1],
                        ],
                    )
                });
                (clean && !used.contains(&key) && ct.labels.inside([cx, cy, z])).then_some((g, key))
            });
            match found {
                Some((grid, key)) => {
                    used.insert(key);
                    jobs.push(Job {
                        kind: JobKind::Control,
                        flaw: flaw.id,
                        layer: s.layer,
                        grid,
                    });
                }
                None => not_found += 1,
            }
        }
    }
    (jobs, not_found)
}

/// Offsets (in patch sides) around a flaw, ring by ring, in a fixed order.
fn control_offsets() -> impl Iterator<Item = (i64, i64)> {
    (1..=8i64).flat_map(|k| {
        (-k..=k).flat_map(move |j| {
            (-k..=k)
                .filter(move |&i| i.abs().max(j.abs()) == k)
                .map(move |i| (i, j))
        })
    })
}

/// The rectified patches of every job in every view (None where the original is missing).
/// A rectified patch and its [`CocoImage::value_scale`].
type Patch = (Gray16Image, u16);

/// The build's views the patches are cut from.
fn views_of(record: &BuildRecord, phase: Option<Phase>) -> Vec<View> {
    let mut views = record.config.views.all();
    views.retain(|v| phase.is_none_or(|p| v.phase == p));
    views
}

fn cut(record: &BuildRecord, jobs: &[Job], views: &[View]) -> Result<Vec<Vec<Option<Patch>>>> {
    let calibration = record.calibration.as_ref().ok_or_else(|| {
        FlawsError::Invalid(format!(
            "{}: the build has no calibration.toml, so its frames cannot be rectified",
            record.dir.display()
        ))
    })?;
    let camera = calibration.camera();
    let mut by_layer: BTreeMap<u32, Vec<usize>> = BTreeMap::new();
    for (i, j) in jobs.iter().enumerate() {
        by_layer.entry(j.layer).or_default().push(i);
    }
    let work: Vec<(u32, usize)> = by_layer
        .keys()
        .flat_map(|&layer| (0..views.len()).map(move |v| (layer, v)))
        .collect();
    let interpolation = record.config.calibration.interpolation;
    let fill = record.config.calibration.fill;
    let done: Vec<Vec<(usize, usize, Patch)>> = work
        .par_iter()
        .map(|&(layer, v)| -> Result<Vec<(usize, usize, Patch)>> {
            let view = views[v];
            let shot = Shot {
                layer,
                phase: view.phase,
                light: view.light,
            };
            let Some(path) = crate::build_dir::original_path(&record.dir, &shot) else {
                return Ok(Vec::new());
            };
            let bytes = crate::build_dir::original::read(&path)?.bytes;
            let luma = crate::rectify::decode_frame_luma(&bytes)
                .map_err(|source| FlawsError::Frame { path, source })?;
            by_layer[&layer]
                .iter()
                .map(|&j| {
                    let r = Rectifier::new(&camera, jobs[j].grid, interpolation, fill)?;
                    Ok((j, v, to16(luma.rectified(&r))))
                })
                .collect()
        })
        .collect::<Result<_>>()?;
    let mut out = vec![vec![None; views.len()]; jobs.len()];
    for (j, v, img) in done.into_iter().flatten() {
        out[j][v] = Some(img);
    }
    Ok(out)
}

fn to16(luma: FrameLuma) -> Patch {
    match luma {
        FrameLuma::Gamma8(g) => {
            let (w, h) = g.dimensions();
            let data = g
                .into_raw()
                .into_iter()
                .map(|v| v as u16 * GAMMA8_SCALE)
                .collect();
            (
                ImageBuffer::from_raw(w, h, data).expect("same size"),
                GAMMA8_SCALE,
            )
        }
        FrameLuma::Linear16(g) => (g, 1),
    }
}

#[derive(Serialize)]
struct CocoImage {
    id: usize,
    file_name: String,
    width: usize,
    height: usize,
    layer: u32,
    view: String,
    kind: JobKind,
    /// The flaw the patch is centred on, or (controls) the flaw it is the control of.
    flaw_id: u32,
    /// The patch's grid (docs/frames.md): pixel (r, c) is centred at
    /// (x_min + (c + 0.5)·pixel_mm, y_max − (r + 0.5)·pixel_mm).
    grid: Grid,
    /// 16-bit value = 8-bit luma x this for JPEG frames; 1 for raw (linear) frames.
    value_scale: u16,
}

#[derive(Serialize)]
struct CocoAnnotation {
    id: usize,
    image_id: usize,
    category_id: u32,
    /// [x, y, width, height] in patch pixels (x = column), the flaw's section in this layer.
    bbox: [f64; 4],
    area: f64,
    iscrowd: u8,
    flaw_id: u32,
    layer: u32,
    view: String,
}

#[derive(Serialize)]
struct CocoCategory {
    id: u32,
    name: &'static str,
    supercategory: &'static str,
}

/// The section boxes of every flaw at `layer` that reach into `grid`, as patch pixel boxes.
fn annotations_in(grid: &Grid, layer: u32, flaws: &[Flaw]) -> Vec<(u32, u32, [f64; 4])> {
    let p = grid.pixel_mm;
    let (w, h) = (grid.columns() as f64, grid.rows() as f64);
    flaws
        .iter()
        .flat_map(|f| {
            f.sections
                .iter()
                .filter(move |s| s.layer == layer && overlaps(grid, s.bbox_mm))
                .map(move |s| {
                    let x0 = ((s.bbox_mm[0] - grid.x_min) / p).clamp(0.0, w);
                    let x1 = ((s.bbox_mm[2] - grid.x_min) / p).clamp(0.0, w);
                    let y0 = ((grid.y_max - s.bbox_mm[3]) / p).clamp(0.0, h);
                    let y1 = ((grid.y_max - s.bbox_mm[1]) / p).clamp(0.0, h);
                    (f.id, f.kind.category(), [x0, y0, x1 - x0, y1 - y0])
                })
        })
        .collect()
}

/// Writes a PNG atomically, its folder created.
fn save_png(path: &Path, img: image::DynamicImage) -> Result<()> {
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|source| FlawsError::Image {
        path: path.to_path_buf(),
        source,
    })?;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    }
    Ok(crate::fsutil::write_atomic(path, &bytes, false)?)
}

/// Cuts, writes and labels the patches of every flaw of `table` in `out`.
pub fn cut_patches(
    record: &BuildRecord,
    table: &FlawTable,
    ct: Option<&CtContext>,
    options: &PatchOptions,
    out: &Path,
) -> Result<PatchSummary> {
    if options.patch_px == 0 || options.patch_px.is_multiple_of(2) || options.patch_px > 4096 {
        return Err(FlawsError::Invalid(format!(
            "patch size {} px: give an odd number of pixels up to 4095, so the flaw is the centre pixel",
            options.patch_px
        )));
    }
    let (jobs, not_found) = plan(record, &table.flaws, &table.flaws, options, ct);
    let views = views_of(record, options.phase);
    if views.is_empty() {
        return Err(FlawsError::Invalid(format!(
            "{}: the build captures no {} views (its [views] phases)",
            record.dir.display(),
            options.phase.map_or(String::new(), |p| p.to_string())
        )));
    }
    let patches = cut(record, &jobs, &views)?;
    let mut summary = PatchSummary {
        controls_not_found: not_found,
        ..PatchSummary::default()
    };
    let mut images = Vec::new();
    let mut annotations = Vec::new();
    let mut csv = String::from(
        "file,kind,flaw_id,layer,view,center_x_mm,center_y_mm,label,label_flaw_id,bbox_x,bbox_y,bbox_w,bbox_h\n",
    );
    for (job, cut) in jobs.iter().zip(&patches) {
        for (v, img) in cut.iter().enumerate() {
            let Some((img, value_scale)) = img else {
                summary.missing_frames += 1;
                continue;
            };
            let view = views[v];
            let file_name = format!("{}.png", job.stem(view));
            save_png(
                &out.join(&file_name),
                image::DynamicImage::ImageLuma16(img.clone()),
            )?;
            match job.kind {
                JobKind::Flaw => summary.flaw_patches += 1,
                JobKind::Control => summary.control_patches += 1,
            }
            let id = images.len() + 1;
            let (cx, cy) = job.grid.center_of(
                (job.grid.rows() / 2) as f64,
                (job.grid.columns() / 2) as f64,
            );
            let found = annotations_in(&job.grid, job.layer, &table.flaws);
            if found.is_empty() {
                csv.push_str(&format!(
                    "{file_name},{:?},{},{},{view},{cx:.4},{cy:.4},none,,,,,\n",
                    job.kind, job.flaw, job.layer
                ));
            }
            for (flaw_id, category, bbox) in found {
                let kind = table
                    .flaws
                    .iter()
                    .find(|f| f.id == flaw_id)
                    .map_or("", |f| f.kind.as_str());
                csv.push_str(&format!(
                    "{file_name},{:?},{},{},{view},{cx:.4},{cy:.4},{kind},{flaw_id},{:.2},{:.2},{:.2},{:.2}\n",
                    job.kind, job.flaw, job.layer, bbox[0], bbox[1], bbox[2], bbox[3]
                ));
                annotations.push(CocoAnnotation {
                    id: annotations.len() + 1,
                    image_id: id,
                    category_id: category,
                    bbox,
                    area: bbox[2] * bbox[3],
                    iscrowd: 0,
                    flaw_id,
                    layer: job.layer,
                    view: view.to_string(),
                });
            }
            images.push(CocoImage {
                id,
                file_name,
                width: job.grid.columns(),
                height: job.grid.rows(),
                layer: job.layer,
                view: view.to_string(),
                kind: job.kind,
                flaw_id: job.flaw,
                grid: job.grid,
                value_scale: *value_scale,
            });
        }
    }
    let csv = csv
        .replace("Flaw,", "flaw,")
        .replace("Control,", "control,");
    let coco = serde_json::json!({
        "info": {
            "description": "layerwise flaws: CT flaws on the layer-wise views",
            "ct": table.ct,
            "registration": table.registration,
            "build": record.dir.display().to_string(),
        },
        "images": images,
        "annotations": annotations,
        "categories": [
            CocoCategory { id: 1, name: "gas_pore", supercategory: "flaw" },
            CocoCategory { id: 2, name: "lack_of_fusion", supercategory: "flaw" },
        ],
    });
    for (name, text) in [
        (
            LABELS_JSON,
            serde_json::to_string_pretty(&coco).unwrap_or_default(),
        ),
        (LABELS_CSV, csv),
    ] {
        let path = out.join(name);
        crate::fsutil::write_atomic(&path, text.as_bytes(), false).map_err(FlawsError::from)?;
    }
    let flaw_jobs: Vec<(usize, &Job)> = jobs
        .iter()
        .enumerate()
        .filter(|(_, j)| j.kind == JobKind::Flaw)
        .take(options.sheet_rows)
        .collect();
    if !flaw_jobs.is_empty() {
        let sheet = draw_sheet(record, &views, &flaw_jobs, &patches, &table.flaws, ct);
        let path = out.join(CONTACT_SHEET);
        save_png(&path, image::DynamicImage::ImageRgb8(sheet))?;
        summary.sheet = Some(path);
    }
    Ok(summary)
}

/// The contact sheet of one flaw (`locate --flaw`): its patches in every view of every layer it
/// spans, no controls, no CT.
pub fn flaw_sheet(record: &BuildRecord, flaw: &Flaw, patch_px: usize, out: &Path) -> Result<()> {
    let options = PatchOptions {
        patch_px,
        controls: false,
        sheet_rows: usize::MAX,
        phase: None,
    };
    let (jobs, _) = plan(
        record,
        std::slice::from_ref(flaw),
        std::slice::from_ref(flaw),
        &options,
        None,
    );
    if jobs.is_empty() {
        return Err(FlawsError::Invalid(format!(
            "flaw {} spans no layer of the build",
            flaw.id
        )));
    }
    let views = views_of(record, None);
    let patches = cut(record, &jobs, &views)?;
    let rows: Vec<(usize, &Job)> = jobs.iter().enumerate().collect();
    let sheet = draw_sheet(
        record,
        &views,
        &rows,
        &patches,
        std::slice::from_ref(flaw),
        None,
    );
    save_png(out, image::DynamicImage::ImageRgb8(sheet))
}

/// Rows of tiles: the CT section (when the CT is at hand), then every view, each with the flaw's
/// section box in red and a label (flaw and layer on the first, then the view); views without a
/// frame are grey.
fn draw_sheet(
    record: &BuildRecord,
    views: &[View],
    rows: &[(usize, &Job)],
    patches: &[Vec<Option<Patch>>],
    flaws: &[Flaw],
    ct: Option<&CtContext>,
) -> RgbImage {
    let px = rows[0].1.grid.columns() as u32;
    let scale = (128 / px).max(1);
    let tile = px * scale;
    // Flaw and layer lead each row, on a line of their own when the tiles are too narrow.
    let widest_view = views.iter().map(|v| v.to_string().len()).max().unwrap_or(2);
    let longest = rows
        .iter()
        .map(|(_, job)| format!("F{} L{} ", job.flaw, job.layer).len() + widest_view)
        .max()
        .unwrap_or(0);
    let separator = if longest > sheet::chars_in(tile) {
        "\n"
    } else {
        " "
    };
    let sheet_rows: Vec<Vec<RgbImage>> = rows
        .iter()
        .map(|(j, job)| {
            let mut tiles: Vec<(Option<GrayImage>, String)> = Vec::new();
            if let Some(ct) = ct {
                tiles.push((Some(ct_section(record, job, ct)), "CT".into()));
            }
            tiles.extend(
                patches[*j]
                    .iter()
                    .zip(views)
                    .map(|(p, view)| (p.as_ref().map(|p| display8(&p.0)), view.to_string())),
            );
            let boxes = annotations_in(&job.grid, job.layer, flaws);
            tiles
                .iter()
                .enumerate()
                .map(|(c, (t, name))| {
                    let mut img = RgbImage::from_fn(tile, tile, |x, y| {
                        let v = t
                            .as_ref()
                            .map_or(128, |t| t.get_pixel(x / scale, y / scale)[0]);
                        Rgb([v, v, v])
                    });
                    for (_, _, b) in &boxes {
                        let s = scale as f64;
                        let (bx0, by0) = ((b[0] * s) as u32, (b[1] * s) as u32);
                        let bx1 = (((b[0] + b[2]) * s) as u32).min(tile - 1);
                        let by1 = (((b[1] + b[3]) * s) as u32).min(tile - 1);
                        for x in bx0..=bx1 {
                            img.put_pixel(x, by0, Rgb([255, 0, 0]));
                            img.put_pixel(x, by1, Rgb([255, 0, 0]));
                        }
                        for y in by0..=by1 {
                            img.put_pixel(bx0, y, Rgb([255, 0, 0]));
                            img.put_pixel(bx1, y, Rgb([255, 0, 0]));
                        }
                    }
                    let label = match (c, separator) {
                        (0, _) => format!("F{} L{}{separator}{name}", job.flaw, job.layer),
                        (_, "\n") => format!("\n{name}"),
                        _ => name.clone(),
                    };
                    sheet::labelled(&img, &label)
                })
                .collect()
        })
        .collect();
    sheet::sheet(&sheet_rows, 4)
}

/// 8-bit for looking at: the patch's own range stretched.
fn display8(img: &Gray16Image) -> GrayImage {
    let lo = img.as_raw().iter().copied().min().unwrap_or(0) as f64;
    let hi = img.as_raw().iter().copied().max().unwrap_or(0) as f64;
    let span = (hi - lo).max(1.0);
    GrayImage::from_fn(img.width(), img.height(), |x, y| {
        Luma([((img.get_pixel(x, y)[0] as f64 - lo) / span * 255.0).round() as u8])
    })
}

/// The CT on the patch's grid at the middle of the layer (nearest voxel), void black, material
/// white.
fn ct_section(record: &BuildRecord, job: &Job, ct: &CtContext) -> GrayImage {
    let z = record.heights.z(job.layer) - 0.5 * record.heights.thickness(job.layer);
    let span = (ct.material_level - ct.void_level).max(f64::MIN_POSITIVE);
    let g = job.grid;
    GrayImage::from_fn(g.columns() as u32, g.rows() as u32, |c, r| {
        let (x, y) = g.center_of(r as f64, c as f64);
        let v = ct
            .labels
            .voxel_at([x, y, z])
            .map_or(0.0, |i| (ct.volume.value(i) - ct.void_level) / span);
        Luma([(v.clamp(0.0, 1.0) * 255.0).round() as u8])
    })
}
