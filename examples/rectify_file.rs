//! Rectify one image file onto the default plate grid.
//!
//! Usage: `rectify_file in.png H.json out.png [--reuse]`
//!
//! `H.json` holds the image → build homography as a 3x3 array of numbers,
//! either bare (`[[..],[..],[..]]`) or under a key (`{"homography": [[..]]}`).
//! Prints the wall time of the warp alone (median of 5 runs, after 2 untimed ones that bring
//! the allocator to the state a long-running process is in) as
//! `warp_ms_median=<ms>`; decoding and encoding are not timed. Each run
//! allocates a fresh output image, unless `--reuse` is given: then 8-bit
//! grey/RGB input is warped into one output buffer reused across runs. It runs on the
//! `layerwise` binary's allocator (`layerwise::alloc`), as the binary does.

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

use std::process::ExitCode;
use std::time::Instant;

use image::DynamicImage;
use layerwise::geometry::{CameraModel, Homography};
use layerwise::rectify::{Grid, Interpolation, Rectifier};

/// Untimed runs first: a fresh process's first large allocations are fresh pages from the
/// kernel (faulted in and zeroed), a long-running one reuses what it freed, as the daemon does
/// from its second frame on. The peer script warms OpenCV up the same way.
const WARM_UP: usize = 2;

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("rectify_file: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (input, h_path, output, reuse) = match args.as_slice() {
        [i, h, o] => (i, h, o, false),
        [i, h, o, flag] if flag == "--reuse" => (i, h, o, true),
        _ => return Err("usage: rectify_file in.png H.json out.png [--reuse]".into()),
    };
    let src = image::open(input)?;
    let build_from_image = parse_homography(&std::fs::read_to_string(h_path)?)?;
    let camera = CameraModel::pinhole(Homography::from_matrix(build_from_image));
    let rect = Rectifier::new(&camera, Grid::plate(), Interpolation::Bilinear, 0)?;

    let mut times = Vec::new();
    let mut faults = Vec::new();
    let mut out = None;
    let mut gray = image::GrayImage::new(0, 0);
    let mut rgb = image::RgbImage::new(0, 0);
    for run in 0..WARM_UP + 5 {
        let faults_before = minor_faults();
        let t = Instant::now();
        let img = match (&src, reuse) {
            (DynamicImage::ImageLuma8(s), true) => {
                rect.rectify_gray8_into(s, &mut gray);
                None
            }
            (DynamicImage::ImageRgb8(s), true) => {
                rect.rectify_rgb8_into(s, &mut rgb);
                None
            }
            _ => Some(rect.rectify_dynamic(&src)),
        };
        if run >= WARM_UP {
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        faults.push(minor_faults() - faults_before);
        // The previous output is dropped here, outside the timed region.
        out = img;
    }
    let out = match (out, &src) {
        (Some(img), _) => img,
        (None, DynamicImage::ImageLuma8(_)) => DynamicImage::ImageLuma8(gray),
        (None, _) => DynamicImage::ImageRgb8(rgb),
    };
    let order: Vec<String> = times.iter().map(|t| format!("{t:.1}")).collect();
    println!("warp_ms_in_order={}", order.join(","));
    let faults: Vec<String> = faults.iter().map(i64::to_string).collect();
    println!("page_faults_in_order={}", faults.join(","));
    times.sort_by(f64::total_cmp);
    let all: Vec<String> = times.iter().map(|t| format!("{t:.1}")).collect();
    println!("warp_ms_runs={}", all.join(","));
    println!("warp_ms_median={:.2}", times[2]);
    out.save(output)?;
    Ok(())
}

/// The process's minor page faults so far (every thread's): a run that faults thousands of
/// times (or, with huge pages, tens) got fresh pages from the kernel for its output.
fn minor_faults() -> i64 {
    // SAFETY: getrusage fills the zeroed struct it is given and reads nothing else.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: as above; RUSAGE_SELF is a valid `who`.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return 0;
    }
    usage.ru_minflt
}

/// The 9 numbers of the first 3x3 array in `text`.
fn parse_homography(text: &str) -> Result<[[f64; 3]; 3], Box<dyn std::error::Error>> {
    let start = text.find('[').ok_or("H.json: no array found")?;
    let nums: Vec<f64> = text[start..]
        .split(|c: char| !(c.is_ascii_digit() || matches!(c, '.' | '-' | '+' | 'e' | 'E')))
        .filter(|s| !s.is_empty())
        .map(str::parse::<f64>)
        .collect::<Result<_, _>>()?;
    if nums.len() != 9 {
        return Err(format!("H.json: expected 9 numbers, found {}", nums.len()).into());
    }
    let mut h = [[0.0; 3]; 3];
    for (i, v) in nums.into_iter().enumerate() {
        h[i / 3][i % 3] = v;
    }
    Ok(h)
}
