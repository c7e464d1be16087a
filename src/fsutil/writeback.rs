//! Write-behind for large files that are fsynced when complete: the kernel is asked to start
//! writing each few MiB to disk as soon as they are written (`sync_file_range` with
//! `SYNC_FILE_RANGE_WRITE`, which does not wait for it), so that the final fsync waits only for
//! the tail instead of the whole file. What a crash can leave behind does not change: the file
//! is still only complete, and only renamed into place, after its fsync.

use std::fs::File;
use std::io::Write;

/// Bytes written between two requests to start writeback.
const WRITE_BEHIND: u64 = 4 << 20;

/// A [`Write`] into `file` that starts the writeback of every [`WRITE_BEHIND`] bytes written
/// (Linux; elsewhere it only writes). A larger write is taken up to the next such boundary
/// (`write_all` goes on with the rest), so that one large buffer is written behind too.
pub struct WriteBehind<'a> {
    file: &'a File,
    /// Bytes between two starts of writeback (`u64::MAX`: never).
    every: u64,
    /// Bytes written so far.
    written: u64,
    /// Bytes whose writeback has been started.
    started: u64,
}

impl<'a> WriteBehind<'a> {
    /// Writes into `file`, fresh and empty (the ranges it starts count from offset 0); written
    /// behind when `behind` (a file that will be fsynced), else plainly.
    pub fn new(file: &'a File, behind: bool) -> Self {
        WriteBehind {
            file,
            every: if behind { WRITE_BEHIND } else { u64::MAX },
            written: 0,
            started: 0,
        }
    }

    /// Starts the writeback of what was written since the last start. Advisory: a failure here
    /// would show again at the fsync, so it is not reported, and the range counts as started
    /// whatever happens (the next boundary is [`WRITE_BEHIND`] bytes on).
    fn start_writeback(&mut self) {
        let (from, len) = (self.started, self.written - self.started);
        self.started = self.written;
        #[cfg(target_os = "linux")]
        if let (Ok(offset), Ok(len)) = (i64::try_from(from), i64::try_from(len)) {
            use std::os::fd::AsRawFd;
            // SAFETY: a valid open descriptor and a range of it; the call reads no memory of
            // ours.
            let _ = unsafe {
                libc::sync_file_range(
                    self.file.as_raw_fd(),
                    offset,
                    len,
                    libc::SYNC_FILE_RANGE_WRITE,
                )
            };
        }
        #[cfg(not(target_os = "linux"))]
        let _ = (from, len);
    }
}

impl Write for WriteBehind<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let room = self.every - (self.written - self.started);
        let part = &buf[..buf.len().min(usize::try_from(room).unwrap_or(usize::MAX))];
        let n = self.file.write(part)?;
        self.written += n as u64;
        if self.written - self.started >= self.every {
            self.start_writeback();
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_every_byte_in_order_across_writeback_starts() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("big");
        let file = File::create(&path).expect("create");
        let data: Vec<u8> = (0..(3 * WRITE_BEHIND as usize + 12345))
            .map(|i| (i * 7 + i / 4099) as u8)
            .collect();
        let mut w = WriteBehind::new(&file, true);
        for part in data.chunks(1_000_003) {
            w.write_all(part).expect("write");
        }
        // Writeback was started more than once (each time after at least WRITE_BEHIND more
        // bytes), and less than WRITE_BEHIND is left to the fsync.
        assert_eq!(w.written, data.len() as u64);
        assert!(w.started > WRITE_BEHIND && w.written - w.started < WRITE_BEHIND);
        file.sync_data().expect("sync");
        assert_eq!(std::fs::read(&path).expect("read"), data);

        // One large buffer: written in parts ending on every boundary.
        let path = dir.path().join("one");
        let file = File::create(&path).expect("create");
        let mut w = WriteBehind::new(&file, true);
        w.write_all(&data).expect("write");
        assert_eq!(w.started, 3 * WRITE_BEHIND);
        assert_eq!(std::fs::read(&path).expect("read"), data);

        // Not behind: the same bytes, no writeback started.
        let path = dir.path().join("plain");
        let file = File::create(&path).expect("create");
        let mut w = WriteBehind::new(&file, false);
        w.write_all(&data).expect("write");
        assert_eq!((w.written, w.started), (data.len() as u64, 0));
        assert_eq!(std::fs::read(&path).expect("read"), data);
    }
}
