//! A second renderer of the ProX320 plate as the Nikon sees it, written independently of the
//! mock camera (`mock_camera`, `src/sim`) and of the library's raster/rectify code: its own
//! pinhole camera, lens, polygon coverage, textures and light. It takes the geometry of the
//! layers from the vector file (as `layerwise::vectors` reads it), so the frames and the
//! registration's exemplars share only the vectors.
//!
//! What it draws, per recorded pixel (distorted → undistorted by the lens → build mm by the
//! homography):
//! - powder anchored on the plate: multi-scale value noise (0.9 mm and 0.3 mm cells), per-grain
//!   noise on a 0.08 mm lattice and sparse bright grains;
//! - the fused layer: anisotropic track texture along the layer's hatch direction (turning
//!   67° per layer) with a bright contour track at the edge;
//! - a halo of partially fused powder (darker, grainy sinter, as rough as the part next to it)
//!   up to 0.8 mm outside the parts;
//! - the previous layer faintly visible through the thin fresh powder where the current layer
//!   does not cover it;
//! - pixels within 1.5 px of an edge are supersampled 4 x 4 (area coverage, not point sampling);
//! - a mild optical blur, vignetting, a light gradient and a broad hot spot, sensor noise;
//! - radial lens distortion (k1 with the focal length in pixels, about the image centre), the
//!   same model the calibration fits: recorded = c + (p − c)(1 + k1 r²), r = |p − c| / f;
//! - written as JPEG quality 90 by the image crate's encoder.

use image::RgbImage;
use layerwise::vectors::Layer;
use rayon::prelude::*;

/// Half the ProX320 plate's side, mm.
const PLATE_HALF: f64 = 137.5;
/// How far outside a part the partially fused powder reaches, mm.
const HALO_MM: f64 = 0.8;
/// Weight of the sintered powder at a part's edge (falling quadratically to 0 at `HALO_MM`).
const HALO_EDGE: f64 = 0.9;
/// Amplitude of the fused tracks' texture and of the powder's per-grain noise, grey levels.
const TRACK_AMPLITUDE: f64 = 26.0;
const GRAIN_AMPLITUDE: f64 = 8.0;

/// Where the camera stands: `distance_mm` from `target` (a plate point, mm), `tilt_deg` off
/// the plate normal towards azimuth `azimuth_deg` (0: from −y), rolled by `roll_deg`.
#[derive(Clone, Copy, Debug)]
pub struct Pose {
    pub distance_mm: f64,
    pub tilt_deg: f64,
    pub azimuth_deg: f64,
    pub roll_deg: f64,
    pub target: (f64, f64),
}

/// A pinhole camera over the plate with a radial lens: the known truth of a rendered frame.
#[derive(Clone, Copy, Debug)]
pub struct View {
    pub width: u32,
    pub height: u32,
    /// Image (undistorted) pixel from build mm, as a 3x3 matrix on (x, y, 1).
    pub image_from_build: [[f64; 3]; 3],
    pub build_from_image: [[f64; 3]; 3],
    pub center: [f64; 2],
    pub focal_px: f64,
    pub k1: f64,
}

fn apply(m: &[[f64; 3]; 3], x: f64, y: f64) -> (f64, f64) {
    let w = m[2][0] * x + m[2][1] * y + m[2][2];
    (
        (m[0][0] * x + m[0][1] * y + m[0][2]) / w,
        (m[1][0] * x + m[1][1] * y + m[1][2]) / w,
    )
}

fn invert(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let c = |r: usize, s: usize| {
        let (r1, r2) = ((r + 1) % 3, (r + 2) % 3);
        let (s1, s2) = ((s + 1) % 3, (s + 2) % 3);
        m[r1][s1] * m[r2][s2] - m[r1][s2] * m[r2][s1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let mut out = [[0.0; 3]; 3];
    for (r, row) in out.iter_mut().enumerate() {
        for (s, v) in row.iter_mut().enumerate() {
            *v = c(s, r) / det;
        }
    }
    out
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    [a[0] / n, a[1] / n, a[2] / n]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl View {
    /// A camera placed by `pose`, focal length 1.25 image widths (a 45 mm lens on a full-frame
    /// sensor), with radial distortion `k1`.
    pub fn oblique(width: u32, height: u32, pose: Pose, k1: f64) -> View {
        let Pose {
            distance_mm,
            tilt_deg,
            azimuth_deg,
            roll_deg,
            target,
        } = pose;
        let (t, a, roll) = (
            tilt_deg.to_radians(),
            azimuth_deg.to_radians(),
            roll_deg.to_radians(),
        );
        let target = [target.0, target.1, 0.0];
        let eye = [
            target[0] + distance_mm * t.sin() * a.sin(),
            target[1] - distance_mm * t.sin() * a.cos(),
            distance_mm * t.cos(),
        ];
        let z = unit(sub(target, eye));
        // Image x roughly along the plate's x, image y down the plate (towards −y far side up).
        let x0 = unit(cross([0.0, 1.0, 0.0], z));
        let x0 = if dot(x0, [1.0, 0.0, 0.0]) < 0.0 {
            [-x0[0], -x0[1], -x0[2]]
        } else {
            x0
        };
        let y0 = cross(z, x0);
        let (sr, cr) = roll.sin_cos();
        let x = [
            cr * x0[0] + sr * y0[0],
            cr * x0[1] + sr * y0[1],
            cr * x0[2] + sr * y0[2],
        ];
        let y = cross(z, x);
        let f = 1.25 * f64::from(width);
        let (cu, cv) = (
            0.5 * (f64::from(width) - 1.0),
            0.5 * (f64::from(height) - 1.0),
        );
        // Camera coordinates of a plate point p: (x·(p − eye), y·(p − eye), z·(p − eye)).
        let col = |axis: [f64; 3]| [axis[0], axis[1], -dot(axis, eye)];
        let (rx, ry, rz) = (col(x), col(y), col(z));
        let m = [
            [
                f * rx[0] + cu * rz[0],
                f * rx[1] + cu * rz[1],
                f * rx[2] + cu * rz[2],
            ],
            [
                f * ry[0] + cv * rz[0],
                f * ry[1] + cv * rz[1],
                f * ry[2] + cv * rz[2],
            ],
            rz,
        ];
        View {
            width,
            height,
            image_from_build: m,
            build_from_image: invert(&m),
            center: [cu, cv],
            focal_px: f,
            k1,
        }
    }

    /// Undistorted pixel → where this camera records it.
    pub fn distort(&self, u: f64, v: f64) -> (f64, f64) {
        let (du, dv) = (u - self.center[0], v - self.center[1]);
        let r2 = (du * du + dv * dv) / (self.focal_px * self.focal_px);
        let s = 1.0 + self.k1 * r2;
        (self.center[0] + du * s, self.center[1] + dv * s)
    }

    /// Recorded pixel → undistorted pixel (fixed point on the radius, to 1e-10 px).
    pub fn undistort(&self, u: f64, v: f64) -> (f64, f64) {
        let (du, dv) = (u - self.center[0], v - self.center[1]);
        let rd = (du * du + dv * dv).sqrt() / self.focal_px;
        if rd == 0.0 || self.k1 == 0.0 {
            return (u, v);
        }
        // Newton on r (1 + k1 r²) = rd.
        let mut r = rd;
        for _ in 0..30 {
            let g = r * (1.0 + self.k1 * r * r) - rd;
            let dg = 1.0 + 3.0 * self.k1 * r * r;
            let step = g / dg;
            r -= step;
            if step.abs() < 1e-14 {
                break;
            }
        }
        let s = r / rd;
        (self.center[0] + du * s, self.center[1] + dv * s)
    }

    /// Where the camera records build point (x, y) mm: the truth the registration is judged by.
    pub fn true_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        let (u, v) = apply(&self.image_from_build, x, y);
        self.distort(u, v)
    }

    /// The build point (mm) a recorded pixel sees.
    pub fn build_point(&self, u: f64, v: f64) -> (f64, f64) {
        let (u, v) = self.undistort(u, v);
        apply(&self.build_from_image, u, v)
    }
}

/// The closed contours of one part of a layer, its edges and bounding box.
struct Outline {
    edges: Vec<[f64; 4]>,
    /// Bounding box widened by the halo and a little more: outside it nothing is near.
    bbox: [f64; 4],
}

/// The layer's parts: closed polylines grouped by part number, filled even-odd.
fn outlines(layer: &Layer) -> Vec<Outline> {
    let mut by_part: std::collections::BTreeMap<i64, Vec<[f64; 4]>> = Default::default();
    for p in &layer.polylines {
        let pts = &p.points;
        if pts.len() < 4 || pts[0] != pts[pts.len() - 1] {
            continue;
        }
        let edges = by_part.entry(p.part).or_default();
        for w in pts.windows(2) {
            edges.push([w[0][0], w[0][1], w[1][0], w[1][1]]);
        }
    }
    let pad = HALO_MM + 1.5;
    by_part
        .into_values()
        .map(|edges| {
            let mut b = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            for e in &edges {
                b[0] = b[0].min(e[0]).min(e[2]);
                b[1] = b[1].min(e[1]).min(e[3]);
                b[2] = b[2].max(e[0]).max(e[2]);
                b[3] = b[3].max(e[1]).max(e[3]);
            }
            Outline {
                edges,
                bbox: [b[0] - pad, b[1] - pad, b[2] + pad, b[3] + pad],
            }
        })
        .collect()
}

/// Inside the fused area, and the distance to its nearest edge in mm (∞ when far from all).
fn region(outlines: &[Outline], x: f64, y: f64) -> (bool, f64) {
    let (mut inside, mut dist2) = (false, f64::INFINITY);
    for o in outlines {
        let b = o.bbox;
        if x < b[0] || x > b[2] || y < b[1] || y > b[3] {
            continue;
        }
        let mut odd = false;
        for &[ax, ay, bx, by] in &o.edges {
            if (ay > y) != (by > y) && x < ax + (y - ay) * (bx - ax) / (by - ay) {
                odd = !odd;
            }
            let (ex, ey) = (bx - ax, by - ay);
            let len2 = ex * ex + ey * ey;
            let t = if len2 > 0.0 {
                (((x - ax) * ex + (y - ay) * ey) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (dx, dy) = (x - ax - t * ex, y - ay - t * ey);
            dist2 = dist2.min(dx * dx + dy * dy);
        }
        inside |= odd;
    }
    (inside, dist2.sqrt())
}

fn hash(a: i64, b: i64, seed: u64) -> u64 {
    let mut z = seed
        ^ (a as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (b as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Uniform in [−1, 1) per lattice cell.
fn cell(a: i64, b: i64, seed: u64) -> f64 {
    (hash(a, b, seed) >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Smooth value noise in [−1, 1] on a unit lattice.
fn value_noise(x: f64, y: f64, seed: u64) -> f64 {
    let (xf, yf) = (x.floor(), y.floor());
    let (i, j) = (xf as i64, yf as i64);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (fx, fy) = (s(x - xf), s(y - yf));
    let a = cell(i, j, seed) + fx * (cell(i + 1, j, seed) - cell(i, j, seed));
    let b = cell(i, j + 1, seed) + fx * (cell(i + 1, j + 1, seed) - cell(i, j + 1, seed));
    a + fy * (b - a)
}

/// Loose powder at (x, y) mm: grey level before the light.
fn powder(x: f64, y: f64, seed: u64) -> f64 {
    let grain = 0.08;
    let (gi, gj) = ((x / grain).floor() as i64, (y / grain).floor() as i64);
    let bright = if hash(gi, gj, seed ^ 0xB1) % 100 < 4 {
        24.0
    } else {
        0.0
    };
    112.0
        + 6.0 * value_noise(x / 0.9, y / 0.9, seed ^ 0x11)
        + 4.0 * value_noise(x / 0.3, y / 0.3, seed ^ 0x12)
        + GRAIN_AMPLITUDE * cell(gi, gj, seed ^ 0x13)
        + bright
}

/// The fused surface of a layer whose tracks run at `angle` (radians).
fn fused(x: f64, y: f64, angle: f64, seed: u64) -> f64 {
    let (s, c) = angle.sin_cos();
    // Across the tracks (0.11 mm pitch) and along them (ripples ~0.6 mm long).
    let across = (x * c + y * s) / 0.11;
    let along = (-x * s + y * c) / 0.6;
    92.0 + TRACK_AMPLITUDE * value_noise(across, along, seed ^ 0x21)
        + 14.0 * value_noise(x / 0.5, y / 0.5, seed ^ 0x22)
}

/// Partly sintered powder next to a track.
fn sinter(x: f64, y: f64, seed: u64) -> f64 {
    let (gi, gj) = ((x / 0.1).floor() as i64, (y / 0.1).floor() as i64);
    86.0 + 26.0 * cell(gi, gj, seed ^ 0x31) + 8.0 * value_noise(x / 0.25, y / 0.25, seed ^ 0x32)
}

/// One layer to draw: its fused area now, and the layer under it.
pub struct Shot<'a> {
    pub layer: &'a Layer,
    /// The layer below, faintly visible through the fresh powder; `None` on the first layer.
    pub previous: Option<&'a Layer>,
    /// The printer layer number (turns the hatch direction, seeds the texture).
    pub number: u32,
}

/// Scene radiance at build point (x, y) mm.
fn radiance(x: f64, y: f64, now: &[Outline], before: &[Outline], number: u32, seed: u64) -> f64 {
    if x.abs() > PLATE_HALF || y.abs() > PLATE_HALF {
        // The chamber floor around the plate.
        return 35.0 + 6.0 * value_noise(x / 2.0, y / 2.0, seed ^ 0x41);
    }
    let angle = (67.0 * f64::from(number)).to_radians();
    let (inside, d) = region(now, x, y);
    if inside {
        let track = fused(x, y, angle, seed);
        // The contour track along the edge: brighter, smoother.
        return if d < 0.12 {
            0.5 * track + 0.5 * 150.0
        } else {
            track
        };
    }
    let mut p = powder(x, y, seed);
    let (under, du) = region(before, x, y);
    if under {
        // The previous layer through ~50 µm of powder: a little darker, a trace of its tracks.
        let ghost = fused(x, y, angle - 67f64.to_radians(), seed ^ 0x77) - 92.0;
        let fade = (du / 0.3).min(1.0);
        p += fade * (-7.0 + 0.15 * ghost);
    }
    if d < HALO_MM {
        let w = HALO_EDGE * (1.0 - d / HALO_MM).powi(2);
        p = (1.0 - w) * p + w * sinter(x, y, seed);
    }
    p
}

/// Renders `shot` through `view`; `seed` varies the texture and the sensor noise.
pub fn render(view: &View, shot: &Shot, seed: u64) -> RgbImage {
    let (w, h) = (view.width as usize, view.height as usize);
    let now = outlines(shot.layer);
    let before = shot.previous.map(outlines).unwrap_or_default();
    let tex_seed = seed ^ u64::from(shot.number).wrapping_mul(0x51_7CC1_B727_220A);
    let mut scene = vec![0f32; w * h];
    scene.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
        for (u, out) in row.iter_mut().enumerate() {
            let (uf, vf) = (u as f64, v as f64);
            let (x, y) = view.build_point(uf, vf);
            // Pixel size on the plate here, for the edge test.
            let (x1, y1) = view.build_point(uf + 1.0, vf);
            let mm_px = (x1 - x).hypot(y1 - y);
            let (_, d) = region(&now, x, y);
            let (_, db) = region(&before, x, y);
            let near = 1.5 * mm_px + HALO_MM;
            *out = if d < near
                || db < 1.5 * mm_px
                || (x.abs() - PLATE_HALF).abs() < 2.0 * mm_px
                || (y.abs() - PLATE_HALF).abs() < 2.0 * mm_px
            {
                // Area coverage: 4 x 4 samples over the pixel.
                let mut sum = 0.0;
                for j in 0..4 {
                    for i in 0..4 {
                        let (su, sv) = (
                            uf - 0.375 + 0.25 * f64::from(i),
                            vf - 0.375 + 0.25 * f64::from(j),
                        );
                        let (sx, sy) = view.build_point(su, sv);
                        sum += radiance(sx, sy, &now, &before, shot.number, tex_seed);
                    }
                }
                (sum / 16.0) as f32
            } else {
                radiance(x, y, &now, &before, shot.number, tex_seed) as f32
            };
        }
    });
    // A mild optical blur: [1 2 1]/4 in each direction.
    let blur = |src: &[f32], du: usize, dv: usize| -> Vec<f32> {
        let mut dst = src.to_vec();
        dst.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, out) in row.iter_mut().enumerate() {
                if u < du || v < dv || u + du >= w || v + dv >= h {
                    continue;
                }
                let at = |uu: usize, vv: usize| src[vv * w + uu];
                *out = 0.25 * at(u - du, v - dv) + 0.5 * at(u, v) + 0.25 * at(u + du, v + dv);
            }
        });
        dst
    };
    let scene = blur(&blur(&scene, 1, 0), 0, 1);
    // Light: vignetting, a gradient from the lamp's side, a broad hot spot; sensor noise.
    let (cu, cv) = (view.center[0], view.center[1]);
    let rmax2 = cu * cu + cv * cv;
    let noise_seed = seed ^ 0xA5A5;
    RgbImage::from_fn(view.width, view.height, |u, v| {
        let (uf, vf) = (f64::from(u), f64::from(v));
        let r2 = ((uf - cu).powi(2) + (vf - cv).powi(2)) / rmax2;
        let vignette = 1.0 - 0.32 * r2;
        let gradient = 0.82 + 0.3 * uf / f64::from(view.width) + 0.06 * vf / f64::from(view.height);
        let (hu, hv) = (0.3 * f64::from(view.width), 0.35 * f64::from(view.height));
        let spot =
            1.0 + 0.12 * (-((uf - hu).powi(2) + (vf - hv).powi(2)) / (2.0 * 300f64.powi(2))).exp();
        let g = f64::from(scene[v as usize * w + u as usize]) * vignette * gradient * spot
            + 2.0 * cell(i64::from(u), i64::from(v), noise_seed);
        let px = |k: f64| (g * k).round().clamp(0.0, 255.0) as u8;
        image::Rgb([px(1.0), px(0.97), px(0.92)])
    })
}

/// JPEG quality 90, as the image crate encodes it.
pub fn jpeg90(img: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .encode_image(img)
        .expect("encode JPEG");
    out
}
