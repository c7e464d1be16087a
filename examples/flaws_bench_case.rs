//! The benchmark case of benches/peers/flaws_vs_scipy.py: the synthetic parameter cylinder at
//! 50 µm (660 x 646 x 395 u16 voxels, the registration bench's size) with its four internal voids,
//! written as a GE phoenix volume (ct.vol + ct.pcr), ct.toml holding the true transform, and
//! truth.json (the voids in build mm).
//!
//! `cargo run --release --features testkit --example flaws_bench_case -- [out_dir] [voxel_mm]`

use std::path::Path;
use std::time::Instant;

use layerwise::ct::{synth, CtRegistration, CtSource, VoxelData};
use layerwise::geometry::Rigid3;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let out = Path::new(args.get(1).map_or("benches/peers/out", String::as_str)).to_path_buf();
    let voxel: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(0.05);
    std::fs::create_dir_all(&out).expect("out dir");
    let t = Instant::now();
    let (_, scan) = synth::bench_case(voxel);
    let [x, y, z] = scan.volume.dims;
    eprintln!("rendered {x} x {y} x {z} in {:.1?}", t.elapsed());
    let VoxelData::U16(data) = &scan.volume.data else {
        unreachable!("synthetic CTs are u16")
    };
    let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(out.join("ct.vol"), bytes).expect("write ct.vol");
    let pcr = out.join("ct.pcr");
    std::fs::write(
        &pcr,
        format!(
            "[VolumeData]\nVolume_SizeX={x}\nVolume_SizeY={y}\nVolume_SizeZ={z}\nVoxelSizeRec={voxel}\nFormat=5\n"
        ),
    )
    .expect("write ct.pcr");
    let truth = Rigid3::from_matrix(scan.ct_to_build).expect("a rotation");
    let source = CtSource {
        path: std::fs::canonicalize(&pcr)
            .expect("ct.pcr")
            .display()
            .to_string(),
        voxel_mm: None,
        size: None,
        dtype: None,
    };
    let toml = CtRegistration::given(truth, 0.0).to_toml_string_with(Some(source));
    std::fs::write(out.join("ct.toml"), toml).expect("write ct.toml");
    let voids: Vec<serde_json::Value> = scan
        .as_built
        .voids
        .iter()
        .map(|(c, r)| serde_json::json!({"center_mm": c, "radius_mm": r}))
        .collect();
    let case = serde_json::json!({"dims": [x, y, z], "voxel_mm": voxel, "voids": voids});
    std::fs::write(out.join("truth.json"), case.to_string()).expect("write truth.json");
    println!("{}", out.display());
}
