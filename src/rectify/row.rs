//! The generic row kernel: phase 1 (`positions.rs`) then phase 2 (`kernel.rs`) run by run
//! along one grid row. `simd.rs` compiles it for AVX2.

use super::kernel::{bicubic_run, bilinear_run, Coords, Job, Sample, CHUNK};
use super::positions::map_run;

pub(crate) fn row_plain<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    row_generic::<T, CN, CUBIC>(job, row, out, co)
}

/// Generic row kernel; `#[inline(always)]` so the AVX2 wrapper in `simd.rs`
/// gets it compiled (and phase 1 vectorised) with AVX2.
#[inline(always)]
pub(crate) fn row_generic<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    let mut col0 = 0;
    for chunk in out.chunks_mut(CHUNK * CN) {
        let n = chunk.len() / CN;
        map_run(job, row, col0, n, co);
        if CUBIC {
            bicubic_run::<T, CN>(job, co, chunk);
        } else {
            bilinear_run::<T, CN>(job, co, chunk, 0);
        }
        col0 += n;
    }
}
