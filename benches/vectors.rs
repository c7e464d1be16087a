//! Read throughput of CLI vector files: a generated 1,000-layer file with 10^7 hatch segments,
//! ASCII and binary, through `read` (whole file), `LayerReader` (streaming) and `info`.
//! `cargo bench --bench vectors`; LAYERWISE_BENCH_HATCHES sets hatches per layer (default 10,000).

use layerwise::vectors::{self, synth, LayerReader};
use std::time::Instant;

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let per_layer: usize = std::env::var("LAYERWISE_BENCH_HATCHES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(if full { 10_000 } else { 100 });
    let layers = if full { 1000 } else { 10 };
    let file = synth::generate(layers, per_layer, 64);
    let dir = tempfile::tempdir().expect("tempdir");
    for (name, binary) in [("ascii", false), ("binary", true)] {
        let path = dir.path().join(format!("bench_{name}.cli"));
        {
            let mut out = std::io::BufWriter::new(std::fs::File::create(&path).expect("create"));
            if binary {
                vectors::write_binary(&file, &mut out).expect("write");
            } else {
                vectors::write_ascii(&file, &mut out).expect("write");
            }
        }
        let mb = std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0) as f64 / 1e6;
        let rate = |label: &str, f: &dyn Fn()| {
            let mut best = f64::MAX;
            for _ in 0..3 {
                let t = Instant::now();
                f();
                best = best.min(t.elapsed().as_secs_f64());
            }
            println!(
                "{name:<6} {label:<12} {mb:>8.1} MB  {:>7.0} MB/s",
                mb / best
            );
        };
        rate("read", &|| {
            vectors::read(&path).expect("read");
        });
        rate("LayerReader", &|| {
            let mut reader = LayerReader::open(&path).expect("open");
            while reader.next_layer().expect("layer").is_some() {}
        });
        rate("info", &|| {
            vectors::info(&path).expect("info");
        });
    }
    println!("({layers} layers x {per_layer} hatch segments; files in the page cache)");
}
