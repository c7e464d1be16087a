//! The calibration file: what `layerwise register images` writes and the rectifier reads.
//! Its `homography` key holds `build_from_image`: image (u, v, 1) to build (x, y, 1) in mm,
//! `H[2][2] = 1` (docs/frames.md); with a `[distortion]` table it maps undistorted pixels.

use super::{Grid, RadialDistortion};
use crate::fsutil::parse_toml;
use crate::geometry::{CameraModel, Homography, Mat3};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistortionTable {
    /// Only "radial" (k1, k2 about a center, in normalized coordinates).
    pub model: String,
    pub center: [f64; 2],
    pub focal_px: f64,
    pub k1: f64,
    pub k2: f64,
}

/// A calibration file that could not be used.
pub type CalibrationError = crate::fsutil::TomlFileError;

/// The calibration file as stored. The keys are the file format (docs/frames.md): they do not
/// change with the names in code.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationFile {
    /// Image → build, `H[2][2] = 1`.
    #[serde(rename = "homography")]
    pub build_from_image: Mat3,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<Grid>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion: Option<DistortionTable>,
    /// How it was obtained: images, layers, residuals (free-form, for people).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fit: Option<toml::Table>,
}

/// A usable calibration.
#[derive(Clone, Debug, PartialEq)]
pub struct Calibration {
    /// Undistorted image pixel → build mm, `H[2][2] = 1` (stored as `homography`).
    pub build_from_image: Homography,
    /// Where the camera records an undistorted pixel (stored as `[distortion]`).
    pub distortion: Option<RadialDistortion>,
    pub grid: Option<Grid>,
    pub fit: Option<toml::Table>,
}

impl Calibration {
    /// The camera this calibration describes: homography and lens.
    pub fn camera(&self) -> CameraModel {
        CameraModel::new(self.build_from_image, self.distortion)
    }

    pub fn load(path: &Path) -> Result<Calibration, CalibrationError> {
        let text = crate::fsutil::read_text_bounded(path, 1 << 20).map_err(|source| {
            CalibrationError::Read {
                file: path.to_path_buf(),
                source,
            }
        })?;
        Calibration::parse(&text, path)
    }

    pub fn parse(text: &str, file: &Path) -> Result<Calibration, CalibrationError> {
        let stored: CalibrationFile = parse_toml(text, file)?;
        let invalid = |key: &str, message: &str| CalibrationError::Invalid {
            file: file.to_path_buf(),
            key: key.to_string(),
            message: message.to_string(),
        };
        let h = stored.build_from_image;
        if h.iter().flatten().any(|v| !v.is_finite()) {
            return Err(invalid("homography", "has a non-finite entry"));
        }
        if (h[2][2] - 1.0).abs() > 1e-9 {
            return Err(invalid(
                "homography",
                "must have H[2][2] = 1.0 (docs/frames.md)",
            ));
        }
        let distortion = match stored.distortion {
            None => None,
            Some(d) if d.model == "radial" => {
                if d.focal_px.is_nan() || d.focal_px <= 0.0 {
                    return Err(invalid("distortion.focal_px", "must be positive"));
                }
                Some(RadialDistortion {
                    center: d.center,
                    focal_px: d.focal_px,
                    k1: d.k1,
                    k2: d.k2,
                })
            }
            Some(d) => {
                return Err(invalid(
                    "distortion.model",
                    &format!("unknown model {:?}: expected \"radial\"", d.model),
                ))
            }
        };
        Ok(Calibration {
            build_from_image: Homography::from_matrix(h),
            distortion,
            grid: stored.grid,
            fit: stored.fit,
        })
    }

    /// A note when this (older) calibration carries a `[grid]` other than `grid`, the one in
    /// use: since the grid moved to the configuration's `[rectify]`, a stored grid is ignored.
    pub fn grid_note(&self, grid: &Grid) -> Option<String> {
        let stored = self.grid.as_ref().filter(|g| *g != grid)?;
        Some(format!(
            "the calibration's [grid] ({} mm/px, x {} … {}, y {} … {}) is ignored: the rectified \
             grid is the configuration's [rectify] ({} mm/px, x {} … {}, y {} … {})",
            stored.pixel_mm,
            stored.x_min,
            stored.x_max,
            stored.y_min,
            stored.y_max,
            grid.pixel_mm,
            grid.x_min,
            grid.x_max,
            grid.y_min,
            grid.y_max
        ))
    }

    pub fn to_toml(&self) -> String {
        let stored = CalibrationFile {
            build_from_image: self.build_from_image.matrix(),
            grid: self.grid,
            distortion: self.distortion.map(|d| DistortionTable {
                model: "radial".into(),
                center: d.center,
                focal_px: d.focal_px,
                k1: d.k1,
                k2: d.k2,
            }),
            fit: self.fit.clone(),
        };
        toml::to_string(&stored).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_contract_checks() {
        let cal = Calibration {
            build_from_image: Homography::from_matrix([
                [0.1, 0.0, -100.0],
                [0.0, -0.1, 80.0],
                [1e-6, 2e-5, 1.0],
            ]),
            distortion: Some(RadialDistortion {
                center: [3680.0, 2456.0],
                focal_px: 9200.0,
                k1: -0.02,
                k2: 0.001,
            }),
            grid: Some(Grid::plate()),
            fit: None,
        };
        let text = cal.to_toml();
        assert!(text.contains("homography = [[0.1, 0.0, -100.0]"), "{text}");
        assert_eq!(Calibration::parse(&text, Path::new("c.toml")).unwrap(), cal);
        let bad = text.replacen("1.0]]", "2.0]]", 1);
        assert_ne!(bad, text, "the edit must apply");
        let err = Calibration::parse(&bad, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.toml") && err.contains("homography") && err.contains("H[2][2]"),
            "{err}"
        );
        let err = Calibration::parse("homography = [[1, 0, 0], [0, 1, 0]]\n", Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("c.toml") && err.contains("homography"),
            "{err}"
        );
    }

    /// A file as the code before the frame-named fields wrote it (the stored struct of commit
    /// 925044f, serialised here) loads unchanged, and is written back byte for byte.
    #[test]
    fn loads_calibrations_written_by_the_previous_layout() {
        #[derive(Serialize)]
        struct PreviousFile {
            homography: [[f64; 3]; 3],
            #[serde(skip_serializing_if = "Option::is_none")]
            grid: Option<Grid>,
            #[serde(skip_serializing_if = "Option::is_none")]
            distortion: Option<DistortionTable>,
            #[serde(skip_serializing_if = "Option::is_none")]
            fit: Option<toml::Table>,
        }
        let h = [
            [0.0412, -0.0031, -151.25],
            [0.0007, -0.0468, 119.5],
            [2.5e-7, -9.75e-6, 1.0],
        ];
        let mut fit = toml::Table::new();
        fit.insert("method".into(), toml::Value::String("clicks".into()));
        let old = PreviousFile {
            homography: h,
            grid: Some(Grid::plate()),
            distortion: Some(DistortionTable {
                model: "radial".into(),
                center: [3679.5, 2455.5],
                focal_px: 9226.0,
                k1: -0.021,
                k2: 0.0012,
            }),
            fit: Some(fit.clone()),
        };
        let text = toml::to_string(&old).unwrap();
        assert!(text.starts_with("homography = [["), "{text}");
        let cal = Calibration::parse(&text, Path::new("old.toml")).expect("loads");
        assert_eq!(cal.build_from_image.matrix(), h);
        assert_eq!(cal.grid, Some(Grid::plate()));
        assert_eq!(cal.fit, Some(fit));
        let d = cal.distortion.expect("distortion");
        assert_eq!(
            (d.center, d.focal_px, d.k1, d.k2),
            ([3679.5, 2455.5], 9226.0, -0.021, 0.0012)
        );
        assert_eq!(cal.to_toml(), text);
        // The minimal file: the homography alone.
        let bare = toml::to_string(&PreviousFile {
            homography: h,
            grid: None,
            distortion: None,
            fit: None,
        })
        .unwrap();
        let cal = Calibration::parse(&bare, Path::new("bare.toml")).expect("loads");
        assert_eq!(
            cal.camera(),
            CameraModel::pinhole(Homography::from_matrix(h))
        );
        assert_eq!(cal.to_toml(), bare);
    }
}
