//! A synthetic CT of a solid given by its signed distance: partial-volume voxels, the scanner's
//! blur and noise, the solid placed in the CT's own frame by a known rigid transform. The demo
//! build's CT (`sim::demo`) and the test phantom (`synth`, feature `testkit`) render through it.

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

use super::align::to_array;
use super::volume::{Volume, VoxelData};

/// Stored value of empty space (air).
pub const BACKGROUND: f64 = 4000.0;
/// Stored value of the part's material.
pub const MATERIAL: f64 = 36000.0;

/// How the scanner sees the solid.
#[derive(Debug, Clone)]
pub struct ScanSpec {
    pub voxel_mm: f64,
    /// Margin around the solid in the CT volume, mm.
    pub margin_mm: f64,
    /// Sub-samples per axis for partial-volume voxels.
    pub supersample: usize,
    /// Gaussian blur σ in voxels (the scanner's point spread).
    pub blur_voxels: f64,
    /// Noise σ as a fraction of the material-background contrast.
    pub noise: f64,
    pub seed: u64,
}

/// Renders the solid `sdf < 0` (build mm, inside `bounds`) into a u16 volume whose physical
/// coordinates are index × voxel size (like a raw `.vol`), the solid rotated by `rotation`
/// (CT → build) and placed `margin_mm` from the CT origin. Returns the volume and the true
/// transform, CT physical mm → build mm.
pub fn render(
    sdf: &(dyn Fn([f64; 3]) -> f64 + Sync),
    bounds: ([f64; 3], [f64; 3]),
    rotation: &Matrix3<f64>,
    spec: &ScanSpec,
) -> (Volume, [[f64; 4]; 4]) {
    let r_true = *rotation;
    // CT = R_trueᵀ (build − t): place the rotated part's box at `margin` from the CT origin.
    let (lo, hi) = bounds;
    let a = r_true.transpose();
    let mut cmin = Vector3::repeat(f64::INFINITY);
    let mut cmax = Vector3::repeat(f64::NEG_INFINITY);
    for k in 0..8 {
        let c = Vector3::new(
            if k & 1 == 0 { lo[0] } else { hi[0] },
            if k & 2 == 0 { lo[1] } else { hi[1] },
            if k & 4 == 0 { lo[2] } else { hi[2] },
        );
        let p = a * c;
        cmin = cmin.inf(&p);
        cmax = cmax.sup(&p);
    }
    let margin = Vector3::repeat(spec.margin_mm);
    let t_true = r_true * (cmin - margin);
    let size = cmax - cmin + 2.0 * margin;
    let h = spec.voxel_mm;
    let dims = [
        (size.x / h).ceil() as usize + 1,
        (size.y / h).ceil() as usize + 1,
        (size.z / h).ceil() as usize + 1,
    ];
    let to_build = |i: f64, j: f64, k: f64| {
        let p = r_true * Vector3::new(i * h, j * h, k * h) + t_true;
        [p.x, p.y, p.z]
    };

    // Partial-volume coverage; 4³ blocks far from the surface are filled without sampling.
    let [nx, ny, nz] = dims;
    let plane = nx * ny;
    let mut cover = vec![0f32; nx * ny * nz];
    let b = 4usize;
    let half_diag_vox = 0.5 * 3f64.sqrt();
    let ss = spec.supersample.max(1);
    cover
        .par_chunks_mut(plane * b)
        .enumerate()
        .for_each(|(bz, slab)| {
            let z0 = bz * b;
            let zs = slab.len() / plane;
            for by in (0..ny).step_by(b) {
                for bx in (0..nx).step_by(b) {
                    let c = to_build(bx as f64 + 1.5, by as f64 + 1.5, z0 as f64 + 1.5);
                    let d = sdf(c);
                    let far = d.abs() > (b as f64 * half_diag_vox + 0.5) * h;
                    for dz in 0..zs.min(b) {
                        for y in by..(by + b).min(ny) {
                            for x in bx..(bx + b).min(nx) {
                                let v = if far {
                                    if d < 0.0 {
                                        1.0
                                    } else {
                                        0.0
                                    }
                                } else {
                                    coverage(sdf, &to_build, [x, y, z0 + dz], ss, h)
                                };
                                slab[x + nx * y + plane * dz] = v;
                            }
                        }
                    }
                }
            }
        });
    let blurred = gaussian_blur(cover, dims, spec.blur_voxels);
    let contrast = MATERIAL - BACKGROUND;
    let sigma = spec.noise * contrast;
    let seed = spec.seed;
    let data: Vec<u16> = blurred
        .par_iter()
        .enumerate()
        .map(|(i, &c)| {
            let v = BACKGROUND + c as f64 * contrast + sigma * normal(seed, i as u64);
            v.round().clamp(0.0, 65535.0) as u16
        })
        .collect();
    let volume = Volume::new_scaled(dims, [h; 3], VoxelData::U16(data))
        .expect("synthetic volume dims are consistent");
    (volume, to_array(&r_true, &t_true))
}

fn coverage(
    sdf: &(dyn Fn([f64; 3]) -> f64 + Sync),
    to_build: &impl Fn(f64, f64, f64) -> [f64; 3],
    idx: [usize; 3],
    ss: usize,
    h: f64,
) -> f32 {
    let c = to_build(idx[0] as f64, idx[1] as f64, idx[2] as f64);
    let d = sdf(c);
    if d.abs() > 0.87 * h {
        return if d < 0.0 { 1.0 } else { 0.0 };
    }
    let mut inside = 0usize;
    for a in 0..ss {
        for b in 0..ss {
            for e in 0..ss {
                let off = |k: usize| (k as f64 + 0.5) / ss as f64 - 0.5;
                let p = to_build(
                    idx[0] as f64 + off(a),
                    idx[1] as f64 + off(b),
                    idx[2] as f64 + off(e),
                );
                if sdf(p) < 0.0 {
                    inside += 1;
                }
            }
        }
    }
    inside as f32 / (ss * ss * ss) as f32
}

/// Separable Gaussian blur (σ in voxels), clamped at the borders.
pub fn gaussian_blur(mut v: Vec<f32>, dims: [usize; 3], sigma: f64) -> Vec<f32> {
    if sigma <= 0.0 {
        return v;
    }
    let r = (3.0 * sigma).ceil() as isize;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|x| *x /= s);
    let [nx, ny, _] = dims;
    let plane = nx * ny;
    let strides = [1usize, nx, plane];
    let mut tmp = vec![0f32; v.len()];
    for axis in 0..3 {
        let n = dims[axis] as isize;
        let stride = strides[axis];
        let src = &v;
        tmp.par_chunks_mut(plane).enumerate().for_each(|(z, out)| {
            for y in 0..ny {
                for x in 0..nx {
                    let p = [x, y, z];
                    let base = x + nx * y + plane * z - p[axis] * stride;
                    let mut acc = 0.0;
                    for (ki, w) in k.iter().enumerate() {
                        let q = (p[axis] as isize + ki as isize - r).clamp(0, n - 1) as usize;
                        acc += w * src[base + q * stride];
                    }
                    out[x + nx * y] = acc;
                }
            }
        });
        std::mem::swap(&mut v, &mut tmp);
    }
    v
}

fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A standard normal deviate from (seed, index): splitmix64 + Box-Muller, so renders are
/// reproducible in parallel.
fn normal(seed: u64, i: u64) -> f64 {
    let a = mix(seed ^ i.wrapping_mul(0xA24B_AED4_963E_E407));
    let b = mix(a);
    let u1 = ((a >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let u2 = (b >> 11) as f64 / (1u64 << 53) as f64;
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// Uniform in [−1, 1) from (seed, index).
pub fn uniform(seed: u64, i: u64) -> f64 {
    let a = mix(mix(seed ^ 0x5555_AAAA) ^ i.wrapping_mul(0xD6E8_FEB8_6659_FD93));
    2.0 * ((a >> 11) as f64 / (1u64 << 53) as f64) - 1.0
}
