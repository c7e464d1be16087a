//! Build image → laser vector registration (paper §3.1 and §4.1): the homography from camera
//! pixels to build-plate mm, refined by inverse-compositional Levenberg-Marquardt against an
//! exemplar rendered from the layer's scan vectors; what `layerwise register images` runs.
//!
//! Pipeline ([`register_frames`]):
//! 1. The starting homography H0 from the user's ≥ 4 clicked correspondences by the normalized
//!    DLT ([`points`]).
//! 2. One exemplar grid around all the chosen layers' geometry (bbox + margin), at about the
//!    image's resolution on the plate there (estimated from H0). Each layer's exemplar is
//!    rendered on it ([`exemplar`], 2x supersampled against mask aliasing); each frame is
//!    std-filtered with, at every pixel, a window covering the same plate area as the
//!    exemplar's ([`filter`]; the oblique view otherwise biases the fit).
//! 3. Each frame is checked: its layer has a fused area, its parts are in view under H0, and the
//!    frame shows contrast there (pre-scan frames do not).
//! 4. IC-LM, coarse to fine, on the warp exemplar pixel → image pixel
//!    M = H⁻¹·G (G the grid's pixel → mm map), optionally with radial k1, k2 ([`homography`]).
//! 5. H = G·M⁻¹, normalised to `H[2][2] = 1` (docs/frames.md), into a [`Calibration`] whose `fit`
//!    table records the images, layers, per-level reports and residual statistics.

// `!(x > y)` is deliberate throughout: a NaN must fail the check. Index loops over the fixed
// 8x8/10x10 normal matrices and power tables read like the formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

pub mod exemplar;
pub mod filter;
pub mod homography;
pub mod overlay;
pub mod points;

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::DynamicImage;
use rayon::prelude::*;

use crate::rectify::{calibration::Calibration, luma, Grid, RadialDistortion};
use crate::vectors::{self, Layer, VectorError};

pub use exemplar::F32Image;
pub use homography::{align, Alignment, LevelReport, LmOptions, Pair, PairFit, Termination};
pub use overlay::{draw_overlay, Mapping};
pub use points::{homography_dlt, parse_points, read_points, Correspondence};

pub use crate::geometry::mat3::{
    grid_matrix, mat_inv, mat_mul, normalise_h, project, singularity, Mat3,
};

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
    #[error("{file}: cannot read: {source}")]
    Read {
        file: PathBuf,
        source: std::io::Error,
    },
    #[error("{file}: {message}")]
    Points { file: PathBuf, message: String },
    #[error(transparent)]
    Vectors(#[from] VectorError),
    #[error("{file}: no layer {layer}: the file has {count} layers (indices 0 to {last})", last = count.saturating_sub(1))]
    NoSuchLayer {
        file: String,
        layer: usize,
        count: usize,
    },
    #[error("layer {layer} has no fused area to register to (no closed contours or hatches)")]
    NoFusedArea { layer: usize },
    #[error("{image}: cannot decode: {message}")]
    Image { image: String, message: String },
    #[error("{image}: layer {layer}'s parts are not in view: {detail}")]
    NotInView {
        image: String,
        layer: usize,
        detail: String,
    },
    #[error(
        "{image}: no fused part visible where layer {layer}'s contours map (mean local std \
         {part:.2} over the parts vs {powder:.2} around them; at least {min_ratio}x needed): a \
         pre-scan or unlit frame, the wrong layer, or start points that are far off"
    )]
    NoContrast {
        image: String,
        layer: usize,
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
    #[error("{file}: cannot write: {message}")]
    Write { file: PathBuf, message: String },
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
    /// The grid written into the calibration; `None`: the whole plate at the image's
    /// resolution at the plate center (the paper's choice), snapped to whole pixels.
    pub output_grid: Option<Grid>,
    pub lm: LmOptions,
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
            output_grid: None,
            lm: LmOptions::default(),
        }
    }
}

/// One frame to register and the vector layer it shows.
#[derive(Clone, Debug, PartialEq)]
pub struct RegistrationImage {
    pub path: PathBuf,
    /// 0-based position of the layer in the vector file.
    pub layer: usize,
}

/// `layerwise register images`: everything the command needs.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRegistration {
    pub vectors: PathBuf,
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
    pub layer: usize,
    pub fit: PairFit,
}

/// What a registration found.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageRegistrationReport {
    /// What is (or would be) written to `out`.
    pub calibration: Calibration,
    /// H0 from the points.
    pub initial_homography: Mat3,
    /// The grid the exemplars were rendered on.
    pub exemplar_grid: Grid,
    /// Coarsest level first.
    pub levels: Vec<LevelReport>,
    pub images: Vec<ImageFit>,
    /// Per correspondence, distance in pixels between the clicked image point and where the
    /// refined mapping puts its build point (large values flag a bad click).
    pub click_residuals_px: Vec<f64>,
    pub seconds: f64,
}

/// A frame in memory, for [`register_frames`].
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// Names the frame in errors and in the fit table.
    pub name: &'a str,
    pub image: &'a DynamicImage,
    pub layer: &'a Layer,
    /// The layer's index in its file (for the report).
    pub layer_index: usize,
}

/// Runs `layerwise register images`: reads the points, vectors and frames, registers, writes
/// the calibration (and the overlay) and returns the report.
pub fn register_images(
    request: &ImageRegistration,
) -> Result<ImageRegistrationReport, RegistrationError> {
    let points = read_points(&request.init_points)?;
    if request.images.is_empty() {
        return Err(RegistrationError::Invalid("no --image given".into()));
    }
    let file = vectors::read(&request.vectors)?;
    let mut layers = Vec::with_capacity(request.images.len());
    for img in &request.images {
        let layer = file
            .layers
            .get(img.layer)
            .ok_or_else(|| RegistrationError::NoSuchLayer {
                file: request.vectors.display().to_string(),
                layer: img.layer,
                count: file.layers.len(),
            })?;
        layers.push(layer);
    }
    let decoded = request
        .images
        .iter()
        .map(|i| load_image(&i.path))
        .collect::<Result<Vec<_>, _>>()?;
    let names: Vec<String> = request
        .images
        .iter()
        .map(|i| i.path.display().to_string())
        .collect();
    let frames: Vec<Frame> = decoded
        .iter()
        .zip(&layers)
        .zip(&names)
        .zip(&request.images)
        .map(|(((image, layer), name), req)| Frame {
            name,
            image,
            layer,
            layer_index: req.layer,
        })
        .collect();
    let mut report = register_frames(
        &frames,
        &points,
        &request.init_points,
        request.distortion,
        &request.options,
    )?;
    if let Some(fit) = report.calibration.fit.as_mut() {
        fit.insert(
            "vectors".into(),
            toml::Value::String(request.vectors.display().to_string()),
        );
    }
    if let Some(out) = &request.out {
        write_atomic(out, report.calibration.to_toml().as_bytes())?;
    }
    if let Some(path) = &request.overlay {
        let cal = &report.calibration;
        let picture = draw_overlay(
            frames[0].image,
            frames[0].layer,
            Mapping {
                homography: &report.initial_homography,
                distortion: None,
            },
            Mapping {
                homography: &cal.homography,
                distortion: cal.distortion.as_ref(),
            },
        );
        picture
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|e| RegistrationError::Write {
                file: path.clone(),
                message: e.to_string(),
            })?;
    }
    Ok(report)
}

/// Registers frames in memory (see the module doc); `points_file` names the points in errors.
pub fn register_frames(
    frames: &[Frame],
    points: &[Correspondence],
    points_file: &Path,
    distortion: DistortionChoice,
    options: &RegistrationOptions,
) -> Result<ImageRegistrationReport, RegistrationError> {
    let started = Instant::now();
    let first = frames
        .first()
        .ok_or_else(|| RegistrationError::Invalid("no frames to register".into()))?;
    let window = options.std_window;
    if window.is_multiple_of(2) || window > 255 {
        return Err(RegistrationError::Invalid(format!(
            "std window must be odd and at most 255, got {window}"
        )));
    }
    let h0 = homography_dlt(points, points_file)?;
    let h0_inv = mat_inv(&h0).ok_or_else(|| RegistrationError::Points {
        file: points_file.to_path_buf(),
        message: "the correspondences give a singular homography".into(),
    })?;

    // One grid around all layers' geometry.
    let mut bbox: Option<[f64; 4]> = None;
    for f in frames {
        let b = exemplar::layer_bbox(f.layer).ok_or(RegistrationError::NoFusedArea {
            layer: f.layer_index,
        })?;
        bbox = Some(match bbox {
            None => b,
            Some(a) => [
                a[0].min(b[0]),
                a[1].min(b[1]),
                a[2].max(b[2]),
                a[3].max(b[3]),
            ],
        });
    }
    let bb = bbox.ok_or_else(|| RegistrationError::Invalid("no geometry".into()))?;
    let center = (0.5 * (bb[0] + bb[2]), 0.5 * (bb[1] + bb[3]));
    let pixel_mm = match options.exemplar_pixel_mm {
        Some(p) => p,
        None => resolution_mm(&h0, &h0_inv, center)
            .map(|r| round_sig(r, 4))
            .ok_or_else(|| {
                RegistrationError::Invalid(
                    "the start points put the parts beyond the image's horizon".into(),
                )
            })?,
    };
    if !(pixel_mm.is_finite() && pixel_mm > 0.0) {
        return Err(RegistrationError::Invalid(format!(
            "exemplar pixel size {pixel_mm} mm"
        )));
    }
    let margin = options
        .margin_mm
        .unwrap_or((window as f64 + 32.0) * pixel_mm);
    let grid = grid_around(bb, margin, pixel_mm)?;

    let (gw, gh) = (grid.columns(), grid.rows());
    let g = grid_matrix(&grid);
    let m0 = mat_mul(&h0_inv, &g);

    let mut filtered = Vec::with_capacity(frames.len());
    let mut exemplars = Vec::with_capacity(frames.len());
    let mut windows_used = (0.0, 0.0);
    for f in frames {
        let (ie, extent_mm) = render_exemplar(
            f.layer,
            &grid,
            window,
            options.exemplar_supersampling,
            options.seed,
        );
        let (ib, used) = filter_frame(
            &luma_f32(f.image),
            &h0,
            &grid,
            extent_mm,
            options.match_footprint,
        )?;
        windows_used = used;
        check_frame(f, &ib, &ie, &m0, options.min_contrast)?;
        filtered.push(ib);
        exemplars.push(ie);
    }
    debug_assert!(exemplars.iter().all(|e| e.width == gw && e.height == gh));

    let dist0 = match distortion {
        DistortionChoice::None => None,
        DistortionChoice::Radial { focal_px } => {
            let (w, h) = (first.image.width(), first.image.height());
            if frames
                .iter()
                .any(|f| f.image.width() != w || f.image.height() != h)
            {
                return Err(RegistrationError::Invalid(
                    "a shared lens distortion needs frames of one size".into(),
                ));
            }
            let focal = focal_px.unwrap_or(DEFAULT_FOCAL_WIDTHS * f64::from(w));
            if !(focal.is_finite() && focal > 0.0) {
                return Err(RegistrationError::Invalid(format!(
                    "focal length {focal} px"
                )));
            }
            Some(RadialDistortion {
                center: [0.5 * (f64::from(w) - 1.0), 0.5 * (f64::from(h) - 1.0)],
                focal_px: focal,
                k1: 0.0,
                k2: 0.0,
            })
        }
    };

    let pairs: Vec<Pair> = filtered
        .iter()
        .zip(&exemplars)
        .map(|(image, exemplar)| Pair { image, exemplar })
        .collect();
    let aligned = align(&pairs, m0, dist0, &options.lm).map_err(|e| match e {
        RegistrationError::NotConverged {
            image,
            correlation,
            initial,
            min,
        } => RegistrationError::NotConverged {
            image: image
                .trim_start_matches('#')
                .parse::<usize>()
                .ok()
                .and_then(|k| frames.get(k))
                .map_or(image, |f| f.name.to_string()),
            correlation,
            initial,
            min,
        },
        other => other,
    })?;
    drop(pairs);

    let m_inv = mat_inv(&aligned.warp).ok_or_else(|| RegistrationError::Diverged {
        level: 0,
        reason: "the refined warp is singular".into(),
    })?;
    let h = normalise_h(&mat_mul(&g, &m_inv)).ok_or_else(|| RegistrationError::Diverged {
        level: 0,
        reason: "the refined homography cannot be normalised to H[2][2] = 1".into(),
    })?;
    let output_grid = match options.output_grid {
        Some(grid) => grid,
        None => plate_grid(&h)?,
    };
    let click_residuals_px: Vec<f64> = {
        let mapping = Mapping {
            homography: &h,
            distortion: aligned.distortion.as_ref(),
        };
        points
            .iter()
            .map(|p| {
                mapping
                    .image_point(p.build[0], p.build[1])
                    .map_or(f64::INFINITY, |(u, v)| {
                        (u - p.image[0]).hypot(v - p.image[1])
                    })
            })
            .collect()
    };
    let images: Vec<ImageFit> = frames
        .iter()
        .zip(&aligned.pairs)
        .map(|(f, fit)| ImageFit {
            name: f.name.to_string(),
            layer: f.layer_index,
            fit: fit.clone(),
        })
        .collect();
    let seconds = started.elapsed().as_secs_f64();
    let fit = fit_table(
        &images,
        points_file,
        &h0,
        &grid,
        (window, windows_used.0, windows_used.1),
        options.seed,
        &aligned,
        &click_residuals_px,
        seconds,
    );
    Ok(ImageRegistrationReport {
        calibration: Calibration {
            homography: h,
            distortion: aligned.distortion,
            grid: Some(output_grid),
            fit: Some(fit),
        },
        initial_homography: h0,
        exemplar_grid: grid,
        levels: aligned.levels,
        images,
        click_residuals_px,
        seconds,
    })
}

/// The exemplar of `layer` on `grid` with a `window`-pixel std window, rendered on a grid
/// `supersampling` times finer (window scaled and made odd) and box-averaged back, so edges
/// along the grid axes land to 1/(2·supersampling) pixel; and the window's extent, mm.
pub fn render_exemplar(
    layer: &Layer,
    grid: &Grid,
    window: usize,
    supersampling: usize,
    seed: u64,
) -> (F32Image, f64) {
    let ss = supersampling.clamp(1, 8);
    let fine_window = if (ss * window) % 2 == 1 {
        ss * window
    } else {
        ss * window + 1
    };
    let fine_grid = Grid {
        pixel_mm: grid.pixel_mm / ss as f64,
        ..*grid
    };
    let fine = exemplar::exemplar(layer, &fine_grid, fine_window, seed);
    (
        box_downsample(&fine, ss),
        fine_window as f64 * fine_grid.pixel_mm,
    )
}

/// I_B: the frame's luma std-filtered where the exemplar `grid` lies under `h` (image → build),
/// plus a margin (0 elsewhere). With `match_footprint` each pixel's window spans `extent_mm` on
/// the plate along u and v ([`filter`]); without, a square of `extent_mm / pixel_mm` pixels.
/// Also returns the window used at the grid's center, pixels.
pub fn filter_frame(
    lum: &F32Image,
    h: &Mat3,
    grid: &Grid,
    extent_mm: f64,
    match_footprint: bool,
) -> Result<(F32Image, (f64, f64)), RegistrationError> {
    let beyond = || {
        RegistrationError::Invalid(
            "the start points put the parts beyond the image's horizon".into(),
        )
    };
    let h_inv = mat_inv(h).ok_or_else(beyond)?;
    let m = mat_mul(&h_inv, &grid_matrix(grid));
    let square_w = extent_mm / grid.pixel_mm;
    let windows = |u: f64, v: f64| {
        if match_footprint {
            footprint_px(h, u, v, extent_mm).unwrap_or((1.0, 1.0))
        } else {
            (square_w, square_w)
        }
    };
    let center = (
        0.5 * (grid.x_min + grid.x_max),
        0.5 * (grid.y_min + grid.y_max),
    );
    let (cu, cv) = project(&h_inv, center.0, center.1).ok_or_else(beyond)?;
    let (gw, gh) = (grid.columns(), grid.rows());
    let (roi, max_window) = filter_roi(&m, gw, gh, lum.width, lum.height, windows);
    let data =
        filter::std_filter_footprint(&lum.data, lum.width, lum.height, roi, max_window, windows);
    Ok((
        F32Image {
            width: lum.width,
            height: lum.height,
            data,
        },
        windows(cu, cv),
    ))
}

/// Refuses a frame whose layer has no fused area, whose parts do not map into it under the
/// start warp, or which shows no contrast where the parts map.
fn check_frame(
    f: &Frame,
    ib: &F32Image,
    ie: &F32Image,
    m0: &Mat3,
    min_contrast: f64,
) -> Result<(), RegistrationError> {
    let max = ie.data.par_iter().copied().reduce(|| 0.0f32, f32::max);
    if !(max > 0.0) {
        return Err(RegistrationError::NoFusedArea {
            layer: f.layer_index,
        });
    }
    // Support: near a part (the std window reaches it). Part: well inside (the exemplar's
    // noise level). Powder: out of the window's reach.
    let (support_thr, part_thr) = (0.01 * max, 0.5 * max);
    struct Acc {
        support: usize,
        outside: usize,
        part: (f64, usize),
        powder: (f64, usize),
    }
    let zero = || Acc {
        support: 0,
        outside: 0,
        part: (0.0, 0),
        powder: (0.0, 0),
    };
    let acc = (0..ie.height)
        .into_par_iter()
        .fold(zero, |mut acc, r| {
            for c in 0..ie.width {
                let e = ie.data[r * ie.width + c];
                let (u, v) = project(m0, c as f64, r as f64).unwrap_or((f64::NAN, f64::NAN));
                let (ui, vi) = (u.round(), v.round());
                let inside =
                    ui >= 0.0 && vi >= 0.0 && ui < ib.width as f64 && vi < ib.height as f64;
                if e > support_thr {
                    acc.support += 1;
                    if !inside {
                        acc.outside += 1;
                    }
                }
                if !inside {
                    continue;
                }
                let b = f64::from(ib.data[vi as usize * ib.width + ui as usize]);
                if e > part_thr {
                    acc.part.0 += b;
                    acc.part.1 += 1;
                } else if e == 0.0 {
                    acc.powder.0 += b;
                    acc.powder.1 += 1;
                }
            }
            acc
        })
        .reduce(zero, |a, b| Acc {
            support: a.support + b.support,
            outside: a.outside + b.outside,
            part: (a.part.0 + b.part.0, a.part.1 + b.part.1),
            powder: (a.powder.0 + b.powder.0, a.powder.1 + b.powder.1),
        });
    let out_frac = acc.outside as f64 / acc.support.max(1) as f64;
    if out_frac > 0.01 {
        return Err(RegistrationError::NotInView {
            image: f.name.to_string(),
            layer: f.layer_index,
            detail: format!(
                "{:.1}% of the area near its contours maps outside the {}x{} frame under the \
                 start points",
                100.0 * out_frac,
                ib.width,
                ib.height
            ),
        });
    }
    let part = acc.part.0 / acc.part.1.max(1) as f64;
    let powder = acc.powder.0 / acc.powder.1.max(1) as f64;
    if acc.part.1 == 0 || acc.powder.1 == 0 || !(part >= min_contrast * powder && part > 0.0) {
        return Err(RegistrationError::NoContrast {
            image: f.name.to_string(),
            layer: f.layer_index,
            part,
            powder,
            min_ratio: min_contrast,
        });
    }
    Ok(())
}

/// Decodes a frame as the daemon does: JPEG through zune-jpeg, camera raw (NEF) through rawler,
/// anything else through `image`.
pub fn load_image(path: &Path) -> Result<DynamicImage, RegistrationError> {
    let bytes = std::fs::read(path).map_err(|source| RegistrationError::Read {
        file: path.to_path_buf(),
        source,
    })?;
    crate::rectify::decode_frame(&bytes).map_err(|e| RegistrationError::Image {
        image: path.display().to_string(),
        message: e.to_string(),
    })
}

/// BT.601 luma as f32 0..255 (the rectifier's luma for RGB frames).
pub fn luma_f32(img: &DynamicImage) -> F32Image {
    match img {
        DynamicImage::ImageLuma8(g) => F32Image::from_gray(g),
        DynamicImage::ImageRgb8(rgb) => F32Image::from_gray(&luma(rgb)),
        other => F32Image::from_gray(&luma(&other.to_rgb8())),
    }
}

/// Mean of each s x s block (s divides both sides).
fn box_downsample(img: &F32Image, s: usize) -> F32Image {
    if s <= 1 {
        return img.clone();
    }
    let (w, h) = (img.width / s, img.height / s);
    let mut data = vec![0.0f32; w * h];
    let norm = 1.0 / (s * s) as f32;
    if w > 0 {
        data.par_chunks_mut(w).enumerate().for_each(|(r, dst)| {
            for i in 0..s {
                let src = &img.data[(s * r + i) * img.width..];
                for (c, d) in dst.iter_mut().enumerate() {
                    *d += src[s * c..s * c + s].iter().sum::<f32>();
                }
            }
            for d in dst.iter_mut() {
                *d *= norm;
            }
        });
    }
    F32Image {
        width: w,
        height: h,
        data,
    }
}

/// A grid of whole `pixel_mm` pixels covering `bb` plus `margin` on every side.
fn grid_around(bb: [f64; 4], margin: f64, pixel_mm: f64) -> Result<Grid, RegistrationError> {
    let cols = ((bb[2] - bb[0] + 2.0 * margin) / pixel_mm).ceil();
    let rows = ((bb[3] - bb[1] + 2.0 * margin) / pixel_mm).ceil();
    if !(cols >= 1.0 && rows >= 1.0)
        || cols > MAX_EXEMPLAR_SIDE as f64
        || rows > MAX_EXEMPLAR_SIDE as f64
    {
        return Err(RegistrationError::Invalid(format!(
            "the exemplar would be {cols} x {rows} pixels of {pixel_mm} mm (at most \
             {MAX_EXEMPLAR_SIDE} per side): check the start points and the pixel size"
        )));
    }
    let (cx, cy) = (0.5 * (bb[0] + bb[2]), 0.5 * (bb[1] + bb[3]));
    let x_min = cx - 0.5 * cols * pixel_mm;
    let y_min = cy - 0.5 * rows * pixel_mm;
    Ok(Grid {
        x_min,
        x_max: x_min + cols * pixel_mm,
        y_min,
        y_max: y_min + rows * pixel_mm,
        pixel_mm,
    })
}

/// The whole plate at the image's resolution at the plate center (paper §4.1), snapped so the
/// plate is a whole number of pixels.
fn plate_grid(h: &Mat3) -> Result<Grid, RegistrationError> {
    let h_inv = mat_inv(h).ok_or_else(|| RegistrationError::Invalid("singular H".into()))?;
    let res = resolution_mm(h, &h_inv, (0.0, 0.0)).ok_or_else(|| {
        RegistrationError::Invalid("the plate center is beyond the image's horizon".into())
    })?;
    let side = 2.0 * PLATE_HALF_MM;
    let n = (side / res)
        .round()
        .clamp(1.0, MAX_EXEMPLAR_SIDE as f64 * 8.0);
    Ok(Grid {
        x_min: -PLATE_HALF_MM,
        x_max: PLATE_HALF_MM,
        y_min: -PLATE_HALF_MM,
        y_max: PLATE_HALF_MM,
        pixel_mm: side / n,
    })
}

/// mm per image pixel at build point `at`: √|det| of H's Jacobian there.
fn resolution_mm(h: &Mat3, h_inv: &Mat3, at: (f64, f64)) -> Option<f64> {
    let (u, v) = project(h_inv, at.0, at.1)?;
    let (ax, ay) = project(h, u + 0.5, v)?;
    let (bx, by) = project(h, u - 0.5, v)?;
    let (cx, cy) = project(h, u, v + 0.5)?;
    let (dx, dy) = project(h, u, v - 0.5)?;
    let det = (ax - bx) * (cy - dy) - (ay - by) * (cx - dx);
    let r = det.abs().sqrt();
    (r.is_finite() && r > 0.0).then_some(r)
}

/// Image pixels spanned along u and along v by `extent_mm` on the plate at image pixel (u, v):
/// `extent_mm` over the lengths of ∂(x, y)/∂u and ∂(x, y)/∂v of H there.
fn footprint_px(h: &Mat3, u: f64, v: f64, extent_mm: f64) -> Option<(f64, f64)> {
    let w = h[2][0] * u + h[2][1] * v + h[2][2];
    if !(w > 0.0) {
        return None;
    }
    let x = (h[0][0] * u + h[0][1] * v + h[0][2]) / w;
    let y = (h[1][0] * u + h[1][1] * v + h[1][2]) / w;
    let mm_u = (h[0][0] - x * h[2][0]).hypot(h[1][0] - y * h[2][0]) / w;
    let mm_v = (h[0][1] - x * h[2][1]).hypot(h[1][1] - y * h[2][1]) / w;
    let (wx, wy) = (extent_mm / mm_u, extent_mm / mm_v);
    let ok = |w: f64| w.is_finite() && w > 0.0;
    (ok(wx) && ok(wy)).then_some((wx, wy))
}

/// The image region the exemplar covers under `m` (exemplar px → image px), plus a margin for
/// the refinement to move in, and the largest window there.
fn filter_roi(
    m: &Mat3,
    gw: usize,
    gh: usize,
    width: usize,
    height: usize,
    windows: impl Fn(f64, f64) -> (f64, f64),
) -> (filter::Roi, f64) {
    let (a, b) = (gw as f64 - 1.0, gh as f64 - 1.0);
    let pts: Vec<(f64, f64)> = [(0.0, 0.0), (a, 0.0), (a, b), (0.0, b)]
        .iter()
        .filter_map(|&(u, v)| project(m, u, v))
        .collect();
    let full = ([0, height, 0, width], 64.0);
    if pts.len() < 4 {
        return full;
    }
    let (u0, u1, v0, v1) = pts.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), &(u, v)| (a.min(u), b.max(u), c.min(v), d.max(v)),
    );
    let margin = (0.1 * (u1 - u0).max(v1 - v0)).max(64.0);
    let clamp = |x: f64, hi: usize| x.clamp(0.0, hi as f64) as usize;
    let roi = [
        clamp((v0 - margin).floor(), height),
        clamp((v1 + margin).ceil() + 1.0, height),
        clamp((u0 - margin).floor(), width),
        clamp((u1 + margin).ceil() + 1.0, width),
    ];
    let max_window = [
        (roi[2], roi[0]),
        (roi[3], roi[0]),
        (roi[2], roi[1]),
        (roi[3], roi[1]),
    ]
    .iter()
    .map(|&(u, v)| {
        let (wx, wy) = windows(u as f64, v as f64);
        wx.max(wy)
    })
    .fold(1.0, f64::max);
    // Windows vary monotonically under a homography, so the corners bound them; 255 px is far
    // beyond any useful window.
    (roi, (max_window * 1.05 + 1.0).min(255.0))
}

fn round_sig(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}

fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), RegistrationError> {
    let err = |e: std::io::Error| RegistrationError::Write {
        file: path.to_path_buf(),
        message: e.to_string(),
    };
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, bytes).map_err(err)?;
    std::fs::rename(&tmp, path).map_err(err)
}

fn matrix_value(m: &Mat3) -> toml::Value {
    toml::Value::Array(
        m.iter()
            .map(|r| toml::Value::Array(r.iter().map(|&v| toml::Value::Float(v)).collect()))
            .collect(),
    )
}

fn floats(v: impl IntoIterator<Item = f64>) -> toml::Value {
    toml::Value::Array(v.into_iter().map(toml::Value::Float).collect())
}

/// The calibration's free-form `fit` table: how it was obtained (for people).
#[allow(clippy::too_many_arguments)]
fn fit_table(
    images: &[ImageFit],
    points_file: &Path,
    h0: &Mat3,
    grid: &Grid,
    (window, wx, wy): (usize, f64, f64),
    seed: u64,
    aligned: &Alignment,
    clicks: &[f64],
    seconds: f64,
) -> toml::Table {
    use toml::Value;
    let mut t = toml::Table::new();
    t.insert(
        "method".into(),
        Value::String(
            "inverse-compositional Levenberg-Marquardt on std-filtered frames against \
             laser-vector exemplars (paper 3.1), gain/offset matched, coarse to fine"
                .into(),
        ),
    );
    t.insert(
        "images".into(),
        Value::Array(
            images
                .iter()
                .map(|i| Value::String(i.name.clone()))
                .collect(),
        ),
    );
    t.insert(
        "layers".into(),
        Value::Array(
            images
                .iter()
                .map(|i| Value::Integer(i.layer as i64))
                .collect(),
        ),
    );
    t.insert(
        "points".into(),
        Value::String(points_file.display().to_string()),
    );
    t.insert("std_window".into(), Value::Integer(window as i64));
    t.insert("image_std_window".into(), floats([wx, wy]));
    // TOML integers are i64: the seed's bits as written.
    t.insert("seed".into(), Value::Integer(seed as i64));
    t.insert("seconds".into(), Value::Float(seconds));
    t.insert("initial_homography".into(), matrix_value(h0));
    if let Ok(Value::Table(g)) = Value::try_from(grid) {
        t.insert("exemplar_grid".into(), Value::Table(g));
    }
    let levels = aligned
        .levels
        .iter()
        .map(|l| {
            let mut r = toml::Table::new();
            r.insert("level".into(), Value::Integer(l.level as i64));
            r.insert("scale".into(), Value::Integer(l.scale as i64));
            r.insert("width".into(), Value::Integer(l.width as i64));
            r.insert("height".into(), Value::Integer(l.height as i64));
            r.insert("iterations".into(), Value::Integer(l.iterations as i64));
            r.insert("initial_cost".into(), Value::Float(l.initial_cost));
            r.insert("final_cost".into(), Value::Float(l.final_cost));
            r.insert(
                "last_step_px".into(),
                Value::Float(finite_or(l.last_step_px)),
            );
            r.insert(
                "termination".into(),
                Value::String(l.termination.name().into()),
            );
            r.insert("correlation".into(), Value::Float(l.correlation));
            Value::Table(r)
        })
        .collect();
    t.insert("levels".into(), Value::Array(levels));
    let mut res = toml::Table::new();
    res.insert(
        "initial_correlation".into(),
        floats(images.iter().map(|i| i.fit.initial_correlation)),
    );
    res.insert(
        "correlation".into(),
        floats(images.iter().map(|i| i.fit.correlation)),
    );
    res.insert("rms".into(), floats(images.iter().map(|i| i.fit.rms)));
    res.insert(
        "photometric".into(),
        Value::Array(
            images
                .iter()
                .map(|i| floats(i.fit.photometric.iter().copied()))
                .collect(),
        ),
    );
    res.insert(
        "pixels".into(),
        Value::Array(
            images
                .iter()
                .map(|i| Value::Integer(i.fit.pixels as i64))
                .collect(),
        ),
    );
    res.insert(
        "click_px".into(),
        floats(clicks.iter().map(|&c| finite_or(c))),
    );
    let finite: Vec<f64> = clicks.iter().copied().filter(|c| c.is_finite()).collect();
    if !finite.is_empty() {
        res.insert(
            "click_mean_px".into(),
            Value::Float(finite.iter().sum::<f64>() / finite.len() as f64),
        );
        res.insert(
            "click_max_px".into(),
            Value::Float(finite.iter().copied().fold(0.0, f64::max)),
        );
    }
    t.insert("residuals".into(), Value::Table(res));
    t
}

/// TOML has no NaN-free infinity for people; write -1 for "not available".
fn finite_or(v: f64) -> f64 {
    if v.is_finite() {
        v
    } else {
        -1.0
    }
}

#[cfg(test)]
mod tests;
