//! JSON-lines logs written like the journal: one record per line in one write, fsynced on request;
//! reading back cuts a torn last record and refuses damage anywhere before it. The journal,
//! `inspection.jsonl`, `alarm.jsonl` and the push logs are kept this way.

use serde::Serialize;
use std::fs::File;
use std::io::{BufRead, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use tracing::warn;

#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("{path}: cannot read or write")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "{path}: damaged at byte {offset} (line {line}), before its last record (frames recorded \
         after it could be lost, so nothing is cut: keep a copy of the file, then repair or remove \
         that line, or restore the journal from a backup, and start again)"
    )]
    Corrupt {
        path: PathBuf,
        /// Byte offset of the start of the damaged line.
        offset: u64,
        line: usize,
        #[source]
        source: LineError,
    },
}

/// Why a line of a JSON-lines log cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum LineError {
    #[error("invalid UTF-8")]
    Utf8(#[source] std::str::Utf8Error),
    #[error("a line longer than {MAX_LINE_BYTES} bytes (no record is that long)")]
    TooLong,
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// The longest line a record of these logs can be: every record is a few hundred bytes (a
/// frame's camera settings, an inspection's flags); a longer line is damage.
pub const MAX_LINE_BYTES: usize = 1 << 20;

/// The largest journal read back: a 10,000-layer build's is about 30 MB.
pub const MAX_JOURNAL_BYTES: u64 = 1 << 30;

/// The largest log whose records are kept in memory when read (inspection.jsonl,
/// alarm.jsonl, a push log): tens of MB for the longest build.
pub const MAX_LOG_BYTES: u64 = 256 << 20;

/// Opens (creating) an append-only log for reading it back and appending to it: a regular file
/// only, never through a symbolic link (fsutil::open_append_regular).
pub(crate) fn open_append(path: &Path) -> std::io::Result<File> {
    crate::fsutil::open_append_regular(path)
}

/// Opens an existing log for reading only (`None` when there is none yet): a regular file of
/// at most `max_bytes`, never through a symbolic link.
pub(crate) fn open_read(path: &Path, max_bytes: u64) -> Result<Option<File>, JournalError> {
    let io = |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    };
    match crate::fsutil::open_regular_nofollow(path) {
        Ok(file) => {
            crate::fsutil::check_size(&file, max_bytes).map_err(io)?;
            Ok(Some(file))
        }
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(io(source)),
    }
}

/// Opens (creating) a JSON-lines file for appending after calling `each` for every record in it;
/// a torn last record, left by a crash in the middle of a write, is cut off. The journal and the
/// inspection log open this way.
pub(crate) fn open_lines<T: serde::de::DeserializeOwned>(
    path: &Path,
    max_bytes: u64,
    each: impl FnMut(T),
) -> Result<File, JournalError> {
    let io = |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = open_append(path).map_err(io)?;
    crate::fsutil::check_size(&file, max_bytes).map_err(io)?;
    let good_end = scan_lines(path, &mut file, each)?;
    let len = file.metadata().map_err(io)?.len();
    if good_end < len {
        warn!(file = %path.display(), offset = good_end, bytes = len - good_end, "cutting off a torn last record left by a crash");
        file.set_len(good_end).map_err(io)?;
    }
    Ok(file)
}

/// Calls `each` for every JSON line of `file` and returns the byte offset after the last good
/// one. Only the last line may be damaged (a write torn by a crash: cut short, or garbage after the
/// last newline); damage anywhere before it is [`JournalError::Corrupt`], never skipped. The
/// journal and the inspection log share it.
pub(crate) fn scan_lines<T: serde::de::DeserializeOwned>(
    path: &Path,
    file: &mut File,
    mut each: impl FnMut(T),
) -> Result<u64, JournalError> {
    let io = |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    };
    file.seek(SeekFrom::Start(0)).map_err(io)?;
    // Line by line, not the whole file at once: a long build's journal is tens of MB and the
    // daemon reads it at every start.
    let mut reader = std::io::BufReader::with_capacity(64 * 1024, file);
    let mut data = Vec::new();
    let mut offset = 0usize;
    let mut number = 0usize;
    loop {
        data.clear();
        // At most one line's worth: a file of zeros (a sparse file, a device) is not one line
        // held in memory.
        let read = std::io::Read::take(&mut reader, MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut data)
            .map_err(io)?;
        if read == 0 {
            break;
        }
        number += 1;
        let complete = data.last() == Some(&b'\n');
        let end = if complete { read - 1 } else { read };
        let last = reader.fill_buf().map_err(io)?.is_empty();
        let parsed = if end > MAX_LINE_BYTES {
            Err(LineError::TooLong)
        } else {
            std::str::from_utf8(&data[..end])
                .map_err(LineError::Utf8)
                .and_then(|text| serde_json::from_str::<T>(text).map_err(LineError::Json))
        };
        match parsed {
            Ok(record) if complete => each(record),
            // A last line without its newline was torn even when it parses.
            Ok(_) => return Ok(offset as u64),
            Err(_) if last => return Ok(offset as u64),
            Err(source) => {
                return Err(JournalError::Corrupt {
                    path: path.to_path_buf(),
                    offset: offset as u64,
                    line: number,
                    source,
                })
            }
        }
        offset += read;
    }
    Ok(offset as u64)
}

/// Appends `record` to `file` as one JSON line in one write, fsynced when asked: the journal's and
/// the inspection log's way of writing. A write that fails half way (a full disk) is cut back off,
/// so the file never holds a torn line before a later record.
pub(crate) fn append_line<T: serde::Serialize>(
    file: &mut File,
    path: &Path,
    fsync: bool,
    record: &T,
) -> Result<(), JournalError> {
    let io = |source| JournalError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut line = serde_json::to_vec(record).map_err(|e| io(std::io::Error::other(e)))?;
    line.push(b'\n');
    let before = file.metadata().map_err(io)?.len();
    let written = file
        .write_all(&line)
        .and_then(|()| if fsync { file.sync_data() } else { Ok(()) });
    if let Err(e) = written {
        if let Err(cut) = file.set_len(before) {
            warn!(file = %path.display(), error = %crate::logging::Chain(&cut), "cannot cut off a failed write");
        }
        return Err(io(e));
    }
    Ok(())
}

impl JournalError {
    /// Whether the write failed for want of disk space.
    pub fn is_disk_full(&self) -> bool {
        matches!(self, JournalError::Io { source, .. } if crate::fsutil::is_disk_full(source))
    }
}

/// A JSON-lines log of `T` records open for appending, written like the journal: one record per
/// line in one write, a torn last record cut off when the writer reopens it. `inspection.jsonl`
/// and `alarm.jsonl` are kept this way.
pub struct LinesLog<T> {
    path: PathBuf,
    file: File,
    fsync: bool,
    /// A lock refused by the file system was logged once.
    lock_failed: bool,
    records: std::marker::PhantomData<fn(&T)>,
}

impl<T: Serialize + serde::de::DeserializeOwned> LinesLog<T> {
    /// Opens (creating) the log and returns the records it holds; a torn last record is cut off.
    pub fn open(path: &Path, fsync: bool) -> Result<(LinesLog<T>, Vec<T>), JournalError> {
        let mut records = Vec::new();
        let file = open_lines(path, MAX_LOG_BYTES, |r| records.push(r))?;
        Ok((LinesLog::new(path, file, fsync), records))
    }

    fn new(path: &Path, file: File, fsync: bool) -> LinesLog<T> {
        LinesLog {
            path: path.to_path_buf(),
            file,
            fsync,
            lock_failed: false,
            records: std::marker::PhantomData,
        }
    }

    /// Opens the log for appending without reading or repairing it (another process may be
    /// writing it); every record fsynced.
    pub fn append_only(path: &Path) -> Result<LinesLog<T>, JournalError> {
        let file = open_append(path).map_err(|source| JournalError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(LinesLog::new(path, file, true))
    }

    /// The records of a log without opening it for writing (none when there is no file yet; a
    /// torn last one ignored).
    pub fn read(path: &Path) -> Result<Vec<T>, JournalError> {
        let Some(mut file) = open_read(path, MAX_LOG_BYTES)? else {
            return Ok(Vec::new());
        };
        let mut records = Vec::new();
        scan_lines(path, &mut file, |r| records.push(r))?;
        Ok(records)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one record as one line, in one write (fsynced when the log was opened so), under
    /// the log's lock ([`LinesLog::append_if`]). A lock another process holds past [`LOCK_WAIT`]
    /// is not waited for, nor a file system that has no locks: the record is appended all the
    /// same (a raise is never held back).
    pub fn append(&mut self, record: &T) -> Result<(), JournalError> {
        self.follow_path();
        let locked = match self.try_lock() {
            Ok(locked) => locked,
            Err(e) => {
                if !self.lock_failed {
                    self.lock_failed = true;
                    warn!(file = %self.path.display(), error = %e, "cannot lock the log; appending without its lock");
                }
                false
            }
        };
        let written = append_line(&mut self.file, &self.path, self.fsync, record);
        if locked {
            self.unlock();
        }
        written
    }

    /// Takes the log's exclusive advisory lock (`flock`), waiting at most [`LOCK_WAIT`]: every
    /// writer of the log appends under it. False when another process kept it.
    fn try_lock(&mut self) -> std::io::Result<bool> {
        use std::os::fd::AsRawFd;
        let waited = std::time::Instant::now();
        loop {
            // SAFETY: flock on a descriptor this log owns.
            if unsafe { libc::flock(self.file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
                return Ok(true);
            }
            let e = std::io::Error::last_os_error();
            match e.raw_os_error() {
                Some(libc::EWOULDBLOCK) if waited.elapsed() < LOCK_WAIT => {
                    std::thread::sleep(std::time::Duration::from_millis(5));
                }
                Some(libc::EWOULDBLOCK) => return Ok(false),
                Some(libc::EINTR) => {}
                _ => return Err(e),
            }
        }
    }

    /// A log replaced at its path (repaired with `sed -i`, renamed over) or removed is written
    /// at its path again, where its readers and other writers look, not into the file that was
    /// there. A path that cannot be opened leaves the log as it was.
    fn follow_path(&mut self) {
        use std::os::unix::fs::MetadataExt;
        let ours = self.file.metadata().ok().map(|m| (m.dev(), m.ino()));
        let here = match std::fs::metadata(&self.path) {
            Ok(m) => Some((m.dev(), m.ino())),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
            Err(_) => return,
        };
        if here.is_some() && here == ours {
            return;
        }
        if let Ok(file) = open_append(&self.path) {
            warn!(file = %self.path.display(), "the log was replaced or removed: appending to the file now at its path");
            self.file = file;
        }
    }

    fn unlock(&mut self) {
        use std::os::fd::AsRawFd;
        // SAFETY: flock on a descriptor this log owns.
        unsafe { libc::flock(self.file.as_raw_fd(), libc::LOCK_UN) };
    }

    /// Appends `record` when `check` passes on the log's records as they are, both under the
    /// log's lock: no other writer appends between the check and the append (what `check` saw is
    /// what the record answers). Returns the records `check` saw; refused
    /// ([`AppendIfError::Busy`]) when another process keeps the lock past [`LOCK_WAIT`].
    pub fn append_if<E>(
        &mut self,
        record: &T,
        check: impl FnOnce(&[T]) -> Result<(), E>,
    ) -> Result<Result<Vec<T>, E>, AppendIfError> {
        self.follow_path();
        let locked = match self.try_lock() {
            Ok(true) => true,
            Ok(false) => {
                return Err(AppendIfError::Busy {
                    path: self.path.clone(),
                })
            }
            // A file system without locks (NFS without lockd): checked and appended as before
            // there were locks, with a warning.
            Err(e) if matches!(e.raw_os_error(), Some(libc::ENOLCK | libc::EOPNOTSUPP)) => {
                if !self.lock_failed {
                    self.lock_failed = true;
                    warn!(file = %self.path.display(), error = %e, "cannot lock the log; the check and the append are not one step");
                }
                false
            }
            Err(source) => {
                return Err(AppendIfError::Log(JournalError::Io {
                    path: self.path.clone(),
                    source,
                }))
            }
        };
        let outcome = Self::read(&self.path)
            .map_err(AppendIfError::Log)
            .and_then(|records| match check(&records) {
                Err(e) => Ok(Err(e)),
                Ok(()) => append_line(&mut self.file, &self.path, self.fsync, record)
                    .map(|()| Ok(records))
                    .map_err(AppendIfError::Log),
            });
        if locked {
            self.unlock();
        }
        outcome
    }
}

/// How long a writer waits for another's lock on a log ([`LinesLog::append`]): a check and an
/// append take milliseconds.
pub const LOCK_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// Why [`LinesLog::append_if`] appended nothing, besides its check.
#[derive(Debug, thiserror::Error)]
pub enum AppendIfError {
    #[error(transparent)]
    Log(JournalError),
    #[error(
        "{}: another process has held the log's lock for over 2 s; try again (a process stopped \
         half-way holds it: `fuser` names the processes that have the file open)",
        path.display()
    )]
    Busy { path: PathBuf },
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{json, Value};
    use std::time::{Duration, Instant};

    #[test]
    fn a_check_and_its_append_are_one_step_for_the_other_writers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("alarm.jsonl");
        let (mut daemon, _) = LinesLog::<Value>::open(&path, false).unwrap();
        assert!(daemon.try_lock().unwrap());
        // The page checks and appends while the daemon holds the lock: it waits.
        let page = {
            let path = path.clone();
            std::thread::spawn(move || {
                LinesLog::<Value>::append_only(&path)
                    .unwrap()
                    .append_if(&json!({"ack": 1}), |seen| {
                        if seen.is_empty() {
                            Ok(())
                        } else {
                            Err(seen.len())
                        }
                    })
                    .unwrap()
            })
        };
        std::thread::sleep(Duration::from_millis(200));
        append_line(&mut daemon.file, &path, false, &json!({"raise": 2})).unwrap();
        daemon.unlock();
        // The page's check saw the raise appended under the lock, and appended nothing.
        assert_eq!(page.join().unwrap(), Err(1));
        assert_eq!(LinesLog::<Value>::read(&path).unwrap().len(), 1);
        // Nobody holding it: appended.
        let seen = LinesLog::<Value>::append_only(&path)
            .unwrap()
            .append_if(&json!({"ack": 2}), |_| Ok::<(), ()>(()))
            .unwrap();
        assert_eq!(seen, Ok(vec![json!({"raise": 2})]));
        assert_eq!(LinesLog::<Value>::read(&path).unwrap().len(), 2);
    }

    #[test]
    fn a_lock_kept_past_the_wait_refuses_a_check_and_lets_an_append_through() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("alarm.jsonl");
        let (mut stopped, _) = LinesLog::<Value>::open(&path, false).unwrap();
        assert!(stopped.try_lock().unwrap());
        let started = Instant::now();
        let err = LinesLog::<Value>::append_only(&path)
            .unwrap()
            .append_if(&json!({"ack": 1}), |_| Ok::<(), ()>(()))
            .unwrap_err();
        assert!(started.elapsed() >= LOCK_WAIT, "{:?}", started.elapsed());
        assert!(err.to_string().contains("try again"), "{err}");
        // A raise is not held back by it.
        let mut daemon = LinesLog::<Value>::append_only(&path).unwrap();
        daemon.append(&json!({"raise": 3})).unwrap();
        assert_eq!(LinesLog::<Value>::read(&path).unwrap().len(), 1);
    }

    /// Before, a writer kept appending to the file it had opened after the log was replaced at
    /// its path (a damaged line repaired with `sed -i`): its records went into an unlinked
    /// file that nobody reads, and its checks read one file while it wrote another.
    #[test]
    fn a_log_replaced_or_removed_at_its_path_is_written_at_its_path() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("alarm.jsonl");
        let (mut daemon, _) = LinesLog::<Value>::open(&path, false).unwrap();
        daemon.append(&json!({"raise": 1})).unwrap();
        let repaired = dir.path().join("alarm.jsonl.new");
        std::fs::write(&repaired, "{\"raise\":1}\n").unwrap();
        std::fs::rename(&repaired, &path).unwrap();
        daemon.append(&json!({"clear": 2})).unwrap();
        let seen = daemon
            .append_if(&json!({"raise": 3}), |seen| match seen.len() {
                2 => Ok(()),
                n => Err(n),
            })
            .unwrap();
        assert_eq!(seen, Ok(vec![json!({"raise": 1}), json!({"clear": 2})]));
        std::fs::remove_file(&path).unwrap();
        daemon.append(&json!({"raise": 4})).unwrap();
        assert_eq!(
            LinesLog::<Value>::read(&path).unwrap(),
            vec![json!({"raise": 4})]
        );
    }
}
