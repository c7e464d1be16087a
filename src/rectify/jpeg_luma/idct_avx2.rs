//! The IDCT of `idct.rs` with AVX2 intrinsics: LLVM left the array version mostly scalar (its
//! transposes and row gathers). Same arithmetic, so the same pixels (tested below).

use std::arch::x86_64::*;
use std::ops::{Add, Mul, Sub};

use super::idct::{band_with, dc_only, idct_1d, Band, Lanes, CONST_BITS, PASS1_BITS};

/// Eight i32 lanes in a ymm register. Only made inside AVX2 functions, so its operators (inlined
/// there) run on a CPU with AVX2.
#[derive(Clone, Copy)]
struct W(__m256i);

impl Add for W {
    type Output = W;
    #[inline(always)]
    fn add(self, o: W) -> W {
        // SAFETY: W exists only where AVX2 is (see the type).
        W(unsafe { _mm256_add_epi32(self.0, o.0) })
    }
}

impl Sub for W {
    type Output = W;
    #[inline(always)]
    fn sub(self, o: W) -> W {
        // SAFETY: as for `add`.
        W(unsafe { _mm256_sub_epi32(self.0, o.0) })
    }
}

impl Mul<i32> for W {
    type Output = W;
    #[inline(always)]
    fn mul(self, c: i32) -> W {
        // SAFETY: as for `add`.
        W(unsafe { _mm256_mullo_epi32(self.0, _mm256_set1_epi32(c)) })
    }
}

impl Lanes for W {
    #[inline(always)]
    fn shl_const_bits(self) -> W {
        // SAFETY: as for `add`.
        W(unsafe { _mm256_slli_epi32::<{ CONST_BITS as i32 }>(self.0) })
    }
}

/// Rows to columns.
#[inline]
#[target_feature(enable = "avx2")]
fn transpose(r: [W; 8]) -> [W; 8] {
    let t0 = _mm256_unpacklo_epi32(r[0].0, r[1].0);
    let t1 = _mm256_unpackhi_epi32(r[0].0, r[1].0);
    let t2 = _mm256_unpacklo_epi32(r[2].0, r[3].0);
    let t3 = _mm256_unpackhi_epi32(r[2].0, r[3].0);
    let t4 = _mm256_unpacklo_epi32(r[4].0, r[5].0);
    let t5 = _mm256_unpackhi_epi32(r[4].0, r[5].0);
    let t6 = _mm256_unpacklo_epi32(r[6].0, r[7].0);
    let t7 = _mm256_unpackhi_epi32(r[6].0, r[7].0);
    let u0 = _mm256_unpacklo_epi64(t0, t2);
    let u1 = _mm256_unpackhi_epi64(t0, t2);
    let u2 = _mm256_unpacklo_epi64(t1, t3);
    let u3 = _mm256_unpackhi_epi64(t1, t3);
    let u4 = _mm256_unpacklo_epi64(t4, t6);
    let u5 = _mm256_unpackhi_epi64(t4, t6);
    let u6 = _mm256_unpacklo_epi64(t5, t7);
    let u7 = _mm256_unpackhi_epi64(t5, t7);
    [
        W(_mm256_permute2x128_si256::<0x20>(u0, u4)),
        W(_mm256_permute2x128_si256::<0x20>(u1, u5)),
        W(_mm256_permute2x128_si256::<0x20>(u2, u6)),
        W(_mm256_permute2x128_si256::<0x20>(u3, u7)),
        W(_mm256_permute2x128_si256::<0x31>(u0, u4)),
        W(_mm256_permute2x128_si256::<0x31>(u1, u5)),
        W(_mm256_permute2x128_si256::<0x31>(u2, u6)),
        W(_mm256_permute2x128_si256::<0x31>(u3, u7)),
    ]
}

/// The 8x8 pixels of one block (as `idct::idct_block`).
#[inline]
#[target_feature(enable = "avx2")]
fn idct_block(coefs: &[i16; 64], quant: &[i32; 64]) -> [[u8; 8]; 8] {
    if let Some(flat) = dc_only(coefs, quant) {
        return flat;
    }
    let rows: [W; 8] = std::array::from_fn(|r| {
        // SAFETY: rows r of 8 i16 and 8 i32 lie within the 64-element arrays.
        unsafe {
            let c = _mm_loadu_si128(coefs.as_ptr().add(r * 8).cast());
            let q = _mm256_loadu_si256(quant.as_ptr().add(r * 8).cast());
            W(_mm256_mullo_epi32(_mm256_cvtepi16_epi32(c), q))
        }
    });
    let round1 = _mm256_set1_epi32(1 << (CONST_BITS - PASS1_BITS - 1));
    let ws = idct_1d(&rows).map(|v| {
        W(_mm256_srai_epi32::<{ (CONST_BITS - PASS1_BITS) as i32 }>(
            _mm256_add_epi32(v.0, round1),
        ))
    });
    let mut cols = transpose(ws);
    cols[0] = W(_mm256_add_epi32(
        cols[0].0,
        _mm256_set1_epi32(1 << (PASS1_BITS + 2)),
    ));
    let out = idct_1d(&cols)
        .map(|v| W(_mm256_srai_epi32::<{ (CONST_BITS + PASS1_BITS + 3) as i32 }>(v.0)));
    let r = transpose(out);
    let bias = _mm256_set1_epi32(128);
    let r: [__m256i; 8] = std::array::from_fn(|i| _mm256_add_epi32(r[i].0, bias));
    // Saturating packs clamp to 0..=255; the permutes undo their lane interleaving.
    let pack4 = |a: __m256i, b: __m256i, c: __m256i, d: __m256i| {
        let ab = _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packs_epi32(a, b));
        let cd = _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packs_epi32(c, d));
        _mm256_permute4x64_epi64::<0b11_01_10_00>(_mm256_packus_epi16(ab, cd))
    };
    let mut px = [[0u8; 8]; 8];
    // SAFETY: two 32-byte stores into the 64-byte array.
    unsafe {
        _mm256_storeu_si256(px.as_mut_ptr().cast(), pack4(r[0], r[1], r[2], r[3]));
        _mm256_storeu_si256(px.as_mut_ptr().add(4).cast(), pack4(r[4], r[5], r[6], r[7]));
    }
    px
}

/// `idct::band` on AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn band(band: Band<'_>, quant: &[i32; 64]) {
    // A closure in an AVX2 function has AVX2 too.
    band_with(band, quant, |c, q| idct_block(c, q));
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_avx2_idct_gives_the_plain_idcts_pixels() {
        if !std::arch::is_x86_feature_detected!("avx2") {
            return;
        }
        let blocks = super::super::idct::tests::random_blocks(5000, 0x9E37_79B9);
        for (case, (coefs, quant)) in blocks.enumerate() {
            // SAFETY: the CPU has AVX2 (checked above).
            let fast = unsafe { super::idct_block(&coefs, &quant) };
            assert_eq!(
                fast,
                super::super::idct::idct_block(&coefs, &quant),
                "case {case}"
            );
        }
    }
}
