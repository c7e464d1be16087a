//! Our side of bench/ecc_vs_ours.py: the IC-LM core on files both sides read.
//!
//! `register_file make DIR [--size N]` renders a mock post-scan frame (N x N, mock_camera's
//! oblique view, five parts) and writes, as .npy: `image.npy` (I_B, the std-filtered frame,
//! f32), `exemplar.npy` (I_E on the whole plate at 0.0625 mm, f32), `contour.npy` (the parts'
//! contour points in exemplar pixels, f64 N x 2); and as text (3 rows of 3): `start.txt` (the
//! warp exemplar px → image px from 4 clicks off by up to ±6 px) and `truth.txt`.
//!
//! `register_file run DIR [--levels L] [--repeat R] [--all-pixels]` aligns (IC-LM, L levels,
//! default 4; `--all-pixels`: the cost over every exemplar pixel, not only near the parts) from
//! `start.txt` and prints one JSON object: best wall time of R runs, the warp, and the mean and
//! max distance to `truth.txt` over the contour points, in image pixels.

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{anyhow, bail, Context, Result};
use layerwise::calibrate::{
    align, dlt_build_from_image, filter_frame, luma_f32, render_exemplar, Correspondence, F32Image,
    LmOptions, Pair,
};
use layerwise::geometry::{BuildPoint, Grid, Homography, ImagePoint, Mat3};
use layerwise::vectors::Layer;
use mock_camera::{Illumination, Renderer, Scene, Shape};

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let flag = |name: &str| -> Option<&str> {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .map(String::as_str)
    };
    match (args.first().map(String::as_str), args.get(1)) {
        (Some("make"), Some(dir)) => {
            let size = flag("--size").map_or(Ok(4400), str::parse)?;
            let half = flag("--half-mm").map_or(Ok(137.5), str::parse)?;
            make(Path::new(dir), size, half)
        }
        (Some("run"), Some(dir)) => {
            let levels = flag("--levels").map_or(Ok(4), str::parse)?;
            let repeat = flag("--repeat").map_or(Ok(1), str::parse)?;
            let all = args.iter().any(|a| a == "--all-pixels");
            align_files(Path::new(dir), levels, repeat, all)
        }
        _ => bail!(
            "usage: register_file make DIR [--size N] [--half-mm H] | \
             run DIR [--levels L] [--repeat R] [--all-pixels]"
        ),
    }
}

/// A part as the mock renders it and its rings in build mm.
type Part = (Shape, Vec<Vec<(f64, f64)>>);

/// Rings in build mm (outer counter-clockwise, holes clockwise); circles as 256-gons.
fn parts() -> Vec<Part> {
    let rect = |x0: f64, y0: f64, x1: f64, y1: f64| vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1)];
    let turn = |ring: Vec<(f64, f64)>, (cx, cy): (f64, f64)| -> Vec<(f64, f64)> {
        let (s, c) = 17f64.to_radians().sin_cos();
        ring.into_iter()
            .map(|(x, y)| {
                let (dx, dy) = (x - cx, y - cy);
                (cx + c * dx - s * dy, cy + s * dx + c * dy)
            })
            .collect()
    };
    let circle: Vec<(f64, f64)> = (0..256)
        .map(|i| {
            let a = TAU * f64::from(i) / 256.0;
            (-70.0 + 8.0 * a.cos(), 50.0 + 8.0 * a.sin())
        })
        .collect();
    let mut hole = rect(67.0, -63.0, 83.0, -47.0);
    hole.reverse();
    let polys = vec![
        vec![turn(rect(40.0, 40.0, 70.0, 60.0), (55.0, 50.0))],
        vec![turn(
            vec![
                (-20.0, -80.0),
                (20.0, -80.0),
                (20.0, -70.0),
                (-10.0, -70.0),
                (-10.0, -40.0),
                (-20.0, -40.0),
            ],
            (-5.0, -65.0),
        )],
        vec![
            turn(rect(60.0, -70.0, 90.0, -40.0), (75.0, -55.0)),
            turn(hole, (75.0, -55.0)),
        ],
        vec![turn(
            vec![(-90.0, -30.0), (-50.0, -30.0), (-70.0, 0.0)],
            (-70.0, -20.0),
        )],
    ];
    let mut out = vec![(
        Shape::Circle {
            cx: -70.0,
            cy: 50.0,
            r: 8.0,
        },
        vec![circle],
    )];
    for rings in polys {
        out.push((
            Shape::Polygon {
                rings: rings.clone(),
            },
            rings,
        ));
    }
    out
}

fn layer(parts: &[Part]) -> Layer {
    let rings: Vec<&[Vec<(f64, f64)>]> = parts.iter().map(|(_, r)| r.as_slice()).collect();
    layerwise::vectors::synth::contour_layer(0, 0.03, &rings)
}

fn make(dir: &Path, size: u32, half_mm: f64) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}", dir.display()))?;
    let truth = mock_camera::Homography::oblique_view(size, size);
    let truth_inv = truth.inverse().ok_or_else(|| anyhow!("singular truth"))?;
    let parts = parts();
    let shapes: Vec<Shape> = parts.iter().map(|p| p.0.clone()).collect();
    let t = Instant::now();
    let frame = Renderer::new(size, size, truth).render(&Scene {
        layer: 1,
        fused: &shapes,
        scanned: true,
        illumination: Illumination::Top,
    });
    eprintln!(
        "rendered {size}x{size} in {:.2} s",
        t.elapsed().as_secs_f64()
    );
    // Clicks: four part corners, off by up to ±6 px.
    let corners = [
        parts[1].1[0][2],
        parts[2].1[0][0],
        parts[3].1[0][1],
        parts[4].1[0][0],
    ];
    let errors = [(5.2, -4.1), (-6.0, 3.3), (4.4, 5.9), (-3.7, -5.5)];
    let mut clicks = Vec::new();
    for (&(x, y), (du, dv)) in corners.iter().zip(errors) {
        let (u, v) = truth_inv
            .apply(x, y)
            .ok_or_else(|| anyhow!("corner beyond the horizon"))?;
        clicks.push(Correspondence {
            image: ImagePoint::new(u + du, v + dv),
            build: BuildPoint::new(x, y),
            line: 0,
        });
    }
    let build_from_image0 = dlt_build_from_image(&clicks, Path::new("clicks"))?;
    let grid = Grid {
        x_min: -half_mm,
        x_max: half_mm,
        y_min: -half_mm,
        y_max: half_mm,
        pixel_mm: 0.0625,
    };
    let build_from_grid = Homography::build_from_grid(&grid);
    let start = build_from_image0
        .inverse()
        .ok_or_else(|| anyhow!("singular start"))?
        .compose(&build_from_grid);
    let truth_warp = Homography::from_matrix(truth_inv.m).compose(&build_from_grid);
    let t = Instant::now();
    let l = layer(&parts);
    let (exemplar, extent_mm) = render_exemplar(&l, &grid, 11, 2, 0x5EED)?;
    let (image, window) = filter_frame(
        &luma_f32(&image::DynamicImage::ImageRgb8(frame)),
        &build_from_image0,
        &grid,
        extent_mm,
        true,
    )?;
    eprintln!(
        "exemplar {}x{} and std-filtered frame (window {:.2} x {:.2} px) in {:.2} s",
        exemplar.width,
        exemplar.height,
        window.0,
        window.1,
        t.elapsed().as_secs_f64()
    );
    let mut contour = Vec::new();
    for (_, rings) in &parts {
        for ring in rings {
            for i in 0..ring.len() {
                let (a, b) = (ring[i], ring[(i + 1) % ring.len()]);
                let steps = ((b.0 - a.0).hypot(b.1 - a.1) / 0.5).ceil().max(1.0) as usize;
                for s in 0..steps {
                    let f = s as f64 / steps as f64;
                    let (x, y) = (a.0 + f * (b.0 - a.0), a.1 + f * (b.1 - a.1));
                    let (r, c) = grid.pixel_of(x, y);
                    contour.extend([c, r]);
                }
            }
        }
    }
    write_npy_f32(&dir.join("image.npy"), &image)?;
    write_npy_f32(&dir.join("exemplar.npy"), &exemplar)?;
    write_npy_f64(&dir.join("contour.npy"), &contour, contour.len() / 2, 2)?;
    write_matrix(&dir.join("start.txt"), &start.matrix())?;
    write_matrix(&dir.join("truth.txt"), &truth_warp.matrix())?;
    eprintln!("wrote {}", dir.display());
    Ok(())
}

fn align_files(dir: &Path, levels: usize, repeat: usize, all_pixels: bool) -> Result<()> {
    let image = read_npy_f32(&dir.join("image.npy"))?;
    let exemplar = read_npy_f32(&dir.join("exemplar.npy"))?;
    let contour = read_npy_f64(&dir.join("contour.npy"))?;
    let start = Homography::from_matrix(read_matrix(&dir.join("start.txt"))?);
    let truth = Homography::from_matrix(read_matrix(&dir.join("truth.txt"))?);
    let mut opts = LmOptions {
        levels: Some(levels),
        ..LmOptions::default()
    };
    if all_pixels {
        // Eq. 7 over every exemplar pixel, as ECC does.
        opts.support_margin_px = None;
    }
    let pair = [Pair {
        image: &image,
        exemplar: &exemplar,
    }];
    let mut best = f64::INFINITY;
    let mut result = None;
    for _ in 0..repeat.max(1) {
        let t = Instant::now();
        let a = align(&pair, start, None, &opts)?;
        best = best.min(t.elapsed().as_secs_f64());
        result = Some(a);
    }
    let a = result.ok_or_else(|| anyhow!("no run"))?;
    let (mean, max) = warp_error(&a.image_from_exemplar, &truth, &contour)?;
    let (mean0, max0) = warp_error(&start, &truth, &contour)?;
    let levels_json: Vec<String> = a
        .levels
        .iter()
        .map(|l| {
            format!(
                "{{\"level\": {}, \"iterations\": {}, \"termination\": \"{}\"}}",
                l.level,
                l.iterations,
                l.termination.name()
            )
        })
        .collect();
    println!(
        "{{\"seconds\": {best:.4}, \"mean_px\": {mean:.5}, \"max_px\": {max:.5}, \
         \"start_mean_px\": {mean0:.4}, \"start_max_px\": {max0:.4}, \"threads\": {}, \
         \"levels\": [{}], \"warp\": {:?}}}",
        rayon::current_num_threads(),
        levels_json.join(", "),
        a.image_from_exemplar.matrix()
    );
    Ok(())
}

fn warp_error(est: &Homography, truth: &Homography, contour: &[f64]) -> Result<(f64, f64)> {
    let (mut sum, mut max, mut n) = (0.0, 0.0f64, 0usize);
    for p in contour.chunks_exact(2) {
        let a = est
            .apply(p[0], p[1])
            .ok_or_else(|| anyhow!("point beyond the horizon"))?;
        let b = truth
            .apply(p[0], p[1])
            .ok_or_else(|| anyhow!("point beyond the horizon"))?;
        let d = (a.0 - b.0).hypot(a.1 - b.1);
        sum += d;
        max = max.max(d);
        n += 1;
    }
    if n == 0 {
        bail!("no contour points");
    }
    Ok((sum / n as f64, max))
}

fn write_matrix(path: &Path, m: &Mat3) -> Result<()> {
    let text: String = m
        .iter()
        .map(|r| format!("{:.17e} {:.17e} {:.17e}\n", r[0], r[1], r[2]))
        .collect();
    std::fs::write(path, text).with_context(|| format!("{}", path.display()))
}

fn read_matrix(path: &Path) -> Result<Mat3> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let v: Vec<f64> = text
        .split_whitespace()
        .map(str::parse)
        .collect::<Result<_, _>>()
        .with_context(|| format!("{}: not numbers", path.display()))?;
    if v.len() != 9 {
        bail!("{}: {} numbers, want 9", path.display(), v.len());
    }
    Ok([[v[0], v[1], v[2]], [v[3], v[4], v[5]], [v[6], v[7], v[8]]])
}

/// NumPy .npy v1.0, little-endian, C order.
fn npy_header(descr: &str, rows: usize, cols: usize) -> Vec<u8> {
    let dict =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': ({rows}, {cols}), }}");
    // Magic (6) + version (2) + length (2) + dict + padding + '\n', a multiple of 64.
    let unpadded = 10 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let len = dict.len() + pad + 1;
    let mut h = b"\x93NUMPY\x01\x00".to_vec();
    h.extend((len as u16).to_le_bytes());
    h.extend(dict.bytes());
    h.extend(std::iter::repeat_n(b' ', pad));
    h.push(b'\n');
    h
}

fn write_npy_f32(path: &Path, img: &F32Image) -> Result<()> {
    let mut bytes = npy_header("<f4", img.height, img.width);
    bytes.reserve(img.data.len() * 4);
    for v in &img.data {
        bytes.extend(v.to_le_bytes());
    }
    std::fs::write(path, bytes).with_context(|| format!("{}", path.display()))
}

fn write_npy_f64(path: &Path, data: &[f64], rows: usize, cols: usize) -> Result<()> {
    let mut bytes = npy_header("<f8", rows, cols);
    for v in data {
        bytes.extend(v.to_le_bytes());
    }
    std::fs::write(path, bytes).with_context(|| format!("{}", path.display()))
}

/// (descr, shape, data) of an .npy file written by numpy or by us (v1/v2, C order, 2-D).
fn read_npy(path: &Path) -> Result<(String, usize, usize, Vec<u8>)> {
    let name = || PathBuf::from(path).display().to_string();
    let bytes = std::fs::read(path).with_context(name)?;
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        bail!("{}: not an .npy file", name());
    }
    let (len, start) = match bytes[6] {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        _ if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => bail!("{}: truncated header", name()),
    };
    let header = std::str::from_utf8(
        bytes
            .get(start..start + len)
            .ok_or_else(|| anyhow!("{}: truncated", name()))?,
    )?;
    if header.contains("'fortran_order': True") {
        bail!("{}: Fortran order is not supported", name());
    }
    let field = |key: &str| -> Result<&str> {
        let i = header
            .find(key)
            .ok_or_else(|| anyhow!("{}: no {key}", name()))?;
        Ok(&header[i + key.len()..])
    };
    let descr = field("'descr': '")?;
    let descr = descr[..descr.find('\'').unwrap_or(0)].to_string();
    let shape = field("'shape': (")?;
    let shape = &shape[..shape.find(')').unwrap_or(0)];
    let dims: Vec<usize> = shape
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::parse)
        .collect::<Result<_, _>>()
        .with_context(|| format!("{}: shape ({shape})", name()))?;
    let [rows, cols] = dims[..] else {
        bail!("{}: shape ({shape}) is not 2-D", name());
    };
    Ok((descr, rows, cols, bytes[start + len..].to_vec()))
}

fn read_npy_f32(path: &Path) -> Result<F32Image> {
    let (descr, rows, cols, data) = read_npy(path)?;
    if descr != "<f4" || data.len() != rows * cols * 4 {
        bail!(
            "{}: want {rows}x{cols} <f4, have {descr} with {} bytes",
            path.display(),
            data.len()
        );
    }
    Ok(F32Image {
        width: cols,
        height: rows,
        data: data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
    })
}

fn read_npy_f64(path: &Path) -> Result<Vec<f64>> {
    let (descr, rows, cols, data) = read_npy(path)?;
    if descr != "<f8" || data.len() != rows * cols * 8 {
        bail!("{}: want {rows}x{cols} <f8, have {descr}", path.display());
    }
    Ok(data
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect())
}
