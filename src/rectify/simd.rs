//! The SIMD row kernels, picked at run time: AVX-512 (`simd/avx512.rs`) where the CPU has
//! it, else AVX2 (`simd/avx2.rs`), else the scalar ones.
//!
//! The arithmetic is the same exact integer bilinear as
//! `bilinear_run` (`kernel.rs`), so results are bit-identical
//! to the scalar path (unit tests check each kernel).

use super::kernel::{Coords, Job, Sample};

mod avx2;
mod avx512;

/// Whether the AVX2 kernels can run here (cached by std after the first call).
#[inline]
pub(crate) fn available() -> bool {
    std::is_x86_feature_detected!("avx2")
}

/// Whether the AVX-512 builds of the kernels can run here.
#[inline]
fn avx512() -> bool {
    std::is_x86_feature_detected!("avx512f")
        && std::is_x86_feature_detected!("avx512bw")
        && std::is_x86_feature_detected!("avx512vl")
        && std::is_x86_feature_detected!("avx512dq")
        && std::is_x86_feature_detected!("avx512vbmi")
}

/// Largest source buffer the kernels address with i32 gather offsets.
const MAX_I32_LEN: usize = (i32::MAX as usize) - 64;

/// The generic row kernel compiled for AVX2 (phase 1 vectorises 4-wide f64).
pub(crate) fn row_generic<T: Sample, const CN: usize, const CUBIC: bool>(
    job: &Job<'_, T>,
    row: usize,
    out: &mut [T],
    co: &mut Coords,
) {
    if available() {
        // SAFETY: AVX2 is present (checked above).
        unsafe { avx2::row_generic_avx2::<T, CN, CUBIC>(job, row, out, co) }
    } else {
        super::row::row_generic::<T, CN, CUBIC>(job, row, out, co)
    }
}

/// Bilinear 8-bit grey row kernel.
pub(crate) fn row_gray8(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    if available() && job.src.data.len() <= MAX_I32_LEN {
        if avx512() {
            // SAFETY: AVX-512 F/BW/VL/DQ/VBMI are present (checked).
            unsafe { avx512::row_gray8(job, row, out, co) }
        } else {
            // SAFETY: AVX2 is present (checked above).
            unsafe { avx2::row_gray8_avx2(job, row, out, co) }
        }
    } else {
        super::row::row_generic::<u8, 1, false>(job, row, out, co)
    }
}

/// Bilinear 8-bit RGB row kernel.
pub(crate) fn row_rgb8(job: &Job<'_, u8>, row: usize, out: &mut [u8], co: &mut Coords) {
    if available() && job.src.data.len() <= MAX_I32_LEN {
        if avx512() {
            // SAFETY: AVX-512 F/BW/VL/DQ/VBMI are present (checked).
            unsafe { avx512::row_rgb8(job, row, out, co) }
        } else {
            // SAFETY: AVX2 is present (checked above).
            unsafe { avx2::row_rgb8_avx2(job, row, out, co) }
        }
    } else {
        super::row::row_generic::<u8, 3, false>(job, row, out, co)
    }
}

#[cfg(test)]
mod tests {
    use super::avx2::{gray8_run, rgb8_run};
    use super::*;
    use crate::rectify::kernel::{bilinear_run, CHUNK, ONE};

    /// The AVX2 and AVX-512 kernels (`run8`, `run16`) of `CN`-sample pixels give exactly the
    /// scalar kernel's output, on runs that take their window paths (nearby samples in two rows, some steps
    /// crossing to the next row), their other paths (steep runs, scattered samples, outside
    /// ones), and the last column and row.
    fn kernels_match_scalar<const CN: usize>(
        run8: fn(&Job<'_, u8>, &Coords, &mut [u8]),
        run16: fn(&Job<'_, u8>, &Coords, &mut [u8]),
    ) {
        let (w, h) = (300usize, 70usize);
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move |m: u64| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % m) as i32
        };
        let data: Vec<u8> = (0..w * h * CN).map(|_| next(256) as u8).collect();
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let job = Job {
            src: crate::rectify::kernel::Source {
                data: &data,
                width: w,
                height: h,
                stride: w * CN,
            },
            ..Job::for_test(&data, w, h, identity, None)
        };
        let mut co = Coords::new();
        let mut kinds = [0; 3];
        for trial in 0..600 {
            let n = CHUNK - trial % 37;
            let (x0, y0) = (next(w as u64 - 1), next(h as u64 - 1));
            // 0: nearly horizontal (windows), 1: scattered, 2: steep (3 columns per pixel).
            let kind = trial % 3;
            for j in 0..n {
                let (x, y) = match kind {
                    0 => (x0 + (j as i32 * 3) / 4, y0 + j as i32 / 200),
                    1 => (next(w as u64 - 1), next(h as u64 - 1)),
                    _ => ((x0 / 8 + 3 * j as i32) % (w as i32), y0 + j as i32 / 300),
                };
                let outside = trial % 4 == 1 && next(5) == 0;
                co.ix[j] = if outside { -1 } else { x.min(w as i32 - 2) };
                co.iy[j] = y.min(h as i32 - 2);
                co.fx[j] = next(ONE as u64 + 1);
                co.fy[j] = next(ONE as u64 + 1);
            }
            kinds[kind] += 1;
            let mut want = vec![0u8; n * CN];
            bilinear_run::<u8, CN>(&job, &co, &mut want, 0);
            if available() {
                let mut got = vec![1u8; n * CN];
                run8(&job, &co, &mut got);
                assert_eq!(got, want, "AVX2, trial {trial}");
            }
            if avx512() {
                let mut got = vec![1u8; n * CN];
                run16(&job, &co, &mut got);
                assert_eq!(got, want, "AVX-512, trial {trial}");
            }
        }
        assert!(kinds.iter().all(|&k| k == 200));
    }

    #[test]
    fn gray8_kernels_match_scalar() {
        kernels_match_scalar::<1>(
            // SAFETY: called only when AVX2 is present (checked by the caller).
            |j, c, o| unsafe { gray8_run(j, c, o) },
            // SAFETY: called only when AVX-512 F/BW/VL/DQ/VBMI are present (checked).
            |j, c, o| unsafe { avx512::gray8_run16(j, c, o) },
        );
    }

    #[test]
    fn rgb8_kernels_match_scalar() {
        kernels_match_scalar::<3>(
            // SAFETY: called only when AVX2 is present (checked by the caller).
            |j, c, o| unsafe { rgb8_run(j, c, o, 0) },
            // SAFETY: called only when AVX-512 F/BW/VL/DQ/VBMI are present (checked).
            |j, c, o| unsafe { avx512::rgb8_run16(j, c, o) },
        );
    }

    /// The grey row kernels (AVX2, and AVX-512 where the CPU has it), which position and
    /// sample blocks in registers, and phase 1's SIMD lanes give exactly phase 1 pixel by pixel
    /// then the scalar kernel, row by row, on views whose rows take the quadratic
    /// path whole, in shorter blocks, the f32 path and the exact one, with grids overhanging
    /// the frame and runs that are not a multiple of 8 or 16 pixels.
    #[test]
    fn gray8_rows_match_phase_1_then_scalar() {
        use crate::geometry::{homography_from_points, mat3};
        use crate::rectify::positions::tests::PLATE;
        use crate::rectify::positions::{map_run, plan_block, Line, Plan};
        use crate::rectify::row::row_generic;
        if !available() {
            return;
        }
        let (w, h) = (736usize, 491usize);
        let data: Vec<u8> = (0..w * h).map(|i| (i * 7 + i / w * 13) as u8).collect();
        let views = [
            [[140.0, 60.0], [596.0, 60.0], [690.0, 450.0], [46.0, 450.0]],
            [[120.0, 90.0], [610.0, 30.0], [730.0, 470.0], [10.0, 400.0]],
            [[300.0, 20.0], [700.0, 200.0], [500.0, 480.0], [60.0, 250.0]],
            [
                [368.0, 10.0],
                [720.0, 240.0],
                [368.0, 480.0],
                [300.0, 245.0],
            ],
            // The grid's first rows above the frame (outside), and magnified 25-fold (exact).
            [[10.0, 10.0], [200.0, 12.0], [205.0, 150.0], [8.0, 148.0]],
            [
                [-3000.0, -2000.0],
                [4000.0, -2500.0],
                [3900.0, 3000.0],
                [-2800.0, 2900.0],
            ],
        ];
        // Blocks: quadratic whole, quadratic shorter, f32, outside, exact.
        let mut plans = [0usize; 5];
        for (v, img) in views.iter().enumerate() {
            let h_img = homography_from_points(*img, PLATE).unwrap().matrix();
            for p in [0.6, 0.25] {
                let g = [
                    [p, 0.0, -150.0 + 0.5 * p],
                    [0.0, -p, 150.0 - 0.5 * p],
                    [0.0, 0.0, 1.0],
                ];
                let m = mat3::mul(&mat3::inverse(&h_img).0, &g);
                let job = Job::for_test(&data, w, h, m, None);
                let cols = (300.0 / p) as usize;
                let mut co = Coords::new();
                let (mut want, mut got) = (vec![0u8; cols], vec![1u8; cols]);
                let mut generic = vec![2u8; cols];
                for row in (0..cols).step_by(3) {
                    // Phase 1 pixel by pixel (`at`, no SIMD lanes), then the scalar kernel.
                    let line = Line::of_row(&m, row);
                    for c0 in (0..cols).step_by(CHUNK) {
                        let n = CHUNK.min(cols - c0);
                        let mut j0 = 0;
                        while j0 < n {
                            let (plan, len) = plan_block(&job, &line, c0 + j0, n - j0);
                            let k = match plan {
                                Plan::Quad(b) => {
                                    for j in 0..len {
                                        (co.ix[j], co.iy[j], co.fx[j], co.fy[j]) = b.at(&job, j);
                                    }
                                    usize::from(len != n - j0)
                                }
                                Plan::Near(b) => {
                                    for j in 0..len {
                                        let jm = j as i32 - b.mid as i32;
                                        (co.ix[j], co.iy[j], co.fx[j], co.fy[j]) = b.at(&job, jm);
                                    }
                                    2
                                }
                                Plan::Outside | Plan::Exact => {
                                    map_run(&job, row, c0 + j0, len, &mut co);
                                    3 + usize::from(matches!(plan, Plan::Exact))
                                }
                            };
                            plans[k] += 1;
                            let part = &mut want[c0 + j0..c0 + j0 + len];
                            bilinear_run::<u8, 1>(&job, &co, part, 0);
                            j0 += len;
                        }
                    }
                    // The AVX2 kernel itself (`row_gray8` picks AVX-512 where it can).
                    // SAFETY: AVX2 is present (checked above).
                    unsafe { super::avx2::row_gray8_avx2(&job, row, &mut got, &mut co) };
                    assert_eq!(got, want, "view {v}, pixel {p}, row {row}");
                    // The dispatched kernel (AVX-512 where it can) writes every pixel itself.
                    got.fill(3);
                    row_gray8(&job, row, &mut got, &mut co);
                    assert_eq!(got, want, "dispatched, view {v}, pixel {p}, row {row}");
                    row_generic::<u8, 1, false>(&job, row, &mut generic, &mut co);
                    assert_eq!(generic, want, "phase 1, view {v}, pixel {p}, row {row}");
                }
            }
        }
        assert!(plans.iter().all(|&n| n > 0), "blocks per path: {plans:?}");
    }
}
