//! The whole per-frame processing path on D810-size frames (7360 x 4912 JPEG) onto the full
//! 4400 x 4400 plate grid: decode, luma, rectify, DICOM encode and atomic write, for each transfer
//! syntax; and the per-layer total for the six views, run as the processing worker runs them (one
//! frame per core, each slice's commit on a thread beside them). Target: a layer (6 frames) under 2 s on
//! this 2-core machine. Run: `cargo bench --bench frame_path --all-features`.
//! LAYERWISE_BENCH_ROUNDS sets the rounds (each: every frame alone, then one layer; default 3
//! with `--bench`, else 1); the layer line gives the median, fastest and slowest layer, and the
//! CPU line the CPU time of a layer (all threads) and how busy it kept the cores.
//! LAYERWISE_BENCH_DICOM=deflate (or none, jpegls; comma-separated) runs only those transfer
//! syntaxes and no NEF, for profiling one of them (`perf record`).

/// The binary's allocator (`layerwise::alloc`), so that this measures what it does.
#[global_allocator]
static ALLOCATOR: layerwise::alloc::LargeBlockCache = layerwise::alloc::LargeBlockCache::new();

#[path = "support/views.rs"]
mod bench_views;

#[path = "support/manifest.rs"]
mod manifest;

#[path = "support/memory.rs"]
mod memory;

use layerwise::acquisition::processing::FrameProcessor;
use layerwise::acquisition::storage::Storage;
#[cfg(feature = "nef")]
use layerwise::build_dir::BuildManifest;
use layerwise::dicom::Compression;
use layerwise::fsutil::Pending;
use layerwise::hardware::camera::Frame;
use layerwise::rectify::{Calibration, Interpolation};
use layerwise::series::{LayerHeights, LiveSeries, SeriesSettings, StepTimes};
use layerwise::shot::{Light, Phase, Shot, View};
use manifest::bench_manifest;
use rayon::prelude::*;
use std::time::Instant;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// The layer number of the next pass over the views. Every pass writes a layer of its own, as a
/// build does: slices are new files. (Writing the same layer again renames each slice over the
/// one before, and on a file system mounted with `discard`, as this machine's, freeing the old
/// file's blocks made the rename 3-10 ms: not the daemon's cost.)
static NEXT_LAYER: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(1);

fn next_layer() -> u32 {
    NEXT_LAYER.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// The view's shot in `layer`.
fn in_layer(shot: Shot, layer: u32) -> Shot {
    Shot { layer, ..shot }
}

/// This process's CPU time so far (user and system, all threads), s.
fn cpu_s() -> f64 {
    // SAFETY: getrusage fills the struct it is given; a zeroed rusage is a valid one.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `usage` is a valid, writable rusage.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return 0.0;
    }
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 / 1e6;
    s(usage.ru_utime) + s(usage.ru_stime)
}

/// Per-frame times (ms, each frame alone), per-layer times (s, the six frames one per core at
/// a time, as the processing worker runs them), the CPU time of each layer (s, all threads)
/// and the steps of the layers' frames, over `rounds` rounds; and the last layer written.
fn time_frames(
    live: &LiveSeries,
    build_dir: &std::path::Path,
    originals: &[(Shot, std::path::PathBuf)],
    rounds: usize,
) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<StepTimes>, u32) {
    let mut per_frame = Vec::new();
    let mut layer_totals = Vec::new();
    let mut layer_cpu = Vec::new();
    let steps = std::sync::Mutex::new(Vec::new());
    let mut last = 0;
    for _ in 0..rounds {
        let alone = next_layer();
        for (shot, path) in originals {
            let t = Instant::now();
            live.process(build_dir, in_layer(*shot, alone), path)
                .expect("process");
            per_frame.push(t.elapsed().as_secs_f64() * 1e3);
        }
        last = next_layer();
        let (layer, cpu) = (Instant::now(), cpu_s());
        // As the processing worker runs them: one frame per core, each slice's commit (fsync,
        // rename) on a thread of its own while the lanes go on with the next frames.
        std::thread::scope(|scope| {
            // Bounded as the worker's queue is: two slices a lane.
            let (to_commit, commits) = crossbeam_channel::bounded::<(Pending, StepTimes)>(
                2 * rayon::current_num_threads(),
            );
            scope.spawn(|| {
                for (pending, mut frame) in commits {
                    let t = Instant::now();
                    pending.commit().expect("commit");
                    frame.commit_ms = t.elapsed().as_secs_f64() * 1e3;
                    steps.lock().expect("steps").push(frame);
                }
            });
            originals
                .par_iter()
                .for_each_with(to_commit, |to_commit, (shot, path)| {
                    // What `FrameProcessor::process_take_then` runs, with its step times kept.
                    let mut frame = StepTimes::default();
                    let pending = live
                        .write_original_pending(
                            build_dir,
                            in_layer(*shot, last),
                            1,
                            path,
                            &mut frame,
                        )
                        .expect("process");
                    to_commit.send((pending, frame)).expect("commit thread");
                });
        });
        layer_totals.push(layer.elapsed().as_secs_f64());
        layer_cpu.push(cpu_s() - cpu);
    }
    let steps = steps.into_inner().expect("steps");
    (per_frame, layer_totals, layer_cpu, steps, last)
}

/// The medians of the steps of the layers' frames, ms.
fn steps_line(steps: &[StepTimes]) -> String {
    let of = |f: fn(&StepTimes) -> f64| median(steps.iter().map(f).collect());
    format!(
        "read {:.0}, decode {:.0}, rectify {:.0}, encode {:.0}, write {:.0}, commit {:.0}",
        of(|s| s.read_ms),
        of(|s| s.decode_ms),
        of(|s| s.rectify_ms),
        of(|s| s.encode_ms),
        of(|s| s.write_ms),
        of(|s| s.commit_ms)
    )
}

/// One original per view of layer 1 in `build_dir/raw/`, as `frame` encodes it, stored as the
/// daemon stores a frame (with the sidecar the processing checks it against).
fn write_originals(
    build_dir: &std::path::Path,
    views: &[View],
    extension: &str,
    frame: impl Fn(&View) -> Vec<u8>,
) -> Vec<(Shot, std::path::PathBuf)> {
    let storage = Storage::open(build_dir, false).expect("raw");
    views
        .iter()
        .map(|view| {
            let shot = Shot {
                layer: 1,
                phase: view.phase,
                light: view.light,
            };
            let frame = Frame {
                data: frame(view),
                extension: extension.into(),
                capture_ms: 0.0,
                download_ms: 0.0,
            };
            let now = chrono::Utc::now();
            let sidecar = storage
                .store_frame(&shot, 1, &frame, now, now, 1, &Default::default())
                .expect("original");
            (shot, build_dir.join(sidecar.file))
        })
        .collect()
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (w, h, grid) = bench_views::bench_scale(full);
    let rounds = std::env::var("LAYERWISE_BENCH_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n: &usize| n > 0)
        .unwrap_or(if full { 3 } else { 1 });
    let truth = mock_camera::Homography::oblique_view(w, h);
    let renderer = mock_camera::Renderer::new(w, h, truth);
    let parts = mock_camera::demo_parts(1);
    let dir = tempfile::tempdir().expect("tempdir");
    let views: Vec<View> = Phase::ALL
        .iter()
        .flat_map(|&phase| Light::ALL.iter().map(move |&light| View { phase, light }))
        .collect();
    let originals = write_originals(dir.path(), &views, "jpg", |view| {
        renderer.render_jpeg(&bench_views::scene(&parts, view), 95)
    });
    let jpeg_mb = std::fs::metadata(&originals[0].1)
        .map(|m| m.len())
        .unwrap_or(0) as f64
        / 1e6;
    let manifest = bench_manifest(&views);
    let calibration = Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(grid),
        fit: None,
    };
    let mut compressions = vec![Compression::None, Compression::Deflate];
    if cfg!(feature = "jpegls") {
        compressions.push(Compression::JpegLs);
    }
    let only = std::env::var("LAYERWISE_BENCH_DICOM").ok();
    if let Some(only) = &only {
        let name = |c: &Compression| format!("{c:?}").to_lowercase();
        let wanted: Vec<String> = only.split(',').map(|s| s.trim().to_lowercase()).collect();
        let known: Vec<String> = compressions.iter().map(name).collect();
        if let Some(unknown) = wanted.iter().find(|w| !known.contains(w)) {
            eprintln!("LAYERWISE_BENCH_DICOM: no transfer syntax `{unknown}` in this build; one of {known:?}");
            std::process::exit(2);
        }
        compressions.retain(|c| wanted.contains(&name(c)));
    }
    println!(
        "frames {w}x{h} JPEG ({jpeg_mb:.1} MB each) -> grid {}x{} at {} mm",
        grid.columns(),
        grid.rows(),
        grid.pixel_mm
    );
    // The parts of the path on their own, for one frame.
    let bytes = std::fs::read(&originals[5].1).expect("frame");
    let t = Instant::now();
    let decoded = layerwise::rectify::decode_jpeg(&bytes).expect("decode");
    let decode_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let _ = layerwise::rectify::luma(&decoded.to_rgb8());
    let luma_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let gray = layerwise::rectify::decode_jpeg_luma(&bytes).expect("decode");
    let luma_decode_ms = t.elapsed().as_secs_f64() * 1e3;
    let rectifier = layerwise::rectify::Rectifier::new(
        &layerwise::geometry::CameraModel::pinhole(layerwise::geometry::Homography::from_matrix(
            truth.m,
        )),
        grid,
        Interpolation::Bilinear,
        0,
    )
    .expect("rectifier");
    let t = Instant::now();
    let _ = rectifier.rectify_gray8(&gray);
    let rectify_ms = t.elapsed().as_secs_f64() * 1e3;
    println!("one frame: colour decode {decode_ms:.0} ms + luma {luma_ms:.0} ms, or luma-only decode {luma_decode_ms:.0} ms (used); rectify {rectify_ms:.0} ms");
    drop((decoded, gray, bytes));
    for compression in compressions {
        let settings = SeriesSettings {
            grid,
            heights: LayerHeights::uniform(0.03),
            compression,
            interpolation: Interpolation::Bilinear,
            fill: 0,
        };
        let live = LiveSeries::new(&manifest, &views, &calibration, settings).expect("series");
        // The peak of this transfer syntax's processing alone, from the process's resident
        // memory before it (the rendered frames, the renderer).
        let before_kib = memory::current_rss_kib();
        memory::reset_peak();
        let (per_frame, layer_totals, layer_cpu, steps, last) =
            time_frames(&live, dir.path(), &originals, rounds);
        let (cpu, layer_s) = (median(layer_cpu), median(layer_totals.clone()));
        let size = std::fs::metadata(dir.path().join(format!("dicom/post_top/L{last:05}.dcm")))
            .map(|m| m.len())
            .unwrap_or(0);
        let layers = layer_totals.len();
        let (fastest, slowest) = layer_totals
            .iter()
            .fold((f64::MAX, 0f64), |(lo, hi), &t| (lo.min(t), hi.max(t)));
        println!(
            "{compression:?}: per frame alone median {:.0} ms; per layer (6 frames, one per core at a time) median {:.2} s (target < 2 s; {} layers, fastest {fastest:.2} s, slowest {slowest:.2} s); {:.1} MB per slice, {:.0} MB per layer",
            median(per_frame),
            layer_s,
            layers,
            size as f64 / 1e6,
            6.0 * size as f64 / 1e6
        );
        println!(
            "{compression:?}: steps of a frame within the layers (medians, ms, two frames at a time): {}",
            steps_line(&steps)
        );
        println!(
            "{compression:?}: CPU of a layer (median, all threads) {cpu:.2} s, {:.0} % of its time",
            100.0 * cpu / layer_s
        );
        println!(
            "{compression:?}: peak resident memory while processing {:.0} MiB ({:.0} MiB before it)",
            memory::peak_rss_kib() as f64 / 1024.0,
            before_kib as f64 / 1024.0
        );
    }
    #[cfg(feature = "nef")]
    if only.is_none() {
        raw_frames(
            &renderer,
            &parts,
            &views,
            &manifest,
            &calibration,
            &rectifier,
            full,
        );
    }
}

/// The same path when the camera is set to NEF (14-bit lossless compressed, the D810's
/// default): decode with rawler, luminance from the mosaic, 16-bit rectify, DICOM write.
#[cfg(feature = "nef")]
fn raw_frames(
    renderer: &mock_camera::Renderer,
    parts: &[mock_camera::Shape],
    views: &[View],
    manifest: &BuildManifest,
    calibration: &Calibration,
    rectifier: &layerwise::rectify::Rectifier,
    full: bool,
) {
    let dir = tempfile::tempdir().expect("tempdir");
    let originals = write_originals(dir.path(), views, "nef", |view| {
        mock_camera::nef::encode_nef(
            &renderer.render(&bench_views::scene(parts, view)),
            &mock_camera::nef::NefOptions::default(),
        )
    });
    let bytes = std::fs::read(&originals[5].1).expect("frame");
    let t = Instant::now();
    let raw = layerwise::rectify::raw::decode(&bytes).expect("decode");
    let decode_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let luminance = raw.luminance().expect("luminance");
    let luminance_ms = t.elapsed().as_secs_f64() * 1e3;
    // The full colour development, which pictures (PNG, overlays) still take.
    let t = Instant::now();
    let developed = raw.develop().expect("develop");
    let _ = developed.luminance();
    let develop_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let _ = rectifier.rectify_gray16(&luminance);
    let rectify_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "NEF {}x{} ({:.1} MB): decode {decode_ms:.0} ms, mosaic to luminance {luminance_ms:.0} ms \
         (full colour development and mixing down instead: {develop_ms:.0} ms, {:.1}x), rectify 16-bit {rectify_ms:.0} ms",
        luminance.width(),
        luminance.height(),
        bytes.len() as f64 / 1e6,
        develop_ms / luminance_ms
    );
    let settings = SeriesSettings {
        grid: rectifier.grid(),
        heights: LayerHeights::uniform(0.03),
        compression: Compression::None,
        interpolation: Interpolation::Bilinear,
        fill: 0,
    };
    let live = LiveSeries::new(manifest, views, calibration, settings).expect("series");
    let (per_frame, layer_totals, _, _, _) =
        time_frames(&live, dir.path(), &originals, if full { 2 } else { 1 });
    println!(
        "NEF, None: per frame alone median {:.0} ms; per layer (6 frames, one per core at a time) median {:.2} s",
        median(per_frame),
        median(layer_totals)
    );
}
