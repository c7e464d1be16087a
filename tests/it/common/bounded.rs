//! Commands run the way a user runs them, bounded: under an address-space limit (an allocation
//! sized by a wild header aborts the child instead of swapping the machine) and a time limit (a
//! hang fails), for the tests of hostile inputs (bounded_inputs, trusted_files, …).

use super::cli::report;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Address space a refusal may use: far below what any of these headers claims.
pub const MEMORY_LIMIT: u64 = 2 << 30;
/// Time a refusal may take on a loaded CI machine.
pub const TIME_LIMIT: Duration = Duration::from_secs(30);

/// Runs `command` under [`MEMORY_LIMIT`] and [`TIME_LIMIT`] (killed after it: a hang fails).
pub fn bounded(command: &mut Command) -> Output {
    // SAFETY: setrlimit is async-signal-safe; nothing else runs between fork and exec.
    unsafe {
        command.pre_exec(|| {
            let limit = libc::rlimit {
                rlim_cur: MEMORY_LIMIT,
                rlim_max: MEMORY_LIMIT,
            };
            if libc::setrlimit(libc::RLIMIT_AS, &limit) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let started = Instant::now();
    let mut child = command
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("{command:?} did not start: {e}"));
    while child.try_wait().expect("wait").is_none() {
        if started.elapsed() > TIME_LIMIT {
            let _ = child.kill();
            let out = child.wait_with_output().expect("output");
            panic!(
                "{command:?} still ran after {TIME_LIMIT:?}: {}",
                report(&out)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.wait_with_output().expect("output")
}

/// Runs `command` bounded and checks it refused (exit 1) with a message holding every `words`.
pub fn refused(command: &mut Command, words: &[&str]) -> String {
    let out = bounded(command);
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(out.status.code(), Some(1), "{command:?}: {}", report(&out));
    for w in words {
        assert!(
            stderr.contains(w),
            "{command:?}: the message does not name {w:?}: {stderr}"
        );
    }
    assert!(!stderr.contains("panicked"), "{stderr}");
    stderr
}

/// Makes a FIFO at `path` (nothing ever writes to it: a reader that opens it blocking hangs).
pub fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(
        unsafe { libc::mkfifo(c.as_ptr(), 0o600) },
        0,
        "mkfifo {path:?}"
    );
}
