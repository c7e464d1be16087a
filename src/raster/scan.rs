//! Scan conversion of one layer: filled contours and stroked segments, sampled at
//! S x S sub-samples per pixel.
//!
//! Everything is converted once into continuous pixel units (u right, v down, the grid's
//! top-left corner at (0, 0), so pixel (r, c) spans [c, c+1] x [r, r+1]). Sub-sample (q, j) sits
//! at ((j + 0.5)/S, (q + 0.5)/S). Rows are processed in parallel bands; each band keeps its
//! own active edge list, so the cost is proportional to crossings plus covered spans, never
//! to pixels x edges.

use rayon::prelude::*;

use super::options::{FillRule, RasterOptions};
use crate::geometry::Grid;
use crate::vectors::{Direction, Layer};

/// A non-horizontal contour edge, `v_top < v_bot`.
#[derive(Debug, Clone, Copy)]
struct Edge {
    v_top: f64,
    v_bot: f64,
    u_top: f64,
    /// du/dv.
    slope: f64,
    /// +1 or −1 by the edge's direction (up or down in the build frame).
    wind: i32,
}

/// A segment stroked with radius `r`: the set of points within r of it (a capsule).
#[derive(Debug, Clone, Copy)]
struct Capsule {
    v_top: f64,
    v_bot: f64,
    a: [f64; 2],
    b: [f64; 2],
    r: f64,
}

/// A layer's geometry ready for scanning at one grid.
pub(crate) struct Scene {
    edges: Vec<Edge>,
    capsules: Vec<Capsule>,
    rule: FillRule,
    width: usize,
    height: usize,
}

/// True when a polyline's first and last points coincide (to 1 nm).
pub(crate) fn is_closed(points: &[[f64; 2]]) -> bool {
    match (points.first(), points.last()) {
        (Some(a), Some(b)) if points.len() > 2 => {
            (a[0] - b[0]).abs() <= 1e-6 && (a[1] - b[1]).abs() <= 1e-6
        }
        _ => false,
    }
}

impl Scene {
    /// Collects the edges to fill and the segments to stroke, as `opts` asks.
    pub(crate) fn new(layer: &Layer, grid: &Grid, opts: &RasterOptions) -> Scene {
        let to_uv = |p: &[f64; 2]| -> [f64; 2] {
            [
                (p[0] - grid.x_min) / grid.pixel_mm,
                (grid.y_max - p[1]) / grid.pixel_mm,
            ]
        };
        let keep = |part: i64| opts.part.is_none_or(|want| want == part);
        let hatch_r = 0.5 * opts.hatch_width_mm.max(0.0) / grid.pixel_mm;
        let contour_r = 0.5 * opts.contour_width_mm.max(0.0) / grid.pixel_mm;
        let mut scene = Scene {
            edges: Vec::new(),
            capsules: Vec::new(),
            rule: opts.fill_rule,
            width: grid.columns(),
            height: grid.rows(),
        };
        for poly in layer.polylines.iter().filter(|p| keep(p.part)) {
            let pts: Vec<[f64; 2]> = poly
                .points
                .iter()
                .filter(|p| p[0].is_finite() && p[1].is_finite())
                .map(to_uv)
                .collect();
            let fill = match poly.direction {
                Direction::Clockwise | Direction::CounterClockwise => true,
                Direction::Open => opts.fill_closed_open && is_closed(&poly.points),
            };
            if fill && pts.len() >= 3 {
                // Implicitly closed: the last edge goes back to the first point.
                for (i, a) in pts.iter().enumerate() {
                    let b = &pts[(i + 1) % pts.len()];
                    scene.push_edge(*a, *b);
                }
            }
            let stroke_r = if poly.direction == Direction::Open {
                hatch_r
            } else {
                contour_r
            };
            if stroke_r > 0.0 {
                for w in pts.windows(2) {
                    scene.push_capsule(w[0], w[1], stroke_r);
                }
                // Contours close implicitly, like their fill.
                let n = pts.len();
                if poly.direction != Direction::Open && n > 2 && pts[0] != pts[n - 1] {
                    scene.push_capsule(pts[n - 1], pts[0], stroke_r);
                }
                if pts.len() == 1 {
                    scene.push_capsule(pts[0], pts[0], stroke_r);
                }
            }
        }
        if hatch_r > 0.0 {
            for h in layer.hatches.iter().filter(|h| keep(h.part)) {
                for s in &h.segments {
                    if s.iter().all(|v| v.is_finite()) {
                        scene.push_capsule(to_uv(&[s[0], s[1]]), to_uv(&[s[2], s[3]]), hatch_r);
                    }
                }
            }
        }
        // Sorted by top so that each band's active list is fed in order.
        scene
            .edges
            .sort_unstable_by(|a, b| a.v_top.total_cmp(&b.v_top));
        scene
            .capsules
            .sort_unstable_by(|a, b| a.v_top.total_cmp(&b.v_top));
        scene
    }

    fn push_edge(&mut self, a: [f64; 2], b: [f64; 2]) {
        if a[1] == b[1] {
            return; // Horizontal edges never cross a scanline under the half-open rule.
        }
        let (top, bot, wind) = if a[1] < b[1] { (a, b, 1) } else { (b, a, -1) };
        self.edges.push(Edge {
            v_top: top[1],
            v_bot: bot[1],
            u_top: top[0],
            slope: (bot[0] - top[0]) / (bot[1] - top[1]),
            wind,
        });
    }

    fn push_capsule(&mut self, a: [f64; 2], b: [f64; 2], r: f64) {
        self.capsules.push(Capsule {
            v_top: a[1].min(b[1]) - r,
            v_bot: a[1].max(b[1]) + r,
            a,
            b,
            r,
        });
    }

    /// Renders into `out` (row-major, `width * height`) with `s` x `s` sub-samples per
    /// pixel. `binary` writes 255 where any sub-sample is covered (with s = 1: the pixel center),
    /// otherwise the covered fraction scaled to 0..255.
    pub(crate) fn render(&self, s: usize, binary: bool, out: &mut [u8]) {
        let (w, h) = (self.width, self.height);
        debug_assert_eq!(out.len(), w * h);
        if w == 0 || h == 0 {
            return;
        }
        let s = s.clamp(1, 16);
        let threads = rayon::current_num_threads().max(1);
        let band = h.div_ceil(threads * 8).clamp(8, 256);
        out.par_chunks_mut(band * w)
            .enumerate()
            .for_each(|(bi, rows)| self.render_band(bi * band, rows, s, binary));
    }

    fn render_band(&self, row0: usize, out: &mut [u8], s: usize, binary: bool) {
        let w = self.width;
        let nrows = out.len() / w;
        let sf = s as f64;
        let v_first = row0 as f64 + 0.5 / sf;
        let v_last = (row0 + nrows) as f64 - 0.5 / sf;
        // Only what can reach this band; both lists stay sorted by top.
        let edges: Vec<&Edge> = self
            .edges
            .iter()
            .take_while(|e| e.v_top <= v_last)
            .filter(|e| e.v_bot > v_first)
            .collect();
        let caps: Vec<&Capsule> = self
            .capsules
            .iter()
            .take_while(|c| c.v_top <= v_last)
            .filter(|c| c.v_bot >= v_first)
            .collect();
        let (mut next_edge, mut next_cap) = (0usize, 0usize);
        let mut active_edges: Vec<&Edge> = Vec::new();
        let mut active_caps: Vec<&Capsule> = Vec::new();
        let mut crossings: Vec<(f64, i32)> = Vec::new();
        let mut spans: Vec<(i64, i64)> = Vec::new();
        let mut acc = vec![0u16; w];
        let mut diff = vec![0i32; w * s + 1];
        let j_max = (w * s) as i64 - 1;
        let n = (s * s) as u32;
        for (ri, out_row) in out.chunks_mut(w).enumerate() {
            acc.fill(0);
            for sub in 0..s {
                let v = (row0 + ri) as f64 + (sub as f64 + 0.5) / sf;
                spans.clear();
                // Fill: crossings of the active edges, half-open in v so that shared
                // vertices count once.
                while next_edge < edges.len() && edges[next_edge].v_top <= v {
                    active_edges.push(edges[next_edge]);
                    next_edge += 1;
                }
                active_edges.retain(|e| e.v_bot > v);
                if !active_edges.is_empty() {
                    crossings.clear();
                    crossings.extend(
                        active_edges
                            .iter()
                            .map(|e| (e.u_top + (v - e.v_top) * e.slope, e.wind)),
                    );
                    crossings.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
                    let mut winding = 0i32;
                    let mut start = 0.0;
                    for &(u, wind) in &crossings {
                        let was = self.rule.inside(winding);
                        winding += wind;
                        let now = self.rule.inside(winding);
                        if !was && now {
                            start = u;
                        } else if was && !now {
                            // Samples with start <= center < u.
                            let ja = ceil_i64(start * sf - 0.5);
                            let jb = ceil_i64(u * sf - 0.5) - 1;
                            push_span(&mut spans, ja, jb, j_max);
                        }
                    }
                }
                // Strokes: the scanline meets each capsule in one interval (it is convex).
                while next_cap < caps.len() && caps[next_cap].v_top <= v {
                    active_caps.push(caps[next_cap]);
                    next_cap += 1;
                }
                active_caps.retain(|c| c.v_bot >= v);
                for c in &active_caps {
                    if let Some((lo, hi)) = capsule_span(c, v) {
                        let ja = ceil_i64(lo * sf - 0.5);
                        let jb = floor_i64(hi * sf - 0.5);
                        push_span(&mut spans, ja, jb, j_max);
                    }
                }
                accumulate(&mut spans, &mut acc, s, &mut diff);
            }
            if binary {
                for (o, &a) in out_row.iter_mut().zip(&acc) {
                    *o = if a > 0 { 255 } else { 0 };
                }
            } else {
                for (o, &a) in out_row.iter_mut().zip(&acc) {
                    *o = ((a as u32 * 255 + n / 2) / n) as u8;
                }
            }
        }
    }
}

impl FillRule {
    fn inside(self, winding: i32) -> bool {
        match self {
            FillRule::NonZero => winding != 0,
            FillRule::EvenOdd => winding & 1 != 0,
        }
    }
}

fn push_span(spans: &mut Vec<(i64, i64)>, ja: i64, jb: i64, j_max: i64) {
    let (ja, jb) = (ja.max(0), jb.min(j_max));
    if ja <= jb {
        spans.push((ja, jb));
    }
}

/// `x.ceil() as i64` without the libm call (the default x86-64 target has no `roundsd`),
/// saturating like `as`; the scanline's inner loop does this per span end.
#[inline]
fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x {
        t.saturating_add(1)
    } else {
        t
    }
}

/// `x.floor() as i64`, as [`ceil_i64`].
#[inline]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t.saturating_sub(1)
    } else {
        t
    }
}

/// Adds the union of the sub-sample spans of one sub-scanline to the pixel counts.
///
/// Few spans: sorted and merged. Many (a scanline across dense hatching meets thousands):
/// counted in a difference array over the touched range instead, which costs
/// O(spans + range) rather than a sort. `diff` is all zero on entry and on return.
fn accumulate(spans: &mut [(i64, i64)], acc: &mut [u16], s: usize, diff: &mut [i32]) {
    if spans.is_empty() {
        return;
    }
    if spans.len() > 32 {
        let (mut lo, mut hi) = (usize::MAX, 0usize);
        for &(a, b) in spans.iter() {
            let (a, b) = (a as usize, b as usize + 1);
            diff[a] += 1;
            diff[b] -= 1;
            lo = lo.min(a);
            hi = hi.max(b);
        }
        let mut run = 0i32;
        for p in lo / s..hi.div_ceil(s) {
            let mut count = 0u16;
            for d in &mut diff[(p * s).max(lo)..((p + 1) * s).min(hi)] {
                run += *d;
                *d = 0;
                count += (run > 0) as u16;
            }
            acc[p] += count;
        }
        diff[hi] = 0;
        return;
    }
    spans.sort_unstable();
    let mut add = |a: i64, b: i64| {
        let (a, b) = (a as usize, b as usize);
        let (pa, pb) = (a / s, b / s);
        if pa == pb {
            acc[pa] += (b - a + 1) as u16;
        } else {
            acc[pa] += (s - a % s) as u16;
            for v in &mut acc[pa + 1..pb] {
                *v += s as u16;
            }
            acc[pb] += (b % s + 1) as u16;
        }
    };
    let (mut ca, mut cb) = spans[0];
    for &(a, b) in &spans[1..] {
        if a > cb + 1 {
            add(ca, cb);
            ca = a;
            cb = b;
        } else {
            cb = cb.max(b);
        }
    }
    add(ca, cb);
}

/// The u-interval where the scanline v lies within `c.r` of the segment, if any.
fn capsule_span(c: &Capsule, v: f64) -> Option<(f64, f64)> {
    let r = c.r;
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for p in [c.a, c.b] {
        let dv = v - p[1];
        let h2 = r * r - dv * dv;
        if h2 >= 0.0 {
            let hw = h2.sqrt();
            lo = lo.min(p[0] - hw);
            hi = hi.max(p[0] + hw);
        }
    }
    let (du, dv) = (c.b[0] - c.a[0], c.b[1] - c.a[1]);
    let len = (du * du + dv * dv).sqrt();
    if len > 0.0 {
        // With x = u − a.u: along = (x·du + (v − a.v)·dv)/len in [0, len],
        // across = (−x·dv + (v − a.v)·du)/len in [−r, r].
        let ev = v - c.a[1];
        let mut xlo = f64::NEG_INFINITY;
        let mut xhi = f64::INFINITY;
        let mut feasible = true;
        for (k, c0, bl, bh) in [
            (du / len, ev * dv / len, 0.0, len),
            (-dv / len, ev * du / len, -r, r),
        ] {
            if k.abs() < 1e-12 {
                if c0 < bl || c0 > bh {
                    feasible = false;
                }
            } else {
                let (t1, t2) = ((bl - c0) / k, (bh - c0) / k);
                xlo = xlo.max(t1.min(t2));
                xhi = xhi.min(t1.max(t2));
            }
        }
        if feasible && xlo <= xhi {
            lo = lo.min(c.a[0] + xlo);
            hi = hi.max(c.a[0] + xhi);
        }
    }
    (lo <= hi).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accumulate_paths_agree() {
        let mut seed = 7u64;
        let mut rnd = move |n: i64| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as i64
        };
        for s in [1usize, 3, 4] {
            let w = 50;
            for n in [5usize, 40, 200] {
                let spans: Vec<(i64, i64)> = (0..n)
                    .map(|_| {
                        let a = rnd((w * s) as i64);
                        (a, (a + rnd(12)).min((w * s) as i64 - 1))
                    })
                    .collect();
                // Reference: sample by sample.
                let mut want = vec![0u16; w];
                for j in 0..(w * s) as i64 {
                    if spans.iter().any(|&(a, b)| a <= j && j <= b) {
                        want[j as usize / s] += 1;
                    }
                }
                let mut got = vec![0u16; w];
                let mut diff = vec![0i32; w * s + 1];
                accumulate(&mut spans.clone(), &mut got, s, &mut diff);
                assert_eq!(got, want, "s {s} n {n}");
                assert!(diff.iter().all(|&d| d == 0));
            }
        }
        assert_eq!((ceil_i64(-0.5), ceil_i64(2.0), ceil_i64(2.1)), (0, 2, 3));
        assert_eq!(
            (floor_i64(-0.5), floor_i64(2.0), floor_i64(2.9)),
            (-1, 2, 2)
        );
        assert_eq!(ceil_i64(f64::NAN), 0);
        assert_eq!(ceil_i64(1e300), i64::MAX);
    }

    #[test]
    fn capsule_span_matches_distance() {
        let c = Capsule {
            v_top: 0.0,
            v_bot: 0.0,
            a: [1.0, 2.0],
            b: [7.0, 5.0],
            r: 1.3,
        };
        let dist = |u: f64, v: f64| {
            let (du, dv) = (c.b[0] - c.a[0], c.b[1] - c.a[1]);
            let t = (((u - c.a[0]) * du + (v - c.a[1]) * dv) / (du * du + dv * dv)).clamp(0.0, 1.0);
            ((u - c.a[0] - t * du).powi(2) + (v - c.a[1] - t * dv).powi(2)).sqrt()
        };
        for iv in 0..100 {
            let v = iv as f64 * 0.09;
            let span = capsule_span(&c, v);
            for iu in 0..1000 {
                let u = -1.0 + iu as f64 * 0.011;
                let d = dist(u, v);
                let inside = span.is_some_and(|(lo, hi)| u >= lo && u <= hi);
                if (d - c.r).abs() > 1e-9 {
                    assert_eq!(inside, d < c.r, "u {u} v {v} d {d} span {span:?}");
                }
            }
        }
    }
}
