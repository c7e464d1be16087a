//! The soak benchmark's driver (benches/support/soak.rs) on a short build, so it does not rot:
//! 50 layers over a serial pty with a repeated, a skipped and a garbage signal, the disk filled
//! and freed (as root, as CI runs), one `kill -9` and restart. No original lost or overwritten,
//! every injected event journaled. Memory flatness needs the long run: `cargo bench --bench soak`.

#[path = "../../benches/support/soak.rs"]
mod driver;

#[test]
fn soak_driver_short_build_loses_nothing_and_journals_every_injection() {
    let dir = tempfile::tempdir().unwrap();
    let mut options = driver::Options::new(
        env!("CARGO_BIN_EXE_layerwise").into(),
        dir.path().join("soak"),
        50,
    );
    options.kill_every = 25;
    options.window = 25;
    options.inject_every = 12;
    options.fsync = false;
    let report = driver::run(&options);
    let table = report.table();
    assert!(report.data_ok(), "{table}");
    assert_eq!(report.kills, 1, "{table}");
    assert!(
        report.events.iter().all(|(_, want, _)| *want > 0),
        "{table}"
    );
    assert_eq!(report.disk_filled, driver::is_root(), "{table}");
    assert!(report.originals >= 40 * 6, "{table}");
    assert_eq!(report.windows.len(), 2, "{table}");
}
