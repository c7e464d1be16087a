//! This process's peak resident memory, for benches that report what a step costs in memory.
//! (Each bench uses what it reports.)
#![allow(dead_code)]

/// Forgets the peak so far (Linux `clear_refs` 5): the next [`peak_rss_kib`] is the peak from here.
pub fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// This process's peak resident memory (VmHWM), KiB; 0 where /proc does not say.
pub fn peak_rss_kib() -> u64 {
    status_kib("VmHWM:")
}

/// This process's resident memory now (VmRSS), KiB; 0 where /proc does not say.
pub fn current_rss_kib() -> u64 {
    status_kib("VmRSS:")
}

/// A `kB` line of /proc/self/status.
fn status_kib(field: &str) -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix(field))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}
