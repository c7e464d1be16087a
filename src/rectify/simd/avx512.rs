//! AVX-512 kernels (AVX-512 F/BW/VL/DQ/VBMI, selected at run time by `simd.rs`): phase 2 16
//! pixels per step, the samples picked with `vpermb` from source-row windows where they lie
//! close together (a grid row maps to a nearly straight image line, so they usually do), zmm
//! gathers (grey) or the AVX2 kernel (RGB) otherwise. Grey blocks on phase 1's quadratic path
//! are positioned in registers too, 16 lanes of 64-bit integers; other positions come from
//! `map_run`, compiled here. The arithmetic is `bilinear_run`'s exact integers, so results are
//! bit-identical to the scalar path.

use std::arch::x86_64::*;

use super::avx2::{gray8_row, rgb8_run, row_8bit};
use crate::rectify::kernel::{bilinear_run, Coords, Job, FRAC_BITS, ONE, ROUND2};
use crate::rectify::positions::QuadBlock;

/// Even bytes of each dword: the sample pairs, odd bytes zero (i16 lanes for `madd`).
const EVEN: __mmask64 = 0x5555_5555_5555_5555;

/// Bilinear 8-bit grey row: a block of phase 1's quadratic path is positioned and sampled 16
/// pixels at a time in registers ([`gray8_quad16`]: its coordinates never go through memory);
/// other blocks, and rows with distortion, are phase 1 (compiled 16 lanes wide) then
/// [`gray8_run16`].
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn row_gray8(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    gray8_row(
        job,
        row,
        out,
        co,
        |j, b, o, c| gray8_quad16(j, b, o, c),
        |j, c, o| gray8_run16(j, c, o),
    )
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
    let bx = co.ix[i].min(co.ix[i + 15]);
    let by = co.iy[i].min(co.iy[i + 15]);
    let [ix, iy, fx, fy] = [&co.ix, &co.iy, &co.fx, &co.fy].map(|v| load16(v, i));
    Step16::of(ix, iy, fx, fy, bx, by)
}

impl Step16 {
    /// The step of 16 positions, with the window origin `(bx, by)`.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    #[inline]
    fn of(ix: __m512i, iy: __m512i, fx: __m512i, fy: __m512i, bx: i32, by: i32) -> Step16 {
        Step16 {
            fx,
            fy,
            inside: _mm512_cmpgt_epi32_mask(ix, _mm512_set1_epi32(-1)),
            bx,
            by,
            dx: _mm512_sub_epi32(ix, _mm512_set1_epi32(bx)),
            dy: _mm512_sub_epi32(iy, _mm512_set1_epi32(by)),
            ix,
            iy,
        }
    }

    /// The step of 16 positions in registers, the window origin from their first and last.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    #[inline]
    fn of_lanes(ix: __m512i, iy: __m512i, fx: __m512i, fy: __m512i) -> Step16 {
        let first = |v: __m512i| _mm_cvtsi128_si32(_mm512_castsi512_si128(v));
        let last = |v: __m512i| _mm_extract_epi32::<3>(_mm512_extracti32x4_epi32::<3>(v));
        let (bx, by) = (first(ix).min(last(ix)), first(iy).min(last(iy)));
        Step16::of(ix, iy, fx, fy, bx, by)
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

/// Grey: [`gray8_run`](super::avx2::gray8_run) 16 pixels per step ([`Gray16::step`]), from
/// the coordinates phase 1 wrote.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
pub(super) fn gray8_run16(job: &Job<'_, u8>, co: &Coords, out: &mut [u8]) {
    let k = Gray16::new(job);
    let n = out.len();
    let mut i = 0;
    while i + 16 <= n {
        let px = k.step(job, step16(co, i));
        let dst = &mut out[i..i + 16];
        // SAFETY: `dst` is exactly 16 bytes; unaligned store.
        unsafe { _mm_storeu_si128(dst.as_mut_ptr().cast(), px) };
        i += 16;
    }
    bilinear_run::<u8, 1>(job, co, out, i);
}

/// Grey, one block of phase 1's quadratic path ([`QuadBlock`]): 16 lanes of 64-bit positions
/// stepped by their differences ([`Lanes16`], the integers [`QuadBlock::fill`] gives) and
/// sampled at once ([`Gray16::step`]). The last `len % 16` pixels go through `at` and the
/// scalar kernel.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
fn gray8_quad16(job: &Job<'_, u8>, b: &QuadBlock, out: &mut [u8], co: &mut Coords) {
    let k = Gray16::new(job);
    let n = out.len();
    let mut lanes = Lanes16::new(b);
    let mut i = 0;
    while i + 16 <= n {
        let (xq, yq) = lanes.next();
        let [ix, iy, fx, fy] = k.finish(xq, yq);
        let px = k.step(job, Step16::of_lanes(ix, iy, fx, fy));
        let dst = &mut out[i..i + 16];
        // SAFETY: `dst` is exactly 16 bytes; unaligned store.
        unsafe { _mm_storeu_si128(dst.as_mut_ptr().cast(), px) };
        i += 16;
    }
    for j in i..n {
        (co.ix[j], co.iy[j], co.fx[j], co.fy[j]) = b.at(job, j);
    }
    bilinear_run::<u8, 1>(job, co, out, i);
}

/// The quadratics' 16 lanes ([`QuadBlock::lanes`]): pixels 0-7 in the first register of each
/// pair, 8-15 in the second; the high dword of each lane is the fixed-point position.
struct Lanes16 {
    x: [__m512i; 2],
    dx: [__m512i; 2],
    ddx: __m512i,
    y: [__m512i; 2],
    dy: [__m512i; 2],
    ddy: __m512i,
    /// `vpermt2d` indices of the 16 high dwords, in pixel order.
    high: __m512i,
}

impl Lanes16 {
    /// The lanes of block pixels 0..16.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    fn new(b: &QuadBlock) -> Lanes16 {
        const _: () = assert!(
            crate::rectify::positions::QF == 32,
            "the high half of each lane is the fixed-point position"
        );
        // SAFETY: each half is exactly 8 i64; unaligned loads.
        let split = |v: &[i64; 16]| unsafe {
            [
                _mm512_loadu_si512(v[..8].as_ptr().cast()),
                _mm512_loadu_si512(v[8..].as_ptr().cast()),
            ]
        };
        let (vx, dx, ddx) = QuadBlock::lanes::<16>(&b.x, 0);
        let (vy, dy, ddy) = QuadBlock::lanes::<16>(&b.y, 0);
        Lanes16 {
            x: split(&vx),
            dx: split(&dx),
            ddx: _mm512_set1_epi64(ddx),
            y: split(&vy),
            dy: split(&dy),
            ddy: _mm512_set1_epi64(ddy),
            high: _mm512_setr_epi32(1, 3, 5, 7, 9, 11, 13, 15, 17, 19, 21, 23, 25, 27, 29, 31),
        }
    }

    /// The next 16 pixels' fixed-point positions (x, y), as 16 i32 each in pixel order.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    #[inline]
    fn next(&mut self) -> (__m512i, __m512i) {
        let q = (
            _mm512_permutex2var_epi32(self.x[0], self.high, self.x[1]),
            _mm512_permutex2var_epi32(self.y[0], self.high, self.y[1]),
        );
        for k in 0..2 {
            self.x[k] = _mm512_add_epi64(self.x[k], self.dx[k]);
            self.dx[k] = _mm512_add_epi64(self.dx[k], self.ddx);
            self.y[k] = _mm512_add_epi64(self.y[k], self.dy[k]);
            self.dy[k] = _mm512_add_epi64(self.dy[k], self.ddy);
        }
        q
    }
}

/// The grey kernel's constants, 16 lanes.
struct Gray16 {
    shuf_top: __m512i,
    shuf_bot: __m512i,
    stride_v: __m512i,
    fillv: __m512i,
    max_dx: __m512i,
    max_dy: __m512i,
    /// Phase 1's `finish`: the last fixed-point positions inside, the last window origins.
    xmax: __m512i,
    ymax: __m512i,
    wm2: __m512i,
    hm2: __m512i,
}

impl Gray16 {
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    fn new(job: &Job<'_, u8>) -> Gray16 {
        const Z: i8 = -128;
        #[rustfmt::skip]
        let shuf_top = _mm512_broadcast_i32x4(_mm_setr_epi8(
            0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z, 13, Z,
        ));
        #[rustfmt::skip]
        let shuf_bot = _mm512_broadcast_i32x4(_mm_setr_epi8(
            2, Z, 3, Z, 6, Z, 7, Z, 10, Z, 11, Z, 14, Z, 15, Z,
        ));
        Gray16 {
            shuf_top,
            shuf_bot,
            stride_v: _mm512_set1_epi32(job.src.stride as i32),
            fillv: _mm512_set1_epi32(i32::from(job.fill)),
            max_dx: _mm512_set1_epi32(62),
            max_dy: _mm512_set1_epi32(1),
            xmax: _mm512_set1_epi32(job.xmax_q),
            ymax: _mm512_set1_epi32(job.ymax_q),
            wm2: _mm512_set1_epi32(job.wm2),
            hm2: _mm512_set1_epi32(job.hm2),
        }
    }

    /// Phase 1's `finish` on 16 fixed-point positions, as
    /// [`Finish8`](crate::rectify::positions::Finish8) does it on 8: (ix, iy, fx, fy), `ix` −1
    /// outside.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    #[inline]
    fn finish(&self, xq: __m512i, yq: __m512i) -> [__m512i; 4] {
        let ok = _mm512_cmple_epu32_mask(xq, self.xmax) & _mm512_cmple_epu32_mask(yq, self.ymax);
        let xi = _mm512_min_epi32(_mm512_srai_epi32::<{ FRAC_BITS }>(xq), self.wm2);
        let iy = _mm512_min_epi32(_mm512_srai_epi32::<{ FRAC_BITS }>(yq), self.hm2);
        let fx = _mm512_sub_epi32(xq, _mm512_slli_epi32::<{ FRAC_BITS }>(xi));
        let fy = _mm512_sub_epi32(yq, _mm512_slli_epi32::<{ FRAC_BITS }>(iy));
        let ix = _mm512_mask_mov_epi32(_mm512_set1_epi32(-1), ok, xi);
        [ix, iy, fx, fy]
    }

    /// 16 grey pixels (outside ones filled), as 16 bytes: the samples picked with `vpermb`
    /// from 64-byte row windows (any 16 samples within 62 columns and two source rows), or
    /// gathered otherwise. Same integer arithmetic as `gray8_run`, so bit-identical.
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512dq,avx512vbmi")]
    #[inline]
    fn step(&self, job: &Job<'_, u8>, s: Step16) -> __m128i {
        let (data, stride) = (job.src.data, job.src.stride);
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
        } = s;
        let mut pairs = None;
        // Rows by..=by+2 from column bx, 64 bytes each, must be in the buffer.
        if bx >= 0 && (by as usize + 2) * stride + bx as usize + 64 <= data.len() {
            let fits =
                _mm512_cmple_epu32_mask(dx, self.max_dx) & _mm512_cmple_epu32_mask(dy, self.max_dy);
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
                let base = data.as_ptr();
                // SAFETY: stride ≥ 2 (width ≥ 2 is checked by the driver).
                let base_bot = unsafe { base.add(stride - 2) };
                // Outside samples read offset 0 (in bounds) and become fill.
                let off = _mm512_maskz_add_epi32(valid, _mm512_mullo_epi32(iy, self.stride_v), ix);
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
                    _mm512_shuffle_epi8(gt, self.shuf_top),
                    _mm512_shuffle_epi8(gb, self.shuf_bot),
                )
            }
        };
        let val = lerp(pt, pb, fx, fy);
        // Values are 0..=255 (a convex blend of bytes, fill clamped), so truncation is exact.
        _mm512_cvtepi32_epi8(_mm512_mask_blend_epi32(valid, self.fillv, val))
    }
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
