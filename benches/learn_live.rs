//! The defect model live: one layer of six D810-size views (7360 x 4912 JPEGs rectified to the
//! 4400 x 4400 plate grid) classified tile by tile at 1 mm cells, side by side with the per-layer
//! processing it joins in the worker (decode and rectify the six views). The model has the
//! architecture `learn train` gives frames (8-16-32-64 channels, 3 pools); its weights do not
//! change the time. Target: ≤ 0.3 s per layer on this 2-core machine.
//! Run: `cargo bench --bench learn_live` (without `--bench`: small frames, a quick check).

#[path = "support/views.rs"]
mod bench_views;

use layerwise::config::model::ModelConfig;
use layerwise::learn::live::LiveModel;
use layerwise::learn::{Model, TrainOptions};
use layerwise::rectify::{Calibration, FrameLuma, Interpolation, Rectifier};
use layerwise::shot::{Light, Phase, View};
use rayon::prelude::*;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// A frame model of the default architecture, trained one epoch on noise pictures.
fn model(dir: &std::path::Path) -> std::path::PathBuf {
    for (k, class) in ["No_Defect", "Spots"].iter().enumerate() {
        let d = dir.join(class);
        std::fs::create_dir_all(&d).expect("class dir");
        for i in 0..4u32 {
            let img = image::GrayImage::from_fn(128, 128, |x, y| {
                image::Luma([(90 + (x * 7 + y * 13 + i * 31) % 17 + 20 * k as u32) as u8])
            });
            img.save(d.join(format!("f_{i:04}.png"))).expect("picture");
        }
    }
    let data = layerwise::learn::source::open(dir, None).expect("data");
    let opts = TrainOptions {
        epochs: 1,
        frame_px: 128,
        cell_px: 4,
        cell_mm: Some(1.0),
        ..TrainOptions::default()
    };
    let (net, mut header) = layerwise::learn::train(&data, &opts, |_| {}).expect("train");
    let path = dir.join("model.safetensors");
    Model::save(&path, &net, &mut header).expect("save");
    path
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (w, h, grid) = bench_views::bench_scale(full);
    let tmp = tempfile::tempdir().expect("tempdir");
    let cfg = ModelConfig::for_file(model(tmp.path()));
    let live = LiveModel::open(&cfg, &grid).expect("model");
    let truth = mock_camera::Homography::oblique_view(w, h);
    let renderer = mock_camera::Renderer::new(w, h, truth);
    let parts = mock_camera::demo_parts(1);
    let views: Vec<View> = Phase::ALL
        .iter()
        .flat_map(|&phase| Light::ALL.iter().map(move |&light| View { phase, light }))
        .collect();
    let jpegs: Vec<Vec<u8>> = views
        .iter()
        .map(|view| renderer.render_jpeg(&bench_views::scene(&parts, view), 95))
        .collect();
    let calibration = Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(grid),
        fit: None,
    };
    let rectifier =
        Rectifier::new(&calibration.camera(), grid, Interpolation::Bilinear, 0).expect("rectifier");
    println!(
        "frames {w}x{h} JPEG -> grid {}x{} at {} mm; model cells {} px = 1 mm, tiles {} mm; {} rayon threads",
        grid.columns(),
        grid.rows(),
        grid.pixel_mm,
        live.cell_px(),
        live.cell_px() as f64 * grid.pixel_mm * live.model.header.arch.stride() as f64,
        rayon::current_num_threads()
    );
    let (mut process, mut model) = (Vec::new(), Vec::new());
    for _ in 0..3 {
        let t = Instant::now();
        let rectified: Vec<(View, FrameLuma)> = views
            .par_iter()
            .zip(&jpegs)
            .map(|(view, bytes)| {
                let luma = layerwise::rectify::decode_frame_luma(bytes).expect("decode");
                (*view, luma.rectified(&rectifier))
            })
            .collect();
        process.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        let mut tiles = 0;
        for (view, luma) in &rectified {
            let cells = live.install(|| {
                layerwise::inspect::cells::Cells::from_luma(luma, &grid, live.cell_px())
            });
            let scan = live
                .scan_cells(
                    *view,
                    (cells.rows, cells.cols),
                    &cells.mean,
                    &cells.texture,
                    &grid,
                )
                .expect("scan");
            tiles += scan.rows * scan.cols;
            let _ = live.flags(&scan, &grid);
        }
        model.push(t.elapsed().as_secs_f64());
        assert!(tiles > 0);
    }
    let (p, m) = (median(process), median(model));
    println!(
        "per layer of six views: decode + rectify {p:.3} s; the model (cells, network, flags) {m:.3} s = {:.0} % of it (target <= 0.3 s)",
        100.0 * m / p
    );
}
