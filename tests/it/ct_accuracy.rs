//! Ground-truth accuracy of the CT registration on a synthetic CT of the parameter cylinder.
//!
//! Debug builds scan at 150 µm (seconds); `cargo test --release --all-features --test it
//! ct_accuracy::` scans at the paper-like 50 µm. The tolerances are the same: rotation ≤ 0.05°,
//! displacement at the part ≤ 5 µm. Each test also checks that its start is worse than the
//! tolerance, so passing means the registration did the work.

#![allow(clippy::needless_range_loop)]

use std::sync::OnceLock;

use layerwise::ct::{
    self, synth, CtError, CtParams, DistanceField, InitialTransform, PartShape, Threshold,
};
use layerwise::geometry::Rigid3;

const ROT_TOL_DEG: f64 = 0.05;
const DISP_TOL_MM: f64 = 0.005;

fn voxel_mm() -> f64 {
    if cfg!(debug_assertions) {
        0.15
    } else {
        0.05
    }
}

struct Nominal {
    part: synth::Part,
    field: synth::GridField,
    shape: PartShape,
}

fn nominal() -> &'static Nominal {
    static N: OnceLock<Nominal> = OnceLock::new();
    N.get_or_init(|| {
        let part = synth::Part::parameter_cylinder([40.0, -25.0, 0.0], 1.0);
        let (lo, hi) = part.bounds();
        // The vectors' TSDF: voxelised at ≤ 0.1 mm, truncated at 1 mm.
        let step = voxel_mm().min(0.1);
        let field = synth::GridField::from_sdf(|p| part.sdf(p), lo, hi, step, 1.0);
        let shape = synth::nominal_shape(&part, 0.1);
        Nominal { part, field, shape }
    })
}

fn scan(angle_deg: f64, axis: [f64; 3], reflections: bool) -> synth::SynthCt {
    let spec = synth::SynthSpec {
        voxel_mm: voxel_mm(),
        angle_deg,
        axis,
        reflections,
        ..Default::default()
    };
    synth::render(&nominal().part, &spec)
}

/// The main scan: 25° about (1, 2, 3), translation of tens of mm.
fn tilted() -> &'static synth::SynthCt {
    static CT: OnceLock<synth::SynthCt> = OnceLock::new();
    CT.get_or_init(|| scan(25.0, [1.0, 2.0, 3.0], false))
}

/// The "roughly oriented by the analyst" scan: 3° off.
fn nearly_upright() -> &'static synth::SynthCt {
    static CT: OnceLock<synth::SynthCt> = OnceLock::new();
    CT.get_or_init(|| scan(3.0, [0.3, -1.0, 0.4], false))
}

/// A point in the middle of the part, in CT mm (where the displacement error is measured).
fn part_center_ct(ct: &synth::SynthCt) -> [f64; 3] {
    let (lo, hi) = nominal().part.bounds();
    let c = [
        0.5 * (lo[0] + hi[0]),
        0.5 * (lo[1] + hi[1]),
        0.5 * (lo[2] + hi[2]),
    ];
    let t = &ct.ct_to_build;
    let d: [f64; 3] = std::array::from_fn(|a| c[a] - t[a][3]);
    // Rᵀ (c − t)
    std::array::from_fn(|j| (0..3).map(|i| t[i][j] * d[i]).sum())
}

fn check(
    name: &str,
    ct: &synth::SynthCt,
    init: &InitialTransform,
    start: [[f64; 4]; 4],
    params: &CtParams,
) -> ct::CtRegistration {
    let n = nominal();
    let at = part_center_ct(ct);
    let (a0, d0) = synth::transform_error(&start, &ct.ct_to_build, at);
    let reg = ct::register(&ct.volume, &n.field, &n.shape, init, params)
        .unwrap_or_else(|e| panic!("{name}: {e}"))
        .registration;
    let (a, d) = synth::transform_error(reg.build_from_ct.matrix(), &ct.ct_to_build, at);
    println!(
        "{name}: voxel {} mm, start {a0:.3}° / {:.1} µm → rotation error {a:.5}°, displacement \
         {:.3} µm; {} iterations ({}), mean |Ψ| {:.2} µm, p95 {:.2} µm, {} points used, {} plate",
        voxel_mm(),
        d0 * 1e3,
        d * 1e3,
        reg.iterations,
        reg.termination,
        reg.mean_abs_um,
        reg.p95_abs_um,
        reg.points_used,
        reg.points_excluded_plate,
    );
    assert!(
        a0 > ROT_TOL_DEG || d0 > DISP_TOL_MM,
        "{name}: the start is already within tolerance"
    );
    assert!(
        a <= ROT_TOL_DEG,
        "{name}: rotation error {a}° > {ROT_TOL_DEG}°"
    );
    assert!(
        d <= DISP_TOL_MM,
        "{name}: displacement {} µm > 5 µm",
        d * 1e3
    );
    assert!(
        reg.points_excluded_plate > 0,
        "{name}: no plate-side points were left out"
    );
    reg
}

#[test]
fn three_point_starts_with_clicking_error() {
    let ct = tilted();
    // Three seeds of ±0.3 mm clicking error (all three in release, one in debug).
    let seeds: &[u64] = if cfg!(debug_assertions) {
        &[7]
    } else {
        &[7, 11, 23]
    };
    for &seed in seeds {
        let pairs = synth::landmark_pairs(ct, 3, 0.3, seed);
        let start = *ct::horn(&pairs).expect("horn").matrix();
        check(
            &format!("3-point start (seed {seed})"),
            ct,
            &InitialTransform::Points(pairs),
            start,
            &CtParams::default(),
        );
    }
}

#[test]
fn centroid_start_for_a_roughly_oriented_scan() {
    let ct = nearly_upright();
    check(
        "centroid start (3°)",
        ct,
        &InitialTransform::Centroid,
        centroid_start(ct),
        &CtParams::default(),
    );
}

#[test]
fn iso50_threshold_and_huber_against_reflections() {
    // Two bright blobs where the fin meets the cylinder (the paper's reflections): Huber
    // (k = 50 µm) keeps them from pulling the fit.
    let ct = scan(25.0, [1.0, 2.0, 3.0], true);
    let pairs = synth::landmark_pairs(&ct, 3, 0.3, 5);
    let start = *ct::horn(&pairs).expect("horn").matrix();
    let params = CtParams {
        threshold: Threshold::Iso50,
        huber_k_mm: Some(0.05),
        ..Default::default()
    };
    let reg = check(
        "Huber + reflections",
        &ct,
        &InitialTransform::Points(pairs),
        start,
        &params,
    );
    assert!(
        reg.max_abs_um > 150.0,
        "the reflections should show as additive error: max {}",
        reg.max_abs_um
    );
}

#[test]
fn outputs_ct_toml_and_ply() {
    let ct = tilted();
    let n = nominal();
    let pairs = synth::landmark_pairs(ct, 3, 0.3, 7);
    let params = CtParams {
        max_points: Some(20_000),
        ..Default::default()
    };
    let r = ct::register(
        &ct.volume,
        &n.field,
        &n.shape,
        &InitialTransform::Points(pairs),
        &params,
    )
    .expect("register");
    let dir = std::env::temp_dir().join(format!("layerwise-ct-out-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("tmp dir");
    let toml_path = dir.join("ct.toml");
    r.registration.write_toml(&toml_path).expect("write toml");
    let back = ct::CtRegistration::read_toml(&toml_path).expect("read toml");
    assert_eq!(back.build_from_ct, r.registration.build_from_ct);
    assert_eq!(back.points.used, r.registration.points_used);
    let text = std::fs::read_to_string(&toml_path).expect("toml text");
    for key in [
        "transform",
        "iterations",
        "termination",
        "mean_abs_distance_um",
        "[percentiles]",
        "[points]",
    ] {
        assert!(text.contains(key), "ct.toml lacks {key}:\n{text}");
    }
    let ply = dir.join("ct.ply");
    ct::ply::write_ply(&ply, &r.points_build_mm, &r.distances_mm, 0.05).expect("ply");
    let text = std::fs::read_to_string(&ply).expect("ply text");
    assert!(text.starts_with("ply\nformat ascii 1.0\n"));
    assert!(text.contains(&format!("element vertex {}\n", r.points_build_mm.len())));
    assert_eq!(text.lines().count(), r.points_build_mm.len() + 11);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn empty_threshold_is_a_clear_error() {
    let ct = tilted();
    let n = nominal();
    let params = CtParams {
        threshold: Threshold::Value(70_000.0),
        ..Default::default()
    };
    let e = ct::register(
        &ct.volume,
        &n.field,
        &n.shape,
        &InitialTransform::Centroid,
        &params,
    )
    .expect_err("nothing is above 70000");
    assert!(matches!(e, CtError::EmptyThreshold { .. }), "{e}");
    assert!(e.to_string().contains("empty threshold"), "{e}");
}

#[test]
fn wrong_voxel_size_names_the_ratio() {
    let ct = tilted();
    let n = nominal();
    // The scanner said half the real voxel size.
    let mut vol = ct.volume.clone();
    let h = vol.voxel_mm[0] * 0.5;
    vol.voxel_mm = [h; 3];
    for a in 0..3 {
        vol.index_to_mm[a][a] = h;
    }
    let e = ct::register(
        &vol,
        &n.field,
        &n.shape,
        &InitialTransform::Centroid,
        &CtParams::default(),
    )
    .expect_err("half-size CT");
    let msg = e.to_string();
    assert!(matches!(e, CtError::ScaleMismatch { .. }), "{msg}");
    assert!(
        msg.contains("the CT part is 0.50x the size of the vectors: check the voxel size"),
        "{msg}"
    );
}

#[test]
fn non_convergence_and_no_overlap_are_errors() {
    let ct = tilted();
    let n = nominal();
    let pairs = synth::landmark_pairs(ct, 3, 0.3, 7);
    let params = CtParams {
        max_iterations: 2,
        ..Default::default()
    };
    let e = ct::register(
        &ct.volume,
        &n.field,
        &n.shape,
        &InitialTransform::Points(pairs),
        &params,
    )
    .expect_err("2 iterations cannot converge");
    assert!(
        matches!(e, CtError::NotConverged { iterations: 2, .. }),
        "{e}"
    );
    assert!(
        e.to_string().contains("did not converge in 2 iterations"),
        "{e}"
    );

    // A start 50 mm away: no point in the field.
    let mut far = ct.ct_to_build;
    far[0][3] += 50.0;
    let e = ct::register(
        &ct.volume,
        &n.field,
        &n.shape,
        &InitialTransform::Matrix(Rigid3::from_matrix(far).expect("rigid")),
        &CtParams::default(),
    )
    .expect_err("no overlap");
    assert!(matches!(e, CtError::NoOverlap { used: 0, .. }), "{e}");
}

#[test]
fn field_is_consistent_with_the_part() {
    // The test field itself: zero on the surface, gradient of unit length near it.
    let n = nominal();
    let p = [40.0 + 5.0, -25.0, 5.0 + 0.013];
    let (d, g) = n.field.sample_with_gradient(p).expect("inside");
    assert!(d.abs() < 2e-3, "{d}");
    let norm = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
    assert!((norm - 1.0).abs() < 0.02, "{norm}");
}

/// The start the centroid registration computes (R = I, centroid onto centroid), recomputed
/// to check the starting error.
fn centroid_start(ct: &synth::SynthCt) -> [[f64; 4]; 4] {
    let seg = ct::surface::segment(&ct.volume, &Threshold::Otsu, 0.1).expect("segment");
    let shape = ct::surface::solid_shape(&ct.volume, &seg);
    let mut start = ct::align::IDENTITY;
    for a in 0..3 {
        start[a][3] = nominal().shape.centroid[a] - shape.centroid[a];
    }
    start
}

/// The basin of the centroid start (R = I). Measured at 150 µm, 5° to 45° in 5° steps: within
/// tolerance up to 15° about z (the cylinder's axis; 20° fails), 20° about (1, 2, 3) (25°
/// fails) and 45° about x; past the edge it converges to a wrong minimum, and says so. Asserted
/// with a margin on both sides: 10° about each axis registers within tolerance; 30° about z and
/// 45° about (1, 2, 3) are refused as a poor fit (never a wrong transform given as a result).
#[test]
fn the_centroid_start_registers_within_its_basin_and_refuses_beyond_it() {
    for axis in [[1.0, 2.0, 3.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]] {
        let ct = scan(10.0, axis, false);
        check(
            &format!("centroid start, 10° about {axis:?}"),
            &ct,
            &InitialTransform::Centroid,
            centroid_start(&ct),
            &CtParams::default(),
        );
    }
    let n = nominal();
    for (angle, axis) in [(30.0, [0.0, 0.0, 1.0]), (45.0, [1.0, 2.0, 3.0])] {
        let ct = scan(angle, axis, false);
        let result = ct::register(
            &ct.volume,
            &n.field,
            &n.shape,
            &InitialTransform::Centroid,
            &CtParams::default(),
        );
        match result {
            Err(e @ CtError::PoorFit { .. }) => {
                assert!(e.to_string().contains("start from point pairs"), "{e}")
            }
            Err(e) => panic!("{angle}° about {axis:?}: refused, but not as a poor fit: {e}"),
            Ok(r) => panic!(
                "{angle}° about {axis:?}: outside the basin, yet a result (error {:?})",
                synth::transform_error(
                    r.registration.build_from_ct.matrix(),
                    &ct.ct_to_build,
                    part_center_ct(&ct)
                )
            ),
        }
    }
}
