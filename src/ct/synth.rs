//! A synthetic CT of the paper's "parameter cylinder" (a vertical cylinder with a spiral
//! staircase and one large fin, §4), with known ground truth, and test distance fields.
//!
//! The part is a union of exact primitive SDFs (a finite cylinder and boxes rotated about z).
//! The min of exact SDFs is exact outside the union and a lower bound of |d| inside, with an
//! exact zero level: good enough for a test field, and conservative for the renderer's
//! empty-block skipping.

use nalgebra::{Matrix3, Rotation3, Unit, Vector3};
use rayon::prelude::*;

use super::phantom::{self, ScanSpec};
use super::surface::PartShape;
use super::volume::Volume;
use super::{DistanceField, PointPair};

pub use super::phantom::{gaussian_blur, uniform};

/// A box rotated by `angle` about the vertical through the origin of its part.
#[derive(Debug, Clone, Copy)]
pub struct ZBox {
    /// Centre in the part frame before the rotation.
    pub center: [f64; 3],
    pub half: [f64; 3],
    /// Rotation about z, radians.
    pub angle: f64,
}

impl ZBox {
    fn sdf(&self, p: [f64; 3]) -> f64 {
        // Rotate p by −angle into the box's frame.
        let (s, c) = self.angle.sin_cos();
        let x = c * p[0] + s * p[1] - self.center[0];
        let y = -s * p[0] + c * p[1] - self.center[1];
        let z = p[2] - self.center[2];
        let q = [
            x.abs() - self.half[0],
            y.abs() - self.half[1],
            z.abs() - self.half[2],
        ];
        let outside =
            (q[0].max(0.0).powi(2) + q[1].max(0.0).powi(2) + q[2].max(0.0).powi(2)).sqrt();
        outside + q[0].max(q[1]).max(q[2]).min(0.0)
    }

    /// A point given in the box's frame (before rotation), in the part frame.
    fn point(&self, local: [f64; 3]) -> [f64; 3] {
        let (s, c) = self.angle.sin_cos();
        [
            c * local[0] - s * local[1],
            s * local[0] + c * local[1],
            local[2],
        ]
    }
}

/// The parameter cylinder in build mm: its cylinder axis at `origin` (x, y), bottom at z = 0.
#[derive(Debug, Clone)]
pub struct Part {
    pub origin: [f64; 3],
    pub radius: f64,
    pub height: f64,
    pub steps: Vec<ZBox>,
    pub fin: ZBox,
}

impl Part {
    /// r = 5 mm, h = 10 mm, 12 steps every 30° rising 0.8 mm each, one 6.5 mm fin; all sizes
    /// times `scale`.
    pub fn parameter_cylinder(origin: [f64; 3], scale: f64) -> Self {
        let s = scale;
        let steps = (0..12)
            .map(|k| ZBox {
                center: [6.25 * s, 0.0, (0.8 * (k + 1) as f64 - 0.25) * s],
                half: [1.75 * s, 0.75 * s, 0.25 * s],
                angle: (30.0 * k as f64).to_radians(),
            })
            .collect();
        let fin = ZBox {
            center: [7.75 * s, 0.0, 4.5 * s],
            half: [3.25 * s, 0.4 * s, 4.5 * s],
            angle: 195f64.to_radians(),
        };
        Self {
            origin,
            radius: 5.0 * s,
            height: 10.0 * s,
            steps,
            fin,
        }
    }

    /// Signed distance of the nominal part (negative inside), mm.
    pub fn sdf(&self, p: [f64; 3]) -> f64 {
        let q = [
            p[0] - self.origin[0],
            p[1] - self.origin[1],
            p[2] - self.origin[2],
        ];
        let hz = 0.5 * self.height;
        let d = [
            (q[0] * q[0] + q[1] * q[1]).sqrt() - self.radius,
            (q[2] - hz).abs() - hz,
        ];
        let cyl = d[0].max(d[1]).min(0.0) + (d[0].max(0.0).powi(2) + d[1].max(0.0).powi(2)).sqrt();
        let mut m = cyl.min(self.fin.sdf(q));
        for s in &self.steps {
            m = m.min(s.sdf(q));
        }
        m
    }

    /// Axis-aligned bounds of the nominal part (build mm).
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let r = (self.fin.center[0] + self.fin.half[0]).max(self.radius) + 0.01;
        (
            [self.origin[0] - r, self.origin[1] - r, self.origin[2]],
            [
                self.origin[0] + r,
                self.origin[1] + r,
                self.origin[2] + self.height,
            ],
        )
    }

    /// Points a user would click for the 3-point start: the fin's outer top edge, the cylinder's
    /// top centre, the first step's outer top edge, the seventh step's outer top edge.
    pub fn landmarks(&self) -> [[f64; 3]; 4] {
        let o = self.origin;
        let add = |p: [f64; 3]| [p[0] + o[0], p[1] + o[1], p[2] + o[2]];
        let edge = |b: &ZBox| b.point([b.center[0] + b.half[0], 0.0, b.center[2] + b.half[2]]);
        [
            add(edge(&self.fin)),
            add([0.0, 0.0, self.height]),
            add(edge(&self.steps[0])),
            add(edge(&self.steps[6])),
        ]
    }
}

/// Material as scanned: the nominal part without its bottom `cut` slab (lost when removed from
/// the plate), minus internal voids, plus optional reflection blobs.
#[derive(Debug, Clone)]
pub struct AsBuilt {
    pub part: Part,
    pub cut_mm: f64,
    /// (centre build mm, radius mm) spheres of missing material.
    pub voids: Vec<([f64; 3], f64)>,
    /// (centre build mm, radius mm) spheres of spurious material (CT reflections).
    pub blobs: Vec<([f64; 3], f64)>,
}

fn sphere(p: [f64; 3], c: [f64; 3], r: f64) -> f64 {
    ((p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) + (p[2] - c[2]).powi(2)).sqrt() - r
}

impl AsBuilt {
    pub fn sdf(&self, p: [f64; 3]) -> f64 {
        let mut d = self.part.sdf(p);
        for (c, r) in &self.blobs {
            d = d.min(sphere(p, *c, *r));
        }
        d = d.max(self.part.origin[2] + self.cut_mm - p[2]);
        for (c, r) in &self.voids {
            d = d.max(-sphere(p, *c, *r));
        }
        d
    }
}

/// How to scan the synthetic part.
#[derive(Debug, Clone)]
pub struct SynthSpec {
    pub voxel_mm: f64,
    /// The true CT → build rotation: `angle_deg` about `axis` (the translation follows from
    /// placing the part at `margin_mm` from the CT origin; see [`SynthCt::ct_to_build`]).
    pub axis: [f64; 3],
    pub angle_deg: f64,
    /// Margin around the part in the CT volume, mm.
    pub margin_mm: f64,
    /// Material lost at the bottom, mm.
    pub cut_mm: f64,
    /// Sub-samples per axis for partial-volume voxels.
    pub supersample: usize,
    /// Gaussian blur σ in voxels (the scanner's point spread).
    pub blur_voxels: f64,
    /// Noise σ as a fraction of the material-background contrast.
    pub noise: f64,
    pub voids: bool,
    pub reflections: bool,
    pub seed: u64,
}

impl Default for SynthSpec {
    fn default() -> Self {
        Self {
            voxel_mm: 0.05,
            axis: [1.0, 2.0, 3.0],
            angle_deg: 25.0,
            margin_mm: 1.5,
            cut_mm: 0.25,
            supersample: 4,
            blur_voxels: 0.7,
            noise: 0.05,
            voids: true,
            reflections: false,
            seed: 1,
        }
    }
}

/// A rendered synthetic CT and its ground truth.
#[derive(Debug, Clone)]
pub struct SynthCt {
    pub volume: Volume,
    /// The true transform, CT physical mm → build mm.
    pub ct_to_build: [[f64; 4]; 4],
    pub as_built: AsBuilt,
}

/// Render the part into a u16 CT volume (physical = index × voxel size, like a raw `.vol`).
pub fn render(part: &Part, spec: &SynthSpec) -> SynthCt {
    let axis = Unit::new_normalize(Vector3::from(spec.axis));
    let rot = Rotation3::from_axis_angle(&axis, spec.angle_deg.to_radians());
    let r_true: Matrix3<f64> = *rot.matrix();
    let o = part.origin;
    let voids = if spec.voids {
        let s = part.radius / 5.0;
        vec![
            ([o[0] + 1.5 * s, o[1], o[2] + 3.0 * s], 0.3 * s),
            ([o[0] - 2.0 * s, o[1] + 1.0 * s, o[2] + 5.5 * s], 0.2 * s),
            ([o[0], o[1] - 2.5 * s, o[2] + 7.5 * s], 0.25 * s),
            ([o[0] + 0.5 * s, o[1] + 2.0 * s, o[2] + 2.0 * s], 0.15 * s),
        ]
    } else {
        Vec::new()
    };
    let blobs = if spec.reflections {
        // Where the fin meets the cylinder, as in the paper's figures 11-12.
        let f = &part.fin;
        let corner = |dz: f64, side: f64| {
            let p = f.point([part.radius, side * (f.half[1] + 0.05), dz]);
            [p[0] + o[0], p[1] + o[1], p[2] + o[2]]
        };
        vec![(corner(6.0, 1.0), 0.35), (corner(3.0, -1.0), 0.3)]
    } else {
        Vec::new()
    };
    let as_built = AsBuilt {
        part: part.clone(),
        cut_mm: spec.cut_mm,
        voids,
        blobs,
    };
    let scan = ScanSpec {
        voxel_mm: spec.voxel_mm,
        margin_mm: spec.margin_mm,
        supersample: spec.supersample,
        blur_voxels: spec.blur_voxels,
        noise: spec.noise,
        seed: spec.seed,
    };
    let (volume, ct_to_build) =
        phantom::render(&|p| as_built.sdf(p), part.bounds(), &r_true, &scan);
    SynthCt {
        volume,
        ct_to_build,
        as_built,
    }
}

/// The benchmarks' case: the parameter cylinder at (40, −25, 0) mm scanned with the default
/// spec at `voxel_mm` (50 µm: 660 x 646 x 395 voxels).
pub fn bench_case(voxel_mm: f64) -> (Part, SynthCt) {
    let part = Part::parameter_cylinder([40.0, -25.0, 0.0], 1.0);
    let spec = SynthSpec {
        voxel_mm,
        ..Default::default()
    };
    let scan = render(&part, &spec);
    (part, scan)
}

/// The benchmarks' voxel size: `CT_BENCH_VOXEL_MM`, else 50 µm.
pub fn bench_voxel_mm() -> f64 {
    std::env::var("CT_BENCH_VOXEL_MM")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.05)
}

/// The analytic SDF of a part as a distance field, truncated; gradient by central differences.
pub struct AnalyticField<'a> {
    pub part: &'a Part,
    pub truncation: f64,
}

impl DistanceField for AnalyticField<'_> {
    fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let d = self.part.sdf(p);
        if d.abs() >= self.truncation {
            return Some((d.clamp(-self.truncation, self.truncation), [0.0; 3]));
        }
        let e = 1e-5;
        let g = std::array::from_fn(|a| {
            let mut lo = p;
            let mut hi = p;
            lo[a] -= e;
            hi[a] += e;
            (self.part.sdf(hi) - self.part.sdf(lo)) / (2.0 * e)
        });
        Some((d, g))
    }

    fn truncation_mm(&self) -> f64 {
        self.truncation
    }
}

/// A voxelised TSDF (f32 nodes) with trilinear sampling: what the laser-vector TSDF looks like.
#[derive(Debug, Clone)]
pub struct GridField {
    pub origin: [f64; 3],
    pub step: f64,
    pub dims: [usize; 3],
    pub values: Vec<f32>,
    pub truncation: f64,
}

impl GridField {
    /// Sample `sdf` at the nodes of a grid covering `lo..hi` plus the truncation band.
    pub fn from_sdf(
        sdf: impl Fn([f64; 3]) -> f64 + Sync,
        lo: [f64; 3],
        hi: [f64; 3],
        step: f64,
        truncation: f64,
    ) -> Self {
        let pad = truncation + 2.0 * step;
        let origin = lo.map(|v| v - pad);
        let dims: [usize; 3] =
            std::array::from_fn(|a| ((hi[a] - lo[a] + 2.0 * pad) / step).ceil() as usize + 1);
        let [nx, ny, _] = dims;
        let plane = nx * ny;
        let mut values = vec![0f32; dims.iter().product()];
        // 4x4 columns of nodes far outside the band are filled from one sample (the SDF is
        // 1-Lipschitz, or a lower bound of |d|, so |d(centre)| > trunc + reach is conservative).
        let reach = 2.0 * 2f64.sqrt() * step;
        values
            .par_chunks_mut(plane)
            .enumerate()
            .for_each(|(z, out)| {
                let node = |x: f64, y: f64| {
                    [
                        origin[0] + x * step,
                        origin[1] + y * step,
                        origin[2] + z as f64 * step,
                    ]
                };
                for by in (0..ny).step_by(4) {
                    for bx in (0..nx).step_by(4) {
                        let d = sdf(node(bx as f64 + 1.5, by as f64 + 1.5));
                        let far = d.abs() > truncation + reach;
                        for y in by..(by + 4).min(ny) {
                            for x in bx..(bx + 4).min(nx) {
                                let v = if far {
                                    d
                                } else {
                                    sdf(node(x as f64, y as f64))
                                };
                                out[x + nx * y] = v.clamp(-truncation, truncation) as f32;
                            }
                        }
                    }
                }
            });
        Self {
            origin,
            step,
            dims,
            values,
            truncation,
        }
    }
}

impl DistanceField for GridField {
    fn sample_with_gradient(&self, p: [f64; 3]) -> Option<(f64, [f64; 3])> {
        let mut i = [0usize; 3];
        let mut f = [0f64; 3];
        for a in 0..3 {
            let u = (p[a] - self.origin[a]) / self.step;
            if !(u >= 0.0 && u < (self.dims[a] - 1) as f64) {
                return None;
            }
            i[a] = u as usize;
            f[a] = u - i[a] as f64;
        }
        let [nx, ny, _] = self.dims;
        let at = |dx: usize, dy: usize, dz: usize| {
            self.values[(i[0] + dx) + nx * ((i[1] + dy) + ny * (i[2] + dz))] as f64
        };
        let c: [[[f64; 2]; 2]; 2] = std::array::from_fn(|dz| {
            std::array::from_fn(|dy| std::array::from_fn(|dx| at(dx, dy, dz)))
        });
        let lerp = |a: f64, b: f64, t: f64| a + (b - a) * t;
        let [fx, fy, fz] = f;
        // Value and analytic derivative of the trilinear interpolant.
        let c00 = lerp(c[0][0][0], c[0][0][1], fx);
        let c10 = lerp(c[0][1][0], c[0][1][1], fx);
        let c01 = lerp(c[1][0][0], c[1][0][1], fx);
        let c11 = lerp(c[1][1][0], c[1][1][1], fx);
        let c0 = lerp(c00, c10, fy);
        let c1 = lerp(c01, c11, fy);
        let v = lerp(c0, c1, fz);
        let dz = (c1 - c0) / self.step;
        let dy = lerp(c10 - c00, c11 - c01, fz) / self.step;
        let dx = {
            let e0 = lerp(c[0][0][1] - c[0][0][0], c[0][1][1] - c[0][1][0], fy);
            let e1 = lerp(c[1][0][1] - c[1][0][0], c[1][1][1] - c[1][1][0], fy);
            lerp(e0, e1, fz) / self.step
        };
        Some((v, [dx, dy, dz]))
    }

    fn truncation_mm(&self) -> f64 {
        self.truncation
    }
}

/// The nominal part's centroid and principal extents, from a grid of material points: what the
/// lead computes from the rasterised vectors.
pub fn nominal_shape(part: &Part, step: f64) -> PartShape {
    let (lo, hi) = part.bounds();
    let n: [usize; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / step).ceil() as usize);
    let pts: Vec<[f64; 3]> = (0..n[2])
        .into_par_iter()
        .flat_map_iter(|z| {
            let mut out = Vec::new();
            for y in 0..n[1] {
                for x in 0..n[0] {
                    let p = [
                        lo[0] + (x as f64 + 0.5) * step,
                        lo[1] + (y as f64 + 0.5) * step,
                        lo[2] + (z as f64 + 0.5) * step,
                    ];
                    if part.sdf(p) < 0.0 {
                        out.push(p);
                    }
                }
            }
            out
        })
        .collect();
    PartShape::from_points(&pts)
}

/// Point pairs for a 3-point start: landmarks in build mm and their CT positions perturbed by
/// up to ±`error_mm` per coordinate (a user's clicking error).
pub fn landmark_pairs(ct: &SynthCt, count: usize, error_mm: f64, seed: u64) -> Vec<PointPair> {
    let (r, t) = super::align::split(&ct.ct_to_build);
    let lm = ct.as_built.part.landmarks();
    lm.iter()
        .take(count)
        .enumerate()
        .map(|(i, b)| {
            let c = r.transpose() * (Vector3::from(*b) - t);
            let e: [f64; 3] = std::array::from_fn(|a| error_mm * uniform(seed, (3 * i + a) as u64));
            PointPair {
                ct: [c.x + e[0], c.y + e[1], c.z + e[2]],
                build: *b,
            }
        })
        .collect()
}

/// Rotation error (degrees) and the displacement (mm) at `at` (CT mm) between two transforms.
pub fn transform_error(est: &[[f64; 4]; 4], truth: &[[f64; 4]; 4], at: [f64; 3]) -> (f64, f64) {
    let (re, te) = super::align::split(est);
    let (rt, tt) = super::align::split(truth);
    let ang = super::align::rotation_angle(&(re * rt.transpose())).to_degrees();
    let p = Vector3::from(at);
    let disp = ((re * p + te) - (rt * p + tt)).norm();
    (ang, disp)
}
