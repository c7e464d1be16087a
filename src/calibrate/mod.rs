//! Build image → laser vector registration (paper §3.1 and §4.1): the homography from camera
//! pixels to build-plate mm, refined by inverse-compositional Levenberg-Marquardt against an
//! exemplar rendered from the layer's scan vectors; what `layerwise register images` runs.
//!
//! Pipeline ([`register_frames`], in `pipeline.rs`):
//! 1. The starting homography H0 (`build_from_image`) from the user's ≥ 4 clicked
//!    correspondences ([`points`], by the one DLT of [`Homography::from_correspondences`]).
//! 2. One exemplar grid around all the chosen layers' geometry (bbox + margin), at about the
//!    image's resolution on the plate there (estimated from H0). Each layer's exemplar is
//!    rendered on it ([`exemplar`], 2x supersampled against mask aliasing); each frame is
//!    std-filtered with, at every pixel, a window covering the same plate area as the
//!    exemplar's ([`filter`]; the oblique view otherwise biases the fit). Both in `prepare.rs`.
//! 3. Each frame is checked: its layer has a fused area, its parts are in view under H0, and the
//!    frame shows contrast there (pre-scan frames do not).
//! 4. IC-LM, coarse to fine, on the warp `image_from_exemplar` = H⁻¹·G (G = `build_from_grid`,
//!    the exemplar grid's pixel → mm map), optionally with radial k1, k2 ([`lm`]).
//! 5. H = G·M⁻¹, normalised to `H[2][2] = 1` (docs/frames.md), into a [`Calibration`] whose `fit`
//!    table records the images, layers, per-level reports and residual statistics (`report.rs`,
//!    which also prints the [`ImageRegistrationReport`]).

// `!(x > y)` is deliberate throughout: a NaN must fail the check. Index loops over the fixed
// 8x8/10x10 normal matrices and power tables read like the formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

pub mod exemplar;
pub mod filter;
pub mod identify;
pub mod lm;
pub mod overlay;
mod pipeline;
pub mod points;
mod prepare;
mod report;
pub mod spread;

use std::path::PathBuf;

use image::DynamicImage;

use crate::geometry::{Grid, Homography};
use crate::raster::RasterError;
use crate::rectify::calibration::Calibration;
use crate::vectors::{Layer, LayerNumbering, VectorError};

pub use exemplar::F32Image;
pub use lm::{align, Alignment, LevelReport, LmOptions, Pair, PairFit, Termination};
pub use overlay::draw_overlay;
pub use pipeline::{register_frames, register_images, register_images_with};
pub use points::{
    calibrate_from_points, dlt_build_from_image, parse_points, read_points, Correspondence,
    PointsFit, SpreadTargets,
};
pub use prepare::{filter_frame, load_image, luma_f32, render_exemplar};
pub use spread::{ErrorModel, PartCentre, PointPair, SpreadReport};

/// Half the side of the ProX320 plate, mm (the default output grid spans it).
const PLATE_HALF_MM: f64 = 137.5;
/// Largest exemplar side, pixels: beyond it the exemplar pixel (or the margin) is wrong.
const MAX_EXEMPLAR_SIDE: usize = 16384;
/// Default focal length for the distortion model, in image widths: a 45 mm lens on a 35.9 mm
/// wide full-frame sensor (the paper's D810 with the PC-E 45 mm). Only the scale of k1, k2
/// depends on it.
pub const DEFAULT_FOCAL_WIDTHS: f64 = 45.0 / 35.9;

/// Why a registration could not be done. Every variant names the file or image concerned.
#[derive(Debug, thiserror::Error)]
pub enum RegistrationError {
    #[error("{file}: cannot read")]
    Read {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Points { file: PathBuf, message: String },
    /// The start points give no homography (the cases `Points` does not spell out by line).
    #[error("{file}: the start points give no homography")]
    Dlt {
        file: PathBuf,
        #[source]
        source: crate::geometry::DltError,
    },
    #[error(transparent)]
    Vectors(#[from] VectorError),
    /// The exemplar could not be rendered (e.g. its grid is too large).
    #[error("cannot render the exemplar")]
    Raster(#[from] RasterError),
    #[error("{file}: no vectors for printer layer {layer}: the file has {available}; check --layer (the number in the frame's name) or --layer-match/--layer-offset")]
    NoSuchLayer {
        file: String,
        layer: u32,
        available: String,
    },
    #[error("layer {layer} has no fused area to register to (no closed contours or hatches)")]
    NoFusedArea { layer: u32 },
    #[error(
        "the parts' contours cannot tell a lens distortion from the homography: k1 = {probe} \
         would move them only {visible_px:.2} px beyond it (at least {min} px needed; the parts \
         reach {pct:.0}% of the way to the frame's corners). Register several layers at once \
         (--layer/--image per frame), frames whose parts reach further out, or a calibration \
         target; or use --distortion none",
        probe = identify::PROBE_K,
        min = identify::MIN_VISIBLE_PX,
        pct = 100.0 * max_radius
    )]
    DistortionNotIdentifiable { visible_px: f64, max_radius: f64 },
    #[error("{image}: cannot decode")]
    Image {
        image: String,
        #[source]
        source: crate::rectify::RectifyError,
    },
    #[error("{image}: layer {layer}'s parts are not in view: {detail}")]
    NotInView {
        image: String,
        layer: u32,
        detail: String,
    },
    #[error(
        "{image}: no fused part visible where layer {layer}'s contours map (mean local std \
         {part:.2} over the parts vs {powder:.2} around them; at least {min_ratio}x needed): a \
         pre-scan or unlit frame, the wrong layer, or start points that are far off"
    )]
    NoContrast {
        image: String,
        layer: u32,
        part: f64,
        powder: f64,
        min_ratio: f64,
    },
    #[error("registration diverged at pyramid level {level}: {reason}; check the start points")]
    Diverged { level: usize, reason: String },
    #[error(
        "registration did not converge for {image}: correlation with the exemplar {correlation:.3} \
         (at the start {initial:.3}) is below {min}; check the start points and that the image \
         shows this layer after its scan"
    )]
    NotConverged {
        image: String,
        correlation: f64,
        initial: f64,
        min: f64,
    },
    #[error("invalid registration input: {0}")]
    Invalid(String),
    #[error(transparent)]
    Write(#[from] crate::fsutil::WriteError),
    #[error("{file}: cannot write the overlay")]
    Overlay {
        file: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

/// Lens model to fit along with the homography.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum DistortionChoice {
    /// The plain homography (paper §3.1).
    #[default]
    None,
    /// Radial k1, k2 about the image center (§4.1's suggested extension). `focal_px` defaults to
    /// [`DEFAULT_FOCAL_WIDTHS`] x the image width.
    Radial { focal_px: Option<f64> },
}

/// Settings of a registration; `Default` is what the CLI uses.
#[derive(Clone, Debug, PartialEq)]
pub struct RegistrationOptions {
    /// Standard deviation window of the exemplars, exemplar pixels (odd). The frames are
    /// filtered over the same plate area ([`filter`]), or with this many image pixels when
    /// `match_footprint` is off.
    pub std_window: usize,
    /// Size the frames' std window to the exemplar window's footprint on the plate (under H0,
    /// at the parts); off: the same square window in image pixels.
    pub match_footprint: bool,
    /// Exemplar pixel size, mm; `None`: the image's resolution at the parts under H0.
    pub exemplar_pixel_mm: Option<f64>,
    /// The exemplar is rendered on an s-times finer grid (window s·n, made odd) and then box
    /// averaged s x s: the binary mask then places edges to 1/(2s) pixel instead of ½ pixel,
    /// which matters for edges along the grid axes (measured: ½-pixel shifts of box parts).
    pub exemplar_supersampling: usize,
    /// Margin around the layers' geometry, mm; `None`: (window + 32) exemplar pixels.
    pub margin_mm: Option<f64>,
    /// Seed of the exemplar's white noise.
    pub seed: u64,
    /// A frame must show at least this ratio of mean local std over the parts to around them.
    pub min_contrast: f64,
    pub lm: LmOptions,
    /// The plate whose corners the report across the plate looks at ([`spread`]): the
    /// configuration's `[rectify]` grid.
    pub plate: Grid,
    /// The expected error beyond which the report warns, mm.
    pub max_error_mm: f64,
}

impl Default for RegistrationOptions {
    fn default() -> Self {
        RegistrationOptions {
            std_window: exemplar::DEFAULT_STD_WINDOW,
            match_footprint: true,
            exemplar_pixel_mm: None,
            exemplar_supersampling: 2,
            margin_mm: None,
            seed: exemplar::DEFAULT_SEED,
            min_contrast: 1.5,
            lm: LmOptions::default(),
            plate: Grid::default(),
            max_error_mm: spread::DEFAULT_MAX_ERROR_MM,
        }
    }
}

/// One frame to register and the vector layer it shows.
#[derive(Clone, Debug, PartialEq)]
pub struct RegistrationImage {
    pub path: PathBuf,
    /// The printer layer the frame shows (from 1, the number in its file name).
    pub layer: u32,
}

/// `layerwise register images`: everything the command needs.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRegistration {
    pub vectors: PathBuf,
    /// How printer layers pair with the vector file's layers.
    pub numbering: LayerNumbering,
    /// One or more frames from the same camera pose; they share one homography.
    pub images: Vec<RegistrationImage>,
    /// POINTS.txt: `u v x y` per line, at least 4.
    pub init_points: PathBuf,
    /// Where to write the calibration TOML (`None`: not written).
    pub out: Option<PathBuf>,
    /// Where to write the overlay PNG of the first image (`None`: not drawn).
    pub overlay: Option<PathBuf>,
    pub distortion: DistortionChoice,
    pub options: RegistrationOptions,
}

/// How one frame fits after registration.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageFit {
    pub name: String,
    /// The printer layer (from 1).
    pub layer: u32,
    pub fit: PairFit,
}

/// What a registration found.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRegistrationReport {
    /// What is (or would be) written to `out`.
    pub calibration: Calibration,
    /// H0, `build_from_image` from the clicked points.
    pub initial_build_from_image: Homography,
    /// The grid the exemplars were rendered on.
    pub exemplar_grid: Grid,
    /// The frame's resolution at the plate center, mm per pixel (advice for `[rectify]
    /// pixel_mm`; the calibration stores no grid).
    pub native_pixel_mm: f64,
    /// Why the distortion was fitted in part or not kept, when it was asked for.
    pub distortion_note: Option<String>,
    /// Coarsest level first.
    pub levels: Vec<LevelReport>,
    pub images: Vec<ImageFit>,
    /// Per correspondence, distance in pixels between the clicked image point and where the
    /// refined mapping puts its build point (large values flag a bad click).
    pub click_residuals_px: Vec<f64>,
    /// The expected error across the plate, from the parts' contours the fit leans on (`None`
    /// when they cannot support a homography).
    pub spread: Option<SpreadReport>,
    pub seconds: f64,
}

/// A frame in memory, for [`register_frames`].
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Names the frame in errors and in the fit table.
    pub name: &'a str,
    pub image: &'a DynamicImage,
    pub layer: &'a Layer,
    /// The printer layer (from 1) the frame shows (for the report).
    pub layer_number: u32,
}

#[cfg(test)]
mod tests;
