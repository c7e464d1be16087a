//! AVX-512 kernels (AVX-512 F/BW/VL/DQ/VBMI, selected at run time by `simd.rs`): phase 2 16
//! pixels per step, the samples picked with `vpermb` from source-row windows where they lie
//! close together (a grid row maps to a nearly straight image line, so they usually do), zmm
//! gathers (grey) or the AVX2 kernel (RGB) otherwise. Phase 1 is `map_run` compiled 16 lanes
//! wide. The arithmetic is `bilinear_run`'s exact integers, so results are bit-identical to the
//! scalar path.

use std::arch::x86_64::*;

use super::avx2::{rgb8_run, row_8bit};
use crate::rectify::kernel::{bilinear_run, Coords, Job, FRAC_BITS, ONE, ROUND2};

/// Even bytes of each dword: the sample pairs, odd bytes zero (i16 lanes for `madd`).
const EVEN: __mmask64 = 0x5555_5555_5555_5555;

/// Bilinear 8-bit grey row: phase 1 compiled 16 lanes wide, phase 2 [`gray8_run16`].
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn row_gray8(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    row_8bit::<1>(job, row, out, co, |j, c, o| gray8_run16(j, c, o))
}

/// Bilinear 8-bit RGB row: phase 1 compiled 16 lanes wide, phase 2 [`rgb8_run16`].
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn row_rgb8(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    row_8bit::<3>(job, row, out, co, |j, c, o| rgb8_run16(j, c, o))
}

/// Loads 16 i32 from `v[i..i + 16]`.
#[inline(always)]
fn load16(v: &[i32], i: usize) -> __m512i {
    let s = &v[i..i + 16];
    // SAFETY: `s` holds exactly 16 i32 (bounds-checked slice); unaligned load.
    unsafe { _mm512_loadu_si512(s.as_ptr().cast()) }
}

/// 16 positions of a run (from `Coords`), which are inside, and their offsets from the window
/// origin (`bx`, `by`): the smaller end of the 16 per axis (runs are monotonic in practice;
/// the kernels check every lane against their window anyway).
struct Step16 {
    fx: __m512i,
    fy: __m512i,
    inside: __mmask16,
    bx: i32,
    by: i32,
    dx: __m512i,
    dy: __m512i,
    /// Only the gather path needs these.
    ix: __m512i,
    iy: __m512i,
}

/// The [`Step16`] of pixels `i..i + 16` of the run.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
fn step16(co: &Coords, i: usize) -> Step16 {
    let ix = load16(&co.ix, i);
    let iy = load16(&co.iy, i);
    let bx = co.ix[i].min(co.ix[i + 15]);
    let by = co.iy[i].min(co.iy[i + 15]);
    Step16 {
        fx: load16(&co.fx, i),
        fy: load16(&co.fy, i),
        inside: _mm512_cmpgt_epi32_mask(ix, _mm512_set1_epi32(-1)),
        bx,
        by,
        dx: _mm512_sub_epi32(ix, _mm512_set1_epi32(bx)),
        dy: _mm512_sub_epi32(iy, _mm512_set1_epi32(by)),
        ix,
        iy,
    }
}

/// The bilinear blend of sample pairs `pt` (top row) and `pb` (bottom row), as i16 pairs in
/// each dword, with weights `fx`, `fy`: `bilinear_run`'s integers, 16 lanes.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
fn lerp(pt: __m512i, pb: __m512i, fx: __m512i, fy: __m512i) -> __m512i {
    let wx = _mm512_or_si512(
        _mm512_sub_epi32(_mm512_set1_epi32(ONE), fx),
        _mm512_slli_epi32::<16>(fx),
    );
    let top = _mm512_madd_epi16(pt, wx);
    let bot = _mm512_madd_epi16(pb, wx);
    // top·(ONE − fy) + bot·fy = top·ONE + (bot − top)·fy
    let val = _mm512_add_epi32(
        _mm512_slli_epi32::<{ FRAC_BITS }>(top),
        _mm512_mullo_epi32(_mm512_sub_epi32(bot, top), fy),
    );
    _mm512_srai_epi32::<{ 2 * FRAC_BITS }>(_mm512_add_epi32(val, _mm512_set1_epi32(ROUND2 as i32)))
}

/// Grey: [`gray8_run`](super::avx2::gray8_run) 16 pixels per step, the row windows 64 bytes wide (any 16
/// samples within 62 columns and two source rows) picked from with `vpermb`. Same integer
/// arithmetic, so bit-identical.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn gray8_run16(job: &Job<'_, u8>, co: &Coords, out: &mut [u8]) {
    let (data, stride, n) = (job.src.data, job.src.stride, out.len());
    let base = data.as_ptr();
    const Z: i8 = -128;
    #[rustfmt::skip]
    let shuf_top = _mm512_broadcast_i32x4(_mm_setr_epi8(
        0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z, 13, Z,
    ));
    #[rustfmt::skip]
    let shuf_bot = _mm512_broadcast_i32x4(_mm_setr_epi8(
        2, Z, 3, Z, 6, Z, 7, Z, 10, Z, 11, Z, 14, Z, 15, Z,
    ));
    let stride_v = _mm512_set1_epi32(stride as i32);
    let fillv = _mm512_set1_epi32(i32::from(job.fill));
    let max_dx = _mm512_set1_epi32(62);
    let max_dy = _mm512_set1_epi32(1);
    // SAFETY: stride ≥ 2 (width ≥ 2 is checked by the driver).
    let base_bot = unsafe { base.add(stride - 2) };
    let mut i = 0;
    while i + 16 <= n {
        let Step16 {
            fx,
            fy,
            inside: valid,
            bx,
            by,
            dx,
            dy,
            ix,
            iy,
        } = step16(co, i);
        let mut pairs = None;
        // Rows by..=by+2 from column bx, 64 bytes each, must be in the buffer.
        if bx >= 0 && (by as usize + 2) * stride + bx as usize + 64 <= data.len() {
            let fits = _mm512_cmple_epu32_mask(dx, max_dx) & _mm512_cmple_epu32_mask(dy, max_dy);
            if fits == 0xffff {
                let at = by as usize * stride + bx as usize;
                let w = &data[at..at + 2 * stride + 64];
                if let Some(ahead) = data.get(at + 3 * stride) {
                    _mm_prefetch::<_MM_HINT_T0>((ahead as *const u8).cast());
                }
                // SAFETY: each 64-byte window lies inside `w` (bounds-checked slice).
                let row = |k: usize| unsafe { _mm512_loadu_si512(w[k * stride..].as_ptr().cast()) };
                // Byte index per dword: [dx, ·, dx + 1, ·].
                let idx = _mm512_add_epi32(
                    _mm512_add_epi32(dx, _mm512_slli_epi32::<16>(dx)),
                    _mm512_set1_epi32(0x1_0000),
                );
                let pick = |r: __m512i| _mm512_maskz_permutexvar_epi8(EVEN, idx, r);
                let (t0, t1) = (pick(row(0)), pick(row(1)));
                // Lanes with dy = 0 use rows (by, by+1), the others (by+1, by+2).
                let first = _mm512_cmpeq_epi32_mask(dy, _mm512_setzero_si512());
                pairs = Some(if first == u16::MAX {
                    (t0, t1)
                } else {
                    let t2 = pick(row(2));
                    (
                        _mm512_mask_blend_epi32(first, t1, t0),
                        _mm512_mask_blend_epi32(first, t2, t1),
                    )
                });
            }
        }
        let (pt, pb) = match pairs {
            Some(p) => p,
            None => {
                // Outside samples read offset 0 (in bounds) and become fill.
                let off = _mm512_maskz_add_epi32(valid, _mm512_mullo_epi32(iy, stride_v), ix);
                // SAFETY: as in gray8_run: inside samples have ix ≤ W−2, iy ≤ H−2, so the top
                // dword [off, off+3] ends at ≤ (H−1)·W + 1 < W·H and the bottom dword
                // [off+W−2, off+W+1] ends at ≤ H·W − 1; offset 0 is in bounds since W, H ≥ 2.
                // The driver caps the buffer below i32::MAX.
                let (gt, gb) = unsafe {
                    (
                        _mm512_i32gather_epi32::<1>(off, base.cast()),
                        _mm512_i32gather_epi32::<1>(off, base_bot.cast()),
                    )
                };
                (
                    _mm512_shuffle_epi8(gt, shuf_top),
                    _mm512_shuffle_epi8(gb, shuf_bot),
                )
            }
        };
        let val = lerp(pt, pb, fx, fy);
        // Values are 0..=255 (a convex blend of bytes, fill clamped), so truncation is exact.
        let px = _mm512_cvtepi32_epi8(_mm512_mask_blend_epi32(valid, fillv, val));
        let dst = &mut out[i..i + 16];
        // SAFETY: `dst` is exactly 16 bytes; unaligned store.
        unsafe { _mm_storeu_si128(dst.as_mut_ptr().cast(), px) };
        i += 16;
    }
    bilinear_run::<u8, 1>(job, co, out, i);
}

/// RGB: 16 pixels per step. Where all 16 are inside and lie within 40 columns and two
/// consecutive source rows, their samples are picked with `vpermt2b` from 128-byte windows of
/// three rows, one channel at a time; other steps go to the AVX2 [`rgb8_run`].
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn rgb8_run16(job: &Job<'_, u8>, co: &Coords, out: &mut [u8]) {
    let (data, stride) = (job.src.data, job.src.stride);
    let n = out.len() / 3;
    // [r g b 0] per dword → 48 packed bytes: byte k from 4·(k / 3) + k % 3.
    let mut pack = [0u8; 64];
    for (k, v) in pack.iter_mut().enumerate().take(48) {
        *v = (4 * (k / 3) + k % 3) as u8;
    }
    // SAFETY: 64 bytes; unaligned load.
    let pack = unsafe { _mm512_loadu_si512(pack.as_ptr().cast()) };
    let mut i = 0;
    while i + 16 <= n {
        let Step16 {
            fx,
            fy,
            inside,
            bx,
            by,
            dx,
            dy,
            ..
        } = step16(co, i);
        let fits = inside
            & _mm512_cmple_epu32_mask(dx, _mm512_set1_epi32(40))
            & _mm512_cmple_epu32_mask(dy, _mm512_set1_epi32(1));
        // Rows by..=by+2 from pixel bx, 128 bytes each, must be in the buffer (bx, by ≥ 0 when
        // every lane is inside).
        let at = match fits {
            u16::MAX => by as usize * stride + 3 * bx as usize,
            _ => usize::MAX,
        };
        // (A frame smaller than the window has no room for it anywhere, `at` = 0 included.)
        if at
            .checked_add(2 * stride + 128)
            .is_none_or(|end| end > data.len())
        {
            rgb8_run(job, co, &mut out[..3 * (i + 16)], i);
            i += 16;
            continue;
        }
        let w = &data[at..at + 2 * stride + 128];
        if let Some(ahead) = data.get(at + 3 * stride + 64) {
            _mm_prefetch::<_MM_HINT_T0>((ahead as *const u8).cast());
        }
        // SAFETY: both 64-byte halves lie inside `w` (bounds-checked slice).
        let row = |k: usize| unsafe {
            (
                _mm512_loadu_si512(w[k * stride..].as_ptr().cast()),
                _mm512_loadu_si512(w[k * stride + 64..].as_ptr().cast()),
            )
        };
        let pick = |r: (__m512i, __m512i), idx: __m512i| {
            _mm512_maskz_permutex2var_epi8(EVEN, r.0, idx, r.1)
        };
        // Byte index per dword, channel 0: [3·dx, ·, 3·dx + 3, ·]; channel c adds c.
        let d3 = _mm512_add_epi32(dx, _mm512_add_epi32(dx, dx));
        let idx0 = _mm512_add_epi32(
            d3,
            _mm512_slli_epi32::<16>(_mm512_add_epi32(d3, _mm512_set1_epi32(3))),
        );
        let (r0, r1) = (row(0), row(1));
        // Lanes with dy = 0 use rows (by, by+1), the others (by+1, by+2).
        let first = _mm512_cmpeq_epi32_mask(dy, _mm512_setzero_si512());
        let mut v = [_mm512_setzero_si512(); 3];
        if first == u16::MAX {
            for (c, vc) in v.iter_mut().enumerate() {
                let idx = _mm512_add_epi32(idx0, _mm512_set1_epi32(c as i32 * 0x1_0001));
                *vc = lerp(pick(r0, idx), pick(r1, idx), fx, fy);
            }
        } else {
            let r2 = row(2);
            for (c, vc) in v.iter_mut().enumerate() {
                let idx = _mm512_add_epi32(idx0, _mm512_set1_epi32(c as i32 * 0x1_0001));
                let (t0, t1, t2) = (pick(r0, idx), pick(r1, idx), pick(r2, idx));
                *vc = lerp(
                    _mm512_mask_blend_epi32(first, t1, t0),
                    _mm512_mask_blend_epi32(first, t2, t1),
                    fx,
                    fy,
                );
            }
        }
        // Values are 0..=255 (convex blends of bytes): [r g b 0] per dword, then packed.
        let rgb0 = _mm512_or_si512(
            v[0],
            _mm512_or_si512(_mm512_slli_epi32::<8>(v[1]), _mm512_slli_epi32::<16>(v[2])),
        );
        let px = _mm512_permutexvar_epi8(pack, rgb0);
        let dst = &mut out[3 * i..3 * i + 48];
        // SAFETY: `dst` is exactly 48 bytes; masked store of those 48.
        unsafe { _mm512_mask_storeu_epi8(dst.as_mut_ptr().cast(), (1 << 48) - 1, px) };
        i += 16;
    }
    rgb8_run(job, co, out, i);
}
