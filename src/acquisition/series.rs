//! The live DICOM series: each stored original is decoded, reduced to luma (the CT Image IOD is
//! MONOCHROME2; colour stays in the original), rectified onto the build grid through the
//! calibration and written as the slice of its layer in its view's series.

use super::processing::FrameProcessor;
use super::status::BuildManifest;
use crate::config::Config;
use crate::dicom::{self, Compression, Plane, Series, Slice, Study};
use crate::rectify::{self, Calibration, FrameLuma, Grid, Interpolation, Rectifier};
use crate::vectors::LayerIndex;
use crate::view::{Shot, View};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Where layer k sits in z: the k-th layer of the vector file, or k x the layer thickness.
#[derive(Clone, Debug)]
pub struct LayerHeights {
    z_mm: Option<Vec<f64>>,
    thickness_mm: f64,
}

impl LayerHeights {
    pub fn from_config(config: &Config) -> Result<LayerHeights, String> {
        let thickness_mm = config.build.layer_thickness_mm;
        let z_mm = match &config.build.vectors {
            Some(path) => {
                let index = LayerIndex::build(path).map_err(|e| e.to_string())?;
                Some((0..index.len()).filter_map(|k| index.z_mm(k)).collect())
            }
            None => None,
        };
        Ok(LayerHeights { z_mm, thickness_mm })
    }

    pub fn uniform(thickness_mm: f64) -> LayerHeights {
        LayerHeights {
            z_mm: None,
            thickness_mm,
        }
    }

    /// z of layer `layer` (1-based, as the printer counts).
    pub fn z(&self, layer: u32) -> f64 {
        match &self.z_mm {
            Some(z) if layer >= 1 && (layer as usize) <= z.len() => z[layer as usize - 1],
            _ => layer as f64 * self.thickness_mm,
        }
    }

    /// The layer whose slab (z of the layer below, z of the layer] holds `z`.
    pub fn layer_at(&self, z: f64) -> Option<u32> {
        match &self.z_mm {
            Some(zs) => {
                let k = zs.partition_point(|&top| top < z - 1e-9);
                let bottom = if k == 0 {
                    zs.first().map(|z1| z1 - self.thickness_mm)?
                } else {
                    zs[k - 1]
                };
                (k < zs.len() && z > bottom - 1e-9).then_some(k as u32 + 1)
            }
            None => {
                let k = (z / self.thickness_mm - 1e-9).ceil();
                (k >= 1.0 && k <= u32::MAX as f64).then_some(k as u32)
            }
        }
    }

    /// Thickness of layer `layer`: its z minus the one below.
    pub fn thickness(&self, layer: u32) -> f64 {
        match &self.z_mm {
            Some(z) if layer >= 2 && (layer as usize) <= z.len() => {
                let t = z[layer as usize - 1] - z[layer as usize - 2];
                if t > 0.0 {
                    t
                } else {
                    self.thickness_mm
                }
            }
            _ => self.thickness_mm,
        }
    }
}

/// How the live series are made.
#[derive(Clone, Debug)]
pub struct SeriesSettings {
    pub grid: Grid,
    pub heights: LayerHeights,
    pub compression: Compression,
    pub interpolation: Interpolation,
    pub fill: u16,
}

impl SeriesSettings {
    /// From the daemon's configuration: the grid (cropped around `calibration.crop_part` when
    /// set), layer heights, transfer syntax and interpolation.
    pub fn from_config(config: &Config) -> Result<SeriesSettings, String> {
        let grid = match (config.calibration.crop_part, &config.build.vectors) {
            (Some(part), Some(vectors)) => {
                let info = crate::vectors::info(vectors).map_err(|e| e.to_string())?;
                let bbox = info
                    .parts
                    .iter()
                    .find(|p| p.id == part)
                    .and_then(|p| p.bbox)
                    .ok_or_else(|| {
                        format!(
                            "calibration.crop_part: {} has no part {part} with geometry",
                            vectors.display()
                        )
                    })?;
                config
                    .rectify
                    .around(bbox, config.calibration.crop_margin_mm)
            }
            _ => config.rectify,
        };
        Ok(SeriesSettings {
            grid,
            heights: LayerHeights::from_config(config)?,
            compression: config.storage.dicom,
            interpolation: config.calibration.interpolation,
            fill: config.calibration.fill,
        })
    }
}

/// One series per view, all in the build's study.
pub struct LiveSeries {
    study: Study,
    series: BTreeMap<View, Series>,
    /// Where the series folders go instead of `<build_dir>/dicom` (the exporter's).
    root: Option<PathBuf>,
    rectifier: Rectifier,
    heights: LayerHeights,
    compression: Compression,
}

/// The series folder of a view: `dicom/<phase>_<light>/`.
pub fn series_dir(build_dir: &Path, view: View) -> PathBuf {
    build_dir.join("dicom").join(view.to_string())
}

impl LiveSeries {
    pub fn new(
        manifest: &BuildManifest,
        views: &[View],
        calibration: &Calibration,
        settings: SeriesSettings,
    ) -> Result<LiveSeries, String> {
        let SeriesSettings {
            grid,
            heights,
            compression,
            interpolation,
            fill,
        } = settings;
        let study = Study::of_build(manifest);
        let series = views
            .iter()
            .enumerate()
            .map(|(i, view)| {
                (
                    *view,
                    Series::named(&study, i as u32 + 1, &view.to_string()),
                )
            })
            .collect();
        let rectifier = Rectifier::new(
            calibration.homography,
            grid,
            calibration.distortion,
            interpolation,
            fill,
        )
        .map_err(|e| format!("calibration: {e}"))?;
        Ok(LiveSeries {
            root: None,
            study,
            series,
            rectifier,
            heights,
            compression,
        })
    }

    /// The rectified luma of an original, as the slice will hold it: 8-bit luma of a JPEG, or
    /// linear 16-bit luminance of a raw frame.
    pub fn rectified_luma(&self, original: &[u8]) -> Result<FrameLuma, String> {
        let luma = rectify::decode_frame_luma(original).map_err(|e| e.to_string())?;
        Ok(luma.rectified(&self.rectifier))
    }

    /// The same series under other names (`{view} {label}`, numbered from `first_number`) in
    /// folders below `root`: how the exporter writes its copies (e.g. cropped to a part).
    pub fn relabelled(mut self, root: &Path, label: &str, first_number: u32) -> LiveSeries {
        for (i, (view, series)) in self.series.iter_mut().enumerate() {
            let name = if label.is_empty() {
                view.to_string()
            } else {
                format!("{view} {label}")
            };
            *series = Series::named(&self.study, first_number + i as u32, &name);
        }
        self.root = Some(root.to_path_buf());
        self
    }

    /// Where the slice of `shot` is written.
    pub fn slice_path(&self, build_dir: &Path, shot: Shot) -> PathBuf {
        let dir = match &self.root {
            Some(root) => root.join(self.series.get(&shot.view()).map_or_else(
                || shot.view().to_string(),
                |s| s.description.replace(' ', "_"),
            )),
            None => series_dir(build_dir, shot.view()),
        };
        dir.join(format!("L{:05}.dcm", shot.layer))
    }

    /// The grid the slices are on.
    pub fn grid(&self) -> Grid {
        self.rectifier.grid()
    }

    pub fn study(&self) -> &Study {
        &self.study
    }

    pub fn write(
        &self,
        build_dir: &Path,
        shot: Shot,
        original: &[u8],
        acquired: Option<chrono::DateTime<chrono::Utc>>,
    ) -> Result<PathBuf, String> {
        let series = self
            .series
            .get(&shot.view())
            .ok_or_else(|| format!("view {} is not configured", shot.view()))?;
        let rectified = self.rectified_luma(original)?;
        let (window, derivation) = (rectified.window(), rectified.derivation());
        let pixels = rectified.into_u16();
        let grid = self.rectifier.grid();
        let plane = Plane {
            origin: [
                grid.x_min + grid.pixel_mm / 2.0,
                grid.y_max - grid.pixel_mm / 2.0,
                self.heights.z(shot.layer),
            ],
            pixel_mm: grid.pixel_mm,
            rows: grid.rows(),
            columns: grid.columns(),
            thickness_mm: self.heights.thickness(shot.layer),
        };
        let slice = Slice {
            layer: shot.layer,
            plane,
            pixels: &pixels,
            acquired,
            window,
            derivation,
        };
        let path = self.slice_path(build_dir, shot);
        dicom::write_slice(&path, &self.study, series, &slice, self.compression)
            .map_err(|e| e.to_string())?;
        Ok(path)
    }
}

impl FrameProcessor for LiveSeries {
    fn process(&self, build_dir: &Path, shot: Shot, original: &Path) -> Result<(), String> {
        let bytes = std::fs::read(original).map_err(|e| format!("{}: {e}", original.display()))?;
        let sidecar = original.with_extension("json");
        let acquired = std::fs::read(&sidecar)
            .ok()
            .and_then(|b| serde_json::from_slice::<super::storage::Sidecar>(&b).ok())
            .map(|s| s.captured_at);
        self.write(build_dir, shot, &bytes, acquired).map(|_| ())
    }
}
