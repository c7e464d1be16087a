//! `layerwise register images` on frames of a second, independently written renderer
//! (tests/it/common/render2.rs: its own camera, lens, textures, halo, previous layer, light and
//! JPEG), judged against the renderer's known truth over the parts' pixels. Prints the accuracy
//! table of docs/tutorial.md (`cargo test --release --test it renderer2:: -- --nocapture`).

use crate::common;
use crate::common::render2;

use std::f64::consts::TAU;
use std::path::PathBuf;

use layerwise::calibrate::{
    register_images, DistortionChoice, ImageRegistration, RegistrationImage, RegistrationOptions,
};
use layerwise::geometry::BuildPoint;
use layerwise::rectify::calibration::Calibration;
use layerwise::vectors::{self, Format, Header, Layer, LayerMap, LayerNumbering, VectorFile};
use render2::{Pose, Shot, View};

const W: u32 = 1600;
const H: u32 = 1100;
/// The lens of the radial cases.
const K1: f64 = -0.2;

type Ring = Vec<(f64, f64)>;

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Ring {
    vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
}

fn turned(ring: Ring, deg: f64) -> Ring {
    let n = ring.len() as f64;
    let cx = ring.iter().map(|p| p.0).sum::<f64>() / n;
    let cy = ring.iter().map(|p| p.1).sum::<f64>() / n;
    let (s, c) = deg.to_radians().sin_cos();
    ring.into_iter()
        .map(|(x, y)| {
            let (dx, dy) = (x - cx, y - cy);
            (cx + c * dx - s * dy, cy + s * dx + c * dy)
        })
        .collect()
}

fn disc(cx: f64, cy: f64, r: f64) -> Ring {
    (0..180)
        .map(|i| {
            let a = TAU * f64::from(i) / 180.0;
            (cx + r * a.cos(), cy + r * a.sin())
        })
        .collect()
}

/// Parts (each a list of rings, outer first) of printer layers 1, 2, 3: most parts go through
/// all three, one ends after layer 1, one starts at layer 2, one replaces the triangle at 3.
/// Spread out to the plate's corners so a lens distortion shows; some edges along the axes.
fn build() -> Vec<Vec<Vec<Ring>>> {
    let mut hole = rect(67.0, -63.0, 83.0, -47.0);
    hole.reverse();
    let common = vec![
        vec![disc(-70.0, 50.0, 9.0)],
        vec![turned(rect(40.0, 40.0, 70.0, 60.0), 17.0)],
        vec![vec![
            (-25.0, -80.0),
            (25.0, -80.0),
            (25.0, -70.0),
            (5.0, -70.0),
            (5.0, -40.0),
            (-5.0, -40.0),
            (-5.0, -70.0),
            (-25.0, -70.0),
        ]],
        vec![rect(60.0, -70.0, 90.0, -40.0), hole],
        vec![turned(rect(-107.0, -107.0, -93.0, -93.0), 10.0)],
        vec![rect(93.0, -107.0, 107.0, -93.0)],
        vec![turned(rect(93.0, 93.0, 107.0, 107.0), -25.0)],
        vec![rect(-107.0, 93.0, -93.0, 107.0)],
    ];
    let triangle = vec![vec![(-90.0, -30.0), (-50.0, -30.0), (-70.0, 0.0)]];
    let bar = vec![turned(rect(-45.0, 88.0, 5.0, 96.0), 4.0)];
    let new_disc = vec![disc(100.0, 10.0, 10.0)];
    let hexagon = vec![(0..6)
        .map(|i| {
            let a = TAU * f64::from(i) / 6.0 + 0.2;
            (-70.0 + 16.0 * a.cos(), -18.0 + 16.0 * a.sin())
        })
        .collect()];
    let mut l1 = common.clone();
    l1.extend([triangle.clone(), bar]);
    let mut l2 = common.clone();
    l2.extend([triangle, new_disc.clone()]);
    let mut l3 = common;
    l3.extend([hexagon, new_disc]);
    vec![l1, l2, l3]
}

fn layer_of(index: usize, parts: &[Vec<Ring>]) -> Layer {
    let rings: Vec<&[Ring]> = parts.iter().map(Vec::as_slice).collect();
    vectors::synth::contour_layer(index, 0.03 * (index as f64 + 1.0), &rings)
}

/// How far off each of the four clicks lands, px.
const CLICK_ERRORS: [(f64, f64); 4] = [(4.8, -3.9), (-5.5, 3.1), (4.1, 5.6), (-3.4, -5.2)];

/// Part corners a person would click in [`build`]'s parts (the box, the T, the frame, the
/// triangle), mm.
fn clicks() -> Vec<(f64, f64)> {
    let boxed = turned(rect(40.0, 40.0, 70.0, 60.0), 17.0)[2];
    vec![boxed, (-25.0, -80.0), (90.0, -70.0), (-90.0, -30.0)]
}

/// The points file: the clicks where the camera shows them, `scale` x [`CLICK_ERRORS`] off.
fn points_text(view: &View, clicks: &[(f64, f64)], scale: f64) -> String {
    let mut s = String::from("# u v x y: part corners clicked in the frame\n");
    for (&(x, y), &(du, dv)) in clicks.iter().zip(CLICK_ERRORS.iter().cycle()) {
        let (u, v) = view.true_pixel(x, y);
        s += &format!("{:.2} {:.2} {x} {y}\n", u + scale * du, v + scale * dv);
    }
    s
}

/// Build points over a part: its contours every 0.5 mm and its inside on a 0.5 mm grid.
fn part_samples(rings: &[Ring]) -> Vec<(f64, f64)> {
    let mut out = Vec::new();
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for ring in rings {
        for i in 0..ring.len() {
            let (a, b) = (ring[i], ring[(i + 1) % ring.len()]);
            (x0, y0, x1, y1) = (x0.min(a.0), y0.min(a.1), x1.max(a.0), y1.max(a.1));
            let steps = ((b.0 - a.0).hypot(b.1 - a.1) / 0.5).ceil().max(1.0) as usize;
            for s in 0..steps {
                let t = s as f64 / steps as f64;
                out.push((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)));
            }
        }
    }
    let inside = |x: f64, y: f64| {
        let mut odd = false;
        for ring in rings {
            for i in 0..ring.len() {
                let (a, b) = (ring[i], ring[(i + 1) % ring.len()]);
                if (a.1 > y) != (b.1 > y) && x < a.0 + (y - a.1) * (b.0 - a.0) / (b.1 - a.1) {
                    odd = !odd;
                }
            }
        }
        odd
    };
    let mut y = y0 + 0.25;
    while y < y1 {
        let mut x = x0 + 0.25;
        while x < x1 {
            if inside(x, y) {
                out.push((x, y));
            }
            x += 0.5;
        }
        y += 0.5;
    }
    out
}

/// One row of the table.
struct Row {
    case: String,
    mean: f64,
    max: f64,
    worst_part: f64,
    k1_true: f64,
    k1_fit: Option<f64>,
    seconds: f64,
}

/// Error of the written calibration against the truth, px, over the parts of `layers`: mean,
/// max, and the worst per-part mean.
fn accuracy(cal: &Calibration, view: &View, layers: &[&[Vec<Ring>]]) -> (f64, f64, f64) {
    let camera = cal.camera();
    let (mut sum, mut n, mut max, mut worst) = (0.0, 0usize, 0.0f64, 0.0f64);
    for parts in layers {
        for rings in parts.iter() {
            let (mut ps, mut pn) = (0.0, 0usize);
            for (x, y) in part_samples(rings) {
                let (tu, tv) = view.true_pixel(x, y);
                let e = camera
                    .image_point(BuildPoint::new(x, y))
                    .expect("in front of the camera");
                let d = (e.u - tu).hypot(e.v - tv);
                ps += d;
                pn += 1;
                max = max.max(d);
            }
            sum += ps;
            n += pn;
            eprintln!(
                "  part {:?}: mean {:.3} px over {pn}",
                rings[0][0],
                ps / pn as f64
            );
            worst = worst.max(ps / pn as f64);
        }
    }
    (sum / n as f64, max, worst)
}

struct Case {
    dir: tempfile::TempDir,
    vectors: PathBuf,
    parts: Vec<Vec<Vec<Ring>>>,
    clicks: Vec<(f64, f64)>,
    /// Scale of [`CLICK_ERRORS`] (on small parts a person clicks closer).
    click_error: f64,
}

impl Case {
    /// A vector file of `parts` (per printer layer, from 1) in a fresh folder; `clicks` are the
    /// part corners the start points name.
    fn new(parts: Vec<Vec<Vec<Ring>>>, clicks: Vec<(f64, f64)>) -> Case {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = VectorFile {
            header: Header::new(Format::Ascii, 0.001),
            layers: parts
                .iter()
                .enumerate()
                .map(|(i, p)| layer_of(i, p))
                .collect(),
        };
        let vectors = dir.path().join("build.cli");
        let mut out = std::fs::File::create(&vectors).expect("create CLI");
        vectors::write_ascii(&file, &mut out).expect("write CLI");
        Case {
            dir,
            vectors,
            parts,
            clicks,
            click_error: 1.0,
        }
    }

    /// Renders printer layers `numbers` through `view` from the vector file, as JPEGs named as
    /// the daemon names them; returns their paths.
    fn frames(&self, view: &View, numbers: &[u32], tag: &str) -> Vec<PathBuf> {
        let file = vectors::read(&self.vectors).expect("read CLI");
        let map = LayerMap::of_file(&file, LayerNumbering::default());
        let layer = |n: u32| map.position(n).map(|k| &file.layers[k]);
        numbers
            .iter()
            .map(|&n| {
                let shot = Shot {
                    layer: layer(n).expect("layer in the file"),
                    previous: n.checked_sub(1).and_then(layer),
                    number: n,
                };
                let img = render2::render(view, &shot, 0x2EED + u64::from(n));
                let path = self.dir.path().join(format!("{tag}_L{n:05}_post_top.jpg"));
                std::fs::write(&path, render2::jpeg90(&img)).expect("write JPEG");
                path
            })
            .collect()
    }

    /// `layerwise register images` on `frames` (printer layers `numbers`), as a user runs it:
    /// its output, the calibration file and the seconds it took.
    fn run(
        &self,
        view: &View,
        frames: &[PathBuf],
        numbers: &[u32],
        radial: bool,
        tag: &str,
    ) -> (std::process::Output, PathBuf, f64) {
        let points = self.dir.path().join(format!("{tag}_points.txt"));
        std::fs::write(&points, points_text(view, &self.clicks, self.click_error))
            .expect("write points");
        let out = self.dir.path().join(format!("{tag}_calibration.toml"));
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"));
        cmd.args(["register", "images", "--vectors"])
            .arg(&self.vectors)
            .arg("--init")
            .arg(&points)
            .arg("--out")
            .arg(&out);
        for (frame, n) in frames.iter().zip(numbers) {
            cmd.arg("--layer")
                .arg(n.to_string())
                .arg("--image")
                .arg(frame);
        }
        if radial {
            cmd.args(["--distortion", "radial", "--focal-px"])
                .arg(view.focal_px.to_string());
        }
        let started = std::time::Instant::now();
        let output = cmd.output().expect("runs");
        let seconds = started.elapsed().as_secs_f64();
        eprintln!(
            "{tag}:\n{}{}",
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        (output, out, seconds)
    }

    /// As [`Case::row`], but in the library with the dilation fit switched off: what the
    /// registration did before it modelled the halo.
    fn row_without_dilation(&self, view: &View, numbers: &[u32], case: &str) -> Row {
        let tag = case.replace([' ', ',', '(', ')'], "_");
        let frames = self.frames(view, numbers, &tag);
        let points = self.dir.path().join(format!("{tag}_points.txt"));
        std::fs::write(&points, points_text(view, &self.clicks, self.click_error))
            .expect("write points");
        let mut options = RegistrationOptions::default();
        options.lm.fit_dilation = false;
        let report = register_images(&ImageRegistration {
            vectors: self.vectors.clone(),
            numbering: LayerNumbering::default(),
            images: frames
                .iter()
                .zip(numbers)
                .map(|(path, &layer)| RegistrationImage {
                    path: path.clone(),
                    layer,
                })
                .collect(),
            init_points: points,
            out: None,
            overlay: None,
            distortion: DistortionChoice::None,
            options,
        })
        .expect("registers");
        self.measured(&report.calibration, view, numbers, case, report.seconds)
    }

    fn row(&self, view: &View, numbers: &[u32], radial: bool, case: &str) -> Row {
        let tag = case.replace([' ', ','], "_");
        let frames = self.frames(view, numbers, &tag);
        let (cal, seconds) = loaded(self.run(view, &frames, numbers, radial, &tag));
        self.measured(&cal, view, numbers, case, seconds)
    }

    /// The row of calibration `cal` of printer layers `numbers` against `view`'s truth.
    fn measured(
        &self,
        cal: &Calibration,
        view: &View,
        numbers: &[u32],
        case: &str,
        seconds: f64,
    ) -> Row {
        // self.parts holds printer layers 1, 2, … in order.
        let layers: Vec<&[Vec<Ring>]> = numbers
            .iter()
            .map(|&n| self.parts[n as usize - 1].as_slice())
            .collect();
        let (mean, max, worst_part) = accuracy(cal, view, &layers);
        Row {
            case: case.to_string(),
            mean,
            max,
            worst_part,
            k1_true: view.k1,
            k1_fit: cal.distortion.map(|d| d.k1),
            seconds,
        }
    }
}

/// What a successful [`Case::run`] wrote: the calibration, and the seconds it took.
fn loaded((output, out, seconds): (std::process::Output, PathBuf, f64)) -> (Calibration, f64) {
    common::assert_success(&output);
    (
        Calibration::load(&out).expect("calibration written"),
        seconds,
    )
}

fn table(rows: &[Row]) -> String {
    let mut s = String::from(
        "| case | mean px | max px | worst part, mean px | k1 true | k1 fitted |\n\
         | --- | --- | --- | --- | --- | --- |\n",
    );
    for r in rows {
        s += &format!(
            "| {} | {:.3} | {:.3} | {:.3} | {} | {} |\n",
            r.case,
            r.mean,
            r.max,
            r.worst_part,
            r.k1_true,
            r.k1_fit.map_or("–".to_string(), |k| format!("{k:.3}"))
        );
    }
    s
}

fn view(k1: f64) -> View {
    let pose = Pose {
        distance_mm: 560.0,
        tilt_deg: 28.0,
        azimuth_deg: 12.0,
        roll_deg: 3.0,
        target: (4.0, -6.0),
    };
    View::oblique(W, H, pose, k1)
}

#[test]
fn registration_is_accurate_on_a_second_renderer() {
    let case = Case::new(build(), clicks());
    let plain = view(0.0);
    let lens = view(K1);
    let (weak, strong) = (view(-0.1), view(-0.3));
    // The plate must be in the frame, as on the machine.
    for v in [&plain, &lens, &weak, &strong] {
        for (x, y) in [
            (-137.5, -137.5),
            (137.5, -137.5),
            (137.5, 137.5),
            (-137.5, 137.5),
        ] {
            let (u, w) = v.true_pixel(x, y);
            assert!(
                u > 0.0 && w > 0.0 && u < f64::from(W) && w < f64::from(H),
                "plate corner ({x}, {y}) at ({u:.0}, {w:.0})"
            );
        }
    }
    let rows = vec![
        case.row(&plain, &[2], false, "plain, one layer"),
        case.row(&plain, &[1, 2, 3], false, "plain, three layers"),
        case.row(&lens, &[2], true, "radial, one layer"),
        case.row(&lens, &[1, 2, 3], true, "radial, three layers"),
        case.row(&weak, &[2], true, "radial, one layer, weaker lens"),
        case.row(&strong, &[2], true, "radial, one layer, stronger lens"),
    ];
    let before = case.row_without_dilation(&plain, &[2], "plain, one layer, no dilation fit");
    let text = table(&rows);
    let reference = table(std::slice::from_ref(&before));
    eprintln!(
        "for reference, without the dilation fit (library):\n{}",
        reference.lines().nth(2).unwrap_or_default()
    );
    eprintln!("second renderer, {W} x {H} JPEG q90, register images through the binary:\n{text}");
    for r in &rows {
        eprintln!("{}: {:.1} s", r.case, r.seconds);
    }
    for r in &rows {
        assert!(
            r.mean <= 0.25 && r.max <= 0.75,
            "{}: mean {:.3} px, max {:.3} px\n{text}",
            r.case,
            r.mean,
            r.max
        );
    }
    // The halo is what the dilation fit is for: without it the same frame fits worse.
    assert!(
        rows[0].mean < before.mean && rows[0].max < before.max,
        "with the dilation fit {:.3}/{:.3} px, without {:.3}/{:.3} px",
        rows[0].mean,
        rows[0].max,
        before.mean,
        before.max
    );
    for r in rows.iter().filter(|r| r.k1_true != 0.0) {
        let k1 = r.k1_fit.expect("the distortion is fitted");
        assert!(
            (k1 - r.k1_true).abs() <= 0.05,
            "{}: k1 {k1}\n{text}",
            r.case
        );
    }
}

/// The runaway case on this renderer: three small parts near the plate centre, a lens with
/// k1 = −0.3. `--distortion radial` must refuse (the parts cannot show the lens) or do no worse
/// than the plain homography.
#[test]
fn clustered_small_parts_do_not_run_away() {
    let parts = vec![
        vec![turned(rect(-19.0, -2.0, -11.0, 6.0), 17.0)],
        vec![turned(rect(9.0, 4.0, 19.0, 14.0), 17.0)],
        vec![disc(1.0, -14.0, 4.0)],
    ];
    let clicks = vec![
        parts[0][0][0],
        parts[0][0][2],
        parts[1][0][1],
        parts[1][0][3],
    ];
    // Corners 10 px apart: clicks within 2 px, or the start is no homography at all.
    let mut case = Case::new(vec![parts.clone()], clicks);
    case.click_error = 0.4;
    let lens = view(-0.3);
    let frames = case.frames(&lens, &[1], "clustered");
    let (plain, _) = loaded(case.run(&lens, &frames, &[1], false, "clustered_plain"));
    let (pm, px, _) = accuracy(&plain, &lens, &[&parts]);
    eprintln!("clustered, k1 = -0.3, plain: mean {pm:.3} px, max {px:.3} px");
    let (output, out, _) = case.run(&lens, &frames, &[1], true, "clustered_radial");
    if output.status.success() {
        let radial = Calibration::load(&out).expect("calibration written");
        let (rm, rx, _) = accuracy(&radial, &lens, &[&parts]);
        eprintln!(
            "plain {pm:.3}/{px:.3} px, radial {rm:.3}/{rx:.3} px: {:?}",
            radial.distortion
        );
        assert!(
            rm <= pm + 0.02 && rx <= px + 0.1,
            "radial {rm}/{rx}, plain {pm}/{px}"
        );
    } else {
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{stderr}");
        assert!(
            stderr.contains("cannot tell a lens distortion")
                && stderr.contains("--distortion none"),
            "{stderr}"
        );
        assert!(!out.exists(), "nothing written");
    }
}
