//! After the build: where one point of the build frame is in every modality: its layer, its pixel
//! in each rectified view and original frame, and its voxel in the registered CT; `mark` draws it
//! side by side (the paper's Fig. 9).

use crate::ct::{CtLocation, Volume};
use crate::geometry::{BuildPoint, Rigid3};
use crate::raster::sheet;
use crate::rectify::Rectifier;
use crate::series::{series_dir, BuildRecord};
use crate::shot::{Shot, View};
use serde::Serialize;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum LocateError {
    #[error("{0}")]
    Invalid(String),
    #[error("the calibration cannot rectify the build's grid")]
    Calibration(#[source] crate::rectify::RectifyError),
    #[error(transparent)]
    Vectors(#[from] crate::vectors::VectorError),
    #[error("cannot draw the layer's vectors")]
    Raster(#[from] crate::raster::RasterError),
    #[error("CT: cannot resample the section through the point")]
    Ct(#[source] crate::ct::CtError),
    #[error("cannot read {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Original(#[from] crate::build_dir::original::OriginalError),
    #[error("{path}: cannot decode the frame")]
    Decode {
        path: PathBuf,
        #[source]
        source: crate::rectify::RectifyError,
    },
    #[error("cannot write {path}")]
    Write {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
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
    /// The original frame's size (width, height) in pixels, when it could be read.
    pub frame_size: Option<[u32; 2]>,
}

impl ViewLocation {
    /// Whether the image pixel falls inside the original frame (None: unknown).
    pub fn in_frame(&self) -> Option<bool> {
        let ([u, v], [w, h]) = (self.image_pixel?, self.frame_size?);
        Some(u >= -0.5 && v >= -0.5 && u <= f64::from(w) - 0.5 && v <= f64::from(h) - 0.5)
    }
}

#[derive(Clone, Debug, Serialize)]
pub struct Location {
    /// The point in the build frame, mm.
    pub build_mm: [f64; 3],
    pub ct: Option<CtLocation>,
    pub layer: Option<u32>,
    pub layer_z_mm: Option<f64>,
    /// Why the point has no layer (above or below the build), when it has none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outside: Option<String>,
    pub views: Vec<ViewLocation>,
}

/// Where `point` (build mm) is in the layer stack, the rectified views and the original frames.
pub fn locate(record: &BuildRecord, point: [f64; 3]) -> Result<Location, LocateError> {
    let mut layer = record.heights.layer_at(point[2]);
    let mut outside = None;
    if let Some(last) = last_layer(record) {
        let top = record.heights.z(last);
        if point[2] > top + 1e-9 {
            layer = None;
            outside = Some(format!(
                "z = {} mm is above the last layer of the build in {} (layer {last}, top at z = {top:.4} mm)",
                point[2],
                record.dir.display(),
            ));
        }
    }
    if layer.is_none() && outside.is_none() {
        outside = Some(format!("z = {} mm is in no layer of the build", point[2]));
    }
    let rectifier = match &record.calibration {
        Some(c) => Some(
            Rectifier::new(&c.camera(), record.grid, Default::default(), 0)
                .map_err(LocateError::Calibration)?,
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
            let original = shot.and_then(|s| crate::build_dir::original_path(&record.dir, &s));
            ViewLocation {
                view: view.to_string(),
                rectified_pixel: on_grid.then_some([row, col]),
                dicom,
                image_pixel: rectifier
                    .as_ref()
                    .and_then(|r| r.image_point(BuildPoint::new(point[0], point[1])))
                    .map(|p| [p.u, p.v]),
                frame_size: original
                    .as_ref()
                    .and_then(|p| image::image_dimensions(p).ok())
                    .map(|(w, h)| [w, h]),
                original,
            }
        })
        .collect();
    Ok(Location {
        ct: None,
        build_mm: point,
        layer,
        layer_z_mm: layer.map(|k| record.heights.z(k)),
        outside,
        views,
    })
}

/// The build's last layer: the highest one the journal recorded, else the configured count.
fn last_layer(record: &BuildRecord) -> Option<u32> {
    let journal = record.dir.join(crate::build_dir::JOURNAL);
    let recorded = crate::build_dir::journal::Journal::read(&journal)
        .ok()
        .and_then(|r| {
            r.frames
                .keys()
                .chain(r.missing.keys())
                .map(|s| s.layer)
                .max()
        });
    recorded.or(record.config.build.layers)
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.build_mm;
        writeln!(f, "build point   ({x}, {y}, {z}) mm")?;
        match (self.layer, self.layer_z_mm) {
            (Some(k), Some(zk)) => writeln!(f, "layer         {k} (top at z = {zk} mm)")?,
            _ => writeln!(
                f,
                "layer         none: {}",
                self.outside.as_deref().unwrap_or("z is outside the build")
            )?,
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
            let outside = match (v.in_frame(), v.frame_size) {
                (Some(false), Some([w, h])) => format!(" (outside the {w} x {h} frame)"),
                _ => String::new(),
            };
            let img = v.image_pixel.map_or("not in view".to_string(), |[u, v]| {
                format!("u {u:.1}, v {v:.1}{outside}")
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

/// The registered CT for [`mark`]'s CT tile.
pub struct CtSection<'a> {
    pub volume: &'a Volume,
    /// CT physical mm → build mm (ct.toml's `transform`).
    pub build_from_ct: Rigid3,
}

/// Draws the point in each view, side by side: the layer's vectors, the CT's section through
/// the point in the layer plane (with `ct`), then per view the rectified view (re-rectified from
/// the original, the same pixels as its DICOM slice) and the original frame, cropped around the
/// point, each with a green marker and a label (what, layer, pixel): the paper's Fig. 9.
pub fn mark(
    record: &BuildRecord,
    location: &Location,
    ct: Option<&CtSection>,
    out: &Path,
) -> Result<(), LocateError> {
    const HALF: i64 = 80;
    let calibration = record
        .calibration
        .as_ref()
        .ok_or_else(|| LocateError::Invalid("the build has no calibration.toml".into()))?;
    let rectifier = Rectifier::new(&calibration.camera(), record.grid, Default::default(), 0)
        .map_err(LocateError::Calibration)?;
    let mut tiles: Vec<(image::RgbImage, String)> = Vec::new();
    let rgb = |gray: image::GrayImage| image::DynamicImage::ImageLuma8(gray).to_rgb8();
    let on_grid = location.views.first().and_then(|v| v.rectified_pixel);
    let layer_label = location
        .layer
        .map_or("no layer".into(), |k| format!("L{k}"));
    // First the laser vectors of the layer (contours blue, hatches red), as in the paper's Fig. 9.
    if let (Some(path), Some(k), Some([r, c])) =
        (&record.config.build.vectors, location.layer, on_grid)
    {
        let file = crate::vectors::read(path)?;
        let map = crate::vectors::LayerMap::of_file(&file, record.config.build.numbering());
        if let Some(layer) = map.position(k).and_then(|p| file.layers.get(p)) {
            let picture = crate::raster::rgb(
                layer,
                &record.grid,
                &crate::raster::RasterOptions::default(),
            )?;
            tiles.push((
                crop_with_marker(&picture, r, c, HALF),
                format!("vectors {layer_label}"),
            ));
        }
    }
    // The CT through the point, in the layer plane, on the same pixels.
    if let (Some(ct), Some(_)) = (ct, on_grid) {
        let [x, y, z] = location.build_mm;
        let side = (2 * HALF + 1) as usize;
        let crop = record.grid.patch_around([x, y], side);
        let thickness = location.layer.map_or(0.03, |k| record.heights.thickness(k));
        let slices = crate::ct::resample::resample_slices(
            ct.volume,
            &ct.build_from_ct,
            crop,
            &[(location.layer.unwrap_or(0), z, thickness)],
        )
        .map_err(LocateError::Ct)?;
        if let Some(slice) = slices.first() {
            let gray = image::GrayImage::from_fn(side as u32, side as u32, |c, r| {
                image::Luma([(slice.pixels[r as usize * side + c as usize] >> 8) as u8])
            });
            let h = HALF as f64;
            tiles.push((
                crop_with_marker(&rgb(gray), h, h, HALF),
                format!("CT {layer_label} z {z:.3}"),
            ));
        }
    }
    for v in &location.views {
        let Some(original) = &v.original else {
            continue;
        };
        let bytes = crate::build_dir::original::read(original)?.bytes;
        let luma =
            crate::rectify::decode_frame_luma(&bytes).map_err(|source| LocateError::Decode {
                path: original.clone(),
                source,
            })?;
        if let Some([r, c]) = v.rectified_pixel {
            let rect = luma.rectified(&rectifier).to_display8();
            tiles.push((
                crop_with_marker(&rgb(rect), r, c, HALF),
                format!("{} {layer_label} r{r:.0} c{c:.0}", v.view),
            ));
        }
        if let Some([u, vv]) = v.image_pixel {
            tiles.push((
                crop_with_marker(&rgb(luma.to_display8()), vv, u, HALF),
                format!("{} frame u{u:.0} v{vv:.0}", v.view),
            ));
        }
    }
    if tiles.is_empty() {
        return Err(LocateError::Invalid(
            "nothing to draw: no frame of that layer holds the point".into(),
        ));
    }
    let row: Vec<image::RgbImage> = tiles
        .iter()
        .map(|(tile, label)| sheet::labelled(tile, label))
        .collect();
    sheet::sheet(&[row], 4)
        .save(out)
        .map_err(|source| LocateError::Write {
            path: out.to_path_buf(),
            source,
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
