//! Dequantisation and the inverse DCT of the luma blocks: libjpeg's `jidctint` ("islow", the
//! integer IDCT libjpeg-turbo and zune-jpeg use), eight columns (then eight rows) at a time as
//! eight-lane vectors that LLVM turns into AVX2 instructions where the CPU has them.
//!
//! Arithmetic wraps (as libjpeg's 32-bit SIMD versions do) so that corrupt coefficients give
//! wrong pixels, never an overflow panic.

use std::ops::{Add, Mul, Sub};

/// Eight lanes of i32, as the 1-D IDCT needs them: wrapping add, subtract, multiply by a
/// constant, shift left by `CONST_BITS`.
pub(super) trait Lanes:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<i32, Output = Self>
{
    fn shl_const_bits(self) -> Self;
}

/// Eight lanes of i32 in an array (LLVM vectorises what it can).
#[derive(Clone, Copy, Default)]
struct V([i32; 8]);

impl Lanes for V {
    #[inline(always)]
    fn shl_const_bits(self) -> V {
        self.shl(CONST_BITS)
    }
}

impl Add for V {
    type Output = V;
    #[inline(always)]
    fn add(self, o: V) -> V {
        V(std::array::from_fn(|i| self.0[i].wrapping_add(o.0[i])))
    }
}

impl Sub for V {
    type Output = V;
    #[inline(always)]
    fn sub(self, o: V) -> V {
        V(std::array::from_fn(|i| self.0[i].wrapping_sub(o.0[i])))
    }
}

impl Mul<i32> for V {
    type Output = V;
    #[inline(always)]
    fn mul(self, c: i32) -> V {
        V(std::array::from_fn(|i| self.0[i].wrapping_mul(c)))
    }
}

impl V {
    #[inline(always)]
    fn shl(self, n: u32) -> V {
        V(std::array::from_fn(|i| self.0[i].wrapping_shl(n)))
    }

    /// `(x + add) >> n`, arithmetic.
    #[inline(always)]
    fn descale(self, add: i32, n: u32) -> V {
        V(std::array::from_fn(|i| self.0[i].wrapping_add(add) >> n))
    }
}

pub(super) const CONST_BITS: u32 = 13;
pub(super) const PASS1_BITS: u32 = 2;

/// One 1-D pass of jidctint on eight lanes: `s[k]` is frequency k; returns the eight samples
/// before descaling.
#[inline(always)]
pub(super) fn idct_1d<T: Lanes>(s: &[T; 8]) -> [T; 8] {
    // Even part.
    let z1 = (s[2] + s[6]) * 4433;
    let tmp2 = z1 + s[6] * -15137;
    let tmp3 = z1 + s[2] * 6270;
    let tmp0 = (s[0] + s[4]).shl_const_bits();
    let tmp1 = (s[0] - s[4]).shl_const_bits();
    let tmp10 = tmp0 + tmp3;
    let tmp13 = tmp0 - tmp3;
    let tmp11 = tmp1 + tmp2;
    let tmp12 = tmp1 - tmp2;
    // Odd part.
    let (t0, t1, t2, t3) = (s[7], s[5], s[3], s[1]);
    let z1 = t0 + t3;
    let z2 = t1 + t2;
    let z3 = t0 + t2;
    let z4 = t1 + t3;
    let z5 = (z3 + z4) * 9633;
    let t0 = t0 * 2446;
    let t1 = t1 * 16819;
    let t2 = t2 * 25172;
    let t3 = t3 * 12299;
    let z1 = z1 * -7373;
    let z2 = z2 * -20995;
    let z3 = z3 * -16069 + z5;
    let z4 = z4 * -3196 + z5;
    let t0 = t0 + z1 + z3;
    let t1 = t1 + z2 + z4;
    let t2 = t2 + z2 + z3;
    let t3 = t3 + z1 + z4;
    [
        tmp10 + t3,
        tmp11 + t2,
        tmp12 + t1,
        tmp13 + t0,
        tmp13 - t0,
        tmp12 - t1,
        tmp11 - t2,
        tmp10 - t3,
    ]
}

#[inline(always)]
fn transpose(m: &[V; 8]) -> [V; 8] {
    std::array::from_fn(|c| V(std::array::from_fn(|r| m[r].0[c])))
}

/// The pixels of a block whose AC coefficients are all zero (`None` for any other): the two
/// passes reduce to one value, exactly as jidctint's shortcuts.
#[inline(always)]
pub(super) fn dc_only(coefs: &[i16; 64], quant: &[i32; 64]) -> Option<[[u8; 8]; 8]> {
    if coefs[1..].iter().fold(0i16, |a, &c| a | c) != 0 {
        return None;
    }
    let dc = i32::from(coefs[0]).wrapping_mul(quant[0]);
    let v = (dc.wrapping_shl(PASS1_BITS).wrapping_add(16) >> 5).wrapping_add(128);
    Some([[v.clamp(0, 255) as u8; 8]; 8])
}

/// The 8x8 pixels of one block (natural-order coefficients, natural-order quantisation).
#[inline(always)]
pub(super) fn idct_block(coefs: &[i16; 64], quant: &[i32; 64]) -> [[u8; 8]; 8] {
    if let Some(flat) = dc_only(coefs, quant) {
        return flat;
    }
    // Pass 1: columns (lanes) over the rows.
    let rows: [V; 8] = std::array::from_fn(|r| {
        V(std::array::from_fn(|c| {
            i32::from(coefs[r * 8 + c]).wrapping_mul(quant[r * 8 + c])
        }))
    });
    let ws = idct_1d(&rows);
    let ws: [V; 8] = std::array::from_fn(|r| {
        ws[r].descale(1 << (CONST_BITS - PASS1_BITS - 1), CONST_BITS - PASS1_BITS)
    });
    // Pass 2: rows (lanes) over the columns; the rounding of the final descale added to the DC.
    let mut cols = transpose(&ws);
    cols[0] = cols[0] + V([1 << (PASS1_BITS + 2); 8]);
    let out = idct_1d(&cols);
    let out: [V; 8] = std::array::from_fn(|c| out[c].descale(0, CONST_BITS + PASS1_BITS + 3));
    // out[c] holds column c for every row.
    std::array::from_fn(|r| {
        std::array::from_fn(|c| out[c].0[r].wrapping_add(128).clamp(0, 255) as u8)
    })
}

/// A band of luma blocks to pixels.
pub(super) struct Band<'a> {
    /// `block_rows` rows of `blocks_per_row` blocks of 64 natural-order coefficients; zeroed on
    /// return.
    pub(super) coefs: &'a mut [i16],
    pub(super) blocks_per_row: usize,
    /// Rows of `width` pixels from the band's top (fewer than the blocks cover at the bottom).
    pub(super) out: &'a mut [u8],
    pub(super) width: usize,
    /// Per block row, the blocks to turn into pixels (all if `None`); the others hold zeros
    /// (they were never written) and their pixels are left as they are.
    pub(super) needed: Option<&'a [std::ops::Range<usize>]>,
}

/// Dequantises and IDCTs `band` without AVX2 (`idct_avx2::band` with).
pub(super) fn band(band: Band<'_>, quant: &[i32; 64]) {
    band_with(band, quant, idct_block);
}

/// `band` to pixels, each block by `idct`.
#[inline(always)]
pub(super) fn band_with(
    band: Band<'_>,
    quant: &[i32; 64],
    idct: impl Fn(&[i16; 64], &[i32; 64]) -> [[u8; 8]; 8],
) {
    let Band {
        coefs,
        blocks_per_row,
        out,
        width,
        needed,
    } = band;
    if width == 0 || blocks_per_row == 0 {
        return;
    }
    let rows = out.len() / width;
    for (br, row_coefs) in coefs.chunks_exact_mut(blocks_per_row * 64).enumerate() {
        let y0 = br * 8;
        if y0 >= rows {
            row_coefs.fill(0);
            continue;
        }
        let h = (rows - y0).min(8);
        let band_out = &mut out[y0 * width..(y0 + h) * width];
        let columns = needed.map_or(0..blocks_per_row, |n| n.get(br).cloned().unwrap_or(0..0));
        let blocks = row_coefs.chunks_exact_mut(64).enumerate();
        for (bc, block) in blocks.skip(columns.start).take(columns.len()) {
            let x0 = bc * 8;
            let Ok(block) = <&mut [i16; 64]>::try_from(block) else {
                continue;
            };
            if x0 < width {
                let px = idct(block, quant);
                let w = (width - x0).min(8);
                for (r, line) in px.iter().enumerate().take(h) {
                    let dst = &mut band_out[r * width + x0..r * width + x0 + w];
                    if let Ok(dst) = <&mut [u8; 8]>::try_from(&mut *dst) {
                        // A whole row: one 8-byte store, not a call to memcpy.
                        *dst = *line;
                    } else {
                        dst.copy_from_slice(&line[..w]);
                    }
                }
            }
            *block = [0; 64];
        }
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// jidctint with libjpeg's column and row shortcuts, scalar, as written in jidctint.c.
    fn reference(coefs: &[i16; 64], quant: &[i32; 64]) -> [[u8; 8]; 8] {
        let mut ws = [0i64; 64];
        let f = |x: f64| (x * 8192.0 + 0.5) as i64;
        let (c0298, c0390, c0541, c0765, c0899, c1175, c1501, c1847, c1961, c2053, c2562, c3072) = (
            f(0.298631336),
            f(0.390180644),
            f(0.541196100),
            f(0.765366865),
            f(0.899976223),
            f(1.175875602),
            f(1.501321110),
            f(1.847759065),
            f(1.961570560),
            f(2.053119869),
            f(2.562915447),
            f(3.072711026),
        );
        let one_d = |s: [i64; 8]| -> [i64; 8] {
            let z1 = (s[2] + s[6]) * c0541;
            let tmp2 = z1 - s[6] * c1847;
            let tmp3 = z1 + s[2] * c0765;
            let tmp0 = (s[0] + s[4]) << 13;
            let tmp1 = (s[0] - s[4]) << 13;
            let (tmp10, tmp13, tmp11, tmp12) = (tmp0 + tmp3, tmp0 - tmp3, tmp1 + tmp2, tmp1 - tmp2);
            let (t0, t1, t2, t3) = (s[7], s[5], s[3], s[1]);
            let (z1, z2, z3, z4) = (t0 + t3, t1 + t2, t0 + t2, t1 + t3);
            let z5 = (z3 + z4) * c1175;
            let (t0, t1, t2, t3) = (t0 * c0298, t1 * c2053, t2 * c3072, t3 * c1501);
            let (z1, z2) = (-z1 * c0899, -z2 * c2562);
            let (z3, z4) = (-z3 * c1961 + z5, -z4 * c0390 + z5);
            let (t0, t1, t2, t3) = (t0 + z1 + z3, t1 + z2 + z4, t2 + z2 + z3, t3 + z1 + z4);
            [
                tmp10 + t3,
                tmp11 + t2,
                tmp12 + t1,
                tmp13 + t0,
                tmp13 - t0,
                tmp12 - t1,
                tmp11 - t2,
                tmp10 - t3,
            ]
        };
        for c in 0..8 {
            let s: [i64; 8] =
                std::array::from_fn(|r| i64::from(coefs[r * 8 + c]) * i64::from(quant[r * 8 + c]));
            let o = one_d(s);
            for r in 0..8 {
                ws[r * 8 + c] = (o[r] + (1 << 10)) >> 11;
            }
        }
        std::array::from_fn(|r| {
            let s: [i64; 8] = std::array::from_fn(|c| ws[r * 8 + c]);
            let o = one_d(s);
            std::array::from_fn(|c| (((o[c] + (1 << 17)) >> 18) + 128).clamp(0, 255) as u8)
        })
    }

    /// Random blocks and tables: sparse, every tenth block DC only; dequantised values within
    /// what 8-bit JPEGs hold (jidctint's 32-bit arithmetic then never wraps).
    pub(in crate::rectify::jpeg_luma) fn random_blocks(
        count: usize,
        mut seed: u32,
    ) -> impl Iterator<Item = ([i16; 64], [i32; 64])> {
        let mut next = move || {
            seed ^= seed << 13;
            seed ^= seed >> 17;
            seed ^= seed << 5;
            seed
        };
        (0..count).map(move |case| {
            let quant: [i32; 64] = std::array::from_fn(|_| 1 + (next() % 60) as i32);
            let coefs: [i16; 64] = std::array::from_fn(|k| {
                let r = next();
                if k == 0 {
                    (r % 511) as i16 - 255
                } else if case % 10 == 0 || r % 3 != 0 {
                    0
                } else {
                    ((r >> 8) % 81) as i16 - 40
                }
            });
            (coefs, quant)
        })
    }

    #[test]
    fn the_vector_idct_is_jidctint() {
        for (case, (coefs, quant)) in random_blocks(3000, 0x1234_5678).enumerate() {
            assert_eq!(
                idct_block(&coefs, &quant),
                reference(&coefs, &quant),
                "case {case}"
            );
        }
    }
}
