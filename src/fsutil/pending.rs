//! An atomic write in two halves: the content written to a temporary file beside its place
//! ([`write_pending_with`]), then made durable and put in place ([`Pending::commit`]: fsync,
//! rename, fsync of the directory). The fsync is the slow half: waiting for the disk, not
//! working. A caller with other work (the processing worker's next frame) hands the
//! [`Pending`] to a thread of its own to commit, and works on meanwhile.
//!
//! Until its commit nothing under the final name changes, and a [`Pending`] dropped without
//! one removes its temporary file: a crash or an error leaves the old file or the new, whole.

use super::{create_temporary, parent_dir, WriteBehind, WriteError};
use std::fs::File;
use std::path::{Path, PathBuf};

/// A file written under a temporary name beside `path`, not yet fsynced nor renamed into place.
#[must_use = "a pending file is removed unless it is committed"]
#[derive(Debug)]
pub struct Pending {
    /// The temporary file; `None` once committed (nothing left to remove).
    tmp: Option<(PathBuf, File)>,
    path: PathBuf,
    fsync: bool,
}

/// Writes what `write` writes (in parts, as it makes them) to a fresh temporary file beside
/// `path` (written behind when `fsync`: [`WriteBehind`]), and returns it pending: the file under
/// `path` is unchanged until [`Pending::commit`].
pub fn write_pending_with(
    path: &Path,
    fsync: bool,
    write: impl FnOnce(&mut WriteBehind<'_>) -> std::io::Result<()>,
) -> Result<Pending, WriteError> {
    let err = |source| WriteError {
        path: path.to_path_buf(),
        source,
    };
    let (tmp, file) = create_temporary(path).map_err(err)?;
    let pending = Pending {
        tmp: Some((tmp, file)),
        path: path.to_path_buf(),
        fsync,
    };
    if let Some((_, file)) = &pending.tmp {
        // On an error the pending file is dropped, and its temporary file with it.
        write(&mut WriteBehind::new(file, fsync)).map_err(err)?;
    }
    Ok(pending)
}

impl Pending {
    /// Where the file goes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Makes the file durable (fsync, when it was written with `fsync`) and puts it in place
    /// (rename, then fsync of the directory). On an error the temporary file is removed and the
    /// file under the final name is the one before.
    pub fn commit(mut self) -> Result<(), WriteError> {
        let Some((tmp, file)) = self.tmp.take() else {
            return Ok(());
        };
        let err = |path: &Path, source| WriteError {
            path: path.to_path_buf(),
            source,
        };
        let placed = (if self.fsync { file.sync_data() } else { Ok(()) }).and_then(|()| {
            drop(file);
            std::fs::rename(&tmp, &self.path)
        });
        if let Err(source) = placed {
            let _ = std::fs::remove_file(&tmp);
            return Err(err(&self.path, source));
        }
        if self.fsync {
            let dir = parent_dir(&self.path);
            File::open(dir)
                .and_then(|d| d.sync_all())
                .map_err(|source| err(dir, source))?;
        }
        Ok(())
    }
}

impl Drop for Pending {
    fn drop(&mut self) {
        if let Some((tmp, _)) = self.tmp.take() {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn names(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }

    #[test]
    fn the_old_file_stays_until_the_commit_and_a_dropped_write_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("slice.dcm");
        std::fs::write(&path, b"old").unwrap();

        let pending = write_pending_with(&path, true, |w| w.write_all(b"new")).unwrap();
        assert_eq!(pending.path(), path);
        // Written, not in place: the old file is whole under its name, the new one beside it.
        assert_eq!(std::fs::read(&path).unwrap(), b"old");
        assert_eq!(names(dir.path()).len(), 2);
        pending.commit().unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(names(dir.path()), ["slice.dcm"]);

        // Dropped without a commit (an error on the way): the temporary file goes.
        let pending = write_pending_with(&path, false, |w| w.write_all(b"lost")).unwrap();
        drop(pending);
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
        assert_eq!(names(dir.path()), ["slice.dcm"]);

        // A write that fails leaves no temporary file and names the file.
        let error = write_pending_with(&path, true, |w| {
            w.write_all(b"part")?;
            Err(std::io::Error::other("no room"))
        })
        .unwrap_err();
        assert_eq!(error.path, path);
        assert_eq!(names(dir.path()), ["slice.dcm"]);
        assert_eq!(std::fs::read(&path).unwrap(), b"new");
    }

    #[test]
    fn a_commit_that_cannot_rename_removes_its_file_and_names_the_place() {
        let dir = tempfile::tempdir().unwrap();
        // The place is a non-empty directory: a file cannot be renamed over it.
        let path = dir.path().join("taken");
        std::fs::create_dir(&path).unwrap();
        std::fs::write(path.join("inside"), b"x").unwrap();
        let pending = write_pending_with(&path, true, |w| w.write_all(b"data")).unwrap();
        let error = pending.commit().unwrap_err();
        assert_eq!(error.path, path);
        assert_eq!(names(dir.path()), ["taken"]);
    }
}
