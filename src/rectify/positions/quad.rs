//! Phase 1's quadratic path: a block's positions as a quadratic in the pixel index, in 64-bit
//! fixed point, stepped by adding differences (no division, no float per pixel).
//!
//! Along a grid row the source position is `U(τ) = U_m + g·τ / (1 + s·τ)` (τ pixels from
//! the block's middle pixel, `g` the derivative there, `s = sw / w_m`), so the quadratic
//! `U_m + g·τ − g·s·τ²` is off by `g·s²·τ³ / (1 + s·τ)`, at most
//! `|g|·s²·h³ / (1 − |s|·h)` on a block of half-length `h`. A block is taken only where that
//! bound is at most [`MAX_ERR`] fixed-point units; where `w` does not change along the row
//! (a camera tilted about the grid's x axis) it is 0 for any length. The coefficients are
//! rounded once to 2^-32 units; from there the values are exact integers, so every way of
//! evaluating them (directly, or 8 lanes stepping by 8 with first and second differences,
//! as the scalar loop below and the AVX2 kernel do) gives the same bits.

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use super::line::{finish, Line};
use crate::rectify::kernel::{Coords, Job, FRAC_BITS, ONE};

/// Fraction bits of the fixed point, below the fixed-point unit (1/2048 px).
pub(crate) const QF: u32 = 32;

/// Most the quadratic may be off the exact position, in fixed-point units (before the floor):
/// with the coefficients' rounding (under 2^-14 units over a block) the floor then differs from
/// the exact one's by at most one unit, and only where the exact value is within 1/8 unit of an
/// integer.
const MAX_ERR: f64 = 0.125;

/// Shortest block the quadratic path takes; shorter ones use the f32 path.
pub(crate) const MIN_LEN: usize = 32;

/// One block's quadratics: the position in fixed-point units times 2^[`QF`] of block pixel
/// `j` is `c[0] + c[1]·j + c[2]·j²`, for x and y.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct QuadBlock {
    pub(crate) x: [i64; 3],
    pub(crate) y: [i64; 3],
}

impl QuadBlock {
    /// The quadratics of the `len` pixels from column `c0` of grid row `l`, if they stay within
    /// [`MAX_ERR`] of the exact positions.
    ///
    /// The caller has checked the block as for the f32 path: `w` positive at both ends, both
    /// ends' positions within 1e9 units and at most 2^21 units apart. With `|s|·h ≤ ½` every
    /// term below then stays under 2^62: values under 2^30 units, slopes under 2^21 units per
    /// pixel.
    pub(crate) fn new(l: &Line, c0: usize, len: usize) -> Option<QuadBlock> {
        if len < MIN_LEN {
            return None;
        }
        let m = len / 2;
        // m ≥ len − 1 − m: the middle pixel is at most m from either end.
        let h = m as f64;
        let (uxm, uym, wm) = l.scaled((c0 + m) as f64);
        let s = l.sw / wm;
        let sh = s.abs() * h;
        if sh.is_nan() || sh > 0.5 {
            return None;
        }
        let one = ONE as f64;
        let gx = (l.sx * one + 0.5 * l.sw - uxm * l.sw) / wm;
        let gy = (l.sy * one + 0.5 * l.sw - uym * l.sw) / wm;
        let err = gx.abs().max(gy.abs()) * s * s * h * h * h / (1.0 - sh);
        // (`max` passes over a NaN slope, so the slopes are checked on their own.)
        if !gx.is_finite() || !gy.is_finite() || err.is_nan() || err > MAX_ERR {
            return None;
        }
        let scale = (1u64 << QF) as f64;
        // U_m + g·(j − m) − g·s·(j − m)² as c0 + c1·j + c2·j².
        let coef = |um: f64, g: f64| {
            let gs = g * s;
            let mf = m as f64;
            [
                ((um - g * mf - gs * mf * mf) * scale).round() as i64,
                ((g + 2.0 * gs * mf) * scale).round() as i64,
                (-gs * scale).round() as i64,
            ]
        };
        Some(QuadBlock {
            x: coef(uxm, gx),
            y: coef(uym, gy),
        })
    }

    /// The value at block pixel `j`.
    #[inline(always)]
    pub(crate) fn value(c: &[i64; 3], j: i64) -> i64 {
        c[0] + j * (c[1] + j * c[2])
    }

    /// `N` lanes for block pixels `j0..j0 + N`: values, their first differences for a step
    /// of `N` pixels, and the (constant) second difference, `2·N²·c2`.
    #[inline(always)]
    pub(crate) fn lanes<const N: usize>(c: &[i64; 3], j0: usize) -> ([i64; N], [i64; N], i64) {
        let mut v = [0i64; N];
        let mut d = [0i64; N];
        for k in 0..N {
            let j = (j0 + k) as i64;
            v[k] = Self::value(c, j);
            d[k] = Self::value(c, j + N as i64) - v[k];
        }
        (v, d, 2 * (N * N) as i64 * c[2])
    }

    /// (ix, iy, fx, fy) of block pixel `j` ([`finish`]).
    #[inline(always)]
    pub(crate) fn at<T>(&self, job: &Job<'_, T>, j: usize) -> (i32, i32, i32, i32) {
        let j = j as i64;
        let xq = (Self::value(&self.x, j) >> QF) as i32;
        let yq = (Self::value(&self.y, j) >> QF) as i32;
        finish(job, xq, yq, true)
    }

    /// Phase 1 for the block's `len` pixels, into `co` from index `j0`: 8 lanes stepping by 8
    /// ([`fill_avx2`] where the CPU has AVX2: compilers leave the scalar loop scalar).
    #[inline(always)]
    pub(crate) fn fill<T>(&self, job: &Job<'_, T>, j0: usize, len: usize, co: &mut Coords) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: AVX2 is present (checked).
            return unsafe { fill_avx2(self, job, j0, len, co) };
        }
        self.fill_scalar(job, j0, len, co)
    }

    /// [`QuadBlock::fill`] without SIMD.
    #[inline(always)]
    pub(crate) fn fill_scalar<T>(&self, job: &Job<'_, T>, j0: usize, len: usize, co: &mut Coords) {
        let (mut vx, mut dx, ddx) = Self::lanes::<8>(&self.x, 0);
        let (mut vy, mut dy, ddy) = Self::lanes::<8>(&self.y, 0);
        let ix = &mut co.ix[j0..j0 + len];
        let iy = &mut co.iy[j0..j0 + len];
        let fx = &mut co.fx[j0..j0 + len];
        let fy = &mut co.fy[j0..j0 + len];
        let whole = len / 8 * 8;
        let groups = ix
            .chunks_exact_mut(8)
            .zip(iy.chunks_exact_mut(8))
            .zip(fx.chunks_exact_mut(8).zip(fy.chunks_exact_mut(8)));
        for ((ix, iy), (fx, fy)) in groups {
            for k in 0..8 {
                let (xq, yq) = ((vx[k] >> QF) as i32, (vy[k] >> QF) as i32);
                (ix[k], iy[k], fx[k], fy[k]) = finish(job, xq, yq, true);
            }
            for k in 0..8 {
                vx[k] += dx[k];
                dx[k] += ddx;
                vy[k] += dy[k];
                dy[k] += ddy;
            }
        }
        for j in whole..len {
            (ix[j], iy[j], fx[j], fy[j]) = self.at(job, j);
        }
    }
}

#[cfg(target_arch = "x86_64")]
/// The quadratics' 8 lanes in AVX2 registers: pixels 0, 1, 4, 5 in one register and 2, 3, 6, 7
/// in the other, so that the high halves picked by one `shufps` (within 128-bit lanes) come
/// out in pixel order.
pub(crate) struct Lanes8 {
    x: [__m256i; 2],
    dx: [__m256i; 2],
    ddx: __m256i,
    y: [__m256i; 2],
    dy: [__m256i; 2],
    ddy: __m256i,
}

#[cfg(target_arch = "x86_64")]
impl Lanes8 {
    /// The lanes of block pixels 0..8.
    #[target_feature(enable = "avx2")]
    pub(crate) fn new(b: &QuadBlock) -> Lanes8 {
        let split = |v: &[i64; 8]| {
            [
                _mm256_setr_epi64x(v[0], v[1], v[4], v[5]),
                _mm256_setr_epi64x(v[2], v[3], v[6], v[7]),
            ]
        };
        let (vx, dx, ddx) = QuadBlock::lanes::<8>(&b.x, 0);
        let (vy, dy, ddy) = QuadBlock::lanes::<8>(&b.y, 0);
        Lanes8 {
            x: split(&vx),
            dx: split(&dx),
            ddx: _mm256_set1_epi64x(ddx),
            y: split(&vy),
            dy: split(&dy),
            ddy: _mm256_set1_epi64x(ddy),
        }
    }

    /// The next 8 pixels' fixed-point positions (x, y), as 8 i32 each in pixel order.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) fn next(&mut self) -> (__m256i, __m256i) {
        const _: () = assert!(
            QF == 32,
            "the high half of each lane is the fixed-point position"
        );
        let high = |v: [__m256i; 2]| {
            _mm256_castps_si256(_mm256_shuffle_ps::<0b1101_1101>(
                _mm256_castsi256_ps(v[0]),
                _mm256_castsi256_ps(v[1]),
            ))
        };
        let q = (high(self.x), high(self.y));
        for k in 0..2 {
            self.x[k] = _mm256_add_epi64(self.x[k], self.dx[k]);
            self.dx[k] = _mm256_add_epi64(self.dx[k], self.ddx);
            self.y[k] = _mm256_add_epi64(self.y[k], self.dy[k]);
            self.dy[k] = _mm256_add_epi64(self.dy[k], self.ddy);
        }
        q
    }
}

#[cfg(target_arch = "x86_64")]
/// Phase 1's `finish` on 8 pixels in AVX2 registers: inside iff 0 ≤ q ≤ max (an unsigned
/// compare); the last column and row step back by one pixel with full weight on the far one.
pub(crate) struct Finish8 {
    xmax: __m256i,
    ymax: __m256i,
    wm2: __m256i,
    hm2: __m256i,
    all: __m256i,
}

#[cfg(target_arch = "x86_64")]
impl Finish8 {
    #[target_feature(enable = "avx2")]
    pub(crate) fn new<T>(job: &Job<'_, T>) -> Finish8 {
        Finish8 {
            xmax: _mm256_set1_epi32(job.xmax_q),
            ymax: _mm256_set1_epi32(job.ymax_q),
            wm2: _mm256_set1_epi32(job.wm2),
            hm2: _mm256_set1_epi32(job.hm2),
            all: _mm256_set1_epi32(-1),
        }
    }

    /// (ix, iy, fx, fy) of 8 fixed-point positions, as [`finish`] gives them.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(crate) fn apply(&self, xq: __m256i, yq: __m256i) -> [__m256i; 4] {
        let ok = _mm256_and_si256(
            _mm256_cmpeq_epi32(_mm256_min_epu32(xq, self.xmax), xq),
            _mm256_cmpeq_epi32(_mm256_min_epu32(yq, self.ymax), yq),
        );
        let xi = _mm256_min_epi32(_mm256_srai_epi32::<{ FRAC_BITS as i32 }>(xq), self.wm2);
        let iy = _mm256_min_epi32(_mm256_srai_epi32::<{ FRAC_BITS as i32 }>(yq), self.hm2);
        let fx = _mm256_sub_epi32(xq, _mm256_slli_epi32::<{ FRAC_BITS as i32 }>(xi));
        let fy = _mm256_sub_epi32(yq, _mm256_slli_epi32::<{ FRAC_BITS as i32 }>(iy));
        let ix = _mm256_or_si256(xi, _mm256_andnot_si256(ok, self.all));
        [ix, iy, fx, fy]
    }
}

#[cfg(target_arch = "x86_64")]
/// [`QuadBlock::fill`] with AVX2: the same integers, 8 pixels a step.
#[target_feature(enable = "avx2")]
fn fill_avx2<T>(b: &QuadBlock, job: &Job<'_, T>, j0: usize, len: usize, co: &mut Coords) {
    let mut lanes = Lanes8::new(b);
    let fin = Finish8::new(job);
    let mut j = 0;
    while j + 8 <= len {
        let (xq, yq) = lanes.next();
        let out = fin.apply(xq, yq);
        for (v, dst) in out
            .iter()
            .zip([&mut co.ix, &mut co.iy, &mut co.fx, &mut co.fy])
        {
            let dst = &mut dst[j0 + j..j0 + j + 8];
            // SAFETY: `dst` is exactly 8 i32; unaligned store.
            unsafe { _mm256_storeu_si256(dst.as_mut_ptr().cast(), *v) };
        }
        j += 8;
    }
    for j in j..len {
        (co.ix[j0 + j], co.iy[j0 + j], co.fx[j0 + j], co.fy[j0 + j]) = b.at(job, j);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Stepping 8 lanes (and 16) by their differences gives the quadratic's exact values at every
    /// pixel, for block lengths that are and are not multiples of 8, and the block is refused
    /// where the bound is over [`MAX_ERR`].
    #[test]
    fn stepped_lanes_give_the_direct_values() {
        let data = vec![0u8; 64 * 48];
        let mut taken = [0usize; 2];
        for (k, sw) in [0.0, 1e-7, -3e-6, 2e-5, 1e-3].into_iter().enumerate() {
            // Grid → image homogeneous rows of a 64 x 48 frame seen obliquely.
            let m = [
                [0.11, 0.01 * k as f64, 3.0],
                [-0.004, 0.09, 2.0],
                [sw, 1e-4, 1.0],
            ];
            let job = Job::for_test(&data, 64, 48, m, None);
            for row in [0usize, 17, 300] {
                let line = Line::of_row(&m, row);
                for len in [32usize, 37, 256, 509, 512] {
                    let Some(b) = QuadBlock::new(&line, 5, len) else {
                        taken[1] += 1;
                        continue;
                    };
                    taken[0] += 1;
                    let (mut co, mut scalar) = (Coords::new(), Coords::new());
                    // Into the run from an index that is not a multiple of 8, where it fits.
                    let at = 3.min(co.ix.len() - len);
                    b.fill(&job, at, len, &mut co);
                    b.fill_scalar(&job, at, len, &mut scalar);
                    // The 16 lanes the AVX-512 grey row steps: the same values.
                    for c in [&b.x, &b.y] {
                        let (mut v, mut d, dd) = QuadBlock::lanes::<16>(c, 0);
                        for j0 in (0..len - 15).step_by(16) {
                            for k in 0..16 {
                                assert_eq!(v[k], QuadBlock::value(c, (j0 + k) as i64));
                                v[k] += d[k];
                                d[k] += dd;
                            }
                        }
                    }
                    for j in 0..len {
                        for c in [&co, &scalar] {
                            let k = at + j;
                            let got = (c.ix[k], c.iy[k], c.fx[k], c.fy[k]);
                            assert_eq!(got, b.at(&job, j), "sw {sw}, row {row}, len {len}, j {j}");
                        }
                    }
                }
            }
        }
        assert!(taken.iter().all(|&n| n > 0), "{taken:?}");
    }
}
