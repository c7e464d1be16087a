//! Phase 1 of the rectifier (see `warp.rs`): fixed-point source positions of a run of grid
//! pixels, incremental along the row, f32 blocks where that is exact enough, f64 elsewhere.

use super::kernel::{Coords, DistParams, Job, CHUNK, ONE};

mod line;
mod quad;

use line::finish;
pub(crate) use line::Line;

#[cfg(target_arch = "x86_64")]
pub(crate) use quad::{Finish8, Lanes8};
pub(crate) use quad::{QuadBlock, QF};

/// Phase 1: fixed-point source positions of grid pixels `col0..col0 + n` of `row`.
#[inline(always)]
pub(crate) fn map_run<T>(job: &Job<'_, T>, row: usize, col0: usize, n: usize, co: &mut Coords) {
    let line = Line::of_row(&job.m, row);
    if let Some(map) = job.map {
        // Cached positions (distortion): only the image bounds are applied.
        // i32::MIN fails finish's unsigned range test, so it stays outside.
        let src = &map[row * job.cols + col0..][..n];
        let ix = &mut co.ix[..n];
        let iy = &mut co.iy[..n];
        let fx = &mut co.fx[..n];
        let fy = &mut co.fy[..n];
        for j in 0..n {
            let [x, y] = src[j];
            (ix[j], iy[j], fx[j], fy[j]) = finish(job, x, y, true);
        }
        return;
    }
    let mut j0 = 0;
    while j0 < n {
        let block = if job.dist.is_some() {
            DIST_BLOCK
        } else {
            BLOCK
        };
        let len = block.min(n - j0);
        j0 += match &job.dist {
            Some(d) => {
                fast_block_distorted(job, d, &line, col0, j0, len, co);
                len
            }
            None => fast_block(job, &line, col0, j0, len, co),
        };
    }
}

/// Pixels per block of the f32 incremental path: a whole run. Each block costs three f64
/// evaluations and its checks; with blocks of 128 pixels those were ~8 % of the grey warp
/// (`perf`), and with 512 the warp is ~8 % faster (7360 x 4912 → 4400² bench, grey, one thread, three
/// alternating runs: 24.8 → 22.8 ms median).
const BLOCK: usize = CHUNK;
/// Largest position change (fixed-point units, 2²¹ = 1024 px) across a block for the f32
/// path. Offsets are taken from the block's middle, so they stay under 2²⁰ units where w
/// changes little along the block, and under 2/3 of the span (2^20.4) where it changes by up to
/// the 2x allowed; their rounding error is then under ~0.3 and ~0.7 unit (1.5·10⁻⁴ and
/// 3.5·10⁻⁴ px): a few f32 roundings of ~6·10⁻⁸ each.
const BLOCK_SPAN: f64 = (1 << 21) as f64;
/// [`BLOCK`] and [`BLOCK_SPAN`] of the distorted path ([`fast_block_distorted`], which builds
/// the position map once per rectifier), whose offsets run from the block's start.
const DIST_BLOCK: usize = 128;
const DIST_BLOCK_SPAN: f64 = (1 << 19) as f64;
/// Homogeneous w at or below this is "beyond the horizon" (keeps 1/w finite).
const W_MIN: f64 = 1e-200;

/// What phase 1 does with one block of pixels (see [`plan_block`]).
pub(crate) enum Plan {
    /// Every pixel of the block samples outside the frame.
    Outside,
    /// The quadratic path applies ([`QuadBlock`]).
    Quad(QuadBlock),
    /// The f32 incremental path applies, with these constants.
    Near(NearBlock),
    /// The exact f64 path ([`exact_run`]).
    Exact,
}

/// The f32 path's constants for one block: the pixel `jm` columns from the block's middle
/// pixel is at `(xmi, ymi)` plus the floors of `(xmf, ymf) + (kx, ky)·t`, with
/// `t = jm / (wmf + swf·jm)`, each clamped to `±lim` (which only NaN and overflow reach).
/// [`NearBlock::at`] is the computation.
#[derive(Clone, Copy, Debug)]
pub(crate) struct NearBlock {
    pub(crate) xmf: f32,
    pub(crate) ymf: f32,
    pub(crate) kx: f32,
    pub(crate) ky: f32,
    pub(crate) wmf: f32,
    pub(crate) swf: f32,
    pub(crate) xmi: i32,
    pub(crate) ymi: i32,
    pub(crate) lim: f32,
    /// The middle pixel's index in the block.
    pub(crate) mid: usize,
}

impl NearBlock {
    /// Fixed-point (ix, iy, fx, fy) of the pixel `jm` columns from the middle one ([`finish`]).
    #[inline(always)]
    pub(crate) fn at<T>(&self, job: &Job<'_, T>, jm: i32) -> (i32, i32, i32, i32) {
        let jf = jm as f32;
        let t = jf / (self.wmf + self.swf * jf);
        let dx = clamp_f32((self.xmf + self.kx * t).floor(), self.lim);
        let dy = clamp_f32((self.ymf + self.ky * t).floor(), self.lim);
        // SAFETY: clamped to ±2^22, finite (NaN became -lim).
        let (dx, dy): (i32, i32) = unsafe { (dx.to_int_unchecked(), dy.to_int_unchecked()) };
        finish(job, self.xmi + dx, self.ymi + dy, true)
    }
}

/// How phase 1 computes pixels from column `c0` of the grid row `l`, and how many of the `len`
/// asked (all but for [`Plan::Quad`], which may take a shorter block where the quadratic is
/// close enough to the positions only over that: the caller plans the rest again).
///
/// Within a block, the position relative to the block's middle pixel `m` is
/// `δ(j) = j·K / w(j)` (`j` from `−m`) with `K = sx·ONE + ½·sw − U_m·sw` (one f64 setup per
/// block), evaluated in f32: δ is small, so f32 loses nothing that matters, and the loop runs 8
/// or 16 lanes wide. Blocks where that does not hold (near the horizon, steep minification)
/// use the exact f64 path. Blocks where a quadratic in the pixel index is close enough take it
/// instead (`positions/quad.rs`): no division per pixel, and no float.
#[inline(always)]
pub(crate) fn plan_block<T>(job: &Job<'_, T>, l: &Line, c0: usize, len: usize) -> (Plan, usize) {
    let first = c0;
    let c0 = c0 as f64;
    let c1 = c0 + (len - 1) as f64;
    let (ux0, uy0, w0) = l.scaled(c0);
    let (ux1, uy1, w1) = l.scaled(c1);
    let (xmax, ymax) = (job.xmax_q as f64, job.ymax_q as f64);
    // w is affine in c, so positive at both ends means positive throughout,
    // and then the position is monotonic along the block.
    if !(w0 > W_MIN && w1 > W_MIN) {
        return (Plan::Exact, len);
    }
    let off_x = (ux0 < 0.0 && ux1 < 0.0) || (ux0 >= xmax + 1.0 && ux1 >= xmax + 1.0);
    let off_y = (uy0 < 0.0 && uy1 < 0.0) || (uy0 >= ymax + 1.0 && uy1 >= ymax + 1.0);
    if off_x || off_y {
        return (Plan::Outside, len);
    }
    let near = (ux1 - ux0).abs() <= BLOCK_SPAN
        && (uy1 - uy0).abs() <= BLOCK_SPAN
        && ux0.abs() < 1e9
        && uy0.abs() < 1e9
        && w1 <= 2.0 * w0
        && w0 <= 2.0 * w1;
    if !near {
        return (Plan::Exact, len);
    }
    let mut q = len;
    while q >= quad::MIN_LEN {
        if let Some(b) = QuadBlock::new(l, first, q) {
            return (Plan::Quad(b), q);
        }
        q /= 2;
    }
    let one = ONE as f64;
    let mid = len / 2;
    // Between the ends (w > 0 and affine: the position is monotonic), so |uxm| stays
    // under 1e9 + BLOCK_SPAN and its floor fits an i32 with room for the offsets.
    let (uxm, uym, wm) = l.scaled(c0 + mid as f64);
    if !(wm as f32).is_normal() {
        // A w too small (or too large) for f32: the f32 path would divide by 0 (or inf).
        return (Plan::Exact, len);
    }
    let (xmi, ymi) = (uxm.floor(), uym.floor());
    let near = NearBlock {
        kx: (l.sx * one + 0.5 * l.sw - uxm * l.sw) as f32,
        ky: (l.sy * one + 0.5 * l.sw - uym * l.sw) as f32,
        xmf: (uxm - xmi) as f32,
        ymf: (uym - ymi) as f32,
        xmi: xmi as i32,
        ymi: ymi as i32,
        wmf: wm as f32,
        swf: l.sw as f32,
        // Twice the most an offset can be, so the clamp only ever catches NaN and overflow.
        lim: 2.0 * BLOCK_SPAN as f32,
        mid,
    };
    (Plan::Near(near), len)
}

/// Phase 1 for a block of up to `len` pixels starting at column `col0 + j0` ([`plan_block`]);
/// returns how many it computed.
#[inline(always)]
fn fast_block<T>(
    job: &Job<'_, T>,
    l: &Line,
    col0: usize,
    j0: usize,
    len: usize,
    co: &mut Coords,
) -> usize {
    let (plan, len) = plan_block(job, l, col0 + j0, len);
    match plan {
        Plan::Outside => co.ix[j0..j0 + len].fill(-1),
        Plan::Quad(b) => b.fill(job, j0, len, co),
        Plan::Exact => exact_run::<T, false>(job, &NO_DIST, l, col0, j0, len, co),
        Plan::Near(b) => {
            let ix = &mut co.ix[j0..j0 + len];
            let iy = &mut co.iy[j0..j0 + len];
            let fx = &mut co.fx[j0..j0 + len];
            let fy = &mut co.fy[j0..j0 + len];
            // j − mid counted on its own, so the loop needs no subtraction per lane.
            for (j, jm) in (0..len).zip(-(b.mid as i32)..) {
                (ix[j], iy[j], fx[j], fy[j]) = b.at(job, jm);
            }
        }
    }
    len
}

/// [`fast_block`] with lens distortion.
///
/// The undistorted offset from the block start, (δu, δv) = j·(Ku, Kv)/w(j),
/// is pushed through the distortion as a difference from the block start:
/// with e = Δr² and κ = Δk = e·(k1 + k2·(2r₀² + e)),
/// `Δu_d = δu·(k₀ + κ) + du₀·κ` (and likewise for v). Every f32 term is a
/// small difference, so the result keeps the block path's precision.
#[inline(always)]
fn fast_block_distorted<T>(
    job: &Job<'_, T>,
    d: &DistParams,
    l: &Line,
    col0: usize,
    j0: usize,
    len: usize,
    co: &mut Coords,
) {
    let c0 = (col0 + j0) as f64;
    let c1 = c0 + (len - 1) as f64;
    let (u0, v0, w0) = l.at(c0);
    let (u1, v1, w1) = l.at(c1);
    let one = ONE as f64;
    if w0 > W_MIN && w1 > W_MIN && w1 <= 2.0 * w0 && w0 <= 2.0 * w1 {
        let (ud0, vd0, in0) = d.apply(u0, v0);
        let (ud1, vd1, in1) = d.apply(u1, v1);
        let span = DIST_BLOCK_SPAN / one;
        let near = in0
            && in1
            && (u1 - u0).abs() <= span
            && (v1 - v0).abs() <= span
            && (ud1 - ud0).abs() <= span
            && (vd1 - vd0).abs() <= span
            && ud0.abs() < 1e5
            && vd0.abs() < 1e5;
        if near {
            let (du0, dv0) = (u0 - d.cu, v0 - d.cv);
            let r20 = (du0 * du0 + dv0 * dv0) * d.inv_f2;
            let k0 = 1.0 + r20 * (d.k1 + r20 * d.k2);
            let (xs, ys) = (ud0 * one + 0.5, vd0 * one + 0.5);
            let (x0i, y0i) = (xs.floor(), ys.floor());
            let (x0f, y0f) = ((xs - x0i) as f32, (ys - y0i) as f32);
            let (x0i, y0i) = (x0i as i32, y0i as i32);
            let ku = (l.sx - u0 * l.sw) as f32;
            let kv = (l.sy - v0 * l.sw) as f32;
            let (w0f, swf) = (w0 as f32, l.sw as f32);
            let (du0f, dv0f, k0f) = (du0 as f32, dv0 as f32, k0 as f32);
            let (au, av, s) = (
                (2.0 * du0 * d.inv_f2) as f32,
                (2.0 * dv0 * d.inv_f2) as f32,
                d.inv_f2 as f32,
            );
            let (k1, k2, r20f) = (d.k1 as f32, d.k2 as f32, r20 as f32);
            // Room left below the fold, as a limit on Δr².
            let e_max = (d.r2_max - r20) as f32;
            let onef = one as f32;
            let lim = 2.0 * DIST_BLOCK_SPAN as f32;
            let ix = &mut co.ix[j0..j0 + len];
            let iy = &mut co.iy[j0..j0 + len];
            let fx = &mut co.fx[j0..j0 + len];
            let fy = &mut co.fy[j0..j0 + len];
            for j in 0..len {
                let jf = j as i32 as f32;
                let t = jf / (w0f + swf * jf);
                let (du, dv) = (ku * t, kv * t);
                let e = (au + s * du) * du + (av + s * dv) * dv;
                let kappa = e * (k1 + k2 * (2.0 * r20f + e));
                let dud = du * (k0f + kappa) + du0f * kappa;
                let dvd = dv * (k0f + kappa) + dv0f * kappa;
                let dx = clamp_f32((x0f + dud * onef).floor(), lim);
                let dy = clamp_f32((y0f + dvd * onef).floor(), lim);
                // SAFETY: clamped to ±2^20, finite (NaN became -lim).
                let (dx, dy): (i32, i32) =
                    unsafe { (dx.to_int_unchecked(), dy.to_int_unchecked()) };
                (ix[j], iy[j], fx[j], fy[j]) = finish(job, x0i + dx, y0i + dy, e < e_max);
            }
            return;
        }
    }
    exact_run::<T, true>(job, d, l, col0, j0, len, co);
}

/// `x` limited to [−lim, lim]; NaN gives −lim. Plain compares, so it
/// vectorises to max/min.
#[inline(always)]
fn clamp_f32(x: f32, lim: f32) -> f32 {
    let x = if x > -lim { x } else { -lim };
    if x < lim {
        x
    } else {
        lim
    }
}

const NO_DIST: DistParams = DistParams {
    cu: 0.0,
    cv: 0.0,
    inv_f2: 0.0,
    k1: 0.0,
    k2: 0.0,
    r2_max: f64::INFINITY,
};

/// Phase 1, exact f64 per pixel (with distortion, or where the f32 block
/// path does not apply); pixels `j0..j0 + len` of the run.
#[inline(always)]
fn exact_run<T, const DIST: bool>(
    job: &Job<'_, T>,
    d: &DistParams,
    l: &Line,
    col0: usize,
    j0: usize,
    len: usize,
    co: &mut Coords,
) {
    let one = ONE as f64;
    // Clamp range for the float → int conversion (outside either way).
    let (xlim, ylim) = (job.xmax_q as f64 + 4.0, job.ymax_q as f64 + 4.0);
    let ix = &mut co.ix[j0..j0 + len];
    let iy = &mut co.iy[j0..j0 + len];
    let fx = &mut co.fx[j0..j0 + len];
    let fy = &mut co.fy[j0..j0 + len];
    for j in 0..len {
        // Grid sides are < 2^17, so the i32 round trip is exact (and i32→f64
        // converts in SIMD, usize→f64 does not).
        let c = (col0 + j0 + j) as i32 as f64;
        let w = l.bw + c * l.sw;
        let mut ok = w > W_MIN;
        let rw = 1.0 / if ok { w } else { 1.0 }; // one division per pixel
        let mut u = (l.bx + c * l.sx) * rw;
        let mut v = (l.by + c * l.sy) * rw;
        if DIST {
            let (du, dv, in_model) = d.apply(u, v);
            u = du;
            v = dv;
            ok &= in_model;
        }
        let xq = clamp_f64((u * one + 0.5).floor(), xlim);
        let yq = clamp_f64((v * one + 0.5).floor(), ylim);
        // SAFETY: clamped to [−4, max + 4] ⊂ i32, finite (NaN became −4).
        let (xq, yq): (i32, i32) = unsafe { (xq.to_int_unchecked(), yq.to_int_unchecked()) };
        (ix[j], iy[j], fx[j], fy[j]) = finish(job, xq, yq, ok);
    }
}

/// `x` limited to [−4, hi]; NaN gives −4.
#[inline(always)]
fn clamp_f64(x: f64, hi: f64) -> f64 {
    let x = if x > -4.0 { x } else { -4.0 };
    if x < hi {
        x
    } else {
        hi
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::geometry::mat3;
    use crate::geometry::{homography_from_points, RadialDistortion};
    use crate::rectify::kernel::FRAC_BITS;

    /// The plate's corners in build mm (a 275 mm square), which the tests' views map.
    pub(crate) const PLATE: [[f64; 2]; 4] = [
        [-137.5, 137.5],
        [137.5, 137.5],
        [137.5, -137.5],
        [-137.5, -137.5],
    ];

    /// The quadratic and f32 block paths (with and without distortion) agree with the
    /// exact f64 path to within one fixed-point unit (1/2048 px), including
    /// the inside/outside verdict away from the boundary.
    #[test]
    fn f32_blocks_match_exact_positions() {
        let (w, h) = (7360usize, 4912usize);
        let data = vec![0u8; w * h];
        let views = [
            [
                [1400.0, 600.0],
                [5960.0, 600.0],
                [6900.0, 4500.0],
                [460.0, 4500.0],
            ],
            [
                [1200.0, 900.0],
                [6100.0, 300.0],
                [7300.0, 4700.0],
                [100.0, 4000.0],
            ],
            [
                [3000.0, 2000.0],
                [4000.0, 2100.0],
                [4200.0, 2900.0],
                [2900.0, 2800.0],
            ],
            // Seen from a corner: w changes fast along the grid's rows.
            [
                [3600.0, 100.0],
                [7200.0, 2400.0],
                [3700.0, 4800.0],
                [2600.0, 2450.0],
            ],
        ];
        let lens = RadialDistortion {
            center: [3650.0, 2500.0],
            focal_px: 8000.0,
            k1: -0.06,
            k2: 0.015,
        };
        let mut fast_blocks = [0usize; 2];
        // Blocks without distortion: quadratic (whole runs, shorter), f32.
        let mut plans = [0usize; 3];
        for ((k, img), dist) in views
            .iter()
            .enumerate()
            .flat_map(|v| [(v, None), (v, Some(DistParams::new(&lens)))])
        {
            let h_img = homography_from_points(*img, PLATE).unwrap().matrix();
            // Overhanging grid (pixels outside the image) at two scales.
            let p = if k == 2 { 0.5 } else { 0.0625 };
            let g = [
                [p, 0.0, -150.0 + 0.5 * p],
                [0.0, -p, 150.0 - 0.5 * p],
                [0.0, 0.0, 1.0],
            ];
            let (hi, _) = mat3::inverse(&h_img);
            let m = mat3::mul(&hi, &g);
            let j = Job::for_test(&data, w, h, m, dist);
            let cols = (300.0 / p) as usize;
            let (mut a, mut b) = (Coords::new(), Coords::new());
            for row in (0..cols).step_by(97) {
                // Whole runs along the row, and a run of one pixel (a row's last run can be).
                let runs = (0..cols)
                    .step_by(CHUNK)
                    .map(|c| (c, CHUNK.min(cols - c)))
                    .chain([((row * 7) % cols, 1)]);
                for (col0, n) in runs {
                    map_run(&j, row, col0, n, &mut a);
                    let line = Line::of_row(&m, row);
                    let mut j0 = 0;
                    while dist.is_none() && j0 < n {
                        let (plan, len) = plan_block(&j, &line, col0 + j0, n - j0);
                        match plan {
                            Plan::Quad(_) if len == n => plans[0] += 1,
                            Plan::Quad(_) => plans[1] += 1,
                            Plan::Near(_) => plans[2] += 1,
                            Plan::Outside | Plan::Exact => {}
                        }
                        j0 += len;
                    }
                    match &dist {
                        Some(d) => exact_run::<u8, true>(&j, d, &line, col0, 0, n, &mut b),
                        None => exact_run::<u8, false>(&j, &NO_DIST, &line, col0, 0, n, &mut b),
                    }
                    for i in 0..n {
                        let q = |c: &Coords| {
                            (
                                (c.ix[i].max(0) << FRAC_BITS) + c.fx[i],
                                (c.iy[i] << FRAC_BITS) + c.fy[i],
                            )
                        };
                        let ((xa, ya), (xb, yb)) = (q(&a), q(&b));
                        let edge = xb.min(j.xmax_q - xb).min(yb).min(j.ymax_q - yb);
                        if (a.ix[i] < 0) != (b.ix[i] < 0) {
                            assert!(
                                edge.abs() <= 1,
                                "verdicts differ away from the edge: row {row} col {}",
                                col0 + i
                            );
                        } else if a.ix[i] >= 0 {
                            assert!(
                                (xa - xb).abs() <= 1 && (ya - yb).abs() <= 1,
                                "row {row} col {}: {xa},{ya} vs {xb},{yb}",
                                col0 + i
                            );
                            fast_blocks[usize::from(dist.is_some())] +=
                                usize::from(xa != xb || ya != yb);
                        }
                    }
                }
            }
        }
        // Tiny differences show each block path really ran (and stayed within 1 unit).
        assert!(fast_blocks.iter().all(|&n| n > 0), "{fast_blocks:?}");
        assert!(plans.iter().all(|&n| n > 0), "{plans:?}");
    }
}
