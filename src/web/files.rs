//! The page's one way to the disk: every file a route reads (an original, a picture's frame, a
//! calibration overlay) is opened here, by names below the build directory, and only when it
//! is a regular file inside it.
//!
//! - Each folder on the way is opened from the one above it (`openat`) with `O_NOFOLLOW`: a
//!   symbolic link planted as `raw/` or as a frame (to `/etc/passwd`, `../../etc/hostname`,
//!   another build's frame) is refused, never followed, as nginx's `disable_symlinks on` does.
//! - The file is looked at before it is opened (`fstatat` without following): a FIFO, a device
//!   or a folder is refused without an `open`, so it can neither block the server nor have the
//!   side effects opening a device has. The open itself is `O_NONBLOCK | O_NOFOLLOW`, and what
//!   was opened is checked to be the file looked at (device and inode).
//! - Its size is capped by its kind, and the read stops at that cap whatever the file does.

use std::ffi::CString;
use std::fs::File;
use std::io::Read;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

/// The kinds of files the page reads, each with the largest it reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FileKind {
    /// An original frame (JPEG, NEF, TIFF, PNG).
    Frame,
    /// A PNG the calibration page wrote.
    Overlay,
    /// A model's heat map (one grey pixel per tile).
    HeatMap,
}

impl FileKind {
    /// The most bytes read of a file of this kind.
    pub fn limit(self) -> u64 {
        match self {
            // A 60-megapixel raw frame uncompressed at 16 bits is 120 MB.
            FileKind::Frame => 256 << 20,
            FileKind::Overlay => 64 << 20,
            // A tile per pixel: a plate of 500 x 500 mm in 1 mm tiles is 250 kB at most.
            FileKind::HeatMap => 16 << 20,
        }
    }

    fn name(self) -> &'static str {
        match self {
            FileKind::Frame => "frame",
            FileKind::Overlay => "overlay",
            FileKind::HeatMap => "heat map",
        }
    }
}

/// A file the page will not read. Messages name the file relative to the build directory.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    #[error("{path}: not a name inside the build directory")]
    BadName { path: String },
    #[error("{path}: no such file in the build")]
    NotFound { path: String },
    #[error("{path}: a symbolic link; the page serves only files inside the build directory")]
    Link { path: String },
    #[error(
        "{path}: not a regular file (a FIFO, a device or a folder); the page does not read it"
    )]
    NotRegular { path: String },
    #[error("{path}: {size} bytes, more than a {kind} may have ({limit} bytes)")]
    TooLarge {
        path: String,
        kind: &'static str,
        size: u64,
        limit: u64,
    },
    #[error("{path}: cannot read")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
}

impl FileError {
    /// The HTTP answer to a file the page will not read: 404 when it is not there, 403 when it
    /// is there and refused (a link, a FIFO, a device, too large), 500 when it cannot be read.
    pub fn status(&self) -> axum::http::StatusCode {
        use axum::http::StatusCode;
        match self {
            FileError::NotFound { .. } | FileError::BadName { .. } => StatusCode::NOT_FOUND,
            FileError::Link { .. } | FileError::NotRegular { .. } | FileError::TooLarge { .. } => {
                StatusCode::FORBIDDEN
            }
            FileError::Read { .. } => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }

    /// Whether the file is simply not there (else: it is there and refused, or unreadable).
    pub fn is_not_found(&self) -> bool {
        matches!(self, FileError::NotFound { .. })
    }
}

/// A regular file inside the build directory, open for reading, with its size.
pub struct Opened {
    pub file: File,
    pub size: u64,
    pub kind: FileKind,
}

/// A file named by its place below a build directory (`raw/L00002_post_top.jpg`).
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BuildFile {
    build: PathBuf,
    parts: Vec<String>,
}

impl BuildFile {
    pub fn new(build: &Path, parts: &[&str]) -> BuildFile {
        BuildFile {
            build: build.to_path_buf(),
            parts: parts.iter().map(|p| p.to_string()).collect(),
        }
    }

    /// Its name relative to the build directory.
    pub fn name(&self) -> String {
        self.parts.join("/")
    }

    /// Its last component.
    pub fn file_name(&self) -> &str {
        self.parts.last().map_or("", String::as_str)
    }

    /// Its path (for messages and keys; never opened by path).
    pub fn path(&self) -> PathBuf {
        self.parts.iter().fold(self.build.clone(), |p, c| p.join(c))
    }

    pub fn open(&self, kind: FileKind) -> Result<Opened, FileError> {
        open(&self.build, &self.part_refs(), kind)
    }

    pub fn read(&self, kind: FileKind) -> Result<Vec<u8>, FileError> {
        read(&self.build, &self.part_refs(), kind)
    }

    fn part_refs(&self) -> Vec<&str> {
        self.parts.iter().map(String::as_str).collect()
    }
}

/// Opens `build/parts[0]/…/parts[n]` (see the module doc).
pub fn open(build: &Path, parts: &[&str], kind: FileKind) -> Result<Opened, FileError> {
    let path = parts.join("/");
    let (name, folders) = match parts.split_last() {
        Some((name, folders)) if parts.iter().all(|p| is_name(p)) => (*name, folders),
        _ => return Err(FileError::BadName { path }),
    };
    let mut dir: OwnedFd = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_DIRECTORY | libc::O_CLOEXEC)
        .open(build)
        .map_err(|e| FileError::Read {
            path: ".".into(),
            source: e,
        })?
        .into();
    for (i, folder) in folders.iter().enumerate() {
        let so_far = parts[..=i].join("/");
        let seen = fstatat(&dir, folder).map_err(|e| classify(e, &so_far))?;
        match seen.st_mode & libc::S_IFMT {
            libc::S_IFDIR => {}
            libc::S_IFLNK => return Err(FileError::Link { path: so_far }),
            _ => return Err(FileError::NotRegular { path: so_far }),
        }
        dir = openat(
            &dir,
            folder,
            libc::O_RDONLY | libc::O_DIRECTORY | libc::O_NOFOLLOW | libc::O_CLOEXEC,
        )
        .map_err(|e| classify(e, &so_far))?;
    }
    let seen = fstatat(&dir, name).map_err(|e| classify(e, &path))?;
    match seen.st_mode & libc::S_IFMT {
        libc::S_IFREG => {}
        libc::S_IFLNK => return Err(FileError::Link { path }),
        _ => return Err(FileError::NotRegular { path }),
    }
    let fd = openat(
        &dir,
        name,
        libc::O_RDONLY | libc::O_NOFOLLOW | libc::O_NONBLOCK | libc::O_NOCTTY | libc::O_CLOEXEC,
    )
    .map_err(|e| classify(e, &path))?;
    let file = File::from(fd);
    let meta = fstat(&file).map_err(|e| classify(e, &path))?;
    // Replaced between the look and the open: refused like what it became.
    if meta.st_mode & libc::S_IFMT != libc::S_IFREG
        || (meta.st_dev, meta.st_ino) != (seen.st_dev, seen.st_ino)
    {
        return Err(FileError::NotRegular { path });
    }
    let size = meta.st_size.max(0) as u64;
    if size > kind.limit() {
        return Err(FileError::TooLarge {
            path,
            kind: kind.name(),
            size,
            limit: kind.limit(),
        });
    }
    // Reads of a regular file never block; back to blocking mode all the same.
    // SAFETY: fcntl on a descriptor this function owns.
    unsafe {
        let flags = libc::fcntl(file.as_raw_fd(), libc::F_GETFL);
        if flags >= 0 {
            libc::fcntl(file.as_raw_fd(), libc::F_SETFL, flags & !libc::O_NONBLOCK);
        }
    }
    Ok(Opened { file, size, kind })
}

/// Reads `build/parts…` whole (see [`open`]), at most its kind's limit.
pub fn read(build: &Path, parts: &[&str], kind: FileKind) -> Result<Vec<u8>, FileError> {
    let opened = open(build, parts, kind)?;
    let path = parts.join("/");
    let limit = kind.limit();
    let mut bytes = Vec::with_capacity(opened.size.min(limit) as usize);
    opened
        .file
        .take(limit + 1)
        .read_to_end(&mut bytes)
        .map_err(|source| FileError::Read {
            path: path.clone(),
            source,
        })?;
    if bytes.len() as u64 > limit {
        // It grew past the limit while being read.
        return Err(FileError::TooLarge {
            path,
            kind: kind.name(),
            size: bytes.len() as u64,
            limit,
        });
    }
    Ok(bytes)
}

/// What is read of a streamed file at a time.
const CHUNK: u64 = 64 * 1024;

/// An opened file as a response body, read [`CHUNK`] bytes at a time on the blocking pool, up to
/// the size it had when opened: a download holds one chunk in memory, however large the file.
pub fn stream(opened: Opened) -> axum::body::Body {
    let chunks = futures_util::stream::unfold(
        (Some(opened.file), opened.size),
        |(file, left)| async move {
            let mut file = file.filter(|_| left > 0)?;
            let want = left.min(CHUNK) as usize;
            let read = tokio::task::spawn_blocking(move || {
                let mut buf = vec![0; want];
                let n = file.read(&mut buf)?;
                buf.truncate(n);
                Ok::<_, std::io::Error>((file, buf))
            })
            .await
            .map_err(std::io::Error::other)
            .and_then(|r| r);
            match read {
                Ok((_, buf)) if buf.is_empty() => None,
                Ok((file, buf)) => {
                    let left = left - buf.len() as u64;
                    Some((Ok(axum::body::Bytes::from(buf)), (Some(file), left)))
                }
                Err(e) => Some((Err(e), (None, 0))),
            }
        },
    );
    axum::body::Body::from_stream(chunks)
}

/// Whether a folder below the build directory is a real folder (not a link, not missing).
pub fn is_real_folder(build: &Path, name: &str) -> bool {
    is_name(name)
        && std::fs::symlink_metadata(build.join(name)).is_ok_and(|m| m.file_type().is_dir())
}

/// One component of a path: not empty, not `.` or `..`, no `/` and no NUL.
fn is_name(part: &str) -> bool {
    !part.is_empty() && part != "." && part != ".." && !part.contains(['/', '\0'])
}

fn classify(e: std::io::Error, path: &str) -> FileError {
    let path = path.to_string();
    match e.raw_os_error() {
        Some(libc::ENOENT) => FileError::NotFound { path },
        // O_NOFOLLOW on a link: ELOOP; O_DIRECTORY on a link to a file: ENOTDIR.
        Some(libc::ELOOP) => FileError::Link { path },
        Some(libc::ENOTDIR) => FileError::NotRegular { path },
        _ => FileError::Read { path, source: e },
    }
}

fn c_name(name: &str) -> std::io::Result<CString> {
    CString::new(name).map_err(|_| std::io::Error::from(std::io::ErrorKind::InvalidInput))
}

fn openat(dir: &OwnedFd, name: &str, flags: libc::c_int) -> std::io::Result<OwnedFd> {
    let name = c_name(name)?;
    // SAFETY: a valid directory descriptor and a NUL-terminated name; the result is owned here.
    let fd = unsafe { libc::openat(dir.as_raw_fd(), name.as_ptr(), flags) };
    if fd < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: openat returned a new descriptor nobody else owns.
    Ok(unsafe { OwnedFd::from_raw_fd(fd) })
}

fn fstatat(dir: &OwnedFd, name: &str) -> std::io::Result<libc::stat> {
    let name = c_name(name)?;
    // SAFETY: zeroed stat is a valid value to be overwritten; valid descriptor and name.
    unsafe {
        let mut stat: libc::stat = std::mem::zeroed();
        if libc::fstatat(
            dir.as_raw_fd(),
            name.as_ptr(),
            &mut stat,
            libc::AT_SYMLINK_NOFOLLOW,
        ) != 0
        {
            return Err(std::io::Error::last_os_error());
        }
        Ok(stat)
    }
}

fn fstat(file: &File) -> std::io::Result<libc::stat> {
    // SAFETY: as fstatat, on a descriptor `file` owns.
    unsafe {
        let mut stat: libc::stat = std::mem::zeroed();
        if libc::fstat(file.as_raw_fd(), &mut stat) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok(stat)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    fn build() -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("raw")).unwrap();
        std::fs::write(dir.path().join("raw/L00001_post_top.jpg"), b"frame").unwrap();
        dir
    }

    #[test]
    fn a_regular_file_inside_the_build_is_read() {
        let dir = build();
        let bytes = read(dir.path(), &["raw", "L00001_post_top.jpg"], FileKind::Frame).unwrap();
        assert_eq!(bytes, b"frame");
        let missing = read(dir.path(), &["raw", "L00002_post_top.jpg"], FileKind::Frame);
        assert!(missing.unwrap_err().is_not_found());
    }

    #[test]
    fn links_fifos_devices_folders_and_odd_names_are_refused() {
        let dir = build();
        let raw = dir.path().join("raw");
        symlink("/etc/passwd", raw.join("passwd.jpg")).unwrap();
        symlink("../../etc/hostname", raw.join("hostname.jpg")).unwrap();
        symlink("/dev/zero", raw.join("zero.jpg")).unwrap();
        let fifo = CString::new(raw.join("fifo.jpg").to_str().unwrap()).unwrap();
        // SAFETY: a NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
        std::fs::create_dir(raw.join("folder.jpg")).unwrap();
        let read_raw = |name: &str| read(dir.path(), &["raw", name], FileKind::Frame);
        for name in ["passwd.jpg", "hostname.jpg", "zero.jpg"] {
            assert!(
                matches!(read_raw(name), Err(FileError::Link { .. })),
                "{name}"
            );
        }
        for name in ["fifo.jpg", "folder.jpg"] {
            assert!(
                matches!(read_raw(name), Err(FileError::NotRegular { .. })),
                "{name}"
            );
        }
        for parts in [&["raw", ".."][..], &["..", "etc"], &["raw/x"], &[], &[""]] {
            assert!(
                matches!(
                    read(dir.path(), parts, FileKind::Frame),
                    Err(FileError::BadName { .. })
                ),
                "{parts:?}"
            );
        }
        // raw/ itself a link to another build's frames.
        let other = build();
        let linked = tempfile::tempdir().unwrap();
        symlink(other.path().join("raw"), linked.path().join("raw")).unwrap();
        assert!(matches!(
            read(
                linked.path(),
                &["raw", "L00001_post_top.jpg"],
                FileKind::Frame
            ),
            Err(FileError::Link { .. })
        ));
        assert!(!is_real_folder(linked.path(), "raw"));
        assert!(is_real_folder(other.path(), "raw"));
    }

    #[test]
    fn files_beyond_their_kind_limit_are_refused_before_reading() {
        let dir = build();
        let big = std::fs::File::create(dir.path().join("raw/big.png")).unwrap();
        big.set_len(FileKind::Overlay.limit() + 1).unwrap();
        assert!(matches!(
            read(dir.path(), &["raw", "big.png"], FileKind::Overlay),
            Err(FileError::TooLarge { .. })
        ));
        // A frame may be that large (sparse: nothing is read here).
        assert!(open(dir.path(), &["raw", "big.png"], FileKind::Frame).is_ok());
    }
}
