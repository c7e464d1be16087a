//! Frame-size luma buffers kept from one frame to the next.
//!
//! A D810 frame's luma is 36 MB. The pages of a fresh buffer are zeroed by the kernel at their
//! first touch, which on this machine's VM took about a sixth of the luma decode (`perf record`
//! of `frame_path`, `clear_page_erms`); a buffer kept from the frame before is only written.
//! [`give_back`] keeps at most one buffer per frame the processing worker has in flight (one per
//! thread of rayon's pool), the newest first; [`take`] hands one of the exact length out again.
//! Its contents are the frame before's: the decoder writes or zeroes every pixel of it.

use std::sync::Mutex;

/// Smaller buffers are not worth keeping: their pages cost little.
const MIN_LEN: usize = 4 << 20;

static FREE: Pool = Pool(Mutex::new(Vec::new()));

/// A kept buffer of exactly `len` bytes (stale contents), if there is one.
pub(super) fn take(len: usize) -> Option<Vec<u8>> {
    FREE.take(len)
}

/// Keeps `buf` for a later [`take`]; the oldest kept buffer is dropped when there are as many
/// as frames in flight.
pub(super) fn give_back(buf: Vec<u8>) {
    FREE.give_back(buf, rayon::current_num_threads().max(1));
}

struct Pool(Mutex<Vec<Vec<u8>>>);

impl Pool {
    fn take(&self, len: usize) -> Option<Vec<u8>> {
        let mut free = self.0.lock().ok()?;
        let i = free.iter().rposition(|b| b.len() == len)?;
        Some(free.swap_remove(i))
    }

    fn give_back(&self, buf: Vec<u8>, most: usize) {
        if buf.len() < MIN_LEN {
            return;
        }
        let Ok(mut free) = self.0.lock() else {
            return;
        };
        if free.len() >= most {
            free.remove(0);
        }
        free.push(buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_buffer_given_back_is_taken_again_by_its_length_only() {
        let pool = Pool(Mutex::new(Vec::new()));
        let len = MIN_LEN + 12_345;
        let mut buf = vec![0u8; len];
        buf[7] = 42;
        pool.give_back(buf, 2);
        assert!(pool.take(len + 1).is_none(), "another length");
        let again = pool.take(len).expect("kept");
        assert_eq!((again.len(), again[7]), (len, 42));
        assert!(pool.take(len).is_none(), "taken once");
        pool.give_back(vec![0u8; 1024], 2);
        assert!(pool.take(1024).is_none(), "small buffers are not kept");
        for i in 0..5u8 {
            pool.give_back(vec![i; len], 2);
        }
        // The two newest are kept, the newest handed out first.
        let firsts: Vec<u8> = std::iter::from_fn(|| pool.take(len))
            .map(|b| b[0])
            .collect();
        assert_eq!(firsts, [4, 3]);
    }
}
