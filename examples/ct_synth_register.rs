//! Render the synthetic parameter cylinder and register it; prints the errors.
//! `cargo run --release --example ct_synth_register -- [voxel_mm] [angle_deg] [start: points|centroid]`
use std::time::Instant;

use layerwise::ct::{self, synth, CtParams, InitialTransform};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let voxel: f64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(0.1);
    let angle: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(25.0);
    let start = args.get(3).map(String::as_str).unwrap_or("points");
    let huber: Option<f64> = args.get(4).and_then(|s| s.parse().ok());
    let part = synth::Part::parameter_cylinder([40.0, -25.0, 0.0], 1.0);
    let spec = synth::SynthSpec {
        voxel_mm: voxel,
        angle_deg: angle,
        reflections: huber.is_some(),
        ..Default::default()
    };
    let t = Instant::now();
    let ct = synth::render(&part, &spec);
    println!("render {:?}: dims {:?}", t.elapsed(), ct.volume.dims);
    let t = Instant::now();
    let (lo, hi) = part.bounds();
    let field = synth::GridField::from_sdf(|p| part.sdf(p), lo, hi, voxel.min(0.1), 1.0);
    let nominal = synth::nominal_shape(&part, 0.1);
    println!("field+nominal {:?}", t.elapsed());
    let init = match start {
        "centroid" => InitialTransform::Centroid,
        _ => InitialTransform::Points(synth::landmark_pairs(&ct, 3, 0.3, 7)),
    };
    let params = CtParams {
        huber_k_mm: huber,
        ..Default::default()
    };
    let t = Instant::now();
    let res = ct::register(&ct.volume, &field, &nominal, &init, &params);
    println!("register {:?}", t.elapsed());
    match res {
        Ok(r) => {
            let reg = &r.registration;
            let (ang, disp) = synth::transform_error(
                reg.build_from_ct.matrix(),
                &ct.ct_to_build,
                ct_centroid(&ct),
            );
            println!("{}", reg.to_toml_string());
            println!(
                "rotation error {:.5} deg, displacement at centroid {:.3} um",
                ang,
                disp * 1e3
            );
        }
        Err(e) => println!("error: {e}"),
    }
}

fn ct_centroid(ct: &synth::SynthCt) -> [f64; 3] {
    let d = ct.volume.dims;
    let h = ct.volume.voxel_mm[0];
    [
        d[0] as f64 * h / 2.0,
        d[1] as f64 * h / 2.0,
        d[2] as f64 * h / 2.0,
    ]
}
