//! How far a calibration can be trusted across the plate (issue 27: a four-click calibration
//! 0.1-0.2 mm right at the parts was 2.4-3.0 mm off at the plate corners, and nothing said so).
//!
//! The homography's 8 parameters are estimated from point correspondences; their covariance,
//! linearised at the fit, is propagated through the mapping's Jacobian to any build point. The
//! points' noise is one figure in image pixels, converted to mm at each point's own scale: the
//! residuals' standard deviation (when there are more points than the 4 a homography needs)
//! with the click precision as its floor, so four exact points do not claim zero error. Inside
//! the points' hull the error stays near the points' own; outside it grows with the distance,
//! the faster the closer together the points are.
//!
//! The figure reported is the expected (root mean square) distance, in build mm, between where
//! the calibration puts a build point and where it is: `sqrt(trace)` of the 2x2 covariance.
//! The parameters are fitted in Hartley-normalised coordinates (centroid at 0, mean distance
//! √2) so the 8x8 normal matrix is well conditioned. A lens distortion, when fitted, is taken
//! as exact: the correspondences are in undistorted pixels.

use std::collections::BTreeMap;
use std::fmt;

use nalgebra::{SMatrix, SVector};

use crate::geometry::{BuildPoint, Grid, Homography, ImagePoint};
use crate::vectors::Layer;

/// How well a user clicks a point, pixels (one standard deviation per coordinate): the floor
/// of the points' noise.
pub const CLICK_PX: f64 = 0.5;
/// The default limit of the expected error, mm (`--max-error-mm`).
pub const DEFAULT_MAX_ERROR_MM: f64 = 0.5;
/// Most places of one kind (parts, between parts) printed; the worst are kept.
const MAX_ROWS_PER_KIND: usize = 8;
/// The plate is also sampled on this many points per side for the worst place.
const PLATE_SAMPLES: usize = 9;

type Mat8 = SMatrix<f64, 8, 8>;

/// One point the fit leans on: image pixel (undistorted) ↔ build mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointPair {
    pub image: ImagePoint,
    pub build: BuildPoint,
}
type Row8 = SVector<f64, 8>;

/// A similarity that moves points' centroid to 0 and their mean distance from it to √2.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Normaliser {
    cx: f64,
    cy: f64,
    scale: f64,
}

impl Normaliser {
    fn of(points: impl Iterator<Item = (f64, f64)>) -> Option<Normaliser> {
        let points: Vec<[f64; 2]> = points.map(|(x, y)| [x, y]).collect();
        let (cx, cy, mean) = crate::geometry::homography::centroid_spread(&points);
        let scale = std::f64::consts::SQRT_2 / mean;
        (scale.is_finite() && scale > 0.0).then_some(Normaliser { cx, cy, scale })
    }

    fn matrix(&self) -> Homography {
        let s = self.scale;
        Homography::from_matrix([
            [s, 0.0, -s * self.cx],
            [0.0, s, -s * self.cy],
            [0.0, 0.0, 1.0],
        ])
    }

    fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        (self.scale * (x - self.cx), self.scale * (y - self.cy))
    }
}

/// The expected position error of a fitted `build_from_image` anywhere on the plate.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorModel {
    build_from_image: Homography,
    image_from_build: Homography,
    image: Normaliser,
    build: Normaliser,
    /// The homography in normalised coordinates, `[2][2] = 1`.
    normalised: Homography,
    /// Covariance of the normalised homography's 8 parameters (row-major, without `[2][2]`).
    covariance: Mat8,
    /// The points' noise used, pixels (per coordinate).
    pub sigma_px: f64,
    /// The residuals' own estimate, pixels; `None` with 4 points (no redundancy).
    pub residual_px: Option<f64>,
    pub points: usize,
}

/// mm per image pixel at image point `q` under `h`: √|det| of its Jacobian there.
fn mm_per_px(h: &Homography, q: ImagePoint) -> Option<f64> {
    let m = h.matrix();
    let w = m[2][0] * q.u + m[2][1] * q.v + m[2][2];
    let (x, y) = h.apply(q.u, q.v)?;
    let j = [
        [(m[0][0] - x * m[2][0]) / w, (m[0][1] - x * m[2][1]) / w],
        [(m[1][0] - y * m[2][0]) / w, (m[1][1] - y * m[2][1]) / w],
    ];
    let r = (j[0][0] * j[1][1] - j[0][1] * j[1][0]).abs().sqrt();
    (r.is_finite() && r > 0.0).then_some(r)
}

/// d(x, y)/d(h11 h12 h13 h21 h22 h23 h31 h32) of `h` (`[2][2] = 1`) at (a, b).
fn jacobian(h: &Homography, a: f64, b: f64) -> Option<(Row8, Row8)> {
    let m = h.matrix();
    let w = m[2][0] * a + m[2][1] * b + m[2][2];
    let (x, y) = h.apply(a, b)?;
    let dx =
        Row8::from_column_slice(&[a / w, b / w, 1.0 / w, 0.0, 0.0, 0.0, -x * a / w, -x * b / w]);
    let dy =
        Row8::from_column_slice(&[0.0, 0.0, 0.0, a / w, b / w, 1.0 / w, -y * a / w, -y * b / w]);
    Some((dx, dy))
}

impl ErrorModel {
    /// The model of `build_from_image` fitted to `points` (image px ↔ build mm), with the
    /// points' noise at least `click_px` pixels. `None` when the points cannot support a
    /// homography (fewer than 4, degenerate, beyond the horizon).
    pub fn fit(
        points: &[PointPair],
        build_from_image: &Homography,
        click_px: f64,
    ) -> Option<ErrorModel> {
        if points.len() < 4 {
            return None;
        }
        let image_from_build = build_from_image.inverse()?;
        let image = Normaliser::of(points.iter().map(|p| (p.image.u, p.image.v)))?;
        let build = Normaliser::of(points.iter().map(|p| (p.build.x, p.build.y)))?;
        let image_inverse = image.matrix().inverse()?;
        let normalised = build
            .matrix()
            .compose(build_from_image)
            .compose(&image_inverse)
            .normalised()?;
        let mut residual_sq = 0.0;
        let mut scales = Vec::with_capacity(points.len());
        for p in points {
            let scale = mm_per_px(build_from_image, p.image)?;
            let (x, y) = build_from_image.apply(p.image.u, p.image.v)?;
            residual_sq += ((x - p.build.x).powi(2) + (y - p.build.y).powi(2)) / (scale * scale);
            scales.push(scale);
        }
        let redundancy = 2 * points.len() - 8;
        let residual_px = (redundancy > 0).then(|| (residual_sq / redundancy as f64).sqrt());
        let sigma_px = residual_px.unwrap_or(0.0).max(click_px);
        let mut information = Mat8::zeros();
        for (p, scale) in points.iter().zip(&scales) {
            let (a, b) = image.apply(p.image.u, p.image.v);
            let (dx, dy) = jacobian(&normalised, a, b)?;
            let sigma = sigma_px * scale * build.scale;
            let weight = 1.0 / (sigma * sigma);
            information += (dx * dx.transpose() + dy * dy.transpose()) * weight;
        }
        let covariance = information.try_inverse()?;
        covariance.iter().all(|v| v.is_finite()).then_some(())?;
        Some(ErrorModel {
            build_from_image: *build_from_image,
            image_from_build,
            image,
            build,
            normalised,
            covariance,
            sigma_px,
            residual_px,
            points: points.len(),
        })
    }

    /// The expected distance, mm, between where the calibration puts build point `at` and
    /// where it is (see the module doc); `None` beyond the camera's horizon.
    pub fn error_mm(&self, at: BuildPoint) -> Option<f64> {
        let (u, v) = self.image_from_build.apply(at.x, at.y)?;
        let (a, b) = self.image.apply(u, v);
        let (dx, dy) = jacobian(&self.normalised, a, b)?;
        let var =
            (dx.transpose() * self.covariance * dx)[0] + (dy.transpose() * self.covariance * dy)[0];
        let e = var.max(0.0).sqrt() / self.build.scale;
        e.is_finite().then_some(e)
    }

    /// mm per image pixel at build point `at` under the fitted homography.
    pub fn resolution_mm(&self, at: BuildPoint) -> Option<f64> {
        let (u, v) = self.image_from_build.apply(at.x, at.y)?;
        mm_per_px(&self.build_from_image, ImagePoint::new(u, v))
    }
}

/// Where a part is: its id in the vector file and the centre of its extent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PartCentre {
    pub part: i64,
    pub centre: BuildPoint,
}

/// The parts of `layers` (their polylines and hatches, grouped by part id), each at the centre
/// of its extent over all of them.
pub fn part_centres<'a>(layers: impl IntoIterator<Item = &'a Layer>) -> Vec<PartCentre> {
    let mut extents: BTreeMap<i64, [f64; 4]> = BTreeMap::new();
    let mut add = |part: i64, x: f64, y: f64| {
        let e = extents.entry(part).or_insert([x, y, x, y]);
        *e = [e[0].min(x), e[1].min(y), e[2].max(x), e[3].max(y)];
    };
    for layer in layers {
        for p in &layer.polylines {
            for q in &p.points {
                add(p.part, q[0], q[1]);
            }
        }
        for h in &layer.hatches {
            for s in &h.segments {
                add(h.part, s[0], s[1]);
                add(h.part, s[2], s[3]);
            }
        }
    }
    extents
        .into_iter()
        .map(|(part, e)| PartCentre {
            part,
            centre: BuildPoint::new(0.5 * (e[0] + e[2]), 0.5 * (e[1] + e[3])),
        })
        .collect()
}

/// What a registration against vectors leans on: per part of `layers`, its contour points
/// farthest along ±x, ±y and the diagonals, as correspondences exact under `build_from_image`
/// (so their noise is the floor's). `None` for a point beyond the horizon.
pub fn contour_support(layers: &[&Layer], build_from_image: &Homography) -> Vec<PointPair> {
    let image_from_build = match build_from_image.inverse() {
        Some(h) => h,
        None => return Vec::new(),
    };
    let directions: [(f64, f64); 8] = [
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, 1.0),
        (0.0, -1.0),
        (1.0, 1.0),
        (1.0, -1.0),
        (-1.0, 1.0),
        (-1.0, -1.0),
    ];
    let mut best: BTreeMap<(i64, usize), (f64, BuildPoint)> = BTreeMap::new();
    for layer in layers {
        for p in &layer.polylines {
            for q in &p.points {
                for (k, (dx, dy)) in directions.iter().enumerate() {
                    let score = q[0] * dx + q[1] * dy;
                    let e = best
                        .entry((p.part, k))
                        .or_insert((score, BuildPoint::new(q[0], q[1])));
                    if score > e.0 {
                        *e = (score, BuildPoint::new(q[0], q[1]));
                    }
                }
            }
        }
    }
    let mut out: Vec<PointPair> = Vec::new();
    for (_, build) in best.into_values() {
        if out.iter().any(|c| c.build.distance(&build) < 1e-6) {
            continue;
        }
        if let Some((u, v)) = image_from_build.apply(build.x, build.y) {
            out.push(PointPair {
                image: ImagePoint::new(u, v),
                build,
            });
        }
    }
    out
}

/// What kind of place a row of the report is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PlaceKind {
    Corner,
    Part,
    Between,
    /// The worst of the places and of a lattice over the plate.
    Worst,
}

/// One row: a named place on the plate and the calibration's expected error there.
#[derive(Clone, Debug, PartialEq)]
pub struct Place {
    pub kind: PlaceKind,
    pub name: String,
    pub at: BuildPoint,
    /// `None` where the camera does not see the place (beyond its horizon).
    pub error_mm: Option<f64>,
}

/// The calibration report across the plate (what `register points` and `register images`
/// print, and the `fit` table's `spread`).
#[derive(Clone, Debug, PartialEq)]
pub struct SpreadReport {
    /// Corners, parts, between parts, then the worst.
    pub places: Vec<Place>,
    pub limit_mm: f64,
    pub sigma_px: f64,
    pub residual_px: Option<f64>,
    pub points: usize,
    /// What the points are ("clicked points", "contour points of the parts").
    pub support: String,
    /// Parts and midpoints left out of the table (the worst are kept).
    pub omitted: usize,
}

impl SpreadReport {
    /// The report of `model` over `plate`'s corners, the `parts`' centres and the midpoints
    /// between each part and its nearest neighbour.
    pub fn new(
        model: &ErrorModel,
        plate: &Grid,
        parts: &[PartCentre],
        limit_mm: f64,
        support: &str,
    ) -> SpreadReport {
        let place = |kind, name: String, at: BuildPoint| Place {
            kind,
            name,
            at,
            error_mm: model.error_mm(at),
        };
        let mut places: Vec<Place> = [
            ("corner -x +y", plate.x_min, plate.y_max),
            ("corner +x +y", plate.x_max, plate.y_max),
            ("corner -x -y", plate.x_min, plate.y_min),
            ("corner +x -y", plate.x_max, plate.y_min),
        ]
        .into_iter()
        .map(|(n, x, y)| place(PlaceKind::Corner, n.into(), BuildPoint::new(x, y)))
        .collect();
        let mut omitted = 0;
        let mut keep_worst = |mut rows: Vec<Place>| {
            if rows.len() > MAX_ROWS_PER_KIND {
                rows.sort_by(|a, b| worse(b, a));
                omitted += rows.len() - MAX_ROWS_PER_KIND;
                rows.truncate(MAX_ROWS_PER_KIND);
            }
            rows
        };
        let part_rows = parts
            .iter()
            .map(|p| place(PlaceKind::Part, format!("part {}", p.part), p.centre))
            .collect();
        places.extend(keep_worst(part_rows));
        let mut pairs: Vec<(usize, usize)> = Vec::new();
        for (i, p) in parts.iter().enumerate() {
            let nearest = parts
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .min_by(|a, b| {
                    let d = |q: &PartCentre| q.centre.distance(&p.centre);
                    d(a.1).total_cmp(&d(b.1))
                });
            if let Some((j, _)) = nearest {
                let pair = (i.min(j), i.max(j));
                if !pairs.contains(&pair) {
                    pairs.push(pair);
                }
            }
        }
        let between_rows = pairs
            .iter()
            .map(|&(i, j)| {
                let (a, b) = (parts[i].centre, parts[j].centre);
                let mid = BuildPoint::new(0.5 * (a.x + b.x), 0.5 * (a.y + b.y));
                let name = format!("between {} and {}", parts[i].part, parts[j].part);
                place(PlaceKind::Between, name, mid)
            })
            .collect();
        places.extend(keep_worst(between_rows));
        let lattice = (0..PLATE_SAMPLES).flat_map(|i| {
            (0..PLATE_SAMPLES).map(move |j| {
                let t = |k: usize| k as f64 / (PLATE_SAMPLES - 1) as f64;
                BuildPoint::new(
                    plate.x_min + t(i) * (plate.x_max - plate.x_min),
                    plate.y_min + t(j) * (plate.y_max - plate.y_min),
                )
            })
        });
        let worst = places
            .iter()
            .cloned()
            .chain(lattice.map(|at| place(PlaceKind::Worst, "plate".into(), at)))
            .max_by(worse);
        if let Some(w) = worst {
            places.push(Place {
                kind: PlaceKind::Worst,
                name: format!("worst ({})", w.name),
                ..w
            });
        }
        SpreadReport {
            places,
            limit_mm,
            sigma_px: model.sigma_px,
            residual_px: model.residual_px,
            points: model.points,
            support: support.into(),
            omitted,
        }
    }

    /// The worst expected error, mm (infinite when a place is beyond the camera's horizon).
    pub fn worst_mm(&self) -> f64 {
        self.places
            .iter()
            .map(|p| p.error_mm.unwrap_or(f64::INFINITY))
            .fold(0.0, f64::max)
    }

    /// The warning to print when the worst exceeds the limit.
    pub fn warning(&self) -> Option<String> {
        let worst = self.places.last()?;
        if !(self.worst_mm() > self.limit_mm) {
            return None;
        }
        let corners = self
            .places
            .iter()
            .filter(|p| p.kind == PlaceKind::Corner)
            .filter_map(|p| p.error_mm)
            .fold(0.0, f64::max);
        Some(format!(
            "WARN: expected calibration error up to {} at {} ({:.1}, {:.1}) mm exceeds the limit \
             {:.2} mm (plate corners up to {corners:.2} mm): the {} cover too little of the \
             plate. Click points near the plate corners (spread them over the whole plate; \
             more than 4 points also show how well they fit), or raise --max-error-mm",
            fmt_mm(worst.error_mm),
            worst.name,
            worst.at.x,
            worst.at.y,
            self.limit_mm,
            self.support,
        ))
    }

    /// The `fit` table's `spread` entry: the limit, the noise used and every row.
    pub fn to_table(&self) -> toml::Table {
        use toml::Value;
        let mut t = toml::Table::new();
        t.insert(
            "method".into(),
            Value::String(
                "linearised covariance of the homography's 8 parameters from the points, \
                 propagated to each place; expected (rms) position error in mm"
                    .into(),
            ),
        );
        t.insert("support".into(), Value::String(self.support.clone()));
        t.insert("points".into(), Value::Integer(self.points as i64));
        t.insert("sigma_px".into(), Value::Float(self.sigma_px));
        if let Some(r) = self.residual_px {
            t.insert("residual_px".into(), Value::Float(r));
        }
        t.insert("max_error_mm".into(), Value::Float(self.limit_mm));
        t.insert("worst_mm".into(), Value::Float(self.worst_mm()));
        t.insert(
            "exceeds_limit".into(),
            Value::Boolean(self.worst_mm() > self.limit_mm),
        );
        let rows = self
            .places
            .iter()
            .map(|p| {
                let mut r = toml::Table::new();
                r.insert("place".into(), Value::String(p.name.clone()));
                r.insert("x_mm".into(), Value::Float(p.at.x));
                r.insert("y_mm".into(), Value::Float(p.at.y));
                if let Some(e) = p.error_mm {
                    r.insert("error_mm".into(), Value::Float(e));
                }
                Value::Table(r)
            })
            .collect();
        t.insert("places".into(), Value::Array(rows));
        t
    }
}

/// Orders places by expected error, unseen ones worst.
fn worse(a: &Place, b: &Place) -> std::cmp::Ordering {
    let e = |p: &Place| p.error_mm.unwrap_or(f64::INFINITY);
    e(a).total_cmp(&e(b))
}

fn fmt_mm(e: Option<f64>) -> String {
    e.map_or("unseen".into(), |e| format!("{e:.2} mm"))
}

/// The table (place, x y mm, expected error mm) and the WARN line when the worst exceeds the
/// limit.
impl fmt::Display for SpreadReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "expected error across the plate ({} {}, {:.2} px each{}):",
            self.points,
            self.support,
            self.sigma_px,
            self.residual_px
                .map_or(String::new(), |r| format!(", residuals {r:.2} px")),
        )?;
        writeln!(
            f,
            "  {:<24} {:>8} {:>8} {:>10}",
            "place", "x mm", "y mm", "error mm"
        )?;
        for p in &self.places {
            let e = p.error_mm.map_or("unseen".into(), |e| format!("{e:.2}"));
            let flag = if p.error_mm.is_none_or(|e| e > self.limit_mm) {
                " > limit"
            } else {
                ""
            };
            writeln!(
                f,
                "  {:<24} {:>8.1} {:>8.1} {:>10}{flag}",
                p.name, p.at.x, p.at.y, e
            )?;
        }
        if self.omitted > 0 {
            writeln!(
                f,
                "  ({} more parts and midpoints, each below the ones shown)",
                self.omitted
            )?;
        }
        match self.warning() {
            Some(w) => writeln!(f, "{w}"),
            None => writeln!(
                f,
                "worst {} is within the limit {:.2} mm",
                fmt_mm(Some(self.worst_mm())),
                self.limit_mm
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// About 0.2-0.3 mm per pixel over a 1472 x 982 frame, viewed obliquely.
    fn truth() -> Homography {
        Homography::from_matrix([
            [0.21, 0.013, -150.0],
            [-0.004, -0.25, 120.0],
            [1.1e-5, -6.0e-5, 1.0],
        ])
    }

    /// Correspondences at build points `at` through `truth()`, each image point moved by
    /// `noise_px` times a fixed pseudo-random unit-ish offset.
    fn clicks(at: &[(f64, f64)], noise_px: f64) -> Vec<PointPair> {
        let inv = truth().inverse().expect("invertible");
        at.iter()
            .enumerate()
            .map(|(i, &(x, y))| {
                let (u, v) = inv.apply(x, y).expect("in view");
                let k = i as f64;
                let (du, dv) = ((1.7 * k + 0.3).sin(), (2.3 * k + 1.1).cos());
                PointPair {
                    image: ImagePoint::new(u + noise_px * du, v + noise_px * dv),
                    build: BuildPoint::new(x, y),
                }
            })
            .collect()
    }

    fn fitted(points: &[PointPair]) -> ErrorModel {
        let image: Vec<[f64; 2]> = points.iter().map(|p| [p.image.u, p.image.v]).collect();
        let build: Vec<[f64; 2]> = points.iter().map(|p| [p.build.x, p.build.y]).collect();
        let h = Homography::from_correspondences(&image, &build).expect("fits");
        ErrorModel::fit(points, &h, CLICK_PX).expect("model")
    }

    fn error(m: &ErrorModel, x: f64, y: f64) -> f64 {
        m.error_mm(BuildPoint::new(x, y)).expect("seen")
    }

    #[test]
    fn the_error_grows_away_from_the_points_hull() {
        let pts = clicks(
            &[
                (-30.0, -20.0),
                (30.0, -25.0),
                (35.0, 20.0),
                (-25.0, 30.0),
                (0.0, 0.0),
                (10.0, -5.0),
            ],
            1.0,
        );
        let m = fitted(&pts);
        assert!(m.residual_px.expect("6 points: redundancy") > 0.0);
        let inside = error(&m, 0.0, 0.0);
        let mut last = inside;
        for r in [40.0, 70.0, 100.0, 137.5] {
            let e = error(&m, r, r);
            assert!(e > 1.2 * last, "at {r}: {e} after {last}");
            last = e;
        }
        // Inside the hull the error is about the points' own (0.5-1 px of 0.25 mm).
        assert!(inside > 0.02 && inside < 0.3, "{inside}");
        assert!(last > 5.0 * inside, "corner {last} vs centre {inside}");
    }

    #[test]
    fn four_exact_points_keep_the_click_floor() {
        let pts = clicks(
            &[(-30.0, -20.0), (30.0, -25.0), (35.0, 20.0), (-25.0, 30.0)],
            0.0,
        );
        let m = fitted(&pts);
        assert_eq!(m.residual_px, None);
        assert_eq!(m.sigma_px, CLICK_PX);
        let at_point = error(&m, 30.0, -25.0);
        // About 0.5 px of about 0.25 mm: not zero, not more than a pixel.
        assert!(at_point > 0.05 && at_point < 0.3, "{at_point}");
    }

    #[test]
    fn residuals_above_the_floor_raise_the_noise() {
        let at = [
            (-100.0, -100.0),
            (100.0, -100.0),
            (100.0, 100.0),
            (-100.0, 100.0),
            (0.0, 0.0),
            (50.0, -30.0),
            (-60.0, 40.0),
            (20.0, 80.0),
        ];
        let quiet = fitted(&clicks(&at, 0.01));
        let noisy = fitted(&clicks(&at, 3.0));
        assert_eq!(quiet.sigma_px, CLICK_PX);
        assert!(noisy.sigma_px > 1.0, "{}", noisy.sigma_px);
        assert!(error(&noisy, 137.5, 137.5) > 2.0 * error(&quiet, 137.5, 137.5));
    }

    /// Issue 27's case: four clicks on parts near the middle are fine at the parts and
    /// millimetres off at the corners; four clicks near the corners are not.
    #[test]
    fn clustered_points_give_the_corners_a_larger_error_than_spread_ones() {
        let clustered = fitted(&clicks(
            &[(-30.0, -20.0), (30.0, -25.0), (35.0, 20.0), (-25.0, 30.0)],
            0.0,
        ));
        let spread = fitted(&clicks(
            &[
                (-130.0, -125.0),
                (125.0, -130.0),
                (130.0, 128.0),
                (-128.0, 130.0),
            ],
            0.0,
        ));
        let plate = Grid::plate();
        let parts = [
            PartCentre {
                part: 1,
                centre: BuildPoint::new(-20.0, 0.0),
            },
            PartCentre {
                part: 2,
                centre: BuildPoint::new(25.0, 5.0),
            },
        ];
        let a = SpreadReport::new(&clustered, &plate, &parts, 0.5, "clicked points");
        let b = SpreadReport::new(&spread, &plate, &parts, 0.5, "clicked points");
        for (pa, pb) in a.places.iter().zip(&b.places) {
            assert_eq!(pa.name, pb.name);
            if pa.kind == PlaceKind::Corner {
                let (ea, eb) = (pa.error_mm.unwrap(), pb.error_mm.unwrap());
                assert!(ea > 1.0 && ea > 5.0 * eb, "{}: {ea} vs {eb}", pa.name);
            }
        }
        assert!(a.worst_mm() > 1.0 && b.worst_mm() < 0.5, "{a}\n{b}");
        let warning = a.warning().expect("clustered clicks warn");
        assert!(warning.starts_with("WARN") && warning.contains("plate corners"));
        assert_eq!(b.warning(), None);
        let names: Vec<&str> = a.places.iter().map(|p| p.name.as_str()).collect();
        assert_eq!(
            names[..7],
            [
                "corner -x +y",
                "corner +x +y",
                "corner -x -y",
                "corner +x -y",
                "part 1",
                "part 2",
                "between 1 and 2"
            ]
        );
        assert!(names[7].starts_with("worst ("));
        let table = a.to_string();
        assert!(
            table.contains("error mm") && table.contains("> limit"),
            "{table}"
        );
        let t = a.to_table();
        assert_eq!(t["max_error_mm"].as_float(), Some(0.5));
        assert_eq!(t["places"].as_array().map(Vec::len), Some(8));
    }

    #[test]
    fn contour_support_takes_each_parts_extremes() {
        let mut layer = Layer::new(0, 0.03);
        layer.polylines.push(crate::vectors::Polyline {
            part: 3,
            direction: crate::vectors::Direction::CounterClockwise,
            points: vec![
                [0.0, 0.0],
                [10.0, 0.0],
                [5.0, 2.0],
                [10.0, 10.0],
                [0.0, 10.0],
            ],
        });
        let support = contour_support(&[&layer], &truth());
        assert_eq!(support.len(), 4, "{support:?}");
        assert!(support
            .iter()
            .all(|c| c.build.distance(&BuildPoint::new(5.0, 2.0)) > 1.0));
        let centres = part_centres([&layer]);
        assert_eq!(centres.len(), 1);
        assert_eq!(centres[0].centre, BuildPoint::new(5.0, 5.0));
    }
}
