//! The raw f32 volume that parallel tasks share row by row (`exact`, `sweep`): x-rows (j, k) of
//! `nx` values, x fastest, then y (`ny` rows per plane), then z.

use std::marker::PhantomData;

/// A volume borrowed for the tasks of one pass, which read and write disjoint x-rows through
/// raw pointers (safe slices would borrow the whole volume).
pub(super) struct Volume<'a> {
    ptr: *mut f32,
    len: usize,
    pub(super) nx: usize,
    ny: usize,
    /// The volume is borrowed mutably for as long as this lives.
    data: PhantomData<&'a mut [f32]>,
}

// SAFETY: a `Volume` hands out rows only through the unsafe `row`/`row_mut`, whose callers
// guarantee that rows handed out concurrently for writing are disjoint and that no row is read
// while another thread writes it (`exact`: each task touches only the rows (j, ·) of its own j;
// `sweep`: the rows written are those of one anti-diagonal, and the rows read belong to the
// adjacent anti-diagonals, which no thread writes at that time). The data are plain `f32`.
unsafe impl Sync for Volume<'_> {}
unsafe impl Send for Volume<'_> {}

impl<'a> Volume<'a> {
    /// `data` as a volume of x-rows of `nx` values, `ny` rows per plane.
    pub(super) fn new(data: &'a mut [f32], nx: usize, ny: usize) -> Self {
        Volume {
            ptr: data.as_mut_ptr(),
            len: data.len(),
            nx,
            ny,
            data: PhantomData,
        }
    }

    /// Offset of row (j, k), which must lie inside the volume.
    fn start(&self, j: usize, k: usize) -> usize {
        let start = self.nx * (j + self.ny * k);
        assert!(
            j < self.ny && start + self.nx <= self.len,
            "row ({j}, {k}) outside the volume"
        );
        start
    }

    /// Row (j, k) for writing.
    ///
    /// # Safety
    /// No other reference to this row may exist while the slice lives.
    #[allow(clippy::mut_from_ref)]
    pub(super) unsafe fn row_mut(&self, j: usize, k: usize) -> &mut [f32] {
        let start = self.start(j, k);
        // SAFETY: `start..start + nx` lies inside the borrowed data (checked above); the caller
        // guarantees that no other reference to the row exists.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), self.nx) }
    }

    /// Row (j, k) for reading.
    ///
    /// # Safety
    /// No thread may write this row while the slice lives.
    pub(super) unsafe fn row(&self, j: usize, k: usize) -> &[f32] {
        let start = self.start(j, k);
        // SAFETY: inside the borrowed data (checked above); the caller guarantees that nobody
        // writes the row meanwhile.
        unsafe { std::slice::from_raw_parts(self.ptr.add(start), self.nx) }
    }
}
