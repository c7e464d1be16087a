//! The build directory's readers given the same bytes as each of their files: shared by the
//! `journal` fuzz target and tests/it/fuzz_smoke.rs, so both fuzz the same list.

use layerwise::build_dir::{alarm, inspection, lifecycle, pushlog, status, Journal};
use std::path::Path;

/// Writes `data` in `dir` as the journal, status.json, build.json, alarm.jsonl,
/// inspection.jsonl, current-build.toml and a push log, and reads each as `layerwise` does.
pub fn read_all(dir: &Path, data: &[u8]) {
    for name in [
        "journal.jsonl",
        "status.json",
        "build.json",
        "alarm.jsonl",
        "inspection.jsonl",
        lifecycle::CURRENT,
        "push.jsonl",
    ] {
        std::fs::write(dir.join(name), data).expect("scratch file");
    }
    let _ = Journal::read(&dir.join("journal.jsonl"));
    let _ = status::report(dir, status::ReportSettings::default());
    let _ = alarm::state(dir);
    let _ = inspection::InspectionLog::read(&dir.join("inspection.jsonl"));
    let _ = lifecycle::current(dir);
    let _ = pushlog::read(&dir.join("push.jsonl"));
}
