//! File-system helpers every writer and reader of the library shares: atomic writes (a crash
//! leaves the whole file or nothing under the final name), SHA-256 of file contents, and TOML
//! files parsed with errors that name the file, the line and the key.

mod identity;
mod pending;
mod writeback;

pub use identity::FileIdentity;
pub use pending::{write_pending_with, Pending};
pub use writeback::WriteBehind;

use sha2::{Digest, Sha256};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// A file could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path} (is the disk full or read-only?)")]
pub struct WriteError {
    pub path: PathBuf,
    #[source]
    pub source: std::io::Error,
}

/// A text file that is not UTF-8: the cause of [`read_text_bounded`]'s `InvalidData` error.
#[derive(Debug, thiserror::Error)]
#[error("not UTF-8 text")]
pub struct NotUtf8(#[source] pub std::string::FromUtf8Error);

/// A TOML file could not be parsed into what it should hold. The message is composed from the
/// parser's own (line, column, key and what went wrong, on one line): the parser's `Display`
/// quotes the file over several lines, so it is not kept as a source.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct TomlError {
    pub file: PathBuf,
    /// Where (line, column, key) and what went wrong.
    pub message: String,
}

/// A TOML file (a configuration, a calibration) that could not be used: unreadable, not valid
/// TOML of the expected shape, or a value that fails its check.
#[derive(Debug, thiserror::Error)]
pub enum TomlFileError {
    #[error("{file}: cannot read")]
    Read {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    Parse(#[from] TomlError),
    #[error("{file}: key `{key}`: {message}")]
    Invalid {
        file: PathBuf,
        key: String,
        message: String,
    },
}

/// Lower-case hexadecimal SHA-256 of `data`.
pub fn sha256_hex(data: &[u8]) -> String {
    let digest = Sha256::digest(data);
    let mut out = String::with_capacity(64);
    for b in digest {
        out.push_str(&format!("{b:02x}"));
    }
    out
}

/// Writes `data` under `path` atomically: a fresh temporary file in the same directory, fsync
/// (when `fsync`), rename, fsync of the directory.
pub fn write_atomic(path: &Path, data: &[u8], fsync: bool) -> Result<(), WriteError> {
    write_atomic_all(&[(path, data)], fsync)
}

/// The directory a file is in; "." for a bare file name (whose `parent()` is the empty path,
/// which cannot be opened to fsync).
pub fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    }
}

/// Whether a directory entry is one of our temporary files (`.NAME.*.tmp`), left by a crash.
pub fn is_temporary(name: &str) -> bool {
    name.starts_with('.') && name.ends_with(".tmp")
}

/// The process id a temporary file's name (`.NAME.PID.N.tmp`) carries, if it is one of ours.
fn temporary_pid(name: &str) -> Option<i32> {
    if !is_temporary(name) {
        return None;
    }
    let mut parts = name.trim_end_matches(".tmp").rsplit('.');
    let _n: u64 = parts.next()?.parse().ok()?;
    parts.next()?.parse().ok()
}

/// Removes the temporary files in `dir` that a process which no longer runs left (a kill -9
/// between writing and renaming): ours by their name (`.NAME.PID.N.tmp`), regular files only,
/// never a link; those of a process still running are its own to finish. Returns their names.
pub fn remove_stale_temporaries(dir: &Path) -> std::io::Result<Vec<String>> {
    let mut removed = Vec::new();
    let entries = match std::fs::read_dir(dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(removed),
        Err(e) => return Err(e),
    };
    for entry in entries {
        let entry = entry?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(pid) = temporary_pid(&name) else {
            continue;
        };
        if !entry.file_type()?.is_file() || process_runs(pid) {
            continue;
        }
        match std::fs::remove_file(entry.path()) {
            Ok(()) => removed.push(name),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e),
        }
    }
    Ok(removed)
}

/// Whether process `pid` exists (another user's too). This process counts as not running: a
/// restart looks before it writes there, and a daemon that is PID 1 in its container has the
/// same id as the one killed before it.
fn process_runs(pid: i32) -> bool {
    if pid <= 0 || pid as u32 == std::process::id() {
        return false;
    }
    // SAFETY: kill with signal 0 sends nothing; it only checks that the process exists.
    let result = unsafe { libc::kill(pid, 0) };
    result == 0 || std::io::Error::last_os_error().raw_os_error() != Some(libc::ESRCH)
}

/// Creates a new temporary file next to `path`: `.NAME.PID.N.tmp`, opened with `O_EXCL` and
/// `O_NOFOLLOW`, so a file or symlink planted under that name is never written through.
fn create_temporary(path: &Path) -> std::io::Result<(PathBuf, File)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = parent_dir(path);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let tmp = dir.join(format!(".{name}.{}.{n}.tmp", std::process::id()));
        match OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(0o644)
            .custom_flags(libc::O_NOFOLLOW | libc::O_CLOEXEC)
            .open(&tmp)
        {
            Ok(file) => return Ok((tmp, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Writes files of one directory atomically, renaming them in the order given, with a single
/// fsync of the directory for all the renames (it is the slowest part of the capture path).
pub fn write_atomic_all(files: &[(&Path, &[u8])], fsync: bool) -> Result<(), WriteError> {
    let writes = files
        .iter()
        .map(|(path, data)| (*path, move |w: &mut WriteBehind<'_>| w.write_all(data)));
    write_atomic_each(writes, fsync)
}

/// [`write_atomic_all`] with each file's content written by its function. Files to be fsynced
/// are written behind ([`WriteBehind`]): a frame's original or a slice goes to disk while its
/// last MiBs are still being written, so the fsync waits for the tail only.
fn write_atomic_each<'p, W: FnOnce(&mut WriteBehind<'_>) -> std::io::Result<()>>(
    files: impl ExactSizeIterator<Item = (&'p Path, W)>,
    fsync: bool,
) -> Result<(), WriteError> {
    let mut renames = Vec::with_capacity(files.len());
    let cleanup = |renames: &[(PathBuf, &Path)]| {
        for (tmp, _) in renames {
            let _ = std::fs::remove_file(tmp);
        }
    };
    for (path, write) in files {
        let err = |source| WriteError {
            path: path.to_path_buf(),
            source,
        };
        let written = create_temporary(path).and_then(|(tmp, file)| {
            let result = write(&mut WriteBehind::new(&file, fsync)).and_then(|()| {
                if fsync {
                    file.sync_data()
                } else {
                    Ok(())
                }
            });
            match result {
                Ok(()) => Ok(tmp),
                Err(e) => {
                    let _ = std::fs::remove_file(&tmp);
                    Err(e)
                }
            }
        });
        match written {
            Ok(tmp) => renames.push((tmp, path)),
            Err(e) => {
                cleanup(&renames);
                return Err(err(e));
            }
        }
    }
    for (i, (tmp, path)) in renames.iter().enumerate() {
        if let Err(source) = std::fs::rename(tmp, path) {
            cleanup(&renames[i..]);
            return Err(WriteError {
                path: path.to_path_buf(),
                source,
            });
        }
    }
    if fsync {
        let mut dirs: Vec<&Path> = renames.iter().map(|(_, p)| parent_dir(p)).collect();
        dirs.dedup();
        for dir in dirs {
            File::open(dir)
                .and_then(|d| d.sync_all())
                .map_err(|source| WriteError {
                    path: dir.to_path_buf(),
                    source,
                })?;
        }
    }
    Ok(())
}

/// Opens an input file for reading, refused unless it is a regular file: a FIFO would block
/// (the open itself is non-blocking, so it cannot wait for a writer), `/dev/zero` never ends, a
/// directory is not a file.
pub fn open_regular(path: &Path) -> std::io::Result<File> {
    open_checked(OpenOptions::new().read(true), path, 0)
}

/// [`open_regular`] that also refuses a symbolic link as the last component (`O_NOFOLLOW`): for
/// the files of a build directory, which are only ever what the daemon wrote there.
pub fn open_regular_nofollow(path: &Path) -> std::io::Result<File> {
    open_checked(OpenOptions::new().read(true), path, libc::O_NOFOLLOW)
}

/// Opens (creating) an append-only log of a build directory for reading it back and appending:
/// refused unless it is a regular file (a FIFO would hang the reader, `/dev/zero` never ends)
/// and not a symbolic link (it would be written through).
pub fn open_append_regular(path: &Path) -> std::io::Result<File> {
    open_checked(
        OpenOptions::new().create(true).read(true).append(true),
        path,
        libc::O_NOFOLLOW,
    )
}

/// Opens with `O_NONBLOCK` (so neither the open nor a later read can wait on a FIFO), refuses
/// what is not a regular file, then goes back to blocking mode (reads from a regular file never
/// block).
fn open_checked(options: &mut OpenOptions, path: &Path, flags: i32) -> std::io::Result<File> {
    let file = options
        .custom_flags(libc::O_NONBLOCK | libc::O_CLOEXEC | flags)
        .open(path)
        .map_err(|e| match e.raw_os_error() {
            // O_NOFOLLOW on a symbolic link.
            Some(libc::ELOOP) => std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                NotRegular("a symbolic link, where only a file the daemon wrote belongs"),
            ),
            _ => e,
        })?;
    let kind = file.metadata()?.file_type();
    if !kind.is_file() {
        use std::os::unix::fs::FileTypeExt;
        let what = if kind.is_fifo() {
            "a FIFO"
        } else if kind.is_dir() {
            "a directory"
        } else if kind.is_char_device() || kind.is_block_device() {
            "a device"
        } else if kind.is_socket() {
            "a socket"
        } else {
            "not a file"
        };
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidInput,
            NotRegular(what),
        ));
    }
    // SAFETY: fcntl on a descriptor this function owns.
    unsafe {
        use std::os::fd::AsRawFd;
        let flags = libc::fcntl(file.as_raw_fd(), libc::F_GETFL);
        if flags >= 0 {
            libc::fcntl(file.as_raw_fd(), libc::F_SETFL, flags & !libc::O_NONBLOCK);
        }
    }
    Ok(file)
}

/// Why an input was refused by type: the cause of [`open_regular`]'s `InvalidInput` error.
#[derive(Debug, thiserror::Error)]
#[error("not a regular file ({0}: it cannot be read as a file)")]
pub struct NotRegular(pub &'static str);

/// A file larger than its kind can be: the cause of the bounded readers' `InvalidData` error.
#[derive(Debug, thiserror::Error)]
#[error("larger than {max_bytes} bytes ({size} bytes): not a file of this kind")]
pub struct TooLarge {
    pub max_bytes: u64,
    pub size: u64,
}

/// An `InvalidData` error for a file of `size` bytes over `max_bytes`.
pub fn too_large(size: u64, max_bytes: u64) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        TooLarge { max_bytes, size },
    )
}

/// Refuses an open file whose size is over `max_bytes` (before anything is read).
pub fn check_size(file: &File, max_bytes: u64) -> std::io::Result<u64> {
    let size = file.metadata()?.len();
    if size > max_bytes {
        return Err(too_large(size, max_bytes));
    }
    Ok(size)
}

/// Reads an open regular file whole, refused if it is or grows over `max_bytes`.
pub fn read_file_bounded(file: File, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let size = check_size(&file, max_bytes)?;
    // Reserved by the size on disk up to 1 GiB; beyond, as it is read (a sparse file reads as
    // zeros it never stored).
    let mut bytes = Vec::with_capacity(size.min(1 << 30) as usize);
    file.take(max_bytes.saturating_add(1))
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(bytes.len() as u64, max_bytes));
    }
    Ok(bytes)
}

/// Reads a whole input file that must be a regular file (see [`open_regular`]) of at most
/// `max_bytes` (the cap of its kind: a frame, a DICOM instance, a JSON record).
pub fn read_bounded(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    read_file_bounded(open_regular(path)?, max_bytes)
}

/// The largest frame (an original: JPEG, NEF, TIFF, PNG) any reader takes: a 100 MP raw is
/// about 200 MB.
pub const MAX_FRAME_BYTES: u64 = 1 << 30;

/// Reads a whole input file (a frame, a vector file) that must be a regular file (see
/// [`open_regular`]) of at most [`MAX_FRAME_BYTES`].
pub fn read_regular(path: &Path) -> std::io::Result<Vec<u8>> {
    read_bounded(path, MAX_FRAME_BYTES)
}

/// Reads a small text file (a configuration, a calibration, a points file) whole: refused unless
/// it is a regular file (a FIFO would block, `/dev/zero` never ends) of at most `max_bytes`.
pub fn read_text_bounded(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    let bytes = read_bounded(path, max_bytes)?;
    String::from_utf8(bytes)
        .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidData, NotUtf8(e)))
}

/// Parses TOML text into `T`; the error names the file, the line and column, and the key. The
/// place is the bad key's own line where the document says where it is (an unknown key, a value
/// of the wrong type inside a table the parser reports as a whole), else the parser's.
pub fn parse_toml<T: serde::de::DeserializeOwned>(text: &str, file: &Path) -> Result<T, TomlError> {
    let deserializer = toml::Deserializer::new(text);
    serde_path_to_error::deserialize(deserializer).map_err(|err| {
        let key = err.path().to_string();
        let inner = err.into_inner();
        let message = inner.message().trim().to_string();
        let key = if key == "." || key.is_empty() {
            String::new()
        } else {
            key
        };
        // "unknown field `isoo`, expected …": the key is one level below the path.
        let unknown = message
            .strip_prefix("unknown field `")
            .and_then(|rest| rest.split_once('`'))
            .map(|(field, _)| field);
        let own_line = match unknown {
            Some(field) if key.is_empty() => key_line(text, field),
            Some(field) => key_line(text, &format!("{key}.{field}")),
            None if key.is_empty() => None,
            // A table read whole (a section chosen by its `kind`) names only the table: the value
            // the parser quotes is on the line looked for.
            None => key_line(text, &key).or_else(|| quoted_value_line(text, &key, &message)),
        };
        let place = match (own_line, inner.span()) {
            (Some(line), _) => format!("line {line}: "),
            (None, Some(span)) => {
                let (line, column) = line_column(text, span.start);
                format!("line {line}, column {column}: ")
            }
            (None, None) => String::new(),
        };
        let key = if key.is_empty() {
            String::new()
        } else {
            format!("key `{key}`: ")
        };
        TomlError {
            file: file.to_path_buf(),
            message: format!("{place}{key}{message}"),
        }
    })
}

/// A TOML document as a tree of where its values are (byte spans), to find a key's line.
enum SpanNode {
    Table(std::collections::BTreeMap<String, toml::Spanned<SpanNode>>),
    Array(Vec<toml::Spanned<SpanNode>>),
    Leaf,
}

impl<'de> serde::Deserialize<'de> for SpanNode {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visit;
        impl<'de> serde::de::Visitor<'de> for Visit {
            type Value = SpanNode;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a TOML value")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<SpanNode, A::Error> {
                let mut table = std::collections::BTreeMap::new();
                while let Some((key, value)) =
                    map.next_entry::<String, toml::Spanned<SpanNode>>()?
                {
                    table.insert(key, value);
                }
                Ok(SpanNode::Table(table))
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<SpanNode, A::Error> {
                let mut items = Vec::new();
                while let Some(item) = seq.next_element::<toml::Spanned<SpanNode>>()? {
                    items.push(item);
                }
                Ok(SpanNode::Array(items))
            }
            fn visit_bool<E>(self, _: bool) -> Result<SpanNode, E> {
                Ok(SpanNode::Leaf)
            }
            fn visit_i64<E>(self, _: i64) -> Result<SpanNode, E> {
                Ok(SpanNode::Leaf)
            }
            fn visit_u64<E>(self, _: u64) -> Result<SpanNode, E> {
                Ok(SpanNode::Leaf)
            }
            fn visit_f64<E>(self, _: f64) -> Result<SpanNode, E> {
                Ok(SpanNode::Leaf)
            }
            fn visit_str<E>(self, _: &str) -> Result<SpanNode, E> {
                Ok(SpanNode::Leaf)
            }
        }
        deserializer.deserialize_any(Visit)
    }
}

/// The line, in the table `table` of `text`, of the value a type error quotes (`invalid type:
/// string "seven", expected u64`, `invalid value: integer `-3``), when exactly one key of the
/// table holds it.
fn quoted_value_line(text: &str, table: &str, message: &str) -> Option<usize> {
    let rest = message
        .strip_prefix("invalid type: ")
        .or_else(|| message.strip_prefix("invalid value: "))?;
    let (_, quoted) = rest.split_once(' ')?;
    let literal = match quoted.chars().next()? {
        '"' => &quoted[..quoted[1..].find('"')? + 2],
        '`' => &quoted[1..quoted[1..].find('`')? + 1],
        _ => return None,
    };
    let root = toml::from_str::<SpanNode>(text).ok()?;
    let mut node = &root;
    for name in table.split('.') {
        let SpanNode::Table(t) = node else {
            return None;
        };
        node = t.get(name)?.get_ref();
    }
    let SpanNode::Table(t) = node else {
        return None;
    };
    let mut lines = t.values().filter_map(|v| {
        let span = v.span();
        (matches!(v.get_ref(), SpanNode::Leaf) && text.get(span.clone())?.trim() == literal)
            .then(|| line_column(text, span.start).0)
    });
    match (lines.next(), lines.next()) {
        (Some(line), None) => Some(line),
        _ => None,
    }
}

/// The 1-based line of the value of `key` in TOML `text` (`section.field`, `pacs[1].url`, as
/// configuration errors name keys); `None` when the text does not hold it, or for a whole table
/// (its header is not its own line).
pub fn key_line(text: &str, key: &str) -> Option<usize> {
    let SpanNode::Table(root) = toml::from_str::<SpanNode>(text).ok()? else {
        return None;
    };
    let mut table = Some(&root);
    let mut found: Option<&toml::Spanned<SpanNode>> = None;
    for segment in key.split('.') {
        let (name, indices) = match segment.find('[') {
            Some(i) => (&segment[..i], &segment[i..]),
            None => (segment, ""),
        };
        let mut node = table?.get(name)?;
        for index in indices.split('[').filter(|i| !i.is_empty()) {
            let i: usize = index.strip_suffix(']')?.parse().ok()?;
            let SpanNode::Array(items) = node.get_ref() else {
                return None;
            };
            node = items.get(i)?;
        }
        found = Some(node);
        table = match node.get_ref() {
            SpanNode::Table(inner) => Some(inner),
            _ => None,
        };
    }
    let node = found?;
    if matches!(node.get_ref(), SpanNode::Table(_)) {
        return None;
    }
    Some(line_column(text, node.span().start).0)
}

/// 1-based line and column of byte `offset` in `text`.
pub fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before
        .rfind('\n')
        .map_or(before.len(), |nl| before.len() - nl - 1)
        + 1;
    (line, column)
}

/// Free space on the filesystem holding a path: the daemon's disk guard and `status` ask through
/// this, so tests can drive it (a simulated probe lives in `sim`).
pub trait FreeSpace: Send + Sync {
    /// Bytes an unprivileged writer can still use on the filesystem holding `path`.
    fn free_bytes(&self, path: &Path) -> std::io::Result<u64>;
}

/// The real free space, from `statvfs(3)`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Statvfs;

impl FreeSpace for Statvfs {
    fn free_bytes(&self, path: &Path) -> std::io::Result<u64> {
        use std::os::unix::ffi::OsStrExt;
        let c_path = std::ffi::CString::new(path.as_os_str().as_bytes())
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
        // SAFETY: statvfs is plain old data; all-zero is a valid value.
        let mut stat: libc::statvfs = unsafe { std::mem::zeroed() };
        // SAFETY: c_path is a valid NUL-terminated string and stat a valid out-pointer.
        let rc = unsafe { libc::statvfs(c_path.as_ptr(), &mut stat) };
        if rc != 0 {
            return Err(std::io::Error::last_os_error());
        }
        Ok((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64))
    }
}

/// Whether a write failed because the disk (or the writer's quota) is full.
pub fn is_disk_full(error: &std::io::Error) -> bool {
    matches!(
        error.raw_os_error(),
        Some(libc::ENOSPC) | Some(libc::EDQUOT)
    )
}

#[cfg(test)]
mod toml_place_tests {
    use super::*;

    #[derive(Debug, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Camera {
        iso: u32,
        seed: u64,
    }

    #[derive(Debug, serde::Deserialize)]
    #[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
    #[allow(dead_code)]
    enum Kind {
        Mock { seed: u64 },
    }

    #[derive(Debug, serde::Deserialize)]
    #[allow(dead_code)]
    struct Doc {
        camera: Camera,
        trigger: Kind,
        pacs: Vec<Camera>,
    }

    const TEXT: &str = "# a comment\n[camera]\niso = 100\nseed = 7\n\n[trigger]\nkind = \"mock\"\n\
                        seed = 3\n\n[[pacs]]\niso = 1\nseed = 2\n\n[[pacs]]\niso = 5\nseed = 6\n";

    fn error(text: &str) -> String {
        parse_toml::<Doc>(text, Path::new("t.toml"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn errors_point_at_the_bad_keys_own_line() {
        assert_eq!(key_line(TEXT, "camera.seed"), Some(4));
        assert_eq!(key_line(TEXT, "pacs[1].seed"), Some(16));
        assert_eq!(
            key_line(TEXT, "camera"),
            None,
            "a table has no line of its own"
        );
        assert_eq!(key_line(TEXT, "camera.seed.deeper"), None);
        assert_eq!(key_line(TEXT, "nowhere"), None);
        let unknown = error(&TEXT.replace("seed = 7\n", "seed = 7\nisoo = 1\n"));
        assert!(
            unknown.starts_with("t.toml: line 5") && unknown.contains("unknown field `isoo`"),
            "{unknown}"
        );
        let unknown_in_tagged = error(&TEXT.replace("seed = 3\n", "seed = 3\nsede = 4\n"));
        assert!(
            unknown_in_tagged.starts_with("t.toml: line 9: key `trigger`: unknown field `sede`"),
            "{unknown_in_tagged}"
        );
        let tagged = error(&TEXT.replace("seed = 3", "seed = \"three\""));
        assert!(
            tagged.starts_with("t.toml: line 8: key `trigger`: invalid type"),
            "{tagged}"
        );
        let typed = error(&TEXT.replace("seed = 6", "seed = \"six\""));
        assert!(typed.starts_with("t.toml: line 16"), "{typed}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        write_atomic(&path, b"one", true).unwrap();
        write_atomic(&path, b"two", false).unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"two");
        let names: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["a.txt"]);
    }

    #[test]
    fn stale_temporaries_go_those_of_a_running_process_and_other_files_stay() {
        let dir = tempfile::tempdir().unwrap();
        let dead = {
            let mut child = std::process::Command::new("true").spawn().unwrap();
            child.wait().unwrap();
            child.id()
        };
        let stale = format!(".L00007.dcm.{dead}.3.tmp");
        // PID 1 always runs.
        let running = ".L00008.dcm.1.0.tmp";
        for name in [
            stale.as_str(),
            running,
            "L00007.dcm",
            ".hidden.tmp",
            "x.tmp",
        ] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        let link = format!(".L00009.dcm.{dead}.0.tmp");
        std::os::unix::fs::symlink(dir.path().join("L00007.dcm"), dir.path().join(&link)).unwrap();
        assert_eq!(remove_stale_temporaries(dir.path()).unwrap(), [stale]);
        let mut left: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        left.sort();
        assert_eq!(
            left,
            [
                ".L00008.dcm.1.0.tmp",
                &link,
                ".hidden.tmp",
                "L00007.dcm",
                "x.tmp"
            ]
        );
        assert!(remove_stale_temporaries(&dir.path().join("absent"))
            .unwrap()
            .is_empty());
    }

    #[test]
    fn a_planted_symlink_is_not_written_through() {
        let dir = tempfile::tempdir().unwrap();
        let outside = dir.path().join("outside");
        let path = dir.path().join("b.txt");
        let trap = dir.path().join(".b.txt.tmp");
        std::os::unix::fs::symlink(&outside, &trap).unwrap();
        write_atomic(&path, b"data", false).unwrap();
        assert!(!outside.exists(), "wrote through a planted symlink");
        assert_eq!(std::fs::read(&path).unwrap(), b"data");
    }

    #[test]
    fn toml_errors_name_line_and_key() {
        #[derive(serde::Deserialize, Debug)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct T {
            a: u32,
        }
        let err = parse_toml::<T>("a = 1\nb = 2\n", Path::new("t.toml")).unwrap_err();
        let text = err.to_string();
        assert!(text.starts_with("t.toml: line 2"), "{text}");
    }

    #[test]
    fn bounded_reads_refuse_devices_fifos_and_huge_files() {
        let dir = tempfile::tempdir().unwrap();
        for device in ["/dev/zero", "/dev/null"] {
            let err = read_text_bounded(Path::new(device), 1024).unwrap_err();
            assert!(
                err.to_string().contains("not a regular file (a device"),
                "{err}"
            );
        }
        let fifo = dir.path().join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
        // SAFETY: a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(
            read_text_bounded(&fifo, 1024).is_err(),
            "a FIFO must not block"
        );
        let big = dir.path().join("big.toml");
        std::fs::write(&big, vec![b'#'; 2048]).unwrap();
        assert!(read_text_bounded(&big, 1024)
            .unwrap_err()
            .to_string()
            .contains("larger than 1024 bytes (2048 bytes)"));
        std::fs::write(&big, "a = 1\n").unwrap();
        assert_eq!(read_text_bounded(&big, 1024).unwrap(), "a = 1\n");
    }

    #[test]
    fn sha256_of_nothing() {
        assert_eq!(
            sha256_hex(b""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
    }
}
