//! The soak benchmark (run with `cargo bench --bench soak`): the release `layerwise run` through
//! a 10,000-layer mock build (64x43 frames, originals, fsync on) fed over a serial pty, with a
//! repeated, a skipped and a garbage signal every 300 layers, the build disk (a tmpfs, when run
//! as root) filled for 3 layers and freed, and a `kill -9` plus restart every 1,000 layers.
//! Prints a table: originals lost or overwritten, injected events journaled, RSS per 1,000-layer
//! window (first vs last within 10 %); exits 1 if a criterion fails.
//!
//! `LAYERWISE_SOAK_LAYERS` shortens it (kills, injections and windows scale down below 2,000
//! layers); `LAYERWISE_SOAK_DIR` keeps the build and the daemon's log there.

#[path = "support/soak.rs"]
mod soak;

fn main() {
    let layers: u32 = std::env::var("LAYERWISE_SOAK_LAYERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000)
        .max(20);
    let temp = tempfile::tempdir().expect("tempdir");
    let work = std::env::var_os("LAYERWISE_SOAK_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| temp.path().join("soak"));
    let mut options = soak::Options::new(env!("CARGO_BIN_EXE_layerwise").into(), work, layers);
    if layers < 2000 {
        options.kill_every = (layers / 4).max(10);
        options.window = options.kill_every;
        options.inject_every = (layers / 5).clamp(6, 300);
    }
    eprintln!(
        "soak: {layers} layers, kill -9 every {}, injections every {}, disk fill {}",
        options.kill_every,
        options.inject_every,
        if options.fill_disk {
            "on"
        } else {
            "off (not root)"
        }
    );
    let report = soak::run(&options);
    println!("{}", report.table());
    if !report.passed() {
        eprintln!("soak: FAILED");
        std::process::exit(1);
    }
}
