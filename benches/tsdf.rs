//! TSDF benchmarks (`cargo bench --bench tsdf`): the signed distance build of a 500 x 500 x 600
//! grid around a parameter-cylinder-like part (the paper's §4: a cylinder of 10 mm diameter
//! with a spiral staircase around it and a fin), 548 layers of 1/32 mm, voxels of 1/32 mm.
//!
//! One-shot mode, for time and peak memory in a fresh process and for the comparison with
//! SciPy and scikit-fmm (bench/sdf_vs_scipy.py):
//!   LAYERWISE_TSDF_ONESHOT=exact|sweep|exact-untruncated cargo bench --bench tsdf
//! builds once, prints seconds and VmHWM (peak RSS) as JSON, and with
//! LAYERWISE_TSDF_WRITE=DIR also writes DIR/solid.u8 (1 inside, 0 outside; x fastest) and
//! DIR/solid.json (dims, voxel size) for the Python side, and DIR/ours_<mode>.json.

use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use criterion::Criterion;
use layerwise::tsdf::{self, Init, Method, TsdfParams};
use layerwise::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};

const T: f64 = 1.0 / 32.0;
const LAYERS: usize = 548;

/// The outline at height z, as a star-shaped polygon r(θ): the cylinder (r = 5), the step of
/// the spiral staircase under way at this height (a 30° sector out to r = 7, one step every
/// 0.5 mm, turning 20° per step) and the fin (a 6° sector out to r = 7 at θ = 0, all heights).
fn outline(z: f64) -> Vec<[f64; 2]> {
    let n = 1440;
    let step = (z / 0.5).floor();
    let start = (20.0 * step).rem_euclid(360.0);
    (0..=n)
        .map(|i| {
            let deg = 360.0 * (i % n) as f64 / n as f64;
            let in_step = (deg - start).rem_euclid(360.0) < 30.0;
            let in_fin = !(3.0..=357.0).contains(&deg);
            let r = if in_step || in_fin { 7.0 } else { 5.0 };
            let a = deg.to_radians();
            [r * a.cos(), r * a.sin()]
        })
        .collect()
}

fn part() -> VectorFile {
    let layers = (0..LAYERS)
        .map(|k| {
            let z = T * (k + 1) as f64;
            let mut l = Layer::new(k, z);
            l.polylines.push(Polyline {
                part: 1,
                direction: Direction::CounterClockwise,
                points: outline(z - 0.5 * T),
            });
            l
        })
        .collect();
    VectorFile {
        header: Header::new(Format::Binary, 0.001),
        layers,
    }
}

fn params(truncation_mm: f64) -> TsdfParams {
    TsdfParams {
        voxel_mm: T,
        margin_mm: 0.8125,
        truncation_mm,
        part: Some(1),
        layer_thickness_mm: None,
    }
}

fn vm_hwm_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

fn oneshot(mode: &str) -> Result<(), Box<dyn std::error::Error>> {
    let file = part();
    let before_kb = vm_hwm_kb();
    let (method, trunc) = match mode {
        "exact" => (Method::Exact, 1.0),
        "exact-untruncated" => (Method::Exact, 1e6),
        "sweep" => (Method::FastSweeping(Init::Full), 1.0),
        _ => return Err(format!("unknown mode {mode}").into()),
    };
    let t0 = Instant::now();
    let t = tsdf::build_with(&file, &params(trunc), method)?;
    let seconds = t0.elapsed().as_secs_f64();
    let peak_kb = vm_hwm_kb();
    let json = format!(
        "{{\"mode\": \"{mode}\", \"dims\": [{}, {}, {}], \"voxel_mm\": {}, \"truncation_mm\": {}, \
         \"seconds\": {seconds:.3}, \"peak_rss_kb\": {peak_kb}, \"peak_rss_before_build_kb\": {before_kb}, \
         \"threads\": {}}}",
        t.dims[0],
        t.dims[1],
        t.dims[2],
        t.voxel_mm,
        trunc,
        rayon::current_num_threads()
    );
    println!("{json}");
    if let Some(dir) = std::env::var_os("LAYERWISE_TSDF_WRITE") {
        let dir = PathBuf::from(dir);
        std::fs::create_dir_all(&dir)?;
        std::fs::write(dir.join(format!("ours_{mode}.json")), &json)?;
        let mask: Vec<u8> = t.data.iter().map(|v| v.is_sign_negative() as u8).collect();
        std::fs::write(dir.join("solid.u8"), &mask)?;
        std::fs::write(
            dir.join("solid.json"),
            format!(
                "{{\"dims_xyz\": [{}, {}, {}], \"voxel_mm\": {}, \"order\": \"x fastest\", \"inside\": 1}}",
                t.dims[0], t.dims[1], t.dims[2], t.voxel_mm
            ),
        )?;
    }
    Ok(())
}

fn main() {
    if let Ok(mode) = std::env::var("LAYERWISE_TSDF_ONESHOT") {
        if let Err(e) = oneshot(&mode) {
            eprintln!("tsdf bench: {e}");
            std::process::exit(1);
        }
        return;
    }
    let file = part();
    let mut c = Criterion::default().configure_from_args();
    let mut g = c.benchmark_group("tsdf_500x500x600");
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    g.bench_function("exact_trunc1mm", |b| {
        b.iter(|| black_box(tsdf::build(&file, &params(1.0)).expect("tsdf")))
    });
    g.bench_function("sweep_trunc1mm", |b| {
        b.iter(|| {
            black_box(
                tsdf::build_with(&file, &params(1.0), Method::FastSweeping(Init::Full))
                    .expect("tsdf"),
            )
        })
    });
    g.finish();
    c.final_summary();
    println!("peak RSS of the whole bench process: {} kB", vm_hwm_kb());
}
