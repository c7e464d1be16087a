//! A small tmpfs in a private mount namespace, as a build disk a test or a benchmark can fill
//! without touching the host's (needs root): tests/it/disk.rs and the soak benchmark.

use std::path::Path;

/// Moves the calling thread (and what it starts) into a private mount namespace with a tmpfs of
/// `mb` MiB at `at`.
pub fn mount(at: &Path, mb: u64) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let c = |s: &[u8]| CString::new(s).map_err(std::io::Error::other);
    let check = |rc: i32| {
        if rc == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    };
    // SAFETY: unshare only changes the calling thread's namespaces.
    check(unsafe { libc::unshare(libc::CLONE_NEWNS) })?;
    let (root, none) = (c(b"/")?, c(b"none")?);
    // SAFETY: valid NUL-terminated strings; no data argument.
    check(unsafe {
        libc::mount(
            none.as_ptr(),
            root.as_ptr(),
            std::ptr::null(),
            libc::MS_REC | libc::MS_PRIVATE,
            std::ptr::null(),
        )
    })?;
    std::fs::create_dir_all(at)?;
    let (target, tmpfs) = (c(at.as_os_str().as_bytes())?, c(b"tmpfs")?);
    let options = c(format!("size={mb}m").as_bytes())?;
    // SAFETY: valid NUL-terminated strings.
    check(unsafe {
        libc::mount(
            tmpfs.as_ptr(),
            target.as_ptr(),
            tmpfs.as_ptr(),
            0,
            options.as_ptr().cast(),
        )
    })
}

pub fn unmount(at: &Path) {
    use std::os::unix::ffi::OsStrExt;
    if let Ok(target) = std::ffi::CString::new(at.as_os_str().as_bytes()) {
        // SAFETY: a valid NUL-terminated path.
        unsafe { libc::umount2(target.as_ptr(), libc::MNT_DETACH) };
    }
}
