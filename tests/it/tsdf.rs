//! Tests of the TSDF: analytic shapes (a cylinder, a 45° wall), an exact reference distance
//! on a voxel-aligned solid, the interpolant and its gradient, real files, errors.

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};

use layerwise::tsdf::{self, Init, Method, Tsdf, TsdfError, TsdfParams};
use layerwise::vectors::{self, Direction, Format, Header, Layer, Polyline, VectorFile};

/// The default exact method and the paper's fast sweeping with both initialisations.
const METHODS: [Method; 3] = [
    Method::Exact,
    Method::FastSweeping(Init::Full),
    Method::FastSweeping(Init::Band),
];

/// Half a voxel: the tolerance. The fast sweeping variants are measured and printed
/// but held only to this bound on planar geometry (see the tsdf module documentation).
fn holds_half_voxel(method: Method) -> bool {
    method == Method::Exact
}

fn file_of(layers: Vec<Layer>) -> VectorFile {
    VectorFile {
        header: Header::new(Format::Ascii, 0.001),
        layers,
    }
}

fn contour(points: Vec<[f64; 2]>, direction: Direction) -> Polyline {
    Polyline {
        part: 1,
        direction,
        points,
    }
}

fn circle(r: f64, n: usize) -> Vec<[f64; 2]> {
    (0..=n)
        .map(|i| {
            let a = TAU * (i % n) as f64 / n as f64;
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

fn rect(x0: f64, y0: f64, x1: f64, y1: f64, ccw: bool) -> Vec<[f64; 2]> {
    let mut p = vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]];
    if !ccw {
        p.reverse();
    }
    p
}

/// Layers k = 0..n at z = t·(k + 1), each made by `f(k)`.
fn stacked(n: usize, t: f64, f: impl Fn(usize) -> Vec<Polyline>) -> VectorFile {
    file_of(
        (0..n)
            .map(|k| {
                let mut l = Layer::new(k, t * (k + 1) as f64);
                l.polylines = f(k);
                l
            })
            .collect(),
    )
}

/// Layers of rectangles `(lo, hi, [x0, y0, x1, y1]...)`, layer k at z = hi (the layers of
/// [`stacked`] with the thickness `hi - lo`): counter-clockwise contours, as [`layered_rects`]
/// measures them.
fn stacked_rects(layers: &[(f64, f64, Vec<[f64; 4]>)]) -> VectorFile {
    file_of(
        layers
            .iter()
            .enumerate()
            .map(|(k, (_, hi, rs))| {
                let mut l = Layer::new(k, *hi);
                l.polylines = rs
                    .iter()
                    .map(|r| {
                        contour(
                            rect(r[0], r[1], r[2], r[3], true),
                            Direction::CounterClockwise,
                        )
                    })
                    .collect();
                l
            })
            .collect(),
    )
}

/// The 45° wall: n layers of thickness t, a 1 x 6 mm rectangle shifted by t in x each layer,
/// starting at x = x0.
fn wall_45(n: usize, t: f64, x0: f64) -> Vec<(f64, f64, Vec<[f64; 4]>)> {
    (0..n)
        .map(|k| {
            let a = x0 + t * k as f64;
            (
                t * k as f64,
                t * (k + 1) as f64,
                vec![[a, -3.0, a + 1.0, 3.0]],
            )
        })
        .collect()
}

/// Largest |tsdf − reference| over the voxels where the reference is within the truncation
/// band (less half a voxel, where clamping starts to differ), and the mean.
fn compare(t: &Tsdf, reference: impl Fn([f64; 3]) -> f64) -> (f64, f64, usize) {
    let [nx, ny, nz] = t.dims;
    let (mut worst, mut sum, mut n) = (0f64, 0f64, 0usize);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = t.index_to_build(i, j, k);
                let want = reference(p);
                let got = t.get(i, j, k).unwrap() as f64;
                // The sign is exact everywhere.
                if want.abs() > 1e-6 {
                    assert_eq!(
                        got < 0.0 || got.is_sign_negative(),
                        want < 0.0,
                        "sign at {p:?}"
                    );
                }
                if want.abs() <= t.truncation_mm - 0.5 * t.voxel_mm {
                    let e = (got - want).abs();
                    worst = worst.max(e);
                    sum += e;
                    n += 1;
                } else {
                    // Beyond the band: clamped, at least nearly the truncation.
                    assert!(
                        got.abs() >= t.truncation_mm - t.voxel_mm,
                        "{p:?}: {got} vs {want}"
                    );
                }
            }
        }
    }
    (worst, sum / n.max(1) as f64, n)
}

/// Signed distance to the finite cylinder ρ ≤ r, z_lo ≤ z ≤ z_hi.
fn cylinder_sdf(p: [f64; 3], r: f64, z_lo: f64, z_hi: f64) -> f64 {
    let dr = (p[0] * p[0] + p[1] * p[1]).sqrt() - r;
    let dz = (z_lo - p[2]).max(p[2] - z_hi);
    if dr > 0.0 || dz > 0.0 {
        (dr.max(0.0).powi(2) + dz.max(0.0).powi(2)).sqrt()
    } else {
        dr.max(dz)
    }
}

#[test]
fn cylinder_within_half_a_voxel() {
    // r = 5 mm, 100 layers of 0.05 mm: the solid is 0 < z ≤ 5.
    let file = stacked(100, 0.05, |_| {
        vec![contour(circle(5.0, 1440), Direction::CounterClockwise)]
    });
    let params = TsdfParams {
        voxel_mm: 0.1,
        margin_mm: 1.0,
        truncation_mm: 1.0,
        part: None,
        layer_thickness_mm: None,
    };
    for method in METHODS {
        let t = tsdf::build_with(&file, &params, method).unwrap();
        assert_eq!(t.dims, [120, 120, 70]);
        let (worst, mean, n) = compare(&t, |p| cylinder_sdf(p, 5.0, 0.0, 5.0));
        println!(
            "cylinder {method:?}: worst {:.3} voxel, mean {:.4} voxel over {n} voxels",
            worst / 0.1,
            mean / 0.1
        );
        if holds_half_voxel(method) {
            assert!(worst <= 0.05, "{method:?}: worst {worst} mm");
        }
    }
}

#[test]
fn wall_at_45_degrees() {
    // A wall 1 mm wide (x) and 6 mm long (y), shifted by the layer thickness in x every
    // layer: its faces are the planes x − z = x0 − t/2 and x0 + 1 − t/2 (the staircase's
    // mean), 60 layers of 0.05 mm.
    let (t, x0) = (0.05, -2.0);
    let file = stacked_rects(&wall_45(60, t, x0));
    let params = TsdfParams {
        voxel_mm: 0.1,
        margin_mm: 0.8,
        truncation_mm: 0.6,
        part: None,
        layer_thickness_mm: None,
    };
    for method in METHODS {
        let tsdf = tsdf::build_with(&file, &params, method).unwrap();
        let (lo, hi) = (x0 - t / 2.0, x0 + 1.0 - t / 2.0);
        let (mut worst, mut n) = (0f64, 0usize);
        let [nx, ny, nz] = tsdf.dims;
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let p = tsdf.index_to_build(i, j, k);
                    // Away from the wall's ends (y) and from its bottom and top.
                    if p[1].abs() > 3.0 - 1.0 || p[2] < 1.0 || p[2] > 3.0 - 1.0 {
                        continue;
                    }
                    let s = p[0] - p[2];
                    let want = (lo - s).max(s - hi) / 2f64.sqrt();
                    if want.abs() > params.truncation_mm - 0.05 {
                        continue;
                    }
                    let got = tsdf.get(i, j, k).unwrap() as f64;
                    worst = worst.max((got - want).abs());
                    n += 1;
                }
            }
        }
        println!(
            "45° wall {method:?}: worst {:.3} voxel over {n} voxels (staircase itself: ±{:.3})",
            worst / 0.1,
            t / 2.0 / 2f64.sqrt() / 0.1
        );
        assert!(n > 1000);
        if holds_half_voxel(method) {
            assert!(worst <= 0.05, "{method:?}: worst {worst} mm");
        }
    }
}

#[test]
fn wall_matches_brute_force_over_layers_when_voxels_are_thicker_than_layers() {
    // The same 45° wall, voxel = 2 layers: every layer counts, sampled by a voxel center or
    // not. Reference: the distance to the union of the layer boxes, brute force over layers.
    let (t, x0) = (0.05, -2.0);
    let layers = wall_45(60, t, x0);
    let file = stacked_rects(&layers);
    let params = TsdfParams {
        voxel_mm: 0.1,
        margin_mm: 0.5,
        truncation_mm: 0.6,
        part: None,
        layer_thickness_mm: None,
    };
    let tsdf = tsdf::build(&file, &params).unwrap();
    let (worst, mean, count) = compare(&tsdf, |p| layered_rects(p, &layers));
    println!(
        "wall, voxel = 2 layers: worst {worst:.2e} mm, mean {mean:.2e} mm over {count} voxels"
    );
    assert!(worst < 1e-4, "worst {worst} mm");
}

/// Exact signed distance to a stack of layers of rectangles (layer k over (lo_k, hi_k], the
/// union of its rectangles), brute force over layers and rectangles.
fn layered_rects(p: [f64; 3], layers: &[(f64, f64, Vec<[f64; 4]>)]) -> f64 {
    // Signed 2D distance to a union of disjoint rectangles (negative inside).
    let sd2 = |x: f64, y: f64, rs: &[[f64; 4]]| -> f64 {
        let mut best_out = f64::INFINITY;
        let mut inside = f64::NAN;
        for r in rs {
            let dx = (r[0] - x).max(x - r[2]);
            let dy = (r[1] - y).max(y - r[3]);
            if dx > 0.0 || dy > 0.0 {
                best_out = best_out.min((dx.max(0.0).powi(2) + dy.max(0.0).powi(2)).sqrt());
            } else {
                inside = dx.max(dy);
            }
        }
        if inside.is_nan() {
            best_out
        } else {
            inside
        }
    };
    let mut inside = false;
    let (mut d_out, mut d_in) = (f64::INFINITY, f64::INFINITY);
    let (mut z_lo, mut z_hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (lo, hi, rs) in layers {
        z_lo = z_lo.min(*lo);
        z_hi = z_hi.max(*hi);
        let sd = sd2(p[0], p[1], rs);
        let dz = (lo - p[2]).max(p[2] - hi).max(0.0);
        if p[2] > *lo && p[2] <= *hi && sd < 0.0 {
            inside = true;
        }
        d_out = d_out.min((sd.max(0.0).powi(2) + dz * dz).sqrt());
        d_in = d_in.min(((-sd).max(0.0).powi(2) + dz * dz).sqrt());
    }
    // Below the first and above the last layer is outside (the layers here are contiguous).
    d_in = d_in.min((p[2] - z_lo).abs()).min((p[2] - z_hi).abs());
    if inside {
        -d_in
    } else {
        d_out
    }
}

#[test]
fn a_layer_no_voxel_center_samples_still_counts() {
    // Layers of 0.03 mm, voxels of 0.1 mm: a block, and in one layer only an extra patch far
    // from the block. Most voxel columns through the patch hold no inside voxel center.
    let t = 0.03;
    let n = 30;
    let block = [0.0, 0.0, 1.0, 1.0];
    let patch = [2.5, -0.5, 4.0, 1.0];
    let layers: Vec<(f64, f64, Vec<[f64; 4]>)> = (0..n)
        .map(|k| {
            let rs = if k == 13 {
                vec![block, patch]
            } else {
                vec![block]
            };
            (t * k as f64, t * (k + 1) as f64, rs)
        })
        .collect();
    let file = stacked_rects(&layers);
    let params = TsdfParams {
        voxel_mm: 0.1,
        margin_mm: 0.4,
        truncation_mm: 0.5,
        part: None,
        layer_thickness_mm: None,
    };
    let tsdf = tsdf::build(&file, &params).unwrap();
    let (worst, mean, count) = compare(&tsdf, |p| layered_rects(p, &layers));
    println!("unsampled layer: worst {worst:.2e} mm, mean {mean:.2e} mm over {count} voxels");
    assert!(worst < 1e-4, "worst {worst} mm");
    // Right above the patch the distance is the height above its top.
    let v = tsdf.sample([3.25, 0.25, 0.42 + 0.1]).unwrap();
    assert!(v > 0.0 && v < 0.2, "{v}");
}

/// Exact signed distance to the boundary of a union of voxel cubes (brute force over the
/// boundary voxels of the other side).
fn exact_voxel_solid(t: &Tsdf) -> Vec<f64> {
    let [nx, ny, nz] = t.dims;
    let h = t.voxel_mm;
    let inside = |i: usize, j: usize, k: usize| t.inside(i, j, k);
    // Voxels with a 6-neighbour of the other side (the grid's outside is outside).
    let mut border_in = Vec::new();
    let mut border_out = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let me = inside(i, j, k);
                let nb = [
                    (i.wrapping_sub(1), j, k),
                    (i + 1, j, k),
                    (i, j.wrapping_sub(1), k),
                    (i, j + 1, k),
                    (i, j, k.wrapping_sub(1)),
                    (i, j, k + 1),
                ];
                let differs = nb.iter().any(|&(a, b, c)| {
                    let other = a < nx && b < ny && c < nz && inside(a, b, c);
                    other != me
                });
                if differs {
                    if me {
                        border_in.push([i as f64, j as f64, k as f64]);
                    } else {
                        border_out.push([i as f64, j as f64, k as f64]);
                    }
                }
            }
        }
    }
    // Distance between a point and a unit cube (voxel units).
    let cube = |p: [f64; 3], c: [f64; 3]| -> f64 {
        let d: f64 = (0..3)
            .map(|a| ((p[a] - c[a]).abs() - 0.5).max(0.0).powi(2))
            .sum();
        d.sqrt()
    };
    let mut out = vec![0f64; nx * ny * nz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = [i as f64, j as f64, k as f64];
                let me = inside(i, j, k);
                // Outside: distance to the nearest inside cube. Inside: to the nearest outside
                // cube, or to the grid's boundary (outside beyond it).
                let others = if me { &border_out } else { &border_in };
                let mut d = others
                    .iter()
                    .map(|&c| cube(p, c))
                    .fold(f64::INFINITY, f64::min);
                if me {
                    let to_edge = [
                        p[0] + 0.5,
                        nx as f64 - 0.5 - p[0],
                        p[1] + 0.5,
                        ny as f64 - 0.5 - p[1],
                        p[2] + 0.5,
                        nz as f64 - 0.5 - p[2],
                    ];
                    d = to_edge.iter().fold(d, |a, &b| a.min(b));
                }
                out[i + nx * (j + ny * k)] = if me { -d * h } else { d * h };
            }
        }
    }
    out
}

#[test]
fn matches_exact_distance_of_a_voxel_aligned_solid() {
    // Layers as thick as the voxels, edges on voxel boundaries (multiples of 0.1 mm, which
    // the plate lattice −137.5 + 0.1·k contains): the solid is exactly a union of voxels, so
    // the exact distance to it is a brute-force minimum over cube faces. A square ring with a
    // hole, then a block sliding sideways one voxel per layer (a 45° overhang), then a thin
    // plate on top.
    let file = stacked(18, 0.1, |k| match k {
        0..=7 => vec![
            contour(rect(0.0, 0.0, 1.6, 1.6, true), Direction::CounterClockwise),
            contour(rect(0.6, 0.6, 1.0, 1.0, false), Direction::Clockwise),
        ],
        8..=15 => {
            let a = 0.1 * (k - 8) as f64;
            vec![contour(
                rect(a, 0.2, a + 0.8, 1.4, true),
                Direction::CounterClockwise,
            )]
        }
        _ => vec![contour(
            rect(-0.3, -0.3, 2.0, 1.9, true),
            Direction::CounterClockwise,
        )],
    });
    let params = TsdfParams {
        voxel_mm: 0.1,
        margin_mm: 0.5,
        truncation_mm: 0.5,
        part: None,
        layer_thickness_mm: None,
    };
    for method in METHODS {
        let t = tsdf::build_with(&file, &params, method).unwrap();
        let exact = exact_voxel_solid(&t);
        let [nx, ny, nz] = t.dims;
        let (mut worst, mut sum, mut n) = (0f64, 0f64, 0usize);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let idx = t.index(i, j, k);
                    let want = exact[idx];
                    if want.abs() > params.truncation_mm - 0.05 {
                        continue;
                    }
                    let e = (t.data[idx] as f64 - want).abs();
                    worst = worst.max(e);
                    sum += e;
                    n += 1;
                }
            }
        }
        println!(
            "voxel-aligned solid {method:?}: worst {:.3} voxel, mean {:.4} voxel over {n} voxels",
            worst / 0.1,
            sum / n as f64 / 0.1
        );
        if holds_half_voxel(method) {
            assert!(worst <= 0.05, "{method:?}: worst {worst} mm");
        }
    }
}

#[test]
fn sampling_interpolates_and_differentiates() {
    // A hand-made volume holding a linear function: trilinear sampling is exact for it.
    let mut t = Tsdf {
        origin: [1.0, -2.0, 0.5],
        voxel_mm: 0.25,
        dims: [5, 4, 3],
        truncation_mm: 10.0,
        data: vec![0.0; 60],
    };
    let f = |p: [f64; 3]| 0.3 * p[0] - 0.7 * p[1] + 0.2 * p[2] + 1.0;
    for k in 0..3 {
        for j in 0..4 {
            for i in 0..5 {
                let idx = t.index(i, j, k);
                t.data[idx] = f(t.index_to_build(i, j, k)) as f32;
            }
        }
    }
    for p in [
        [1.1, -1.9, 0.6],
        [1.99, -1.26, 0.99],
        [2.0, -1.25, 1.0],
        [1.0, -2.0, 0.5],
    ] {
        let (v, g) = t.sample_with_gradient(p).unwrap();
        assert!((v as f64 - f(p)).abs() < 1e-5, "{p:?}");
        assert!(
            (g[0] - 0.3).abs() < 1e-5 && (g[1] + 0.7).abs() < 1e-5 && (g[2] - 0.2).abs() < 1e-5
        );
        assert_eq!(t.sample(p), Some(v));
    }
    // Outside the voxel centers' hull: None.
    for p in [
        [0.99, -1.5, 0.7],
        [2.01, -1.5, 0.7],
        [1.5, -2.01, 0.7],
        [1.5, -1.24, 0.7],
        [1.5, -1.5, 0.49],
        [1.5, -1.5, 1.01],
        [f64::NAN, 0.0, 0.0],
    ] {
        assert_eq!(t.sample(p), None, "{p:?}");
        assert!(t.sample_with_gradient(p).is_none());
    }
}

#[test]
fn gradient_matches_finite_differences() {
    let file = stacked(40, 0.05, |k| {
        let r = 1.5 + 0.01 * k as f64;
        vec![
            contour(circle(r, 360), Direction::CounterClockwise),
            contour(rect(-0.4, -0.3, 0.5, 0.4, false), Direction::Clockwise),
        ]
    });
    let params = TsdfParams {
        voxel_mm: 0.07,
        margin_mm: 0.5,
        truncation_mm: 0.4,
        part: None,
        layer_thickness_mm: None,
    };
    let t = tsdf::build(&file, &params).unwrap();
    let mut s = 0x1234_5678_9abc_def1u64;
    let mut rnd = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let [nx, ny, nz] = t.dims;
    let eps = 1e-5;
    let mut checked = 0;
    let (mut unit, mut near) = (0, 0);
    for _ in 0..2000 {
        // A point well inside a cell, so that ±eps stays in the same cell.
        let f = [
            (rnd() * (nx - 1) as f64).floor() + 0.05 + 0.9 * rnd(),
            (rnd() * (ny - 1) as f64).floor() + 0.05 + 0.9 * rnd(),
            (rnd() * (nz - 1) as f64).floor() + 0.05 + 0.9 * rnd(),
        ];
        let p = [
            t.origin[0] + f[0] * t.voxel_mm,
            t.origin[1] + f[1] * t.voxel_mm,
            t.origin[2] + f[2] * t.voxel_mm,
        ];
        let (v, g) = t.sample_with_gradient(p).unwrap();
        for a in 0..3 {
            let mut lo = p;
            let mut hi = p;
            lo[a] -= eps;
            hi[a] += eps;
            let fd = (t.sample(hi).unwrap() as f64 - t.sample(lo).unwrap() as f64) / (2.0 * eps);
            assert!(
                (fd - g[a] as f64).abs() < 2e-2,
                "axis {a} at {p:?}: {fd} vs {}",
                g[a]
            );
        }
        checked += 1;
        // Near the surface the distance has unit slope, except on ridges (the medial
        // surface, e.g. where the distances to the top face and to the wall meet), where the
        // interpolant averages the two slopes.
        if v.abs() < 0.2 {
            let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
            near += 1;
            if (norm - 1.0).abs() < 0.1 {
                unit += 1;
            }
        }
    }
    assert_eq!(checked, 2000);
    println!("|∇| within 0.1 of 1 at {unit} of {near} points near the surface");
    assert!(near > 50 && unit as f64 > 0.8 * near as f64);
}

/// A real CLI file (see tests/it/raster.rs).
fn shared_cli(name: &str) -> PathBuf {
    let dir = match std::env::var_os("LAYERWISE_SHARED_DATA") {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/cli"),
    };
    let path = dir.join(name);
    assert!(path.is_file(), "test data {} is missing", path.display());
    path
}

#[test]
fn real_files_build() {
    for (name, voxel) in [
        ("s_Cylinder_ex.cli", 0.05),
        ("s_MiniCooper_ex.cli", 0.1),
        ("frustrum_ASCII.cli", 0.2),
        ("Box_support_solid_ascii_with_params.cli", 0.2),
    ] {
        let file = vectors::read(&shared_cli(name)).unwrap();
        let params = TsdfParams {
            voxel_mm: voxel,
            margin_mm: 0.5,
            truncation_mm: 0.5,
            part: Some(1),
            layer_thickness_mm: None,
        };
        let t = tsdf::build(&file, &params).unwrap();
        let inside = t.data.iter().filter(|v| v.is_sign_negative()).count();
        let band = t.data.iter().filter(|v| v.abs() < 0.5).count();
        println!(
            "{name}: dims {:?}, {inside} inside, {band} in the band",
            t.dims
        );
        assert!(inside > 0 && band > inside / 10);
        assert!(t.data.iter().all(|v| v.is_finite() && v.abs() <= 0.5));
    }
}

#[test]
fn errors() {
    let one = stacked(1, 0.05, |_| {
        vec![contour(circle(1.0, 16), Direction::CounterClockwise)]
    });
    assert!(matches!(
        tsdf::build(&one, &TsdfParams::default()),
        Err(TsdfError::NoThickness)
    ));
    let given = TsdfParams {
        layer_thickness_mm: Some(0.05),
        ..TsdfParams::default()
    };
    let t = tsdf::build(&one, &given).unwrap();
    assert!(t.inside(t.dims[0] / 2, t.dims[1] / 2, t.dims[2] / 2));
    let two = stacked(2, 0.05, |_| {
        vec![contour(circle(1.0, 16), Direction::CounterClockwise)]
    });
    for bad in [
        TsdfParams {
            voxel_mm: 0.0,
            ..TsdfParams::default()
        },
        TsdfParams {
            voxel_mm: f64::NAN,
            ..TsdfParams::default()
        },
        TsdfParams {
            margin_mm: -1.0,
            ..TsdfParams::default()
        },
        TsdfParams {
            truncation_mm: 0.0,
            ..TsdfParams::default()
        },
    ] {
        assert!(matches!(
            tsdf::build(&two, &bad),
            Err(TsdfError::InvalidParams(_))
        ));
    }
    let tiny = TsdfParams {
        voxel_mm: 1e-5,
        ..TsdfParams::default()
    };
    assert!(matches!(
        tsdf::build(&two, &tiny),
        Err(TsdfError::TooLarge { .. })
    ));
    let other = TsdfParams {
        part: Some(2),
        ..TsdfParams::default()
    };
    assert!(matches!(
        tsdf::build(&two, &other),
        Err(TsdfError::NoContours { part: Some(2) })
    ));
    // Open lines and hatches alone bound nothing.
    let open = stacked(2, 0.05, |_| {
        vec![contour(
            vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]],
            Direction::Open,
        )]
    });
    assert!(matches!(
        tsdf::build(&open, &TsdfParams::default()),
        Err(TsdfError::NoContours { part: None })
    ));
}
