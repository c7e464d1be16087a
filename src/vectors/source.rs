//! A buffered byte source that knows its offset and the total length.

use std::io::{self, BufRead};

/// Wraps a `BufRead` (a byte slice or a `BufReader<File>`), counting the bytes consumed.
///
/// `len` is the total length of the underlying data, so that announced counts can be checked
/// against the bytes remaining before anything is allocated.
pub(crate) struct Src<R> {
    inner: R,
    pos: u64,
    len: u64,
}

impl<R: BufRead> Src<R> {
    /// `pos` is the offset of the reader's current position in the whole file.
    pub(crate) fn new(inner: R, pos: u64, len: u64) -> Self {
        Src { inner, pos, len }
    }

    pub(crate) fn pos(&self) -> u64 {
        self.pos
    }

    pub(crate) fn remaining(&self) -> u64 {
        self.len.saturating_sub(self.pos)
    }

    pub(crate) fn peek(&mut self) -> io::Result<Option<u8>> {
        Ok(self.inner.fill_buf()?.first().copied())
    }

    /// Consumes one byte that was just peeked.
    pub(crate) fn bump(&mut self) {
        self.inner.consume(1);
        self.pos += 1;
    }

    pub(crate) fn read_exact(&mut self, out: &mut [u8]) -> io::Result<()> {
        self.inner.read_exact(out)?;
        self.pos += out.len() as u64;
        Ok(())
    }

    pub(crate) fn read_array<const N: usize>(&mut self) -> io::Result<[u8; N]> {
        let mut a = [0u8; N];
        self.read_exact(&mut a)?;
        Ok(a)
    }

    /// Appends bytes up to and including the next `\n` (or to the end) to `out`.
    pub(crate) fn read_line(&mut self, out: &mut Vec<u8>) -> io::Result<usize> {
        let n = self.inner.read_until(b'\n', out)?;
        self.pos += n as u64;
        Ok(n)
    }

    /// Skips `n` bytes; fails if the data ends first.
    pub(crate) fn skip(&mut self, mut n: u64) -> io::Result<()> {
        while n > 0 {
            let avail = self.inner.fill_buf()?.len();
            if avail == 0 {
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
            let k = (avail as u64).min(n) as usize;
            self.inner.consume(k);
            self.pos += k as u64;
            n -= k as u64;
        }
        Ok(())
    }

    /// Calls `f` on `count` consecutive records of `N` bytes, straight from the buffer.
    pub(crate) fn for_each_record<const N: usize>(
        &mut self,
        count: u64,
        mut f: impl FnMut(&[u8; N]),
    ) -> io::Result<()> {
        let mut left = count;
        while left > 0 {
            let buf = self.inner.fill_buf()?;
            if buf.is_empty() {
                return Err(io::ErrorKind::UnexpectedEof.into());
            }
            let whole = ((buf.len() / N) as u64).min(left) as usize;
            if whole == 0 {
                // A record straddles the end of the buffer.
                let rec = self.read_array::<N>()?;
                f(&rec);
                left -= 1;
                continue;
            }
            for chunk in buf.chunks_exact(N).take(whole) {
                if let Ok(rec) = <&[u8; N]>::try_from(chunk) {
                    f(rec);
                }
            }
            self.inner.consume(whole * N);
            self.pos += (whole * N) as u64;
            left -= whole as u64;
        }
        Ok(())
    }
}
