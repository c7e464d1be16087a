//! The settings of the page's own process (`layerwise serve`, and the daemon's page process):
//! its memory bound, broken pipes, and how many connections its file descriptors allow.

use tracing::warn;

/// File descriptors kept for what is not a connection (frames, the journal, the runtime).
const SPARE_DESCRIPTORS: u64 = 64;

/// Bounds the process's address space to `mb` MiB (`RLIMIT_AS`, through `prlimit`: the system
/// call systemd's `@system-service` filter allows): an allocation beyond it fails, and an
/// allocation that fails ends the process (Rust aborts), never the machine's memory. Only
/// system calls: safe in a child between fork and exec. Returns the error number on failure.
pub fn limit_memory(mb: u64) -> Result<(), i32> {
    let bytes = mb.saturating_mul(1 << 20);
    let limit = libc::rlimit {
        rlim_cur: bytes,
        rlim_max: bytes,
    };
    // SAFETY: prlimit on this process (pid 0) with a valid new limit and no old-limit pointer.
    let done = unsafe { libc::prlimit(0, libc::RLIMIT_AS, &limit, std::ptr::null_mut()) };
    if done == 0 {
        Ok(())
    } else {
        // SAFETY: errno of this thread.
        Err(unsafe { *libc::__errno_location() })
    }
}

/// A page process: writes to a client that went away are errors, not SIGPIPE (the binary keeps
/// the default disposition for its pipes), and the file descriptors allow the connections.
pub fn prepare_page_process() {
    // SAFETY: ignoring SIGPIPE changes no memory; called before the server's threads start.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    raise_descriptor_limit();
}

/// The soft limit of open files raised to the hard one (as systemd advises for services that
/// need many), at most 65536.
fn raise_descriptor_limit() {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: prlimit reading this process's limit into `limit`.
    if unsafe { libc::prlimit(0, libc::RLIMIT_NOFILE, std::ptr::null(), &mut limit) } != 0 {
        return;
    }
    let wanted = limit.rlim_max.min(65_536);
    if wanted > limit.rlim_cur {
        let raised = libc::rlimit {
            rlim_cur: wanted,
            rlim_max: limit.rlim_max,
        };
        // SAFETY: as above, setting a soft limit within the hard one.
        unsafe { libc::prlimit(0, libc::RLIMIT_NOFILE, &raised, std::ptr::null_mut()) };
    }
}

/// Names the process's main thread `layerwise-page` (`top`, `ps -o comm`).
pub fn name_page_process() {
    // SAFETY: PR_SET_NAME with a NUL-terminated name of at most 16 bytes.
    unsafe {
        libc::prctl(libc::PR_SET_NAME, c"layerwise-page".as_ptr());
    }
}

/// Makes this process the kernel's first choice when the machine runs out of memory
/// (`oom_score_adj` 500, as systemd's `OOMScoreAdjust=`; raising it needs no privilege): the
/// page goes before the daemon that captures. Best effort.
pub fn prefer_for_oom_kill() {
    let _ = std::fs::write("/proc/self/oom_score_adj", "500");
}

/// `wanted` connections, or fewer when the process's open-file limit leaves room for fewer
/// (then said once in the log).
pub fn connection_room(wanted: usize) -> usize {
    let mut limit = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: prlimit reading this process's limit into `limit`.
    if unsafe { libc::prlimit(0, libc::RLIMIT_NOFILE, std::ptr::null(), &mut limit) } != 0 {
        return wanted;
    }
    let room = limit.rlim_cur.saturating_sub(SPARE_DESCRIPTORS).max(8);
    if (wanted as u64) <= room {
        return wanted;
    }
    warn!(
        wanted,
        room,
        "web.max_connections is more than the open-file limit allows (LimitNOFILE=): serving at most {room}"
    );
    room as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connections_fit_the_open_file_limit() {
        assert_eq!(connection_room(8), 8);
        assert!(connection_room(usize::MAX) < usize::MAX);
    }
}
