//! The registration pipeline: `layerwise register images` from files ([`register_images`]) and
//! from frames in memory ([`register_frames`]); see the module doc of `calibrate`.

use std::path::Path;
use std::time::Instant;

use super::prepare::check_frame;
use super::report::fit_table;
use super::spread::SpreadReport;
use super::{
    align, dlt_build_from_image, draw_overlay, exemplar, filter_frame, load_image, luma_f32,
    read_points, render_exemplar, Correspondence, DistortionChoice, Frame, ImageFit,
    ImageRegistration, ImageRegistrationReport, Pair, RegistrationError, RegistrationImage,
    RegistrationOptions, DEFAULT_FOCAL_WIDTHS, MAX_EXEMPLAR_SIDE, PLATE_HALF_MM,
};
use crate::geometry::{CameraModel, Grid, Homography, RadialDistortion};
use crate::rectify::calibration::Calibration;
use crate::vectors;

/// the calibration (and the overlay) and returns the report.
pub fn register_images(
    request: &ImageRegistration,
) -> Result<ImageRegistrationReport, RegistrationError> {
    register_images_with(request, |image| load_image(&image.path))
}

/// [`register_images`] with each frame read and decoded by `load` (the operator page reads its
/// frames only from inside the build directory); the frames' paths still name them.
pub fn register_images_with(
    request: &ImageRegistration,
    mut load: impl FnMut(&RegistrationImage) -> Result<image::DynamicImage, RegistrationError>,
) -> Result<ImageRegistrationReport, RegistrationError> {
    let points = read_points(&request.init_points)?;
    if request.images.is_empty() {
        return Err(RegistrationError::Invalid("no --image given".into()));
    }
    let file = vectors::read(&request.vectors)?;
    let map = vectors::LayerMap::of_file(&file, request.numbering);
    let mut layers = Vec::with_capacity(request.images.len());
    for img in &request.images {
        let layer = map
            .position(img.layer)
            .and_then(|k| file.layers.get(k))
            .ok_or_else(|| RegistrationError::NoSuchLayer {
                file: request.vectors.display().to_string(),
                layer: img.layer,
                available: map.describe(),
            })?;
        layers.push(layer);
    }
    let decoded = request
        .images
        .iter()
        .map(&mut load)
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
            layer_number: req.layer,
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
        crate::fsutil::write_atomic(out, report.calibration.to_toml().as_bytes(), true)?;
    }
    if let Some(path) = &request.overlay {
        let picture = draw_overlay(
            frames[0].image,
            frames[0].layer,
            &CameraModel::pinhole(report.initial_build_from_image),
            &report.calibration.camera(),
        );
        picture
            .save_with_format(path, image::ImageFormat::Png)
            .map_err(|source| RegistrationError::Overlay {
                file: path.clone(),
                source,
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
    let build_from_image0 = dlt_build_from_image(points, points_file)?;
    let image_from_build0 =
        build_from_image0
            .inverse()
            .ok_or_else(|| RegistrationError::Points {
                file: points_file.to_path_buf(),
                message: "the correspondences give a singular homography".into(),
            })?;

    // One grid around all layers' geometry.
    let mut bbox: Option<[f64; 4]> = None;
    for f in frames {
        let b = exemplar::layer_bbox(f.layer).ok_or(RegistrationError::NoFusedArea {
            layer: f.layer_number,
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
        None => resolution_mm(&build_from_image0, &image_from_build0, center)
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
    let build_from_grid = Homography::build_from_grid(&grid);
    let image_from_exemplar0 = image_from_build0.compose(&build_from_grid);

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
        )?;
        let (ib, used) = filter_frame(
            &luma_f32(f.image),
            &build_from_image0,
            &grid,
            extent_mm,
            options.match_footprint,
        )?;
        windows_used = used;
        check_frame(f, &ib, &ie, &image_from_exemplar0, options.min_contrast)?;
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
    // A distortion is fitted only as far as the frames can tell it from the homography, and
    // is kept only when it fits better than the homography alone (calibrate::identify).
    let mut lm = options.lm.clone();
    let mut distortion_note = None;
    if let Some(lens) = &dist0 {
        let layers: Vec<&crate::vectors::Layer> = frames.iter().map(|f| f.layer).collect();
        let size = (first.image.width(), first.image.height());
        let seen = super::identify::visibility(&layers, &image_from_build0, lens, size);
        if !seen.k1_identifiable() {
            return Err(RegistrationError::DistortionNotIdentifiable {
                visible_px: seen.k1_px,
                max_radius: seen.max_radius,
            });
        }
        if !seen.k2_identifiable() {
            lm.fix_k2 = true;
            distortion_note = Some(format!(
                "k2 kept at 0: the parts' contours cannot tell it from k1 and the homography \
                 (k2 = {} moves them {:.2} px beyond both; correlation with k1 {:.3})",
                super::identify::PROBE_K,
                seen.k2_px,
                seen.correlation
            ));
        }
    }
    let plain = if dist0.is_some() {
        align(&pairs, image_from_exemplar0, None, &options.lm).ok()
    } else {
        None
    };
    let fitted = align(&pairs, image_from_exemplar0, dist0, &lm);
    let mean_correlation = |a: &super::Alignment| {
        a.pairs.iter().map(|p| p.correlation).sum::<f64>() / a.pairs.len().max(1) as f64
    };
    let fitted = match (fitted, plain) {
        (Ok(radial), Some(plain)) if mean_correlation(&plain) >= mean_correlation(&radial) => {
            distortion_note = Some(format!(
                "distortion not kept: with it the parts correlate {:.4}, without it {:.4}; the \
                 calibration holds the homography alone",
                mean_correlation(&radial),
                mean_correlation(&plain)
            ));
            Ok(plain)
        }
        (Err(e), Some(plain)) => {
            distortion_note = Some(format!(
                "distortion not kept: its fit failed ({}); the calibration holds the homography alone",
                crate::logging::chain(&e)
            ));
            Ok(plain)
        }
        (fitted, _) => fitted,
    };
    let aligned = fitted.map_err(|e| match e {
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

    let exemplar_from_image =
        aligned
            .image_from_exemplar
            .inverse()
            .ok_or_else(|| RegistrationError::Diverged {
                level: 0,
                reason: "the refined warp is singular".into(),
            })?;
    let build_from_image = build_from_grid
        .compose(&exemplar_from_image)
        .normalised()
        .ok_or_else(|| RegistrationError::Diverged {
            level: 0,
            reason: "the refined homography cannot be normalised to H[2][2] = 1".into(),
        })?;
    let native_pixel_mm = plate_grid(&build_from_image)?.pixel_mm;
    let camera = CameraModel::new(build_from_image, aligned.distortion);
    let click_residuals_px: Vec<f64> = points
        .iter()
        .map(|p| {
            camera
                .image_point(p.build)
                .map_or(f64::INFINITY, |q| q.distance(&p.image))
        })
        .collect();
    let images: Vec<ImageFit> = frames
        .iter()
        .zip(&aligned.pairs)
        .map(|(f, fit)| ImageFit {
            name: f.name.to_string(),
            layer: f.layer_number,
            fit: fit.clone(),
        })
        .collect();
    let layers: Vec<&crate::vectors::Layer> = frames.iter().map(|f| f.layer).collect();
    let spread = super::spread::ErrorModel::fit(
        &super::spread::contour_support(&layers, &build_from_image),
        &build_from_image,
        super::spread::CLICK_PX,
    )
    .map(|model| {
        SpreadReport::new(
            &model,
            &options.plate,
            &super::spread::part_centres(layers.iter().copied()),
            options.max_error_mm,
            "contour points of the parts",
        )
    });
    let seconds = started.elapsed().as_secs_f64();
    let mut fit = fit_table(
        &images,
        points_file,
        &build_from_image0,
        &grid,
        (window, windows_used.0, windows_used.1),
        options.seed,
        &aligned,
        &click_residuals_px,
        seconds,
    );
    if let Some(s) = &spread {
        fit.insert("spread".into(), toml::Value::Table(s.to_table()));
    }
    Ok(ImageRegistrationReport {
        calibration: Calibration {
            build_from_image,
            distortion: aligned.distortion,
            grid: None,
            fit: Some(fit),
        },
        initial_build_from_image: build_from_image0,
        exemplar_grid: grid,
        native_pixel_mm,
        distortion_note,
        levels: aligned.levels,
        images,
        click_residuals_px,
        spread,
        seconds,
    })
}

/// A grid of whole `pixel_mm` pixels covering `bb` plus `margin` on every side.
pub(super) fn grid_around(
    bb: [f64; 4],
    margin: f64,
    pixel_mm: f64,
) -> Result<Grid, RegistrationError> {
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
pub(super) fn plate_grid(build_from_image: &Homography) -> Result<Grid, RegistrationError> {
    let image_from_build = build_from_image
        .inverse()
        .ok_or_else(|| RegistrationError::Invalid("singular H".into()))?;
    let res = resolution_mm(build_from_image, &image_from_build, (0.0, 0.0)).ok_or_else(|| {
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
fn resolution_mm(
    build_from_image: &Homography,
    image_from_build: &Homography,
    at: (f64, f64),
) -> Option<f64> {
    let h = build_from_image;
    let (u, v) = image_from_build.apply(at.0, at.1)?;
    let (ax, ay) = h.apply(u + 0.5, v)?;
    let (bx, by) = h.apply(u - 0.5, v)?;
    let (cx, cy) = h.apply(u, v + 0.5)?;
    let (dx, dy) = h.apply(u, v - 0.5)?;
    let det = (ax - bx) * (cy - dy) - (ay - by) * (cx - dx);
    let r = det.abs().sqrt();
    (r.is_finite() && r > 0.0).then_some(r)
}

pub(super) fn round_sig(x: f64, digits: i32) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * scale).round() / scale
}
