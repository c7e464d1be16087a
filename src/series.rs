//! The live DICOM series: each stored original is decoded, reduced to luma (the CT Image IOD is
//! MONOCHROME2; colour stays in the original), rectified onto the build grid through the
//! calibration and written as the slice of its layer in its view's series.

use crate::build_dir::BuildManifest;
use crate::clock::ms_since;
use crate::config::Config;
use crate::dicom::{self, Compression, DicomError, Plane, Series, Slice, SliceSource, Study};
use crate::fsutil::{Pending, TomlFileError};
use crate::rectify::{self, Calibration, FrameLuma, Grid, Interpolation, Rectifier, RectifyError};
use crate::shot::{Shot, View};
use crate::vectors::{LayerIndex, LayerMap, VectorError};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Why a frame could not be processed, for the journal (the build goes on).
pub type ProcessError = Box<dyn std::error::Error + Send + Sync>;

/// What is left of a take once its slice is written but not yet durable
/// ([`FrameProcessor::process_take_then`]): the slice's commit and what must wait for it.
pub type Then<'a> = Box<dyn FnOnce() -> Result<(), ProcessError> + Send + 'a>;

/// The rest of a take whose slice is `pending`: its commit (timed into `steps`), then the
/// frame's `frame processed` line.
pub fn commit_then(pending: Pending, mut steps: StepTimes, shot: Shot) -> Then<'static> {
    Box::new(move || {
        committed(pending, &mut steps)?;
        steps.log(shot);
        Ok(())
    })
}

/// Commits a slice ([`Pending::commit`]), its time in `steps`; where it now is.
fn committed(pending: Pending, steps: &mut StepTimes) -> Result<PathBuf, SeriesError> {
    let path = pending.path().to_path_buf();
    let started = Instant::now();
    pending.commit().map_err(DicomError::from)?;
    steps.commit_ms = ms_since(started);
    Ok(path)
}

/// Work done on each stored original after capture.
pub trait FrameProcessor: Send + Sync {
    /// `original` is the stored file; errors are recorded in the journal and do not stop the build.
    fn process(&self, build_dir: &Path, shot: Shot, original: &Path) -> Result<(), ProcessError>;

    /// Take `take` of `shot` (1: the frame, more: a retake that replaces the slice with
    /// `[series] take = "last"`); `original` is that take's file.
    fn process_take(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<(), ProcessError> {
        let _ = take;
        self.process(build_dir, shot, original)
    }

    /// [`FrameProcessor::process_take`] up to where it waits for the disk: what it returns does
    /// the rest (the slice's fsync and rename, and what follows them), and the processing worker
    /// runs that on its commit thread while this one goes on with the next frame. The default
    /// does everything here and leaves nothing.
    fn process_take_then(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<Then<'_>, ProcessError> {
        self.process_take(build_dir, shot, take, original)?;
        Ok(Box::new(|| Ok(())))
    }

    /// Called once by the processing worker when it ends (drained or stopped): a processor with
    /// threads of its own (the inspection's alarm) stops them here. `ended`: the build is over
    /// and every frame of it was processed, so what waits for frames that will not come (the
    /// inspection of a last layer a view is missing from) can be completed now.
    fn finish(&self, _ended: bool) {}

    /// Frames already processed that this processor wants again before new ones, with their
    /// take and the journal's file (the inspection's layers a stop left uninspected): the
    /// worker processes them first, with the backlog.
    fn catch_up(&self) -> Vec<(Shot, u32, String)> {
        Vec::new()
    }

    /// A fault of the processor's own parts that the operator must see in the build's health
    /// (the inspection's alarm cannot switch its light, or stopped), while it lasts.
    fn fault(&self) -> Option<String> {
        None
    }
}

/// Keeps originals only.
pub struct KeepOriginals;

impl FrameProcessor for KeepOriginals {
    fn process(
        &self,
        _build_dir: &Path,
        _shot: Shot,
        _original: &Path,
    ) -> Result<(), ProcessError> {
        Ok(())
    }
}

/// Why a series (or a build's record of how its series were made) could not be made.
#[derive(Debug, thiserror::Error)]
pub enum SeriesError {
    #[error(
        "{0}: not a layerwise build directory ({1} missing); pass the daemon's build.output_dir"
    )]
    NotABuild(PathBuf, &'static str),
    /// The build's configuration snapshot.
    #[error(transparent)]
    Config(#[from] crate::config::ConfigError),
    /// The calibration file.
    #[error(transparent)]
    File(#[from] TomlFileError),
    #[error(transparent)]
    Vectors(#[from] VectorError),
    #[error("the calibration cannot rectify the grid")]
    Rectifier(#[source] RectifyError),
    #[error(transparent)]
    Decode(#[from] RectifyError),
    #[error(transparent)]
    Dicom(#[from] DicomError),
    #[error(transparent)]
    Original(#[from] crate::build_dir::original::OriginalError),
    #[error("calibration.crop_part: {file} has no part {part} with geometry")]
    NoSuchPart { file: PathBuf, part: i64 },
    #[error("view {0} is not configured")]
    UnknownView(View),
}

/// Where printer layer k sits in z: the z of the vector file's layer that the build's
/// numbering pairs with it (`vectors::LayerMap`), or k x the layer thickness.
#[derive(Clone, Debug)]
pub struct LayerHeights {
    map: Option<LayerMap>,
    thickness_mm: f64,
}

impl LayerHeights {
    pub fn from_config(config: &Config) -> Result<LayerHeights, SeriesError> {
        let thickness_mm = config.build.layer_thickness_mm;
        let map = match &config.build.vectors {
            Some(path) => Some(LayerIndex::build(path)?.layer_map(config.build.numbering())),
            None => None,
        };
        Ok(LayerHeights { map, thickness_mm })
    }

    pub fn uniform(thickness_mm: f64) -> LayerHeights {
        LayerHeights {
            map: None,
            thickness_mm,
        }
    }

    /// The match of printer layers to the vector file, when the build has one.
    pub fn map(&self) -> Option<&LayerMap> {
        self.map.as_ref()
    }

    /// z of layer `layer` (1-based, as the printer counts).
    pub fn z(&self, layer: u32) -> f64 {
        self.map
            .as_ref()
            .and_then(|m| m.z_mm(layer))
            .unwrap_or(layer as f64 * self.thickness_mm)
    }

    /// The layer whose slab (z of the layer below, z of the layer] holds `z`.
    pub fn layer_at(&self, z: f64) -> Option<u32> {
        let Some(map) = &self.map else {
            let k = (z / self.thickness_mm - 1e-9).ceil();
            return (k >= 1.0 && k <= u32::MAX as f64).then_some(k as u32);
        };
        let (first, last) = map.range()?;
        // Printer layers in z order: the first whose top is at or above z.
        let (mut lo, mut hi) = (first, last);
        if self.z(last) < z - 1e-9 {
            return None;
        }
        while lo < hi {
            let mid = lo + (hi - lo) / 2;
            if self.z(mid) < z - 1e-9 {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        let bottom = self.z(lo) - self.thickness(lo);
        (z > bottom - 1e-9).then_some(lo)
    }

    /// Thickness of layer `layer`: its z minus the one below.
    pub fn thickness(&self, layer: u32) -> f64 {
        let below = layer
            .checked_sub(1)
            .and_then(|b| self.map.as_ref()?.z_mm(b));
        match (self.map.as_ref().and_then(|m| m.z_mm(layer)), below) {
            (Some(z), Some(b)) if z - b > 0.0 => z - b,
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
    pub fn from_config(config: &Config) -> Result<SeriesSettings, SeriesError> {
        let grid = match (config.calibration.crop_part, &config.build.vectors) {
            (Some(part), Some(vectors)) => {
                let info = crate::vectors::info(vectors)?;
                let bbox = info
                    .part_bbox(part)
                    .ok_or_else(|| SeriesError::NoSuchPart {
                        file: vectors.clone(),
                        part,
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

pub use crate::build_dir::series_dir;

impl LiveSeries {
    pub fn new(
        manifest: &BuildManifest,
        views: &[View],
        calibration: &Calibration,
        settings: SeriesSettings,
    ) -> Result<LiveSeries, SeriesError> {
        let SeriesSettings {
            grid,
            heights,
            compression,
            interpolation,
            fill,
        } = settings;
        let study = manifest.study();
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
        let rectifier = Rectifier::new(&calibration.camera(), grid, interpolation, fill)
            .map_err(SeriesError::Rectifier)?;
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
    pub fn rectified_luma(&self, original: &[u8]) -> Result<FrameLuma, SeriesError> {
        self.rectified_luma_timed(original, &mut StepTimes::default())
    }

    /// [`LiveSeries::rectified_luma`], its decode and rectify times put in `steps`.
    pub fn rectified_luma_timed(
        &self,
        original: &[u8],
        steps: &mut StepTimes,
    ) -> Result<FrameLuma, SeriesError> {
        let started = Instant::now();
        let luma = rectify::decode_frame_luma_for(original, &self.rectifier)?;
        steps.decode_ms = ms_since(started);
        let started = Instant::now();
        let rectified = luma.rectified(&self.rectifier);
        steps.rectify_ms = ms_since(started);
        luma.recycle();
        Ok(rectified)
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

    /// The camera the slices are rectified from.
    pub fn camera(&self) -> &crate::geometry::CameraModel {
        self.rectifier.camera()
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
        source: Option<SliceSource>,
    ) -> Result<PathBuf, SeriesError> {
        let rectified = self.rectified_luma(original)?;
        let steps = &mut StepTimes::default();
        let pending =
            self.write_rectified_pending(build_dir, shot, rectified, acquired, source, steps)?;
        committed(pending, steps)
    }

    /// Writes the slice of a frame already rectified ([`LiveSeries::rectified_luma`]), made
    /// from `source` (its take picks the SOP Instance UID), beside its place: not yet fsynced
    /// nor in place until [`Pending::commit`], which replaces the slice atomically. Its encode
    /// and write times go into `steps`.
    pub fn write_rectified_pending(
        &self,
        build_dir: &Path,
        shot: Shot,
        rectified: FrameLuma,
        acquired: Option<chrono::DateTime<chrono::Utc>>,
        source: Option<SliceSource>,
        steps: &mut StepTimes,
    ) -> Result<Pending, SeriesError> {
        let series = self
            .series
            .get(&shot.view())
            .ok_or(SeriesError::UnknownView(shot.view()))?;
        let (window, derivation) = (rectified.window(), rectified.derivation());
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
            pixels: rectified.samples(),
            acquired,
            window,
            derivation,
        };
        let path = self.slice_path(build_dir, shot);
        let (times, pending) = dicom::write_slice_pending(
            &path,
            &self.study,
            series,
            &slice,
            self.compression,
            source,
        )?;
        (steps.encode_ms, steps.write_ms) = (times.encode_ms, times.write_ms);
        Ok(pending)
    }
}

impl LiveSeries {
    /// Writes the slice of take `take` of a stored original (its sidecar gives the acquisition
    /// time; ImageComments names the take and the file).
    pub fn write_original(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<PathBuf, SeriesError> {
        let steps = &mut StepTimes::default();
        let pending = self.write_original_pending(build_dir, shot, take, original, steps)?;
        committed(pending, steps)
    }

    /// [`LiveSeries::write_original`] up to the slice's commit ([`Pending::commit`]), the time
    /// of each step put in `steps`.
    pub fn write_original_pending(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
        steps: &mut StepTimes,
    ) -> Result<Pending, SeriesError> {
        let see = |_: &FrameLuma, _: &mut StepTimes| ();
        let (pending, ()) =
            self.write_original_seen(build_dir, shot, take, original, steps, see)?;
        Ok(pending)
    }

    /// [`LiveSeries::write_original_pending`], the rectified view shown to `see` before it is
    /// written (the inspection reduces it to its cells there); with what `see` gave.
    pub fn write_original_seen<T>(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
        steps: &mut StepTimes,
        see: impl FnOnce(&FrameLuma, &mut StepTimes) -> T,
    ) -> Result<(Pending, T), SeriesError> {
        let started = Instant::now();
        let (bytes, acquired) = read_original(original)?;
        steps.read_ms = ms_since(started);
        let file = source_file(build_dir, original);
        let source = SliceSource { take, file: &file };
        let rectified = self.rectified_luma_timed(&bytes, steps)?;
        let seen = see(&rectified, steps);
        let pending = self.write_rectified_pending(
            build_dir,
            shot,
            rectified,
            acquired,
            Some(source),
            steps,
        )?;
        Ok((pending, seen))
    }
}

/// How long each step of one frame's processing took, ms: reading the original (checked
/// against its sidecar), decoding it to luma, rectifying, encoding the slice, writing it, making
/// it durable and putting it in place (its commit: fsync, rename); and, with inspection on,
/// reducing it to the inspection's cells. Said at DEBUG as `frame processed` (the
/// signal-to-screen benchmark reads them there).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepTimes {
    pub read_ms: f64,
    pub decode_ms: f64,
    pub rectify_ms: f64,
    pub encode_ms: f64,
    pub write_ms: f64,
    pub commit_ms: f64,
    pub cells_ms: f64,
}

impl StepTimes {
    /// The DEBUG line of the frame of `shot` processed.
    pub fn log(&self, shot: Shot) {
        tracing::debug!(
            layer = shot.layer,
            view = %shot.view(),
            read_ms = self.read_ms,
            decode_ms = self.decode_ms,
            rectify_ms = self.rectify_ms,
            encode_ms = self.encode_ms,
            write_ms = self.write_ms,
            commit_ms = self.commit_ms,
            cells_ms = self.cells_ms,
            "frame processed"
        );
    }
}

/// How a slice names its original: relative to the build directory (`raw/L00003_post_front.jpg`).
pub fn source_file(build_dir: &Path, original: &Path) -> String {
    original
        .strip_prefix(build_dir)
        .unwrap_or(original)
        .to_string_lossy()
        .into_owned()
}

/// A stored original's bytes, checked against its sidecar, and when it was captured
/// (build_dir::original: from `raw/` only, a regular file of a frame's size at most).
pub fn read_original(
    original: &Path,
) -> Result<(Vec<u8>, Option<chrono::DateTime<chrono::Utc>>), SeriesError> {
    let original = crate::build_dir::original::read(original)?;
    Ok((original.bytes, Some(original.sidecar.captured_at)))
}

impl FrameProcessor for LiveSeries {
    fn process(&self, build_dir: &Path, shot: Shot, original: &Path) -> Result<(), ProcessError> {
        self.process_take(build_dir, shot, 1, original)
    }

    fn process_take(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<(), ProcessError> {
        self.process_take_then(build_dir, shot, take, original)?()
    }

    fn process_take_then(
        &self,
        build_dir: &Path,
        shot: Shot,
        take: u32,
        original: &Path,
    ) -> Result<Then<'_>, ProcessError> {
        let mut steps = StepTimes::default();
        let pending = self.write_original_pending(build_dir, shot, take, original, &mut steps)?;
        Ok(commit_then(pending, steps, shot))
    }
}

/// What `layerwise status` and the page take from a build's configuration (its snapshot):
/// `storage.min_free_gb` and `[series] take`; the defaults without one.
pub fn report_settings(config: Option<&Config>) -> crate::build_dir::status::ReportSettings {
    let (storage, series) = match config {
        Some(config) => (config.storage.clone(), config.series.clone()),
        None => Default::default(),
    };
    crate::build_dir::status::ReportSettings {
        min_free_bytes: (storage.min_free_gb * 1e9) as u64,
        take: series.take,
    }
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
    pub fn open(dir: &Path) -> Result<BuildRecord, SeriesError> {
        let config_path = dir.join(crate::build_dir::CONFIG_SNAPSHOT);
        if !config_path.exists() {
            return Err(SeriesError::NotABuild(
                dir.to_path_buf(),
                crate::build_dir::CONFIG_SNAPSHOT,
            ));
        }
        let config = Config::load(&config_path)?;
        let calibration_path = dir.join(crate::build_dir::CALIBRATION_COPY);
        let calibration = if calibration_path.exists() {
            Some(Calibration::load(&calibration_path)?)
        } else {
            None
        };
        let settings = SeriesSettings::from_config(&config)?;
        Ok(BuildRecord {
            dir: dir.to_path_buf(),
            config,
            calibration,
            grid: settings.grid,
            heights: settings.heights,
        })
    }
}
