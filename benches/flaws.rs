//! Criterion bench of `layerwise flaws`' detection (segment, candidates, 26-connected labels,
//! measures) on the 50 µm synthetic parameter cylinder (660 x 646 x 395 u16 voxels, the
//! registration bench's size). The side-by-side with scipy.ndimage / scikit-image through the
//! binary is benches/peers/flaws_vs_scipy.py.
//! `cargo bench --features testkit --bench flaws` (CT_BENCH_VOXEL_MM=0.15 for a quick run)

use criterion::{criterion_group, criterion_main, Criterion};
use layerwise::ct::synth;
use layerwise::flaws::{detect, FlawParams};
use layerwise::geometry::Rigid3;
use layerwise::series::LayerHeights;

fn bench(c: &mut Criterion) {
    let (_, scan) = synth::bench_case(synth::bench_voxel_mm());
    let truth = Rigid3::from_matrix(scan.ct_to_build).expect("a rotation");
    let heights = LayerHeights::uniform(0.03);
    let params = FlawParams::default();
    let found = detect(&scan.volume, &truth, &heights, None, &params).expect("detect");
    assert_eq!(found.flaws.len(), scan.as_built.voids.len());
    let [x, y, z] = scan.volume.dims;
    let mut g = c.benchmark_group(format!("flaws_{x}x{y}x{z}"));
    g.sample_size(10);
    g.bench_function("detect (segment, label, measure)", |b| {
        b.iter(|| detect(&scan.volume, &truth, &heights, None, &params).expect("detect"))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
