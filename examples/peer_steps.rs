//! The steps of the frame path on their own, for the side-by-side scripts under benches/peers/.
//!
//! - `peer_steps frames DIR`: writes `DIR/frame.jpg` (a D810-size 7360 x 4912 mock frame, quality
//!   95, as the camera serves) and `DIR/rectified.raw` (its luma rectified onto the 4400 x 4400
//!   plate grid, 8 bits a pixel, rows in order), the same data every peer gets.
//! - `peer_steps luma IN.jpg OUT.raw`: JPEG decode straight to luma (`decode_jpeg_luma`, what
//!   the views use); prints `decode_ms_median=` (5 runs) and `size=WxH`.
//! - `peer_steps colour IN.jpg OUT.raw`: JPEG decode to 8-bit RGB (`decode_jpeg`, zune-jpeg, what
//!   colour images go through); prints `decode_ms_median=` (5 runs) and `size=WxH`.
//! - `peer_steps deflate IN.raw ROWS COLUMNS OUT.dcm`: the slice's DICOM file with the deflated
//!   transfer syntax, from 8-bit samples (stored in 16 bits); prints `encode_ms_median=` (5 runs,
//!   the whole file in memory, not written) and `bytes=`.
//!
//! Times are wall clock on all cores, as the daemon runs them.

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use layerwise::dicom::{Compression, Plane, Samples, Series, Slice, Study};
use layerwise::geometry::{CameraModel, Homography};
use layerwise::rectify::{Grid, Interpolation, Rectifier};

type Error = Box<dyn std::error::Error>;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["frames", dir] => frames(Path::new(dir)),
        ["luma", input, output] => luma(Path::new(input), Path::new(output)),
        ["colour", input, output] => colour(Path::new(input), Path::new(output)),
        ["deflate", input, rows, columns, output] => deflate(input, rows, columns, output),
        _ => Err("usage: peer_steps frames DIR | luma IN.jpg OUT.raw | colour IN.jpg OUT.raw | deflate IN.raw ROWS COLUMNS OUT.dcm".into()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("peer_steps: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Median of five timed runs of `f` (ms), and the last run's result.
fn median_of_5<T>(mut f: impl FnMut() -> Result<T, Error>) -> Result<(f64, T), Error> {
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..5 {
        let t = Instant::now();
        let out = f()?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
        last = Some(out);
    }
    times.sort_by(f64::total_cmp);
    Ok((times[2], last.ok_or("no run")?))
}

fn frames(dir: &Path) -> Result<(), Error> {
    let (w, h) = (7360, 4912);
    let truth = mock_camera::Homography::oblique_view(w, h);
    let renderer = mock_camera::Renderer::new(w, h, truth);
    let parts = mock_camera::demo_parts(1);
    let scene = mock_camera::Scene {
        layer: 1,
        fused: &parts,
        scanned: true,
        illumination: mock_camera::Illumination::Top,
    };
    let jpeg = renderer.render_jpeg(&scene, 95);
    std::fs::create_dir_all(dir)?;
    std::fs::write(dir.join("frame.jpg"), &jpeg)?;
    let camera = CameraModel::pinhole(Homography::from_matrix(truth.m));
    let rectifier = Rectifier::new(&camera, Grid::plate(), Interpolation::Bilinear, 0)?;
    let rectified = rectifier.rectify_gray8(&layerwise::rectify::decode_jpeg_luma(&jpeg)?);
    std::fs::write(dir.join("rectified.raw"), rectified.as_raw())?;
    println!(
        "frame {w}x{h} ({} bytes), rectified {}x{}",
        jpeg.len(),
        rectified.width(),
        rectified.height()
    );
    Ok(())
}

fn luma(input: &Path, output: &Path) -> Result<(), Error> {
    let bytes = std::fs::read(input)?;
    let (ms, gray) = median_of_5(|| Ok(layerwise::rectify::decode_jpeg_luma(&bytes)?))?;
    std::fs::write(output, gray.as_raw())?;
    println!("decode_ms_median={ms:.2}");
    println!("size={}x{}", gray.width(), gray.height());
    Ok(())
}

fn colour(input: &Path, output: &Path) -> Result<(), Error> {
    let bytes = std::fs::read(input)?;
    let (ms, image) = median_of_5(|| Ok(layerwise::rectify::decode_jpeg(&bytes)?))?;
    let rgb = image.into_rgb8();
    std::fs::write(output, rgb.as_raw())?;
    println!("decode_ms_median={ms:.2}");
    println!("size={}x{}", rgb.width(), rgb.height());
    Ok(())
}

fn deflate(input: &str, rows: &str, columns: &str, output: &str) -> Result<(), Error> {
    let samples = std::fs::read(input)?;
    let (rows, columns): (usize, usize) = (rows.parse()?, columns.parse()?);
    let study = Study {
        study_instance_uid: "2.25.1".into(),
        frame_of_reference_uid: "2.25.2".into(),
        date: "20261201".into(),
        time: "120000".into(),
        patient_name: "peer^".into(),
        patient_id: "peer".into(),
        study_id: "1".into(),
        description: "peer bench".into(),
    };
    let series = Series::named(&study, 1, "post_top");
    let slice = Slice {
        layer: 1,
        plane: Plane {
            origin: [0.0, 0.0, 0.03],
            pixel_mm: 0.0625,
            rows,
            columns,
            thickness_mm: 0.03,
        },
        pixels: Samples::Gray8(&samples),
        acquired: None,
        window: (128.0, 256.0),
        derivation: "peer bench",
    };
    let (ms, bytes) = median_of_5(|| {
        Ok(layerwise::dicom::encode_slice(
            &study,
            &series,
            &slice,
            Compression::Deflate,
        )?)
    })?;
    std::fs::write(output, &bytes)?;
    println!("encode_ms_median={ms:.2}");
    println!("bytes={}", bytes.len());
    Ok(())
}
