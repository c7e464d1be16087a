//! A file as it is on disk, to tell whether it changed since the last look.

use std::fmt;
use std::fs::Metadata;
use std::os::unix::fs::MetadataExt;

/// A file's device, inode, size and modification time (seconds, nanoseconds): another file at
/// the same path (a new build, a file replaced by a rename) or the same file written again gives
/// another identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FileIdentity {
    dev: u64,
    ino: u64,
    size: u64,
    mtime: i64,
    mtime_nsec: i64,
}

impl FileIdentity {
    pub fn of(m: &Metadata) -> FileIdentity {
        FileIdentity {
            dev: m.dev(),
            ino: m.ino(),
            size: m.size(),
            mtime: m.mtime(),
            mtime_nsec: m.mtime_nsec(),
        }
    }
}

/// `dev:ino:size:mtime.nsec`.
impl fmt::Display for FileIdentity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let FileIdentity {
            dev,
            ino,
            size,
            mtime,
            mtime_nsec,
        } = self;
        write!(f, "{dev}:{ino}:{size}:{mtime}.{mtime_nsec}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_written_again_or_replaced_is_another_identity() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a");
        std::fs::write(&path, b"one").unwrap();
        let look = || FileIdentity::of(&std::fs::metadata(&path).unwrap());
        let first = look();
        assert_eq!(first, look());
        std::fs::write(&path, b"one!").unwrap();
        let written = look();
        assert_ne!(first, written);
        let other = dir.path().join("b");
        std::fs::write(&other, b"one!").unwrap();
        std::fs::rename(&other, &path).unwrap();
        assert_ne!(written, look(), "another inode");
        let m = std::fs::metadata(&path).unwrap();
        assert_eq!(
            look().to_string(),
            format!(
                "{}:{}:{}:{}.{}",
                m.dev(),
                m.ino(),
                m.size(),
                m.mtime(),
                m.mtime_nsec()
            )
        );
    }
}
