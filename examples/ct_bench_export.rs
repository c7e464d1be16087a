//! The 50 µm benchmark case for benches/peers/ct_vs_simpleitk.py: renders the synthetic parameter
//! cylinder, writes the CT and the rasterised nominal part (the vectors as a volume) as .mha,
//! runs our registration from the 3-point start and writes everything to case.json.
//!
//! `cargo run --release --example ct_bench_export -- [out_dir] [voxel_mm]`

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use layerwise::ct::{self, synth, CtParams, InitialTransform, VoxelData};

fn write_mha(
    path: &Path,
    dims: [usize; 3],
    spacing: f64,
    origin: [f64; 3],
    element: &str,
    bytes: &[u8],
) {
    let mut f = std::io::BufWriter::new(std::fs::File::create(path).expect("create mha"));
    write!(
        f,
        "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n\
         CompressedData = False\nTransformMatrix = 1 0 0 0 1 0 0 0 1\nOffset = {} {} {}\n\
         CenterOfRotation = 0 0 0\nElementSpacing = {spacing} {spacing} {spacing}\n\
         DimSize = {} {} {}\nElementType = {element}\nElementDataFile = LOCAL\n",
        origin[0], origin[1], origin[2], dims[0], dims[1], dims[2]
    )
    .expect("mha header");
    f.write_all(bytes).expect("mha data");
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let out = Path::new(
        args.get(1)
            .map(String::as_str)
            .unwrap_or("benches/peers/out"),
    )
    .to_path_buf();
    let voxel: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(0.05);
    std::fs::create_dir_all(&out).expect("out dir");

    let t = Instant::now();
    let (part, scan) = synth::bench_case(voxel);
    eprintln!("rendered {:?} in {:.1?}", scan.volume.dims, t.elapsed());
    let VoxelData::U16(data) = &scan.volume.data else {
        unreachable!("synthetic CTs are u16")
    };
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_mha(
        &out.join("ct.mha"),
        scan.volume.dims,
        voxel,
        [0.0; 3],
        "MET_USHORT",
        &bytes,
    );

    // The vectors as a volume: a binary raster of the nominal part at the CT's voxel size.
    let (lo, hi) = part.bounds();
    let pad = 1.0;
    let origin = lo.map(|v| v - pad);
    let dims: [usize; 3] =
        std::array::from_fn(|a| ((hi[a] - lo[a] + 2.0 * pad) / voxel).ceil() as usize);
    let mut mask = vec![0u8; dims.iter().product()];
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let p = [
                    origin[0] + x as f64 * voxel,
                    origin[1] + y as f64 * voxel,
                    origin[2] + z as f64 * voxel,
                ];
                mask[x + dims[0] * (y + dims[1] * z)] = u8::from(part.sdf(p) < 0.0);
            }
        }
    }
    write_mha(
        &out.join("nominal.mha"),
        dims,
        voxel,
        origin,
        "MET_UCHAR",
        &mask,
    );

    // Ours: the TSDF is an input (like the raster is SimpleITK's), so it is built untimed.
    let field = synth::GridField::from_sdf(|p| part.sdf(p), lo, hi, voxel.min(0.1), 1.0);
    let nominal = synth::nominal_shape(&part, 0.1);
    let pairs = synth::landmark_pairs(&scan, 3, 0.3, 7);
    let start = *ct::horn(&pairs).expect("horn").matrix();
    let center_build = [40.0, -25.0, 5.0];
    let r = scan.ct_to_build;
    let center_ct: [f64; 3] = {
        let d: [f64; 3] = std::array::from_fn(|a| center_build[a] - r[a][3]);
        std::array::from_fn(|j| (0..3).map(|i| r[i][j] * d[i]).sum())
    };
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t = Instant::now();
        let reg = ct::register(
            &scan.volume,
            &field,
            &nominal,
            &InitialTransform::Points(pairs.clone()),
            &CtParams::default(),
        )
        .expect("register");
        times.push(t.elapsed().as_secs_f64());
        last = Some(reg.registration);
    }
    times.sort_by(f64::total_cmp);
    let reg = last.expect("ran");
    let (a0, d0) = synth::transform_error(&start, &scan.ct_to_build, center_ct);
    let (a, d) = synth::transform_error(reg.build_from_ct.matrix(), &scan.ct_to_build, center_ct);
    eprintln!(
        "ours: {:.2} s (median of 3), rotation error {a:.5}°, displacement {:.3} µm",
        times[1],
        d * 1e3
    );
    let case = serde_json::json!({
        "voxel_mm": voxel,
        "ct_dims": scan.volume.dims,
        "nominal_dims": dims,
        "truth_ct_to_build": scan.ct_to_build,
        "start_ct_to_build": start,
        "center_build_mm": center_build,
        "center_ct_mm": center_ct,
        "start_error": { "rotation_deg": a0, "displacement_um": d0 * 1e3 },
        "ours": {
            "seconds": times[1],
            "seconds_all": times,
            "rotation_error_deg": a,
            "displacement_um": d * 1e3,
            "iterations": reg.iterations,
            "mean_abs_um": reg.mean_abs_um,
            "points_used": reg.points_used,
            "threads": rayon::current_num_threads(),
        },
    });
    std::fs::write(
        out.join("case.json"),
        serde_json::to_string_pretty(&case).expect("json"),
    )
    .expect("case.json");
}
