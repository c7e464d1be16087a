//! The user's point correspondences (POINTS.txt), and the starting homography from them by the
//! geometry's DLT with errors that name the file and its lines.
//!
//! File format: one correspondence per line, `u v x y` (image pixel column and row, build mm),
//! separated by spaces, tabs or commas; `#` starts a comment; blank lines are skipped.

use std::path::Path;

use super::spread::{
    ErrorModel, PartCentre, PointPair, SpreadReport, CLICK_PX, DEFAULT_MAX_ERROR_MM,
};
use super::RegistrationError;
use crate::geometry::{BuildPoint, DltError, Homography, ImagePoint, PointSet};

/// One clicked correspondence: image pixel (u, v) ↔ build point (x, y) in mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub image: ImagePoint,
    pub build: BuildPoint,
    /// 1-based line in the file it came from (0 when made in code).
    pub line: usize,
}

/// The largest coordinate of a point, pixels or mm: any camera or plate is far smaller, and
/// beyond it the fit's squares overflow (a 1e308 point read as a duplicate).
const MAX_COORDINATE: f64 = 1e6;

/// Reads and parses a points file (see the module doc); at least 4 correspondences.
pub fn read_points(path: &Path) -> Result<Vec<Correspondence>, RegistrationError> {
    let text = crate::fsutil::read_text_bounded(path, 1 << 20).map_err(|source| {
        RegistrationError::Read {
            file: path.to_path_buf(),
            source,
        }
    })?;
    parse_points(&text, path)
}

/// Parses the text of a points file; `file` names it in errors.
pub fn parse_points(text: &str, file: &Path) -> Result<Vec<Correspondence>, RegistrationError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("");
        let fields: Vec<&str> = content
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|f| !f.is_empty())
            .collect();
        if fields.is_empty() {
            continue;
        }
        let bad = |message: String| RegistrationError::Points {
            file: file.to_path_buf(),
            message,
        };
        if fields.len() != 4 {
            return Err(bad(format!(
                "line {line}: expected 4 numbers `u v x y`, found {} field(s): {:?}",
                fields.len(),
                content.trim()
            )));
        }
        let mut v = [0.0f64; 4];
        for (k, (slot, f)) in v.iter_mut().zip(&fields).enumerate() {
            let name = ["u", "v", "x", "y"][k];
            *slot = f
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    bad(format!(
                        "line {line}: {name} = {f:?} is not a finite number"
                    ))
                })?;
            if slot.abs() > MAX_COORDINATE {
                return Err(bad(format!(
                    "line {line}: {name} = {f} is out of range: give -{MAX_COORDINATE} to \
                     {MAX_COORDINATE} (pixels for u v, mm for x y)"
                )));
            }
        }
        out.push(Correspondence {
            image: ImagePoint::new(v[0], v[1]),
            build: BuildPoint::new(v[2], v[3]),
            line,
        });
    }
    if out.len() < 4 {
        return Err(RegistrationError::Points {
            file: file.to_path_buf(),
            message: format!(
                "{} correspondence(s); a homography needs at least 4 (lines `u v x y`)",
                out.len()
            ),
        });
    }
    Ok(out)
}

/// The image → build homography (`build_from_image`, `H[2][2] = 1`) from `points` by the
/// normalized DLT ([`Homography::from_correspondences`]). Errors name `file` and the lines of
/// the points concerned.
///
/// Refuses fewer than 4 points, duplicates (in either set), three collinear points of four, all
/// points collinear, or a rank-deficient system.
pub fn dlt_build_from_image(
    points: &[Correspondence],
    file: &Path,
) -> Result<Homography, RegistrationError> {
    let image: Vec<[f64; 2]> = points.iter().map(|p| [p.image.u, p.image.v]).collect();
    let build: Vec<[f64; 2]> = points.iter().map(|p| [p.build.x, p.build.y]).collect();
    Homography::from_correspondences(&image, &build).map_err(|e| {
        let line = |i: usize| points[i].line;
        let names = |s: PointSet| match s {
            PointSet::From => ("image", "px", &image),
            PointSet::To => ("build", "mm", &build),
        };
        let message = match e {
            DltError::Duplicate { set, first, second } => {
                let (name, unit, pts) = names(set);
                format!(
                    "lines {} and {}: duplicate {name} points ({:?} {unit})",
                    line(first),
                    line(second),
                    pts[first]
                )
            }
            DltError::Collinear {
                set,
                points: [a, b, c],
            } => format!(
                "lines {}, {} and {}: the {} points are collinear; pick 4 points no 3 of which \
                 lie on a line",
                line(a),
                line(b),
                line(c),
                names(set).0
            ),
            DltError::AllCollinear { set } => {
                format!("all {} points lie on one line", names(set).0)
            }
            DltError::OriginAtInfinity => {
                "the image origin maps to infinity: H[2][2] would be 0".into()
            }
            source => {
                return RegistrationError::Dlt {
                    file: file.to_path_buf(),
                    source,
                }
            }
        };
        RegistrationError::Points {
            file: file.to_path_buf(),
            message,
        }
    })
}

/// A calibration from points alone (`layerwise register points`): the DLT homography through
/// the correspondences, with each point's residual (where the homography puts its image point
/// against the build point given), for machines without a vector file to refine against.
#[derive(Clone, Debug)]
pub struct PointsFit {
    pub calibration: crate::rectify::Calibration,
    /// (line of the points file, residual in mm), in file order.
    pub residuals: Vec<(usize, f64)>,
    pub rms_mm: f64,
    pub max_mm: f64,
    /// The expected error across the plate (`None` when the points cannot support it).
    pub spread: Option<SpreadReport>,
}

/// Where [`calibrate_from_points`] reports the expected error: the plate (its corners), the
/// parts (their centres and between them) and the limit beyond which it warns.
#[derive(Clone, Debug, PartialEq)]
pub struct SpreadTargets {
    pub plate: crate::geometry::Grid,
    pub parts: Vec<PartCentre>,
    pub max_error_mm: f64,
}

impl Default for SpreadTargets {
    fn default() -> Self {
        SpreadTargets {
            plate: crate::geometry::Grid::default(),
            parts: Vec::new(),
            max_error_mm: DEFAULT_MAX_ERROR_MM,
        }
    }
}

/// Fits [`PointsFit`] to the points of `file` (at least 4; with exactly 4 the homography passes
/// through them and the residuals are 0: more points show how well it fits), with the expected
/// error across the plate at `targets` (in the `fit` table as `spread`).
pub fn calibrate_from_points(
    file: &Path,
    targets: &SpreadTargets,
) -> Result<PointsFit, RegistrationError> {
    let points = read_points(file)?;
    let h = dlt_build_from_image(&points, file)?;
    let residuals: Vec<(usize, f64)> = points
        .iter()
        .map(|p| {
            let d = h
                .apply(p.image.u, p.image.v)
                .map_or(f64::INFINITY, |(x, y)| (x - p.build.x).hypot(y - p.build.y));
            (p.line, d)
        })
        .collect();
    let rms_mm =
        (residuals.iter().map(|(_, d)| d * d).sum::<f64>() / residuals.len() as f64).sqrt();
    let max_mm = residuals.iter().map(|(_, d)| *d).fold(0.0, f64::max);
    let mut fit = toml::Table::new();
    fit.insert("method".into(), "points (DLT)".into());
    fit.insert("points_file".into(), file.display().to_string().into());
    fit.insert("points".into(), (points.len() as i64).into());
    fit.insert("rms_mm".into(), rms_mm.into());
    fit.insert("max_mm".into(), max_mm.into());
    let pairs: Vec<PointPair> = points
        .iter()
        .map(|p| PointPair {
            image: p.image,
            build: p.build,
        })
        .collect();
    let spread = ErrorModel::fit(&pairs, &h, CLICK_PX).map(|model| {
        SpreadReport::new(
            &model,
            &targets.plate,
            &targets.parts,
            targets.max_error_mm,
            "clicked points",
        )
    });
    if let Some(s) = &spread {
        fit.insert("spread".into(), toml::Value::Table(s.to_table()));
    }
    Ok(PointsFit {
        calibration: crate::rectify::Calibration {
            build_from_image: h,
            distortion: None,
            grid: None,
            fit: Some(fit),
        },
        residuals,
        rms_mm,
        max_mm,
        spread,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Homography {
        Homography::from_matrix([
            [0.21, 0.013, -150.0],
            [-0.004, -0.25, 120.0],
            [1.1e-5, -6.0e-5, 1.0],
        ])
    }

    fn correspondences(uv: &[[f64; 2]]) -> Vec<Correspondence> {
        uv.iter()
            .enumerate()
            .map(|(i, &[u, v])| {
                let (x, y) = truth().apply(u, v).expect("in front");
                Correspondence {
                    image: ImagePoint::new(u, v),
                    build: BuildPoint::new(x, y),
                    line: i + 1,
                }
            })
            .collect()
    }

    #[test]
    fn parses_comments_commas_and_names_bad_lines() {
        let text = "# u v x y\n10 20 1.5 2.5\n\n 30,40, -1e1 , 3 # trailing\n1 2 3 4\n5 6 7 8\n";
        let p = parse_points(text, Path::new("pts.txt")).expect("valid");
        assert_eq!(p.len(), 4);
        assert_eq!(p[1].image, ImagePoint::new(30.0, 40.0));
        assert_eq!(p[1].build, BuildPoint::new(-10.0, 3.0));
        assert_eq!(p[1].line, 4);
        let err = parse_points("1 2 3 4\n1 2 x 4\n", Path::new("pts.txt"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("pts.txt") && err.contains("line 2") && err.contains("\"x\""),
            "{err}"
        );
        let err = parse_points("1 2 3\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("line 1") && err.contains("4 numbers"), "{err}");
        let err = parse_points("1 2 3 4\n5 6 7 8\n9 10 11 13\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("3 correspondence") && err.contains("at least 4"),
            "{err}"
        );
        let err = parse_points("1 2 3 inf\n", Path::new("p.txt"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("not a finite number"), "{err}");
    }

    #[test]
    fn dlt_recovers_the_homography_from_4_and_from_many() {
        let four = correspondences(&[
            [100.0, 80.0],
            [1300.0, 90.0],
            [1250.0, 900.0],
            [60.0, 850.0],
        ]);
        let many = correspondences(&[
            [100.0, 80.0],
            [1300.0, 90.0],
            [1250.0, 900.0],
            [60.0, 850.0],
            [700.0, 500.0],
            [400.0, 300.0],
        ]);
        for pts in [four, many] {
            let h = dlt_build_from_image(&pts, Path::new("p")).expect("non-degenerate");
            let (h, want) = (h.matrix(), truth().matrix());
            assert_eq!(h[2][2], 1.0);
            for (got, want) in h.iter().flatten().zip(want.iter().flatten()) {
                assert!((got - want).abs() <= 1e-9 * want.abs().max(1e-3), "{h:?}");
            }
        }
    }

    #[test]
    fn points_alone_give_a_calibration_with_residuals() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("points.txt");
        let mut pts = correspondences(&[
            [100.0, 80.0],
            [1300.0, 90.0],
            [1250.0, 900.0],
            [60.0, 850.0],
            [700.0, 500.0],
        ]);
        pts[4].build.x += 0.5;
        let text: String = pts
            .iter()
            .map(|p| format!("{} {} {} {}\n", p.image.u, p.image.v, p.build.x, p.build.y))
            .collect();
        std::fs::write(&file, text).unwrap();
        let fit = calibrate_from_points(&file, &SpreadTargets::default()).unwrap();
        assert_eq!(fit.residuals.len(), 5);
        assert!(fit.max_mm > 0.05 && fit.max_mm < 0.5, "{fit:?}");
        assert!(fit.rms_mm <= fit.max_mm);
        let back = crate::rectify::Calibration::parse(&fit.calibration.to_toml(), &file).unwrap();
        assert_eq!(back.build_from_image, fit.calibration.build_from_image);
    }

    #[test]
    fn dlt_refuses_degenerate_sets() {
        let p = Path::new("clicks.txt");
        let few = correspondences(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]);
        let err = crate::logging::chain(&dlt_build_from_image(&few, p).unwrap_err());
        assert!(
            err.contains("clicks.txt") && err.contains("at least 4"),
            "{err}"
        );
        let collinear = correspondences(&[[0.0, 0.0], [10.0, 10.0], [20.0, 20.0], [0.0, 50.0]]);
        let err = dlt_build_from_image(&collinear, p).unwrap_err().to_string();
        assert!(
            err.contains("clicks.txt") && err.contains("collinear"),
            "{err}"
        );
        assert!(err.contains("lines 1, 2 and 3"), "{err}");
        let dup = correspondences(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 0.0]]);
        let err = dlt_build_from_image(&dup, p).unwrap_err().to_string();
        assert!(
            err.contains("duplicate") && err.contains("lines 2 and 4"),
            "{err}"
        );
        let line = correspondences(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0]]);
        let err = dlt_build_from_image(&line, p).unwrap_err().to_string();
        assert!(err.contains("one line"), "{err}");
        // Duplicated build points with distinct image points.
        let mut b = correspondences(&[[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]]);
        b[3].build = b[0].build;
        let err = dlt_build_from_image(&b, p).unwrap_err().to_string();
        assert!(err.contains("duplicate build"), "{err}");
    }
}
