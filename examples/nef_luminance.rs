//! The raw path on its own, for benches/peers/nef_vs_rawpy.py.
//!
//! Usage:
//! - `nef_luminance write OUT.nef`: a full-size D810 NEF (7380 x 4928 photosites, lossless
//!   compressed) of the demo plate after the scan of layer 1, top light.
//! - `nef_luminance time IN.nef OUT.y16`: decodes the NEF and takes its linear luminance as the
//!   view series do, 5 times; prints `decode_ms_median=`, `luminance_ms_median=`, `width=`,
//!   `height=` and writes the luminance as little-endian u16, row-major.

use std::process::ExitCode;
use std::time::Instant;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("nef_luminance: {e}");
            ExitCode::FAILURE
        }
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [mode, out] if mode == "write" => {
            let [left, top, right, bottom] = mock_camera::nef::D810_CROP;
            let (w, h) = (7380 - left - right, 4928 - top - bottom);
            let renderer =
                mock_camera::Renderer::new(w, h, mock_camera::Homography::oblique_view(w, h));
            let parts = mock_camera::demo_parts(1);
            let picture = renderer.render(&mock_camera::Scene {
                layer: 1,
                fused: &parts,
                scanned: true,
                illumination: mock_camera::Illumination::Top,
            });
            let nef = mock_camera::nef::encode_nef(&picture, &Default::default());
            std::fs::write(out, nef)?;
            Ok(())
        }
        [mode, input, out] if mode == "time" => {
            let bytes = std::fs::read(input)?;
            let (mut decode_ms, mut luminance_ms) = (Vec::new(), Vec::new());
            let mut luminance = None;
            for _ in 0..5 {
                let t = Instant::now();
                let raw = layerwise::rectify::raw::decode(&bytes)?;
                decode_ms.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                luminance = Some(raw.luminance()?);
                luminance_ms.push(t.elapsed().as_secs_f64() * 1e3);
            }
            let y = luminance.ok_or("no run")?;
            let le: Vec<u8> = y.as_raw().iter().flat_map(|v| v.to_le_bytes()).collect();
            std::fs::write(out, le)?;
            println!(
                "decode_ms_median={:.1} luminance_ms_median={:.1} width={} height={}",
                median(decode_ms),
                median(luminance_ms),
                y.width(),
                y.height()
            );
            Ok(())
        }
        _ => Err("usage: nef_luminance write OUT.nef | nef_luminance time IN.nef OUT.y16".into()),
    }
}
