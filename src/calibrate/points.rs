//! The user's point correspondences (POINTS.txt) and the starting homography from them by the
//! normalized DLT (Hartley & Zisserman, ch. 4, algorithm 4.2).
//!
//! File format: one correspondence per line, `u v x y` (image pixel column and row, build mm),
//! separated by spaces, tabs or commas; `#` starts a comment; blank lines are skipped.

use std::path::Path;

use nalgebra::{DMatrix, Matrix3};

use super::{Mat3, RegistrationError};

/// One clicked correspondence: image pixel (u, v) ↔ build point (x, y) in mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Correspondence {
    pub image: [f64; 2],
    pub build: [f64; 2],
    /// 1-based line in the file it came from (0 when made in code).
    pub line: usize,
}

/// Reads and parses a points file (see the module doc); at least 4 correspondences.
pub fn read_points(path: &Path) -> Result<Vec<Correspondence>, RegistrationError> {
    let text = std::fs::read_to_string(path).map_err(|source| RegistrationError::Read {
        file: path.to_path_buf(),
        source,
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
        }
        out.push(Correspondence {
            image: [v[0], v[1]],
            build: [v[2], v[3]],
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

/// The image → build homography (`H[2][2] = 1`) from `points` by the normalized DLT: both point
/// sets moved to centroid 0 and mean distance √2, the 2n x 9 system solved by SVD, then
/// denormalised. `file` names the source in errors.
///
/// Refuses fewer than 4 points, duplicates (in either set), three collinear points of four, all
/// points collinear, or a rank-deficient system.
pub fn homography_dlt(points: &[Correspondence], file: &Path) -> Result<Mat3, RegistrationError> {
    let bad = |message: String| RegistrationError::Points {
        file: file.to_path_buf(),
        message,
    };
    let n = points.len();
    if n < 4 {
        return Err(bad(format!(
            "{n} correspondence(s); a homography needs at least 4"
        )));
    }
    let image: Vec<[f64; 2]> = points.iter().map(|p| p.image).collect();
    let build: Vec<[f64; 2]> = points.iter().map(|p| p.build).collect();
    let line = |i: usize| points[i].line;
    for (set, name, unit) in [(&image, "image", "px"), (&build, "build", "mm")] {
        let (_, _, spread) = centroid_spread(set);
        for i in 0..n {
            for j in i + 1..n {
                let d = (set[i][0] - set[j][0]).hypot(set[i][1] - set[j][1]);
                if !(d > 1e-6 * spread) {
                    return Err(bad(format!(
                        "lines {} and {}: duplicate {name} points ({:?} {unit})",
                        line(i),
                        line(j),
                        set[i]
                    )));
                }
            }
        }
        if n == 4 {
            for skip in 0..4 {
                let idx: Vec<usize> = (0..4).filter(|&k| k != skip).collect();
                if collinear(set[idx[0]], set[idx[1]], set[idx[2]]) {
                    return Err(bad(format!(
                        "lines {}, {} and {}: the {name} points are collinear; pick 4 points \
                         no 3 of which lie on a line",
                        line(idx[0]),
                        line(idx[1]),
                        line(idx[2])
                    )));
                }
            }
        } else if all_collinear(set) {
            return Err(bad(format!("all {name} points lie on one line")));
        }
    }
    let ti = normaliser(&image);
    let tb = normaliser(&build);
    let apply = |t: &Mat3, p: [f64; 2]| [t[0][0] * p[0] + t[0][2], t[1][1] * p[1] + t[1][2]];
    // At least 9 rows so the SVD yields the full 9 x 9 V even for n = 4 (extra rows are 0).
    let rows = (2 * n).max(9);
    let mut a = DMatrix::<f64>::zeros(rows, 9);
    for k in 0..n {
        let [u, v] = apply(&ti, image[k]);
        let [x, y] = apply(&tb, build[k]);
        // x' × (H x) = 0 with x = (u, v, 1), x' = (x, y, 1).
        let r0 = [-u, -v, -1.0, 0.0, 0.0, 0.0, x * u, x * v, x];
        let r1 = [0.0, 0.0, 0.0, -u, -v, -1.0, y * u, y * v, y];
        for c in 0..9 {
            a[(2 * k, c)] = r0[c];
            a[(2 * k + 1, c)] = r1[c];
        }
    }
    let svd = a.svd(false, true);
    let v_t = svd
        .v_t
        .as_ref()
        .ok_or_else(|| bad("singular value decomposition failed".into()))?;
    let sv = &svd.singular_values;
    let mut order: Vec<usize> = (0..sv.len()).collect();
    order.sort_by(|&i, &j| sv[i].total_cmp(&sv[j]));
    let (smallest, second) = (order[0], order[1]);
    // A second (near-)zero singular value: the points do not pin down one homography.
    if !(sv[second] > 1e-9 * sv[order[sv.len() - 1]]) {
        return Err(bad(
            "the correspondences are rank-deficient (degenerate configuration)".into(),
        ));
    }
    let h = v_t.row(smallest);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    let to_na = |m: &Mat3| Matrix3::from_fn(|r, c| m[r][c]);
    let tb_inv = to_na(&tb)
        .try_inverse()
        .ok_or_else(|| bad("cannot normalise the build points".into()))?;
    let full = tb_inv * hn * to_na(&ti);
    let s = full[(2, 2)];
    if !(s.abs() > 1e-12 * full.abs().max()) {
        return Err(bad(
            "the image origin maps to infinity: H[2][2] would be 0".into()
        ));
    }
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = full[(r, c)] / s;
        }
    }
    if out.iter().flatten().any(|v| !v.is_finite()) || !(super::singularity(&out) > 1e-12) {
        return Err(bad("the correspondences give a singular homography".into()));
    }
    Ok(out)
}

/// Centroid and mean distance to it.
fn centroid_spread(p: &[[f64; 2]]) -> (f64, f64, f64) {
    let n = p.len() as f64;
    let cx = p.iter().map(|q| q[0]).sum::<f64>() / n;
    let cy = p.iter().map(|q| q[1]).sum::<f64>() / n;
    let d = p.iter().map(|q| (q[0] - cx).hypot(q[1] - cy)).sum::<f64>() / n;
    (cx, cy, d)
}

/// Similarity moving the centroid to 0 and the mean distance to √2 (Hartley normalisation).
fn normaliser(p: &[[f64; 2]]) -> Mat3 {
    let (cx, cy, d) = centroid_spread(p);
    let s = std::f64::consts::SQRT_2 / d;
    [[s, 0.0, -s * cx], [0.0, s, -s * cy], [0.0, 0.0, 1.0]]
}

/// Three points on (nearly) one line: the triangle's height over its longest side is below
/// 1e-3 of that side (a user's four clicks need a real spread, not just a nonzero one).
fn collinear(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> bool {
    let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let longest2 = [(a, b), (b, c), (c, a)]
        .iter()
        .map(|(p, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2))
        .fold(0.0, f64::max);
    // height = |cross| / longest, compared with 1e-3·longest.
    !(cross.abs() > 1e-3 * longest2)
}

/// All points on (nearly) one line: the smaller principal axis of their scatter is tiny.
fn all_collinear(p: &[[f64; 2]]) -> bool {
    let (cx, cy, _) = centroid_spread(p);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for q in p {
        let (dx, dy) = (q[0] - cx, q[1] - cy);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    let tr = sxx + syy;
    let det = sxx * syy - sxy * sxy;
    let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
    let (big, small) = (tr / 2.0 + disc, tr / 2.0 - disc);
    !(small > 1e-6 * big)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn apply(h: &Mat3, u: f64, v: f64) -> [f64; 2] {
        let w = h[2][0] * u + h[2][1] * v + h[2][2];
        [
            (h[0][0] * u + h[0][1] * v + h[0][2]) / w,
            (h[1][0] * u + h[1][1] * v + h[1][2]) / w,
        ]
    }

    fn truth() -> Mat3 {
        [
            [0.21, 0.013, -150.0],
            [-0.004, -0.25, 120.0],
            [1.1e-5, -6.0e-5, 1.0],
        ]
    }

    fn correspondences(uv: &[[f64; 2]]) -> Vec<Correspondence> {
        uv.iter()
            .enumerate()
            .map(|(i, &image)| Correspondence {
                image,
                build: apply(&truth(), image[0], image[1]),
                line: i + 1,
            })
            .collect()
    }

    #[test]
    fn parses_comments_commas_and_names_bad_lines() {
        let text = "# u v x y\n10 20 1.5 2.5\n\n 30,40, -1e1 , 3 # trailing\n1 2 3 4\n5 6 7 8\n";
        let p = parse_points(text, Path::new("pts.txt")).expect("valid");
        assert_eq!(p.len(), 4);
        assert_eq!(p[1].image, [30.0, 40.0]);
        assert_eq!(p[1].build, [-10.0, 3.0]);
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
            let h = homography_dlt(&pts, Path::new("p")).expect("non-degenerate");
            assert_eq!(h[2][2], 1.0);
            for (got, want) in h.iter().flatten().zip(truth().iter().flatten()) {
                assert!((got - want).abs() <= 1e-9 * want.abs().max(1e-3), "{h:?}");
            }
        }
    }

    #[test]
    fn dlt_refuses_degenerate_sets() {
        let p = Path::new("clicks.txt");
        let few = correspondences(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]);
        assert!(homography_dlt(&few, p)
            .unwrap_err()
            .to_string()
            .contains("at least 4"));
        let collinear = correspondences(&[[0.0, 0.0], [10.0, 10.0], [20.0, 20.0], [0.0, 50.0]]);
        let err = homography_dlt(&collinear, p).unwrap_err().to_string();
        assert!(
            err.contains("clicks.txt") && err.contains("collinear"),
            "{err}"
        );
        assert!(err.contains("lines 1, 2 and 3"), "{err}");
        let dup = correspondences(&[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 0.0]]);
        let err = homography_dlt(&dup, p).unwrap_err().to_string();
        assert!(
            err.contains("duplicate") && err.contains("lines 2 and 4"),
            "{err}"
        );
        let line = correspondences(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0], [4.0, 4.0]]);
        let err = homography_dlt(&line, p).unwrap_err().to_string();
        assert!(err.contains("one line"), "{err}");
        // Duplicated build points with distinct image points.
        let mut b = correspondences(&[[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]]);
        b[3].build = b[0].build;
        let err = homography_dlt(&b, p).unwrap_err().to_string();
        assert!(err.contains("duplicate build"), "{err}");
    }
}
