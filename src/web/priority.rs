//! The page runs below capture and processing.

/// The page's threads yield the CPU to capture and processing (nice +10, best effort: the
/// hardened unit's system call filter may refuse it, which changes nothing else).
pub(super) fn lower_priority() {
    // SAFETY: nice() only changes the calling thread's scheduling priority on Linux.
    let _ = unsafe { libc::nice(10) };
}
