//! AVX2 kernels: the 8-bit grey and RGB bilinear ones, 8 pixels per step, and the generic row
//! kernel compiled for AVX2. `simd.rs` picks them at run time; the AVX-512 kernels
//! (`avx512.rs`) build on [`row_8bit`] and fall back to [`rgb8_run`].

use std::arch::x86_64::*;

use crate::rectify::kernel::{bilinear_run, Coords, Job, Sample, CHUNK, FRAC_BITS, ONE, ROUND2};
use crate::rectify::positions::QuadBlock;
use crate::rectify::positions::{map_run, plan_block, Finish8, Lanes8, Line, Plan};

/// The generic row kernel compiled for AVX2 (phase 1 vectorises 4-wide f64).
#[target_feature(enable = "avx2")]
pub(super) fn row_generic_avx2<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    crate::rectify::row::row_generic::<T, CN, CUBIC>(job, row, out, co)
}

/// Phase 1 then `run` (a phase-2 kernel), chunk by chunk along one row of `CN`-sample pixels.
#[inline(always)]
pub(super) fn row_8bit<const CN: usize>(
    job: &Job<'_, u8>,
    row: usize,
    out: &mut [u8],
    co: &mut Coords,
    run: impl Fn(&Job<'_, u8>, &Coords, &mut [u8]),
) {
    let mut col0 = 0;
    for chunk in out.chunks_mut(CHUNK * CN) {
        let n = chunk.len() / CN;
        map_run(job, row, col0, n, co);
        run(job, co, chunk);
        col0 += n;
    }
}

/// Bilinear 8-bit grey row. Without distortion, a block that phase 1 takes by its quadratic
/// path ([`Plan::Quad`]) is positioned and sampled 8 pixels at a time in registers
/// ([`gray8_quad`]): its coordinates never go through memory.
/// Other blocks, and rows with distortion, are phase 1 then [`gray8_run`].
#[target_feature(enable = "avx2")]
pub(super) fn row_gray8_avx2(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    gray8_row(
        job,
        row,
        out,
        co,
        |j, b, o, c| gray8_quad(j, b, o, c),
        |j, c, o| gray8_run(j, c, o),
    )
}

/// A grey row, block by block as phase 1 plans them without distortion: `quad` positions and
/// samples a block of the quadratic path ([`Plan::Quad`]) in registers, `run` samples the other
/// blocks, and rows with distortion, from phase 1's coordinates.
#[inline(always)]
pub(super) fn gray8_row(
    job: &Job<'_, u8>,
    row: usize,
    out: &mut [u8],
    co: &mut Coords,
    quad: impl Fn(&Job<'_, u8>, &QuadBlock, &mut [u8], &mut Coords),
    run: impl Fn(&Job<'_, u8>, &Coords, &mut [u8]),
) {
    if job.map.is_some() || job.dist.is_some() {
        return row_8bit::<1>(job, row, out, co, run);
    }
    let line = Line::of_row(&job.m, row);
    let mut col0 = 0;
    for chunk in out.chunks_mut(CHUNK) {
        // Blocks as map_run takes them without distortion.
        let mut j0 = 0;
        while j0 < chunk.len() {
            let (plan, len) = plan_block(job, &line, col0 + j0, chunk.len() - j0);
            let part = &mut chunk[j0..j0 + len];
            match plan {
                Plan::Quad(b) => quad(job, &b, part, co),
                // (The f32 path fused here measured no faster: its float work is the cost.)
                Plan::Near(_) | Plan::Outside | Plan::Exact => {
                    map_run(job, row, col0 + j0, len, co);
                    run(job, co, part);
                }
            }
            j0 += len;
        }
        col0 += chunk.len();
    }
}

/// Bilinear 8-bit RGB row: phase 1, then [`rgb8_run`].
#[target_feature(enable = "avx2")]
pub(super) fn row_rgb8_avx2(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    row_8bit::<3>(job, row, out, co, |j, c, o| rgb8_run(j, c, o, 0))
}

/// Loads 8 i32 from `v[i..i + 8]`.
#[inline(always)]
fn load8(v: &[i32], i: usize) -> __m256i {
    let s = &v[i..i + 8];
    // SAFETY: `s` holds exactly 8 i32 (bounds-checked slice); unaligned load.
    unsafe { _mm256_loadu_si256(s.as_ptr().cast()) }
}

/// Grey: 8 pixels per step, from the coordinates phase 1 wrote ([`Gray8::step`]).
#[target_feature(enable = "avx2")]
pub(super) fn gray8_run(job: &Job<'_, u8>, co: &Coords, out: &mut [u8]) {
    let k = Gray8::new(job);
    let n = out.len();
    let mut i = 0;
    while i + 8 <= n {
        let (ix, iy) = (load8(&co.ix, i), load8(&co.iy, i));
        let (bx, by) = (co.ix[i].min(co.ix[i + 7]), co.iy[i].min(co.iy[i + 7]));
        let px = k.step(job, ix, iy, load8(&co.fx, i), load8(&co.fy, i), bx, by);
        let dst = &mut out[i..i + 8];
        // SAFETY: `dst` is exactly 8 bytes; unaligned 8-byte store.
        unsafe { _mm_storel_epi64(dst.as_mut_ptr().cast(), px) };
        i += 8;
    }
    bilinear_run::<u8, 1>(job, co, out, i);
}

/// Grey, one block of phase 1's quadratic path ([`QuadBlock`]): 8 lanes of 64-bit positions
/// stepped by their differences ([`Lanes8`], the integers [`QuadBlock::fill`] gives) and
/// sampled at once ([`Gray8::step`]). The last `len % 8` pixels go through `at` and the scalar
/// kernel.
#[target_feature(enable = "avx2")]
fn gray8_quad(job: &Job<'_, u8>, b: &QuadBlock, out: &mut [u8], co: &mut Coords) {
    let k = Gray8::new(job);
    let n = out.len();
    let mut lanes = Lanes8::new(b);
    let mut i = 0;
    while i + 8 <= n {
        let (xq, yq) = lanes.next();
        let px = k.finish_step(job, xq, yq);
        let dst = &mut out[i..i + 8];
        // SAFETY: `dst` is exactly 8 bytes; unaligned 8-byte store.
        unsafe { _mm_storel_epi64(dst.as_mut_ptr().cast(), px) };
        i += 8;
    }
    for j in i..n {
        (co.ix[j], co.iy[j], co.fx[j], co.fy[j]) = b.at(job, j);
    }
    bilinear_run::<u8, 1>(job, co, out, i);
}

/// The grey kernel's constants.
struct Gray8 {
    shuf_top: __m256i,
    shuf_bot: __m256i,
    stride_v: __m256i,
    one: __m256i,
    round: __m256i,
    fillv: __m256i,
    minus1: __m256i,
    sign: __m256i,
    max_dx: __m256i,
    max_dy: __m256i,
    idx_bias: __m256i,
    finish: Finish8,
}

impl Gray8 {
    #[target_feature(enable = "avx2")]
    fn new(job: &Job<'_, u8>) -> Gray8 {
        // Byte pairs → i16 pairs for madd: top (p00, p01) are bytes 0,1 of the
        // dword gathered at the pixel, bottom (p10, p11) bytes 2,3 of the dword
        // gathered 2 bytes before it (so the read never passes the buffer end).
        const Z: i8 = -128;
        #[rustfmt::skip]
        let shuf_top = _mm256_setr_epi8(
            0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z, 13, Z,
            0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z, 13, Z,
        );
        #[rustfmt::skip]
        let shuf_bot = _mm256_setr_epi8(
            2, Z, 3, Z, 6, Z, 7, Z, 10, Z, 11, Z, 14, Z, 15, Z,
            2, Z, 3, Z, 6, Z, 7, Z, 10, Z, 11, Z, 14, Z, 15, Z,
        );
        Gray8 {
            shuf_top,
            shuf_bot,
            stride_v: _mm256_set1_epi32(job.src.stride as i32),
            one: _mm256_set1_epi32(ONE),
            round: _mm256_set1_epi32(ROUND2 as i32),
            fillv: _mm256_set1_epi32(i32::from(job.fill)),
            minus1: _mm256_set1_epi32(-1),
            // The window's bounds on dx and dy, with the sign bit flipped (see `step`).
            sign: _mm256_set1_epi32(i32::MIN),
            max_dx: _mm256_set1_epi32(14 ^ i32::MIN),
            max_dy: _mm256_set1_epi32(1 ^ i32::MIN),
            // Shuffle index per dword: [dx, zero, dx + 1, zero].
            idx_bias: _mm256_set1_epi32(0x8001_8000_u32 as i32),
            finish: Finish8::new(job),
        }
    }

    /// 8 grey pixels from their fixed-point positions: phase 1's `finish` ([`Finish8`]), then
    /// [`Gray8::step`].
    #[target_feature(enable = "avx2")]
    #[inline]
    fn finish_step(&self, job: &Job<'_, u8>, xq: __m256i, yq: __m256i) -> __m128i {
        let [ix, iy, fx, fy] = self.finish.apply(xq, yq);
        let bx = _mm256_extract_epi32::<0>(ix).min(_mm256_extract_epi32::<7>(ix));
        let by = _mm256_extract_epi32::<0>(iy).min(_mm256_extract_epi32::<7>(iy));
        self.step(job, ix, iy, fx, fy, bx, by)
    }

    /// 8 grey pixels from their positions (`ix < 0`: outside, filled), as 8 bytes.
    ///
    /// Pairs (p00, p01) and (p10, p11) come from byte shuffles of 16-byte row windows from
    /// (`bx`, `by`) when the 8 samples sit in two or three consecutive source rows within 15
    /// columns (the usual case: a grid row maps to a nearly horizontal image line), and from
    /// two dword gathers otherwise ([`Gray8::gathered`]). Gathers are the slowest part of this
    /// loop, so the shuffle path roughly halves its cost.
    #[allow(clippy::too_many_arguments)]
    #[target_feature(enable = "avx2")]
    #[inline]
    fn step(
        &self,
        job: &Job<'_, u8>,
        ix: __m256i,
        iy: __m256i,
        fx: __m256i,
        fy: __m256i,
        bx: i32,
        by: i32,
    ) -> __m128i {
        let (data, stride) = (job.src.data, job.src.stride);
        // Rows by..=by+2 from column bx, 16 bytes each, must be in the buffer (bx, by are
        // the smaller ends of the run: runs are monotonic in practice; every lane is checked
        // below anyway).
        if bx >= 0 && by >= 0 && (by as usize + 2) * stride + bx as usize + 16 <= data.len() {
            let dx = _mm256_sub_epi32(ix, _mm256_set1_epi32(bx));
            let dy = _mm256_sub_epi32(iy, _mm256_set1_epi32(by));
            // Lanes with dx > 14 or dy > 1 as unsigned numbers: signed compares of the values
            // with their sign bits flipped.
            let beyond = _mm256_or_si256(
                _mm256_cmpgt_epi32(_mm256_xor_si256(dx, self.sign), self.max_dx),
                _mm256_cmpgt_epi32(_mm256_xor_si256(dy, self.sign), self.max_dy),
            );
            if _mm256_testz_si256(beyond, beyond) == 1 {
                // Every lane has ix ≥ bx ≥ 0: all are inside, none is filled.
                let at = by as usize * stride + bx as usize;
                let p = data[at..at + 2 * stride + 16].as_ptr();
                // The row after next is needed by the next grid rows; fetch it now, as curved
                // (distorted) source paths defeat the hardware prefetcher. (A prefetch never
                // faults, so the address needs no check.)
                _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(3 * stride).cast());
                let idx = _mm256_add_epi32(
                    _mm256_add_epi32(dx, _mm256_slli_epi32::<16>(dx)),
                    self.idx_bias,
                );
                // SAFETY: rows by and by+1 from column bx, 16 bytes each, lie in the slice
                // taken above.
                let (t0, t1) = unsafe {
                    (
                        _mm256_shuffle_epi8(
                            _mm256_broadcastsi128_si256(_mm_loadu_si128(p.cast())),
                            idx,
                        ),
                        _mm256_shuffle_epi8(
                            _mm256_broadcastsi128_si256(_mm_loadu_si128(p.add(stride).cast())),
                            idx,
                        ),
                    )
                };
                // Lanes with dy = 0 use rows (by, by+1), the others (by+1, by+2); all of them
                // the first pair where the run stays in one row pair (most runs).
                let (pt, pb) = if _mm256_testz_si256(dy, dy) == 1 {
                    (t0, t1)
                } else {
                    // SAFETY: row by+2 from column bx, 16 bytes, lies in the slice above.
                    let t2 = unsafe {
                        _mm256_shuffle_epi8(
                            _mm256_broadcastsi128_si256(_mm_loadu_si128(p.add(2 * stride).cast())),
                            idx,
                        )
                    };
                    let first = _mm256_cmpeq_epi32(dy, _mm256_setzero_si256());
                    (
                        _mm256_blendv_epi8(t1, t0, first),
                        _mm256_blendv_epi8(t2, t1, first),
                    )
                };
                return pack8(self.weigh(pt, pb, fx, fy));
            }
        }
        self.gathered(job, ix, iy, fx, fy)
    }

    /// [`Gray8::step`] by two dword gathers (samples far apart, or some outside).
    #[target_feature(enable = "avx2")]
    #[inline(never)]
    fn gathered(
        &self,
        job: &Job<'_, u8>,
        ix: __m256i,
        iy: __m256i,
        fx: __m256i,
        fy: __m256i,
    ) -> __m128i {
        let (data, stride) = (job.src.data, job.src.stride);
        let base = data.as_ptr();
        let valid = _mm256_cmpgt_epi32(ix, self.minus1);
        // Outside samples read offset 0 (in bounds) and become fill.
        let off = _mm256_and_si256(
            _mm256_add_epi32(_mm256_mullo_epi32(iy, self.stride_v), ix),
            valid,
        );
        // SAFETY: stride ≥ 2 (width ≥ 2 is checked by the driver).
        let base_bot = unsafe { base.add(stride - 2) };
        // SAFETY: inside samples have ix ≤ W−2, iy ≤ H−2, so the top
        // dword [off, off+3] ends at ≤ (H−1)·W + 1 < W·H and the bottom
        // dword [off+W−2, off+W+1] ends at ≤ H·W − 1; offset 0 is in
        // bounds since W, H ≥ 2. The driver caps the buffer below
        // i32::MAX.
        let (gt, gb) = unsafe {
            (
                _mm256_i32gather_epi32::<1>(base.cast(), off),
                _mm256_i32gather_epi32::<1>(base_bot.cast(), off),
            )
        };
        let val = self.weigh(
            _mm256_shuffle_epi8(gt, self.shuf_top),
            _mm256_shuffle_epi8(gb, self.shuf_bot),
            fx,
            fy,
        );
        pack8(_mm256_blendv_epi8(self.fillv, val, valid))
    }

    /// The bilinear value (i32 lanes) from the pairs (p00, p01) and (p10, p11) as i16.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn weigh(&self, pt: __m256i, pb: __m256i, fx: __m256i, fy: __m256i) -> __m256i {
        // (ONE − fx, fx) as i16 pairs.
        let wx = _mm256_or_si256(_mm256_sub_epi32(self.one, fx), _mm256_slli_epi32::<16>(fx));
        let top = _mm256_madd_epi16(pt, wx);
        let bot = _mm256_madd_epi16(pb, wx);
        // top·(ONE − fy) + bot·fy = top·ONE + (bot − top)·fy
        let val = _mm256_add_epi32(
            _mm256_slli_epi32::<{ FRAC_BITS as i32 }>(top),
            _mm256_mullo_epi32(_mm256_sub_epi32(bot, top), fy),
        );
        _mm256_srai_epi32::<{ 2 * FRAC_BITS as i32 }>(_mm256_add_epi32(val, self.round))
    }
}

/// 8 i32 lanes, each 0..=255 (or clamped there), as 8 bytes.
#[target_feature(enable = "avx2")]
#[inline]
fn pack8(val: __m256i) -> __m128i {
    let p16 = _mm256_packus_epi32(val, val);
    let p8 = _mm256_packus_epi16(p16, p16);
    _mm_unpacklo_epi32(
        _mm256_castsi256_si128(p8),
        _mm256_extracti128_si256::<1>(p8),
    )
}

/// RGB: 8 pixels per step from pixel `start` of the run. Per pixel one 8-byte load from each of
/// the two rows; a pair of pixels shares a 256-bit register (one per 128-bit lane).
#[target_feature(enable = "avx2")]
pub(super) fn rgb8_run(job: &Job<'_, u8>, co: &Coords, out: &mut [u8], start: usize) {
    let src = &job.src;
    let (data, stride) = (src.data, src.stride);
    const Z: i8 = -128;
    // From [top 8 bytes | bottom 8 bytes]: top pairs (r0,r1) (g0,g1) (b0,b1),
    // with the bottom row loaded 2 bytes early (its pixel starts at byte 10).
    #[rustfmt::skip]
    let shuf_top = _mm256_setr_epi8(
        0, Z, 3, Z, 1, Z, 4, Z, 2, Z, 5, Z, Z, Z, Z, Z,
        0, Z, 3, Z, 1, Z, 4, Z, 2, Z, 5, Z, Z, Z, Z, Z,
    );
    #[rustfmt::skip]
    let shuf_bot = _mm256_setr_epi8(
        10, Z, 13, Z, 11, Z, 14, Z, 12, Z, 15, Z, Z, Z, Z, Z,
        10, Z, 13, Z, 11, Z, 14, Z, 12, Z, 15, Z, Z, Z, Z, Z,
    );
    // [r g b 0] x 4 → 12 packed bytes.
    #[rustfmt::skip]
    let pack = _mm_setr_epi8(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, Z, Z, Z, Z);
    let stride_v = _mm256_set1_epi32(stride as i32);
    let three = _mm256_set1_epi32(3);
    let one = _mm256_set1_epi32(ONE);
    let round = _mm256_set1_epi32(ROUND2 as i32);
    let fillv = _mm256_set1_epi32(i32::from(job.fill));
    let minus1 = _mm256_set1_epi32(-1);
    let base = data.as_ptr();
    let mut offs = [0i32; 8];
    let mut i = start;
    // Each 4-pixel store writes 16 bytes (12 used), so keep 4 bytes of slack.
    while 3 * i + 28 <= out.len() {
        let ix = load8(&co.ix, i);
        let iy = load8(&co.iy, i);
        let fx = load8(&co.fx, i);
        let fy = load8(&co.fy, i);
        let valid = _mm256_cmpgt_epi32(ix, minus1);
        let off = _mm256_and_si256(
            _mm256_add_epi32(
                _mm256_mullo_epi32(iy, stride_v),
                _mm256_mullo_epi32(ix, three),
            ),
            valid,
        );
        // SAFETY: `offs` is 8 i32; unaligned store.
        unsafe { _mm256_storeu_si256(offs.as_mut_ptr().cast(), off) };
        // Fetch the row after next early (see gray8_run).
        if let Some(ahead) = data.get(offs[4] as usize + 3 * stride) {
            _mm_prefetch::<_MM_HINT_T0>((ahead as *const u8).cast());
        }
        let wx = _mm256_or_si256(_mm256_sub_epi32(one, fx), _mm256_slli_epi32::<16>(fx));
        let mut res = [_mm256_setzero_si256(); 4];
        for (k, r) in res.iter_mut().enumerate() {
            let (a, b) = (offs[2 * k] as usize, offs[2 * k + 1] as usize);
            // SAFETY: inside samples have ix ≤ W−2, iy ≤ H−2, so the 8 bytes
            // at `off` end at ≤ (H−1)·3W + 1 and the 8 bytes at
            // `off + 3W − 2` end at ≤ 3W·H − 1, both in bounds; outside
            // samples use offset 0 (in bounds since W, H ≥ 2).
            let (ta, ba, tb, bb) = unsafe {
                (
                    _mm_loadl_epi64(base.add(a).cast()),
                    _mm_loadl_epi64(base.add(a + stride - 2).cast()),
                    _mm_loadl_epi64(base.add(b).cast()),
                    _mm_loadl_epi64(base.add(b + stride - 2).cast()),
                )
            };
            let v = _mm256_inserti128_si256::<1>(
                _mm256_castsi128_si256(_mm_unpacklo_epi64(ta, ba)),
                _mm_unpacklo_epi64(tb, bb),
            );
            let lanes = _mm256_setr_epi32(
                2 * k as i32,
                2 * k as i32,
                2 * k as i32,
                2 * k as i32,
                2 * k as i32 + 1,
                2 * k as i32 + 1,
                2 * k as i32 + 1,
                2 * k as i32 + 1,
            );
            let wxk = _mm256_permutevar8x32_epi32(wx, lanes);
            let fyk = _mm256_permutevar8x32_epi32(fy, lanes);
            let vk = _mm256_permutevar8x32_epi32(valid, lanes);
            let top = _mm256_madd_epi16(_mm256_shuffle_epi8(v, shuf_top), wxk);
            let bot = _mm256_madd_epi16(_mm256_shuffle_epi8(v, shuf_bot), wxk);
            let val = _mm256_add_epi32(
                _mm256_slli_epi32::<{ FRAC_BITS as i32 }>(top),
                _mm256_mullo_epi32(_mm256_sub_epi32(bot, top), fyk),
            );
            let val = _mm256_srai_epi32::<{ 2 * FRAC_BITS as i32 }>(_mm256_add_epi32(val, round));
            *r = _mm256_blendv_epi8(fillv, val, vk);
        }
        // res[k] = [pixel 2k | pixel 2k+1], each [r g b 0] as i32.
        for (h, pair) in res.chunks_exact(2).enumerate() {
            let w16 = _mm256_packus_epi32(pair[0], pair[1]); // [p0 p2 | p1 p3]
            let w8 = _mm256_packus_epi16(w16, w16);
            let px = _mm_unpacklo_epi32(
                _mm256_castsi256_si128(w8),
                _mm256_extracti128_si256::<1>(w8),
            ); // p0 p1 p2 p3 as [r g b 0]
            let px = _mm_shuffle_epi8(px, pack);
            let at = 3 * (i + 4 * h);
            let dst = &mut out[at..at + 16];
            // SAFETY: `dst` is exactly 16 bytes (loop condition); the last 4
            // are rewritten by the next store or the scalar tail.
            unsafe { _mm_storeu_si128(dst.as_mut_ptr().cast(), px) };
        }
        i += 8;
    }
    bilinear_run::<u8, 3>(job, co, out, i);
}
