//! What a registration reports: the calibration's free-form `fit` table (for people reading the
//! TOML) and the printed summary of [`ImageRegistrationReport`] (its `Display`).

use std::fmt;
use std::path::Path;

use super::{Alignment, ImageFit, ImageRegistrationReport};
use crate::geometry::{Grid, Homography, Mat3};

/// What `layerwise register images` prints: per pyramid level (coarsest first) the iterations,
/// cost and how it stopped; per image the correlation with its exemplar; the homography
/// (`build_from_image`, row-major) and the distortion's k1, k2 when fitted. One line each.
impl fmt::Display for ImageRegistrationReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for l in &self.levels {
            writeln!(
                f,
                "level {} ({}x{}): {} iterations, cost {:.4e} -> {:.4e}, last step {:.1e} px, {}",
                l.level,
                l.width,
                l.height,
                l.iterations,
                l.initial_cost,
                l.final_cost,
                l.last_step_px,
                l.termination.name()
            )?;
        }
        for i in &self.images {
            writeln!(
                f,
                "{} (layer {}): correlation {:.4} (start {:.4})",
                i.name, i.layer, i.fit.correlation, i.fit.initial_correlation
            )?;
        }
        let h = self.calibration.build_from_image.matrix();
        writeln!(f, "homography = {h:?}")?;
        writeln!(
            f,
            "resolution at the plate center: {:.4} mm per pixel (the rectified grid is [rectify] in the configuration)",
            self.native_pixel_mm
        )?;
        if let Some(d) = self.calibration.distortion {
            writeln!(f, "distortion: k1 = {:.6}, k2 = {:.6}", d.k1, d.k2)?;
        }
        if let Some(note) = &self.distortion_note {
            writeln!(f, "note: {note}")?;
        }
        if let Some(spread) = &self.spread {
            write!(f, "{spread}")?;
        }
        Ok(())
    }
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
pub(super) fn fit_table(
    images: &[ImageFit],
    points_file: &Path,
    initial_build_from_image: &Homography,
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
    t.insert(
        "initial_homography".into(),
        matrix_value(&initial_build_from_image.matrix()),
    );
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
        "dilation_px".into(),
        floats(images.iter().map(|i| i.fit.dilation_px)),
    );
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
mod tests {
    use super::super::{LevelReport, PairFit, Termination};
    use super::*;
    use crate::geometry::RadialDistortion;
    use crate::rectify::calibration::Calibration;

    fn report(distortion: Option<RadialDistortion>) -> ImageRegistrationReport {
        let h = [
            [0.05, 0.001, -150.0],
            [-0.0002, -0.055, 120.5],
            [1e-6, -2.5e-5, 1.0],
        ];
        ImageRegistrationReport {
            calibration: Calibration {
                build_from_image: Homography::from_matrix(h),
                distortion,
                grid: None,
                fit: None,
            },
            initial_build_from_image: Homography::IDENTITY,
            exemplar_grid: Grid::plate(),
            native_pixel_mm: 0.30972,
            distortion_note: None,
            levels: vec![LevelReport {
                level: 1,
                scale: 2,
                width: 400,
                height: 300,
                iterations: 12,
                initial_cost: 12345.678,
                final_cost: 0.012345,
                last_step_px: 3.21e-5,
                termination: Termination::SmallStep,
                correlation: 0.9,
            }],
            images: vec![ImageFit {
                name: "L00001_post_top.jpg".into(),
                layer: 1,
                fit: PairFit {
                    photometric: vec![0.0, 1.0],
                    dilation_px: 0.0,
                    initial_correlation: 0.61234,
                    correlation: 0.95678,
                    rms: 1.0,
                    pixels: 10,
                },
            }],
            click_residuals_px: vec![],
            spread: None,
            seconds: 1.5,
        }
    }

    /// The lines `layerwise register images` printed before the report had a `Display`
    /// (src/main.rs of commit 925044f), formatted the same way here.
    #[test]
    fn display_prints_what_the_command_printed() {
        let r = report(None);
        let h = r.calibration.build_from_image.matrix();
        let want = format!(
            "level 1 (400x300): 12 iterations, cost 1.2346e4 -> 1.2345e-2, last step 3.2e-5 px, \
             small step\nL00001_post_top.jpg (layer 1): correlation 0.9568 (start 0.6123)\n\
             homography = {h:?}\nresolution at the plate center: 0.3097 mm per pixel (the \
             rectified grid is [rectify] in the configuration)\n"
        );
        assert_eq!(r.to_string(), want);
        let d = RadialDistortion {
            center: [1.0, 2.0],
            focal_px: 3.0,
            k1: -0.0123456789,
            k2: 0.5,
        };
        let with = report(Some(d)).to_string();
        assert!(
            with.ends_with("\ndistortion: k1 = -0.012346, k2 = 0.500000\n"),
            "{with}"
        );
        assert!(with.starts_with(&want));
    }
}
