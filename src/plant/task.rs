//! The plant interfaces' threads: each a small tokio runtime of its own, below capture and
//! processing in priority (nice +10), so no broker or client can take time from the capture
//! path; and the machine's name they announce.

use std::future::Future;
use tokio::runtime::Runtime;

/// A current-thread runtime for the thread named `name` (enter it to build what must be made
/// inside a runtime, then hand it to [`spawn_on`]).
pub fn runtime(name: &str) -> std::io::Result<Runtime> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .max_blocking_threads(2)
        .thread_name(name)
        .build()
}

/// Runs `future` to its end on a new thread named `name` with a current-thread runtime.
pub fn spawn(
    name: &str,
    future: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    spawn_on(runtime(name)?, name, future)
}

/// Runs `future` to its end on a new thread named `name` with `runtime`.
pub fn spawn_on(
    runtime: Runtime,
    name: &str,
    future: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name(name.to_string())
        .spawn(move || {
            // SAFETY: nice() only changes the calling thread's scheduling priority on Linux
            // (best effort: the hardened unit's system call filter may refuse it).
            let _ = unsafe { libc::nice(10) };
            runtime.block_on(future);
            runtime.shutdown_timeout(std::time::Duration::from_millis(200));
        })
}

/// This machine's name (MQTT's default client id, the OPC UA server's application URI).
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "host".into())
}
