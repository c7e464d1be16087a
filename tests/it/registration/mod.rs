//! Accuracy and error tests of `layerwise register images` against mock_camera ground truth.
//!
//! Frames are rendered through a known homography (mock_camera's 30° oblique view); the layer's
//! vectors are written in code with the same parts (circle → 256-gon), so the exemplar comes
//! from the vectors as in production. The start points are true part corners moved by up to
//! ±6 px, as a user's clicks would be. The error is measured where it matters: the parts'
//! contour points mapped into the image by the true and by the recovered mapping, in pixels.

use crate::common;
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};

use image::{DynamicImage, RgbImage};
use layerwise::calibrate::{
    self, register_images, DistortionChoice, ImageRegistration, ImageRegistrationReport,
    RegistrationImage, RegistrationOptions,
};
use layerwise::geometry::{BuildPoint, CameraModel};
use layerwise::rectify::{calibration::Calibration, Interpolation, RadialDistortion, Rectifier};
use layerwise::vectors::{self, Format, Header, Layer, LayerNumbering, VectorFile};
use mock_camera::{Homography, Illumination, Renderer, Scene, Shape};

mod refusals;

const W: u32 = 1472;
const H: u32 = 982;
/// Focal length of the distorted test camera, px (a 45 mm lens on a full-frame sensor).
const FOCAL: f64 = 1.25 * W as f64;

/// A part: its rings in build mm (outer counter-clockwise, holes clockwise).
#[derive(Clone)]
struct Part {
    rings: Vec<Vec<(f64, f64)>>,
    /// The mock renders circles exactly; polygons by even-odd.
    circle: Option<(f64, f64, f64)>,
}

impl Part {
    fn polygon(rings: Vec<Vec<(f64, f64)>>) -> Part {
        Part {
            rings,
            circle: None,
        }
    }

    fn circle(cx: f64, cy: f64, r: f64) -> Part {
        let ring = (0..256)
            .map(|i| {
                let a = TAU * f64::from(i) / 256.0;
                (cx + r * a.cos(), cy + r * a.sin())
            })
            .collect();
        Part {
            rings: vec![ring],
            circle: Some((cx, cy, r)),
        }
    }

    fn shape(&self) -> Shape {
        match self.circle {
            Some((cx, cy, r)) => Shape::Circle { cx, cy, r },
            None => Shape::Polygon {
                rings: self.rings.clone(),
            },
        }
    }
}

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Vec<(f64, f64)> {
    vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
}

/// Five parts spread over the plate: a disc, and a box, an L, a frame with a hole and a
/// triangle turned by 17° about their centroids. Turned, because the mock renders by point
/// sampling: an edge along an image row (any y = const edge in mock_camera's oblique view) is
/// drawn up to ½ px off, the same way over its whole length, which the ground truth would then
/// not match (an axis-aligned box measured 0.45 px off for that reason alone).
fn parts() -> Vec<Part> {
    let (sn, cs) = 17f64.to_radians().sin_cos();
    parts_axis()
        .into_iter()
        .enumerate()
        .map(|(k, p)| {
            if k == 0 {
                return p;
            }
            let ring0 = &p.rings[0];
            let n = ring0.len() as f64;
            let cx = ring0.iter().map(|q| q.0).sum::<f64>() / n;
            let cy = ring0.iter().map(|q| q.1).sum::<f64>() / n;
            let rot = |(x, y): (f64, f64)| {
                let (dx, dy) = (x - cx, y - cy);
                (cx + cs * dx - sn * dy, cy + sn * dx + cs * dy)
            };
            Part {
                rings: p
                    .rings
                    .iter()
                    .map(|r| r.iter().copied().map(rot).collect())
                    .collect(),
                circle: p.circle,
            }
        })
        .collect()
}

/// The five parts before turning.
fn parts_axis() -> Vec<Part> {
    let mut hole = rect(67.0, -63.0, 83.0, -47.0);
    hole.reverse();
    vec![
        Part::circle(-70.0, 50.0, 8.0),
        Part::polygon(vec![rect(40.0, 40.0, 70.0, 60.0)]),
        Part::polygon(vec![vec![
            (-20.0, -80.0),
            (20.0, -80.0),
            (20.0, -70.0),
            (-10.0, -70.0),
            (-10.0, -40.0),
            (-20.0, -40.0),
        ]]),
        Part::polygon(vec![rect(60.0, -70.0, 90.0, -40.0), hole]),
        Part::polygon(vec![vec![(-90.0, -30.0), (-50.0, -30.0), (-70.0, 0.0)]]),
    ]
}

/// Part corners a user would click: the box's top right, a corner of the L, of the frame and of
/// the triangle.
fn clicks_mm() -> [(f64, f64); 4] {
    let p = parts();
    [
        p[1].rings[0][2],
        p[2].rings[0][0],
        p[3].rings[0][1],
        p[4].rings[0][0],
    ]
}
/// Click errors, px: up to ±6 in each coordinate.
const CLICK_ERRORS: [(f64, f64); 4] = [(5.2, -4.1), (-6.0, 3.3), (4.4, 5.9), (-3.7, -5.5)];

fn layer_of(index: usize, parts: &[Part]) -> Layer {
    let rings: Vec<&[Vec<(f64, f64)>]> = parts.iter().map(|p| p.rings.as_slice()).collect();
    vectors::synth::contour_layer(index, 0.03 * (index as f64 + 1.0), &rings)
}

fn vector_file(layers: &[Vec<Part>]) -> VectorFile {
    VectorFile {
        header: Header::new(Format::Ascii, 0.001),
        layers: layers
            .iter()
            .enumerate()
            .map(|(i, p)| layer_of(i, p))
            .collect(),
    }
}

fn render(truth: Homography, layer: u32, parts: &[Part], scanned: bool) -> RgbImage {
    let shapes: Vec<Shape> = parts.iter().map(Part::shape).collect();
    Renderer::new(W, H, truth).render(&Scene {
        layer,
        fused: &shapes,
        scanned,
        illumination: Illumination::Top,
    })
}

/// The frame a camera with radial distortion `d` records: each recorded pixel shows what the
/// undistorted camera sees at `d.undistort(pixel)` (nearest pixel, so the texture statistics the
/// std filter sees stay those of the render).
fn distort_frame(undistorted: &RgbImage, d: &RadialDistortion) -> RgbImage {
    let (w, h) = undistorted.dimensions();
    RgbImage::from_fn(w, h, |u, v| {
        let (x, y) = d.undistort(f64::from(u), f64::from(v));
        let (xi, yi) = (x.round(), y.round());
        if xi >= 0.0 && yi >= 0.0 && xi < f64::from(w) && yi < f64::from(h) {
            *undistorted.get_pixel(xi as u32, yi as u32)
        } else {
            image::Rgb([0, 0, 0])
        }
    })
}

/// True image position of a build point: H⁻¹ then the distortion, if any.
fn true_pixel(truth: &Homography, d: Option<&RadialDistortion>, x: f64, y: f64) -> (f64, f64) {
    let inv = truth.inverse().expect("invertible");
    let (u, v) = inv.apply(x, y).expect("finite");
    d.map_or((u, v), |d| d.distort(u, v))
}

fn points_text(truth: &Homography, d: Option<&RadialDistortion>, offset: (f64, f64)) -> String {
    let mut s = String::from("# u v x y: part corners clicked in the frame\n");
    for (&(x, y), &(du, dv)) in clicks_mm().iter().zip(CLICK_ERRORS.iter()) {
        let (u, v) = true_pixel(truth, d, x, y);
        s += &format!(
            "{:.3} {:.3} {x} {y}\n",
            u + du + offset.0,
            v + dv + offset.1
        );
    }
    s
}

/// Mean and max distance, px, between the true and the estimated image positions of the parts'
/// contour points (edges densified to 0.5 mm).
fn contour_error(
    parts: &[Part],
    truth: &Homography,
    true_d: Option<&RadialDistortion>,
    est: CameraModel,
) -> (f64, f64) {
    let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
    for p in parts {
        for ring in &p.rings {
            for i in 0..ring.len() {
                let (a, b) = (ring[i], ring[(i + 1) % ring.len()]);
                let steps = ((b.0 - a.0).hypot(b.1 - a.1) / 0.5).ceil().max(1.0) as usize;
                for s in 0..steps {
                    let t = s as f64 / steps as f64;
                    let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
                    let (tu, tv) = true_pixel(truth, true_d, x, y);
                    let e = est
                        .image_point(BuildPoint::new(x, y))
                        .expect("in front of the camera");
                    let (eu, ev) = (e.u, e.v);
                    let d = (tu - eu).hypot(tv - ev);
                    sum += d;
                    max = max.max(d);
                    n += 1;
                }
            }
        }
    }
    (sum / n as f64, max)
}

/// Per part: mean displacement (du, dv) and mean outward displacement, px (diagnostics).
fn error_structure(parts: &[Part], truth: &Homography, est: CameraModel) {
    for (k, p) in parts.iter().enumerate() {
        let ring = &p.rings[0];
        let n = ring.len() as f64;
        let cx = ring.iter().map(|q| q.0).sum::<f64>() / n;
        let cy = ring.iter().map(|q| q.1).sum::<f64>() / n;
        let (cu, cv) = true_pixel(truth, None, cx, cy);
        let (mut su, mut sv, mut out, mut m) = (0.0, 0.0, 0.0, 0.0);
        for &(x, y) in ring {
            let (tu, tv) = true_pixel(truth, None, x, y);
            let e = est.image_point(BuildPoint::new(x, y)).expect("front");
            let (eu, ev) = (e.u, e.v);
            let (du, dv) = (eu - tu, ev - tv);
            let (ru, rv) = (tu - cu, tv - cv);
            let rn = ru.hypot(rv);
            su += du;
            sv += dv;
            out += (du * ru + dv * rv) / rn;
            m += 1.0;
        }
        eprintln!(
            "  part {k}: shift ({:.3}, {:.3}) px, outward {:.3} px",
            su / m,
            sv / m,
            out / m
        );
    }
}

struct Setup {
    dir: tempfile::TempDir,
    vectors: PathBuf,
}

impl Setup {
    fn new(layers: &[Vec<Part>]) -> Setup {
        let dir = tempfile::tempdir().expect("tempdir");
        let vectors = dir.path().join("build.cli");
        let mut out = std::fs::File::create(&vectors).expect("create CLI");
        vectors::write_ascii(&vector_file(layers), &mut out).expect("write CLI");
        Setup { dir, vectors }
    }

    fn file(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn write_png(&self, name: &str, img: &RgbImage) -> PathBuf {
        let path = self.file(name);
        img.save(&path).expect("write PNG");
        path
    }

    fn write_text(&self, name: &str, text: &str) -> PathBuf {
        let path = self.file(name);
        std::fs::write(&path, text).expect("write text");
        path
    }

    /// Frames with the printer layer (from 1) each shows.
    fn request(&self, images: &[(&Path, u32)], points: &Path) -> ImageRegistration {
        ImageRegistration {
            vectors: self.vectors.clone(),
            numbering: LayerNumbering::default(),
            images: images
                .iter()
                .map(|&(p, layer)| RegistrationImage {
                    path: p.to_path_buf(),
                    layer,
                })
                .collect(),
            init_points: points.to_path_buf(),
            out: Some(self.file("calibration.toml")),
            overlay: None,
            distortion: DistortionChoice::None,
            options: RegistrationOptions::default(),
        }
    }
}

fn print_report(tag: &str, r: &ImageRegistrationReport) {
    eprintln!(
        "{tag}: {:.2} s, exemplar grid {:?}, image window {:?}",
        r.seconds,
        r.exemplar_grid,
        r.calibration
            .fit
            .as_ref()
            .and_then(|f| f.get("image_std_window"))
    );
    // What `layerwise register images` prints, then what only the tests look at.
    eprint!("{r}");
    for l in &r.levels {
        eprintln!("  level {}: rho {:.4}", l.level, l.correlation);
    }
    for i in &r.images {
        eprintln!("  {}: {:?}", i.name, i.fit);
    }
    eprintln!("  clicks px: {:?}", r.click_residuals_px);
}

fn mapping(cal: &Calibration) -> CameraModel {
    cal.camera()
}

#[test]
fn recovers_the_true_homography_to_a_quarter_pixel() {
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png("L00001_post_top.png", &render(truth, 1, &parts, true));
    let points = setup.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let mut request = setup.request(&[(&frame, 1)], &points);
    let overlay = setup.file("overlay.png");
    request.overlay = Some(overlay.clone());
    let report = register_images(&request).expect("registers");
    print_report("plain", &report);

    let start = CameraModel::pinhole(report.initial_build_from_image);
    let (mean0, max0) = contour_error(&parts, &truth, None, start);
    let (mean, max) = contour_error(&parts, &truth, None, mapping(&report.calibration));
    error_structure(&parts, &truth, mapping(&report.calibration));
    eprintln!(
        "start: mean {mean0:.3} px, max {max0:.3} px; refined: mean {mean:.4} px, max {max:.4} px"
    );
    // The test has teeth: the clicks alone are several pixels off.
    assert!(mean0 > 2.0, "start error {mean0}");
    assert!(mean <= 0.25 && max <= 0.5, "mean {mean} px, max {max} px");

    // The calibration file is what the daemon reads: it loads, follows the contract and
    // builds a rectifier.
    let cal = Calibration::load(&setup.file("calibration.toml")).expect("loads");
    assert_eq!(cal, report.calibration);
    assert_eq!(cal.build_from_image.matrix()[2][2], 1.0);
    let fit = cal.fit.as_ref().expect("fit table");
    for key in [
        "images",
        "layers",
        "levels",
        "residuals",
        "initial_homography",
    ] {
        assert!(fit.contains_key(key), "fit lacks {key}: {fit:?}");
    }
    // One grid: the calibration holds the camera model only; the grid is [rectify]'s.
    assert_eq!(cal.grid, None);
    let grid = layerwise::geometry::Grid::default();
    assert!(
        (report.native_pixel_mm - 0.31).abs() < 0.05,
        "{}",
        report.native_pixel_mm
    );
    let pinhole = CameraModel::pinhole(cal.build_from_image);
    Rectifier::new(&pinhole, grid, Interpolation::Bilinear, 0).expect("usable");

    // Fig. 11 left: red (start) and blue (refined) contours on the frame; below it a legend
    // and each part enlarged with both contours again.
    let pic = image::open(&overlay).expect("overlay PNG").to_rgb8();
    assert_eq!(pic.width(), W);
    assert!(pic.height() > H + 200, "{:?}", pic.dimensions());
    let count = |rows: std::ops::Range<u32>, c: [u8; 3]| {
        pic.enumerate_pixels()
            .filter(|(_, y, p)| rows.contains(y) && p.0 == c)
            .count()
    };
    assert!(count(0..H, [255, 0, 0]) > 500 && count(0..H, [0, 0, 255]) > 500);
    let below = H..pic.height();
    assert!(count(below.clone(), [255, 0, 0]) > 2000 && count(below, [0, 0, 255]) > 2000);

    // The expected error across the plate: small at the parts, in the fit table with its limit.
    let spread = report.spread.as_ref().expect("the report across the plate");
    for p in &spread.places {
        if p.kind == calibrate::spread::PlaceKind::Part {
            assert!(p.error_mm.expect("seen") < 0.5, "{spread}");
        }
    }
    assert_eq!(fit["spread"]["max_error_mm"].as_float(), Some(0.5));
}

#[test]
fn two_layers_register_jointly() {
    let truth = Homography::oblique_view(W, H);
    let all = parts();
    let (first, second) = (all[..3].to_vec(), all[2..].to_vec());
    let setup = Setup::new(&[first.clone(), second.clone()]);
    let a = setup.write_png("a.png", &render(truth, 1, &first, true));
    let b = setup.write_png("b.png", &render(truth, 2, &second, true));
    let points = setup.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let report = register_images(&setup.request(&[(&a, 1), (&b, 2)], &points)).expect("joint");
    print_report("joint", &report);
    assert_eq!(report.images.len(), 2);
    assert_eq!(report.images[1].layer, 2);
    let (mean, max) = contour_error(&all, &truth, None, mapping(&report.calibration));
    eprintln!("joint: mean {mean:.4} px, max {max:.4} px");
    assert!(mean <= 0.25 && max <= 0.5, "mean {mean} px, max {max} px");
}

#[test]
fn radial_model_cuts_the_error_of_a_distorted_camera() {
    let truth = Homography::oblique_view(W, H);
    let true_d = RadialDistortion {
        center: [0.5 * (f64::from(W) - 1.0), 0.5 * (f64::from(H) - 1.0)],
        focal_px: FOCAL,
        k1: -0.15,
        k2: 0.0,
    };
    // Lens distortion grows with the radius: parts out to the plate's corners, where a
    // single homography fails most.
    let mut parts = parts();
    for (cx, cy) in [
        (-100.0, -100.0),
        (100.0, -100.0),
        (100.0, 100.0),
        (-100.0, 100.0),
    ] {
        parts.push(Part::polygon(vec![rect(
            cx - 7.0,
            cy - 7.0,
            cx + 7.0,
            cy + 7.0,
        )]));
    }
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png(
        "distorted.png",
        &distort_frame(&render(truth, 1, &parts, true), &true_d),
    );
    let points = setup.write_text(
        "points.txt",
        &points_text(&truth, Some(&true_d), (0.0, 0.0)),
    );
    let mut request = setup.request(&[(&frame, 1)], &points);
    let plain = register_images(&request).expect("plain");
    print_report("distorted, plain", &plain);
    request.distortion = DistortionChoice::Radial {
        focal_px: Some(FOCAL),
    };
    let radial = register_images(&request).expect("radial");
    print_report("distorted, radial", &radial);
    let (pm, px) = contour_error(&parts, &truth, Some(&true_d), mapping(&plain.calibration));
    let (rm, rx) = contour_error(&parts, &truth, Some(&true_d), mapping(&radial.calibration));
    let d = radial.calibration.distortion.expect("distortion fitted");
    eprintln!(
        "plain: mean {pm:.3} px, max {px:.3} px; radial: mean {rm:.3} px, max {rx:.3} px; \
         k1 {:.5} k2 {:.5} (true {})",
        d.k1, d.k2, true_d.k1
    );
    // The plain homography must be clearly wrong here, and the radial model 4x better.
    assert!(pm > 0.75, "plain mean {pm} px: distortion too weak to test");
    assert!(
        4.0 * rm <= pm && 4.0 * rx <= px,
        "plain {pm}/{px}, radial {rm}/{rx}"
    );
    assert!(rm <= 0.25, "radial mean {rm} px");
    assert_eq!(d.center, true_d.center);
    // The written file carries the distortion table the rectifier applies.
    let cal = Calibration::load(&setup.file("calibration.toml")).expect("loads");
    assert_eq!(cal.distortion, Some(d));
}
