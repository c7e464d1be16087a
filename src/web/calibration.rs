//! The calibration page's one write: clicked point pairs saved as a NEW points file in the
//! build directory (`calibration/points-L…-{view}-{time}.txt`, the format `register images
//! --init` reads), then the registration run on that frame and layer, writing a new
//! calibration and overlay beside it. Nothing is ever overwritten; off unless
//! `web.calibration_page` is set.

use super::files::{self, BuildFile, FileError, FileKind};
use crate::calibrate::{
    register_images_with, DistortionChoice, ImageRegistration, RegistrationImage,
    RegistrationOptions,
};
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};

/// The folder of the page's files in the build directory.
pub const CALIBRATION_DIR: &str = "calibration";
/// Most point pairs one request may carry.
pub const MAX_POINTS: usize = 64;

/// One clicked pair: a point of the oblique frame as fractions of its width and height, and
/// the build point in mm.
#[derive(Clone, Copy, Debug, Deserialize)]
pub struct ClickedPair {
    pub fx: f64,
    pub fy: f64,
    pub x: f64,
    pub y: f64,
}

/// What the page gets back.
#[derive(Debug, Serialize)]
pub struct CalibrationResult {
    /// The saved points file, relative to the build directory.
    pub points_file: String,
    /// The calibration written (relative), when the registration succeeded.
    pub calibration_file: Option<String>,
    /// The overlay of the layer's contours through the start (red) and the result (blue).
    pub overlay: Option<String>,
    /// Per pair: image pixels between the click and where the result puts its build point.
    pub click_residuals_px: Vec<f64>,
    /// Correlation of the frame with the vectors' exemplar at the start and at the result.
    pub correlation: Option<(f64, f64)>,
    /// Why the registration failed (the points file is kept).
    pub error: Option<String>,
    pub seconds: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum CalibrationPageError {
    #[error("{0}")]
    Invalid(String),
    #[error("cannot read the frame")]
    Read(#[source] FileError),
    #[error("{}: not a folder of the build (a link or a file is in its place)", path.display())]
    NotAFolder { path: PathBuf },
    #[error("{}: cannot decode the frame", path.display())]
    Decode {
        path: PathBuf,
        #[source]
        source: crate::rectify::RectifyError,
    },
    #[error("{}", path.display())]
    Write {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// A stamp for new files: UTC time to the millisecond, digits and `T` only.
pub fn stamp(now: chrono::DateTime<chrono::Utc>) -> String {
    now.format("%Y%m%dT%H%M%S%3f").to_string()
}

/// Whether a stamp from a request is one [`stamp`] makes.
pub fn is_stamp(text: &str) -> bool {
    text.len() == 18
        && text.bytes().enumerate().all(|(i, b)| {
            if i == 8 {
                b == b'T'
            } else {
                b.is_ascii_digit()
            }
        })
}

/// Saves the pairs as a new points file and registers `original` (layer `layer`, 1-based) to
/// the vector file. Blocking.
pub fn save_and_register(
    build_dir: &Path,
    (vectors, numbering): (&Path, crate::vectors::LayerNumbering),
    original: &BuildFile,
    layer: u32,
    view: &str,
    pairs: &[ClickedPair],
    now: chrono::DateTime<chrono::Utc>,
) -> Result<CalibrationResult, CalibrationPageError> {
    if !(4..=MAX_POINTS).contains(&pairs.len()) {
        return Err(CalibrationPageError::Invalid(format!(
            "{} point pairs: click 4 to {MAX_POINTS} (on the frame, then on the vectors)",
            pairs.len()
        )));
    }
    let ok = |p: &ClickedPair| {
        [p.fx, p.fy, p.x, p.y].iter().all(|v| v.is_finite())
            && (0.0..=1.0).contains(&p.fx)
            && (0.0..=1.0).contains(&p.fy)
            && p.x.abs() < 1e4
            && p.y.abs() < 1e4
    };
    if !pairs.iter().all(ok) {
        return Err(CalibrationPageError::Invalid(
            "a point is outside the frame or not a number".into(),
        ));
    }
    let bytes = original
        .read(FileKind::Frame)
        .map_err(CalibrationPageError::Read)?;
    let frame =
        crate::rectify::decode_frame(&bytes).map_err(|source| CalibrationPageError::Decode {
            path: original.path(),
            source,
        })?;
    drop(bytes);
    let (width, height) = (frame.width(), frame.height());
    let dir = build_dir.join(CALIBRATION_DIR);
    let write_error = |path: &Path| {
        let path = path.to_path_buf();
        move |source| CalibrationPageError::Write { path, source }
    };
    std::fs::create_dir_all(&dir).map_err(write_error(&dir))?;
    // Written only into a folder of the build, never through a link planted in its place.
    if !files::is_real_folder(build_dir, CALIBRATION_DIR) {
        return Err(CalibrationPageError::NotAFolder { path: dir });
    }
    let stamp = stamp(now);
    let name = format!("points-L{layer:05}-{view}-{stamp}.txt");
    let points_path = dir.join(&name);
    let mut text = format!(
        "# layerwise calibration page, {now}: layer {layer} {view}, {}\n# u v x y (image pixel column, row; build mm)\n",
        original.name()
    );
    for p in pairs {
        text.push_str(&format!(
            "{:.2} {:.2} {:.4} {:.4}\n",
            p.fx * f64::from(width),
            p.fy * f64::from(height),
            p.x,
            p.y
        ));
    }
    // create_new: an existing file is never replaced.
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&points_path)
        .and_then(|mut f| f.write_all(text.as_bytes()).and_then(|_| f.sync_all()))
        .map_err(write_error(&points_path))?;
    let calibration_name = format!("calibration-{stamp}.toml");
    let overlay_name = format!("overlay-{stamp}.png");
    // Taken also by a link (dangling or not): nothing is written through one.
    let taken = [&calibration_name, &overlay_name]
        .iter()
        .any(|n| std::fs::symlink_metadata(dir.join(n)).is_ok());
    let relative = |n: &str| format!("{CALIBRATION_DIR}/{n}");
    let started = std::time::Instant::now();
    let request = ImageRegistration {
        vectors: vectors.to_path_buf(),
        numbering,
        images: vec![RegistrationImage {
            path: original.path(),
            layer,
        }],
        init_points: points_path.clone(),
        out: Some(dir.join(&calibration_name)),
        overlay: Some(dir.join(&overlay_name)),
        distortion: DistortionChoice::None,
        options: RegistrationOptions::default(),
    };
    let mut result = CalibrationResult {
        points_file: relative(&name),
        calibration_file: None,
        overlay: None,
        click_residuals_px: Vec::new(),
        correlation: None,
        error: None,
        seconds: 0.0,
    };
    if taken {
        result.error = Some(format!("{calibration_name} exists already: save again"));
        return Ok(result);
    }
    let mut frame = Some(frame);
    let registered = register_images_with(&request, |_| {
        frame.take().ok_or_else(|| {
            crate::calibrate::RegistrationError::Invalid("the page registers one frame".into())
        })
    });
    match registered {
        Ok(report) => {
            result.calibration_file = Some(relative(&calibration_name));
            result.overlay = Some(format!("/api/calibration/{stamp}/overlay.png"));
            result.click_residuals_px = report.click_residuals_px;
            result.correlation = report
                .images
                .first()
                .map(|i| (i.fit.initial_correlation, i.fit.correlation));
        }
        Err(e) => result.error = Some(crate::logging::chain(&e)),
    }
    result.seconds = started.elapsed().as_secs_f64();
    Ok(result)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps_are_recognised_and_nothing_else() {
        let s = stamp(chrono::Utc::now());
        assert!(is_stamp(&s), "{s}");
        for bad in [
            "",
            "..",
            "20261201T2200000000",
            "20261201X220000000",
            "2026120/T220000000",
            &s[1..],
        ] {
            assert!(!is_stamp(bad), "{bad}");
        }
    }

    #[test]
    fn too_few_or_wild_points_write_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = ClickedPair {
            fx: 0.5,
            fy: 0.5,
            x: 0.0,
            y: 0.0,
        };
        let now = chrono::Utc::now();
        let missing = dir.path().join("none.jpg");
        let frame = BuildFile::new(dir.path(), &["none.jpg"]);
        let err = save_and_register(
            dir.path(),
            (&missing, Default::default()),
            &frame,
            1,
            "post_top",
            &[p; 3],
            now,
        );
        assert!(matches!(err, Err(CalibrationPageError::Invalid(_))));
        let wild = ClickedPair { fx: 1.5, ..p };
        let err = save_and_register(
            dir.path(),
            (&missing, Default::default()),
            &frame,
            1,
            "post_top",
            &[p, p, p, wild],
            now,
        );
        assert!(matches!(err, Err(CalibrationPageError::Invalid(_))));
        assert!(!dir.path().join(CALIBRATION_DIR).exists());
    }
}
