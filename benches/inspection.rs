//! Inspection of one layer (six views) on the full 4400 x 4400 plate grid, side by side with the
//! per-layer processing it joins in the worker: the same six D810-size JPEGs processed by the live
//! series alone (decode, rectify, DICOM) and by the series with inspection (the same, plus reducing
//! each view to 0.5 mm cells and inspecting the layer against the demo vectors). Target: inspection
//! ≤ 0.5 s per layer on this 2-core machine. Run: `cargo bench --bench inspection`.

#[path = "support/views.rs"]
mod bench_views;

#[path = "support/manifest.rs"]
mod manifest;

use layerwise::acquisition::alarm::Alarm;
use layerwise::acquisition::inspection::InspectingSeries;
use layerwise::acquisition::processing::FrameProcessor;
use layerwise::clock::SystemClock;
use layerwise::config::{Config, DEMO_CONFIG};
use layerwise::dicom::Compression;
use layerwise::hardware::lights::NoLights;
use layerwise::inspect::Inspector;
use layerwise::rectify::{Calibration, Interpolation, Rectifier};
use layerwise::series::{LayerHeights, LiveSeries, SeriesSettings};
use layerwise::shot::{Light, Phase, Shot, View};
use manifest::bench_manifest;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// CPU seconds this process has used (all threads): on a machine shared with other builds the
/// wall time of a step grows with the load, its CPU time much less.
fn cpu_seconds() -> f64 {
    // SAFETY: getrusage only writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    let seconds = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    seconds(usage.ru_utime) + seconds(usage.ru_stime)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// The six originals of `layers` layers (the same pictures under each layer's names).
fn originals(dir: &Path, pictures: &[(View, Vec<u8>)], layers: u32) -> Vec<Vec<(Shot, PathBuf)>> {
    std::fs::create_dir_all(dir.join("raw")).expect("raw");
    (1..=layers)
        .map(|layer| {
            pictures
                .iter()
                .map(|(view, bytes)| {
                    let shot = Shot {
                        layer,
                        phase: view.phase,
                        light: view.light,
                    };
                    let path = dir.join(format!("raw/{}.jpg", shot.stem()));
                    std::fs::write(&path, bytes).expect("frame");
                    (shot, path)
                })
                .collect()
        })
        .collect()
}

/// Seconds per layer, the six frames one per core at a time as the worker runs them.
fn per_layer(processor: &dyn FrameProcessor, dir: &Path, layers: &[Vec<(Shot, PathBuf)>]) -> f64 {
    let times: Vec<f64> = layers
        .iter()
        .map(|frames| {
            let t = Instant::now();
            frames
                .par_iter()
                .for_each(|(shot, path)| processor.process(dir, *shot, path).expect("process"));
            t.elapsed().as_secs_f64()
        })
        .collect();
    median(times)
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (w, h, grid) = bench_views::bench_scale(full);
    let rounds = if full { 4 } else { 2 };
    let truth = mock_camera::Homography::oblique_view(w, h);
    let renderer = mock_camera::Renderer::new(w, h, truth);
    let views: Vec<View> = Phase::ALL
        .iter()
        .flat_map(|&phase| Light::ALL.iter().map(move |&light| View { phase, light }))
        .collect();
    let parts = mock_camera::demo_parts(1);
    let pictures: Vec<(View, Vec<u8>)> = views
        .iter()
        .map(|view| {
            (
                *view,
                renderer.render_jpeg(&bench_views::scene(&parts, view), 95),
            )
        })
        .collect();
    let tmp = tempfile::tempdir().expect("tempdir");
    let calibration = Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(grid),
        fit: None,
    };
    let vectors = tmp.path().join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, 2 * rounds + 2).expect("vectors");
    let mut config = Config::parse(DEMO_CONFIG, Path::new("demo.toml")).expect("demo config");
    config.rectify = grid;
    config.build.vectors = Some(vectors.clone());
    config.storage.fsync = false;
    let manifest = bench_manifest(&views);
    let live = || {
        let settings = SeriesSettings {
            grid,
            heights: LayerHeights::uniform(0.03),
            compression: Compression::None,
            interpolation: Interpolation::Bilinear,
            fill: 0,
        };
        LiveSeries::new(&manifest, &views, &calibration, settings).expect("series")
    };
    println!(
        "frames {w}x{h} JPEG -> grid {}x{} at {} mm; inspection cells {} mm; {} rayon threads",
        grid.columns(),
        grid.rows(),
        grid.pixel_mm,
        config.inspection.pixel_mm,
        rayon::current_num_threads()
    );

    // Inspection alone: the six rectified views reduced to cells, then the layer inspected.
    let rectifier =
        Rectifier::new(&calibration.camera(), grid, Interpolation::Bilinear, 0).expect("rectifier");
    let rectified: Vec<(View, layerwise::rectify::FrameLuma)> = pictures
        .iter()
        .map(|(view, bytes)| {
            let luma = layerwise::rectify::decode_frame_luma(bytes).expect("decode");
            (*view, luma.rectified(&rectifier))
        })
        .collect();
    let index = layerwise::vectors::LayerIndex::build(&vectors).expect("vectors");
    let mut inspector = Inspector::new(&config.inspection, grid, &views, Some(index));
    let reducer = inspector.reducer();
    let mut reduce = Vec::new();
    let mut inspect = Vec::new();
    let (mut reduce_cpu, mut inspect_cpu) = (Vec::new(), Vec::new());
    let at = chrono::Utc::now();
    for layer in 1..=(2 * rounds) {
        let t = Instant::now();
        let c = cpu_seconds();
        let cells: Vec<_> = rectified
            .par_iter()
            .filter(|(view, _)| reducer.needs(*view))
            .map(|(view, luma)| (*view, reducer.cells(luma)))
            .collect();
        reduce.push(t.elapsed().as_secs_f64());
        reduce_cpu.push(cpu_seconds() - c);
        let t = Instant::now();
        let c = cpu_seconds();
        let mut records = Vec::new();
        for (view, cells) in cells {
            records.extend(inspector.add(layer, view, cells, at));
        }
        inspect.push(t.elapsed().as_secs_f64());
        inspect_cpu.push(cpu_seconds() - c);
        assert_eq!(records.len(), 1);
    }
    println!(
        "inspection alone per layer: reduce the views it uses {:.3} s + inspect {:.3} s = {:.3} s (target <= 0.5 s)",
        median(reduce.clone()),
        median(inspect.clone()),
        median(reduce) + median(inspect)
    );
    println!(
        "  CPU time per layer (all threads): reduce {:.3} s + inspect {:.3} s = {:.3} s",
        median(reduce_cpu.clone()),
        median(inspect_cpu.clone()),
        median(reduce_cpu) + median(inspect_cpu)
    );

    // In the worker: the same layer through the live series, without and with inspection.
    let plain_dir = tmp.path().join("plain");
    let plain_layers = originals(&plain_dir, &pictures, rounds);
    let plain = per_layer(&live(), &plain_dir, &plain_layers);
    let insp_dir = tmp.path().join("inspected");
    config.build.output_dir = insp_dir.clone();
    let layers = originals(&insp_dir, &pictures, rounds);
    let inspecting = InspectingSeries::open(
        &config,
        &insp_dir,
        live(),
        Alarm::new(Box::new(NoLights), &config.inspection.alarm),
        SystemClock::shared(),
    )
    .expect("inspecting series");
    let with = per_layer(&inspecting, &insp_dir, &layers);
    println!(
        "processing per layer (6 views, one per core at a time): series alone {plain:.2} s, series + inspection {with:.2} s (+{:.2} s)",
        with - plain
    );
}
