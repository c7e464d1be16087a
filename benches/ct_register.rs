//! Criterion bench of the CT registration on the 50 µm synthetic parameter cylinder
//! (660 x 646 x 395 u16 voxels, ~395k surface points), by stage and end to end.
//! `CARGO_TARGET_DIR=… cargo bench --bench ct_register`

use criterion::{criterion_group, criterion_main, Criterion};
use layerwise::ct::{self, synth, CtParams, InitialTransform, Threshold};

fn bench(c: &mut Criterion) {
    let voxel = synth::bench_voxel_mm();
    let (part, scan) = synth::bench_case(voxel);
    let (lo, hi) = part.bounds();
    let field = synth::GridField::from_sdf(|p| part.sdf(p), lo, hi, f64::min(voxel, 0.1), 1.0);
    let nominal = synth::nominal_shape(&part, 0.1);
    let pairs = synth::landmark_pairs(&scan, 3, 0.3, 7);
    let start = *ct::horn(&pairs).expect("horn").matrix();
    let params = CtParams::default();
    let seg = ct::surface::segment(&scan.volume, &Threshold::Otsu, 0.1).expect("segment");
    let points = ct::surface::surface_points(&scan.volume, &seg);

    let mut g = c.benchmark_group(format!("ct_{}um", (voxel * 1e3).round()));
    g.sample_size(10);
    g.bench_function("segment (otsu, components, voids)", |b| {
        b.iter(|| ct::surface::segment(&scan.volume, &Threshold::Otsu, 0.1).expect("segment"))
    });
    g.bench_function("surface points", |b| {
        b.iter(|| ct::surface::surface_points(&scan.volume, &seg))
    });
    g.bench_function("refine (LM + stats)", |b| {
        b.iter(|| {
            ct::align::register_points(&points, start, &field, &params, seg.threshold)
                .expect("refine")
        })
    });
    g.bench_function("register end to end", |b| {
        b.iter(|| {
            ct::register(
                &scan.volume,
                &field,
                &nominal,
                &InitialTransform::Points(pairs.clone()),
                &params,
            )
            .expect("register")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
