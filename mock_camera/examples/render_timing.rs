//! Times a 1200 x 800 render + JPEG: `cargo run -p mock_camera --release --example render_timing`.

use std::time::Instant;

use mock_camera::{demo_parts, Homography, Illumination, Renderer, Scene};

fn main() {
    let (w, h) = (1200, 800);
    let renderer = Renderer::new(w, h, Homography::oblique_view(w, h));
    let parts = demo_parts(100);
    let scene = Scene {
        layer: 100,
        fused: &parts,
        scanned: true,
        illumination: Illumination::Top,
    };
    let _ = renderer.render_jpeg(&scene, 90); // warm up the thread pool
    let runs = 20;
    let mut render_ms = 0.0;
    let mut total_ms = 0.0;
    let mut bytes = 0;
    for _ in 0..runs {
        let t = Instant::now();
        let _img = renderer.render(&scene);
        render_ms += t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        bytes = renderer.render_jpeg(&scene, 90).len();
        total_ms += t.elapsed().as_secs_f64() * 1e3;
    }
    println!(
        "{w}x{h}: render {:.1} ms, render+JPEG(q90) {:.1} ms, {bytes} bytes (mean of {runs}, {} threads)",
        render_ms / f64::from(runs),
        total_ms / f64::from(runs),
        rayon::current_num_threads()
    );
}
