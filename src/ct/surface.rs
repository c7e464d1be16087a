//! Threshold → part mask → sub-voxel surface points (paper §3.2: "the part can be thresholded by
//! extracting the high density voxels").
//!
//! Masks are bitsets (128 MiB for 1024³) and flood fills are scanline fills whose stack holds
//! runs, not voxels, so a 1024³ volume segments without a per-voxel label array.

use rayon::prelude::*;

use super::volume::{with_voxels, Volume, Voxel};
use super::{CtError, Result};

/// How the part is separated from the background.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Threshold {
    /// Otsu's between-class-variance threshold (the default).
    Otsu,
    /// Halfway between the medians of Otsu's two classes ("ISO50" of CT metrology): the
    /// partial-volume voxels of a blurred edge then cross at the true edge whatever the
    /// class proportions.
    Iso50,
    /// A value in the volume's physical (rescaled) units.
    Value(f64),
}

/// A fixed-size bitset over the voxels.
#[derive(Debug, Clone)]
pub struct Bitset {
    words: Vec<u64>,
    len: usize,
}

impl Bitset {
    pub fn new(len: usize) -> Self {
        Self {
            words: vec![0; len.div_ceil(64)],
            len,
        }
    }

    #[inline(always)]
    pub fn get(&self, i: usize) -> bool {
        (self.words[i >> 6] >> (i & 63)) & 1 != 0
    }

    #[inline(always)]
    pub fn set(&mut self, i: usize) {
        self.words[i >> 6] |= 1 << (i & 63);
    }

    pub fn count(&self) -> usize {
        self.words.par_iter().map(|w| w.count_ones() as usize).sum()
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

/// The segmented part.
#[derive(Debug, Clone)]
pub struct Segmentation {
    /// Threshold in the volume's physical units (a voxel is material when value ≥ threshold).
    pub threshold: f64,
    /// Kept components with their internal voids filled.
    pub solid: Bitset,
    /// Voxels at or above the threshold.
    pub above_threshold: usize,
    /// 6-connected components found / kept.
    pub components: usize,
    pub components_kept: usize,
    /// Voxels of the kept components, and after filling voids.
    pub kept_voxels: usize,
    pub solid_voxels: usize,
}

/// Otsu's threshold over a 4096-bin (or exact 8-bit) histogram, in physical units.
pub fn otsu(volume: &Volume) -> Result<f64> {
    let h = Histogram::of(volume)?;
    Ok(h.value_at_edge(h.otsu_bin() + 1))
}

/// Halfway between the medians of Otsu's two classes, in physical units.
pub fn iso50(volume: &Volume) -> Result<f64> {
    let (lo, hi) = class_levels(volume)?;
    Ok(0.5 * (lo + hi))
}

/// The medians of Otsu's two classes (background or void, material), in physical units: the
/// two density levels of the CT, for partial-volume fractions.
pub fn class_levels(volume: &Volume) -> Result<(f64, f64)> {
    let h = Histogram::of(volume)?;
    let k = h.otsu_bin();
    let lo = h.median_bin(0, k + 1);
    let hi = h.median_bin(k + 1, h.counts.len());
    Ok((h.value_at_center(lo), h.value_at_center(hi)))
}

struct Histogram {
    counts: Vec<u64>,
    /// Stored (raw) value of bin 0's lower edge, and bin width.
    lo: f64,
    width: f64,
    slope: f64,
    intercept: f64,
}

impl Histogram {
    fn of(volume: &Volume) -> Result<Self> {
        let (min, max) = volume.value_range();
        if !(min.is_finite() && max.is_finite()) {
            return Err(CtError::Invalid(
                "the volume holds NaN or infinite values".into(),
            ));
        }
        // Bins over the stored values; the physical map is applied to the edges.
        let (s, c) = (volume.rescale_slope, volume.rescale_intercept);
        let (rlo, rhi) = {
            let a = (min - c) / s;
            let b = (max - c) / s;
            (a.min(b), a.max(b))
        };
        let integer = !matches!(volume.data, super::VoxelData::F32(_));
        let bins = if integer {
            // One bin per stored integer when that is few enough.
            ((rhi - rlo) as usize + 1).clamp(1, 4096)
        } else {
            4096
        };
        let (lo, width) = if integer && ((rhi - rlo) as usize) < 4096 {
            (rlo - 0.5, 1.0)
        } else {
            let w = ((rhi - rlo) / bins as f64).max(f64::MIN_POSITIVE);
            (rlo, w * (1.0 + 1e-9))
        };
        fn fill<T: Voxel>(v: &[T], lo: f64, width: f64, bins: usize) -> Vec<u64> {
            v.par_chunks(1 << 18)
                .map(|c| {
                    let mut h = vec![0u64; bins];
                    for x in c {
                        let b = ((x.to_f32() as f64 - lo) / width) as usize;
                        h[b.min(bins - 1)] += 1;
                    }
                    h
                })
                .reduce(
                    || vec![0u64; bins],
                    |mut a, b| {
                        a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                        a
                    },
                )
        }
        let counts = with_voxels!(&volume.data, v => fill(v, lo, width, bins));
        Ok(Self {
            counts,
            lo,
            width,
            slope: s,
            intercept: c,
        })
    }

    /// Last bin of the lower class.
    fn otsu_bin(&self) -> usize {
        let total: f64 = self.counts.iter().map(|&c| c as f64).sum();
        let sum_all: f64 = self
            .counts
            .iter()
            .enumerate()
            .map(|(i, &c)| i as f64 * c as f64)
            .sum();
        let (mut w0, mut s0) = (0.0, 0.0);
        let (mut best, mut best_k) = (-1.0, 0);
        for (k, &c) in self
            .counts
            .iter()
            .enumerate()
            .take(self.counts.len().saturating_sub(1))
        {
            w0 += c as f64;
            s0 += k as f64 * c as f64;
            let w1 = total - w0;
            if w0 == 0.0 || w1 == 0.0 {
                continue;
            }
            let d = s0 / w0 - (sum_all - s0) / w1;
            let between = w0 * w1 * d * d;
            if between > best {
                best = between;
                best_k = k;
            }
        }
        best_k
    }

    fn median_bin(&self, from: usize, to: usize) -> usize {
        let n: u64 = self.counts[from..to].iter().sum();
        let mut acc = 0;
        for k in from..to {
            acc += self.counts[k];
            if 2 * acc >= n {
                return k;
            }
        }
        to.saturating_sub(1)
    }

    fn physical(&self, raw: f64) -> f64 {
        raw * self.slope + self.intercept
    }

    fn value_at_edge(&self, k: usize) -> f64 {
        self.physical(self.lo + k as f64 * self.width)
    }

    fn value_at_center(&self, k: usize) -> f64 {
        self.physical(self.lo + (k as f64 + 0.5) * self.width)
    }
}

/// Threshold, keep the large 6-connected components, fill internal voids.
pub fn segment(volume: &Volume, threshold: &Threshold, keep_fraction: f64) -> Result<Segmentation> {
    if volume.is_empty() {
        return Err(CtError::Invalid("the volume is empty".into()));
    }
    let t = match threshold {
        Threshold::Otsu => otsu(volume)?,
        Threshold::Iso50 => iso50(volume)?,
        Threshold::Value(v) => *v,
    };
    let mask = threshold_mask(volume, t);
    let above = mask.count();
    if above == 0 || above == volume.len() {
        let (min, max) = volume.value_range();
        return Err(if above == 0 {
            CtError::EmptyThreshold {
                threshold: t,
                min,
                max,
            }
        } else {
            CtError::FullThreshold {
                threshold: t,
                min,
                max,
            }
        });
    }
    let dims = volume.dims;

    // Component sizes (a seed voxel for each), then re-fill the kept ones.
    let mut visited = Bitset::new(volume.len());
    let mut comps: Vec<(usize, usize)> = Vec::new();
    for (w, &word) in mask.words.iter().enumerate() {
        let mut todo = word & !visited.words[w];
        while todo != 0 {
            let i = w * 64 + todo.trailing_zeros() as usize;
            todo &= todo - 1;
            if visited.get(i) {
                continue;
            }
            let n = flood(dims, |j| mask.get(j), &mut visited, i);
            comps.push((i, n));
            todo &= !visited.words[w];
        }
    }
    let largest = comps.iter().map(|c| c.1).max().unwrap_or(0);
    let min_keep = (keep_fraction.clamp(0.0, 1.0) * largest as f64).ceil() as usize;
    let mut kept = Bitset::new(volume.len());
    let mut kept_voxels = 0;
    let mut components_kept = 0;
    for &(seed, n) in &comps {
        if n >= min_keep.max(1) {
            flood(dims, |j| mask.get(j), &mut kept, seed);
            kept_voxels += n;
            components_kept += 1;
        }
    }
    drop(mask);

    // Voids: background not reachable from outside the kept part's bounding box (+1 voxel).
    let (lo, hi) = bounding_box(&kept, dims);
    let lo = lo.map(|v| v.saturating_sub(1));
    let hi = std::array::from_fn::<usize, 3, _>(|a| (hi[a] + 1).min(dims[a] - 1));
    let inside_box = |j: usize| {
        let x = j % dims[0];
        let y = (j / dims[0]) % dims[1];
        let z = j / (dims[0] * dims[1]);
        (lo[0]..=hi[0]).contains(&x) && (lo[1]..=hi[1]).contains(&y) && (lo[2]..=hi[2]).contains(&z)
    };
    let mut exterior = Bitset::new(volume.len());
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            for x in lo[0]..=hi[0] {
                let on_face = x == lo[0]
                    || x == hi[0]
                    || y == lo[1]
                    || y == hi[1]
                    || z == lo[2]
                    || z == hi[2];
                if !on_face {
                    continue;
                }
                let j = x + dims[0] * (y + dims[1] * z);
                if !kept.get(j) && !exterior.get(j) {
                    flood(dims, |q| !kept.get(q) && inside_box(q), &mut exterior, j);
                }
            }
        }
    }
    // solid = inside the box and not exterior (kept voxels are never exterior).
    let mut solid = kept;
    let (nx, ny) = (dims[0], dims[1]);
    for z in lo[2]..=hi[2] {
        for y in lo[1]..=hi[1] {
            for x in lo[0]..=hi[0] {
                let j = x + nx * (y + ny * z);
                if !exterior.get(j) {
                    solid.set(j);
                }
            }
        }
    }
    let solid_voxels = solid.count();
    Ok(Segmentation {
        threshold: t,
        solid,
        above_threshold: above,
        components: comps.len(),
        components_kept,
        kept_voxels,
        solid_voxels,
    })
}

fn threshold_mask(volume: &Volume, t: f64) -> Bitset {
    let n = volume.len();
    let mut mask = Bitset::new(n);
    // Compare stored values against the threshold mapped back to stored units.
    let (s, c) = (volume.rescale_slope, volume.rescale_intercept);
    fn fill<T: Voxel>(v: &[T], words: &mut [u64], s: f64, c: f64, t: f64) {
        words.par_iter_mut().enumerate().for_each(|(w, word)| {
            let start = w * 64;
            let end = (start + 64).min(v.len());
            let mut bits = 0u64;
            for (b, x) in v[start..end].iter().enumerate() {
                if x.to_f32() as f64 * s + c >= t {
                    bits |= 1 << b;
                }
            }
            *word = bits;
        });
    }
    with_voxels!(&volume.data, v => fill(v, &mut mask.words, s, c, t));
    mask
}

fn bounding_box(mask: &Bitset, dims: [usize; 3]) -> ([usize; 3], [usize; 3]) {
    let plane = dims[0] * dims[1];
    let (lo, hi) = (0..dims[2])
        .into_par_iter()
        .map(|z| {
            let mut lo = [usize::MAX; 3];
            let mut hi = [0usize; 3];
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    if mask.get(x + dims[0] * y + plane * z) {
                        let p = [x, y, z];
                        for a in 0..3 {
                            lo[a] = lo[a].min(p[a]);
                            hi[a] = hi[a].max(p[a]);
                        }
                    }
                }
            }
            (lo, hi)
        })
        .reduce(
            || ([usize::MAX; 3], [0; 3]),
            |a, b| {
                (
                    std::array::from_fn(|i| a.0[i].min(b.0[i])),
                    std::array::from_fn(|i| a.1[i].max(b.1[i])),
                )
            },
        );
    (lo.map(|v| if v == usize::MAX { 0 } else { v }), hi)
}

/// 6-connected scanline flood fill from `seed` over voxels where `pass` holds, marking `visited`.
/// Returns the number of voxels filled.
fn flood(
    dims: [usize; 3],
    pass: impl Fn(usize) -> bool,
    visited: &mut Bitset,
    seed: usize,
) -> usize {
    let (nx, ny, nz) = (dims[0], dims[1], dims[2]);
    let plane = nx * ny;
    let mut stack = vec![seed];
    let mut filled = 0;
    while let Some(s) = stack.pop() {
        if visited.get(s) || !pass(s) {
            continue;
        }
        let row = s - s % nx;
        let (mut x0, mut x1) = (s % nx, s % nx);
        while x0 > 0 && !visited.get(row + x0 - 1) && pass(row + x0 - 1) {
            x0 -= 1;
        }
        while x1 + 1 < nx && !visited.get(row + x1 + 1) && pass(row + x1 + 1) {
            x1 += 1;
        }
        for x in x0..=x1 {
            visited.set(row + x);
        }
        filled += x1 - x0 + 1;
        let y = (row / nx) % ny;
        let z = row / plane;
        let mut push_runs = |nrow: usize| {
            let mut in_run = false;
            for x in x0..=x1 {
                let j = nrow + x;
                let open = !visited.get(j) && pass(j);
                if open && !in_run {
                    stack.push(j);
                }
                in_run = open;
            }
        };
        if y > 0 {
            push_runs(row - nx);
        }
        if y + 1 < ny {
            push_runs(row + nx);
        }
        if z > 0 {
            push_runs(row - plane);
        }
        if z + 1 < nz {
            push_runs(row + plane);
        }
    }
    filled
}

/// Sub-voxel surface points in CT physical mm: for every solid/background voxel pair along x, y
/// and z, the linear interpolation of the threshold crossing between the two voxel values.
pub fn surface_points(volume: &Volume, seg: &Segmentation) -> Vec<[f64; 3]> {
    fn run<T: Voxel>(v: &[T], volume: &Volume, seg: &Segmentation) -> Vec<[f64; 3]> {
        let [nx, ny, nz] = volume.dims;
        let plane = nx * ny;
        let (s, c) = (volume.rescale_slope, volume.rescale_intercept);
        let t = seg.threshold;
        let solid = &seg.solid;
        let val = |i: usize| v[i].to_f32() as f64 * s + c;
        let slices: Vec<Vec<[f64; 3]>> = (0..nz)
            .into_par_iter()
            .map(|z| {
                let mut out = Vec::new();
                for y in 0..ny {
                    for x in 0..nx {
                        let i = x + nx * y + plane * z;
                        let a = solid.get(i);
                        let steps = [
                            (x + 1 < nx, 1usize, 0),
                            (y + 1 < ny, nx, 1),
                            (z + 1 < nz, plane, 2),
                        ];
                        for (ok, d, axis) in steps {
                            if !ok || solid.get(i + d) == a {
                                continue;
                            }
                            // The solid voxel of a kept component is ≥ t and its background
                            // neighbour < t, so the crossing lies within the pair.
                            let (vi, vj) = (val(i), val(i + d));
                            let f = if vj != vi {
                                ((t - vi) / (vj - vi)).clamp(0.0, 1.0)
                            } else {
                                0.5
                            };
                            let mut p = [x as f64, y as f64, z as f64];
                            p[axis] += f;
                            out.push(volume.index_to_physical(p));
                        }
                    }
                }
                out
            })
            .collect();
        slices.concat()
    }
    with_voxels!(&volume.data, v => run(v, volume, seg))
}

/// Centroid and principal extents of a point set (volume centroid for solid voxels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PartShape {
    pub centroid: [f64; 3],
    /// Principal axes (unit vectors), largest extent first.
    pub axes: [[f64; 3]; 3],
    /// Extent (max − min projection) along each principal axis, mm, largest first.
    pub extents_mm: [f64; 3],
}

impl PartShape {
    /// From points sampling the part's volume (voxel centres of a raster, material points).
    pub fn from_points(points: &[[f64; 3]]) -> Self {
        let moments = points
            .par_chunks(1 << 14)
            .map(|c| {
                let mut m = Moments::default();
                c.iter().for_each(|p| m.add(*p));
                m
            })
            .reduce(Moments::default, Moments::merge);
        let (centroid, axes) = moments.principal();
        let (lo, hi) = points
            .par_chunks(1 << 14)
            .map(|c| {
                let mut e = Extents::default();
                c.iter().for_each(|p| e.add(*p, &centroid, &axes));
                e
            })
            .reduce(Extents::default, Extents::merge)
            .bounds();
        Self::finish(centroid, axes, lo, hi)
    }

    fn finish(centroid: [f64; 3], axes: [[f64; 3]; 3], lo: [f64; 3], hi: [f64; 3]) -> Self {
        let mut idx = [0usize, 1, 2];
        let ext: [f64; 3] = std::array::from_fn(|a| (hi[a] - lo[a]).max(0.0));
        idx.sort_by(|&a, &b| ext[b].total_cmp(&ext[a]));
        Self {
            centroid,
            axes: idx.map(|a| axes[a]),
            extents_mm: idx.map(|a| ext[a]),
        }
    }

    /// This part's size relative to `other`: the geometric mean of the sorted extent ratios.
    pub fn size_ratio(&self, other: &PartShape) -> f64 {
        let r: f64 = (0..3)
            .map(|a| self.extents_mm[a] / other.extents_mm[a])
            .product();
        r.cbrt()
    }
}

#[derive(Default, Clone, Copy)]
struct Moments {
    n: f64,
    s: [f64; 3],
    ss: [[f64; 3]; 3],
}

impl Moments {
    fn add(&mut self, p: [f64; 3]) {
        self.n += 1.0;
        for a in 0..3 {
            self.s[a] += p[a];
            for b in 0..3 {
                self.ss[a][b] += p[a] * p[b];
            }
        }
    }

    fn merge(mut self, o: Self) -> Self {
        self.n += o.n;
        for a in 0..3 {
            self.s[a] += o.s[a];
            for b in 0..3 {
                self.ss[a][b] += o.ss[a][b];
            }
        }
        self
    }

    fn principal(&self) -> ([f64; 3], [[f64; 3]; 3]) {
        let n = self.n.max(1.0);
        let c: [f64; 3] = std::array::from_fn(|a| self.s[a] / n);
        let cov = nalgebra::Matrix3::from_fn(|a, b| self.ss[a][b] / n - c[a] * c[b]);
        let eig = cov.symmetric_eigen();
        let axes = std::array::from_fn(|k| {
            let v = eig.eigenvectors.column(k);
            [v[0], v[1], v[2]]
        });
        (c, axes)
    }
}

#[derive(Clone, Copy)]
struct Extents {
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Default for Extents {
    fn default() -> Self {
        Self {
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
        }
    }
}

impl Extents {
    fn add(&mut self, p: [f64; 3], c: &[f64; 3], axes: &[[f64; 3]; 3]) {
        let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        for (k, ax) in axes.iter().enumerate() {
            let t = d[0] * ax[0] + d[1] * ax[1] + d[2] * ax[2];
            self.lo[k] = self.lo[k].min(t);
            self.hi[k] = self.hi[k].max(t);
        }
    }

    fn merge(self, o: Self) -> Self {
        Self {
            lo: std::array::from_fn(|k| self.lo[k].min(o.lo[k])),
            hi: std::array::from_fn(|k| self.hi[k].max(o.hi[k])),
        }
    }

    fn bounds(self) -> ([f64; 3], [f64; 3]) {
        (self.lo, self.hi)
    }
}

/// Centroid and principal extents of the solid voxels (voxel centres, physical mm).
pub fn solid_shape(volume: &Volume, seg: &Segmentation) -> PartShape {
    let [nx, ny, nz] = volume.dims;
    let plane = nx * ny;
    let solid = &seg.solid;
    // Two passes over the bitset: moments, then extents along the principal axes.
    let moments = (0..nz)
        .into_par_iter()
        .map(|z| {
            let mut m = Moments::default();
            for y in 0..ny {
                for x in 0..nx {
                    if solid.get(x + nx * y + plane * z) {
                        m.add(volume.index_to_physical([x as f64, y as f64, z as f64]));
                    }
                }
            }
            m
        })
        .reduce(Moments::default, Moments::merge);
    let (centroid, axes) = moments.principal();
    let (lo, hi) = (0..nz)
        .into_par_iter()
        .map(|z| {
            let mut e = Extents::default();
            for y in 0..ny {
                for x in 0..nx {
                    if solid.get(x + nx * y + plane * z) {
                        let p = volume.index_to_physical([x as f64, y as f64, z as f64]);
                        e.add(p, &centroid, &axes);
                    }
                }
            }
            e
        })
        .reduce(Extents::default, Extents::merge)
        .bounds();
    PartShape::finish(centroid, axes, lo, hi)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::VoxelData;

    /// A 20³ u8 volume: a 10³ cube (value 200) with a 2³ void (value 10), plus a 1-voxel speck.
    fn cube() -> Volume {
        let n = 20;
        let mut v = vec![10u8; n * n * n];
        for z in 5..15 {
            for y in 5..15 {
                for x in 5..15 {
                    v[x + n * (y + n * z)] = 200;
                }
            }
        }
        for z in 9..11 {
            for y in 9..11 {
                for x in 9..11 {
                    v[x + n * (y + n * z)] = 10;
                }
            }
        }
        v[1 + n * (1 + n)] = 200;
        Volume::new_scaled([n; 3], [0.5; 3], VoxelData::U8(v)).expect("volume")
    }

    #[test]
    fn otsu_splits_a_bimodal_volume() {
        let t = otsu(&cube()).expect("otsu");
        assert!(t > 10.0 && t <= 200.0, "{t}");
        let t50 = iso50(&cube()).expect("iso50");
        assert!((t50 - 105.0).abs() < 1.0, "{t50}");
    }

    #[test]
    fn components_and_voids() {
        let vol = cube();
        let seg = segment(&vol, &Threshold::Value(100.0), 0.1).expect("segment");
        assert_eq!(seg.components, 2);
        assert_eq!(seg.components_kept, 1);
        assert_eq!(seg.kept_voxels, 1000 - 8);
        assert_eq!(seg.solid_voxels, 1000, "the void is filled");
        // Surface: the 6 faces of the cube, 100 crossings each, halfway between the voxel
        // centres (threshold 105 = midway between 10 and 200).
        let pts = surface_points(&vol, &seg);
        assert_eq!(pts.len(), 600);
        // The −x face: between voxel 4 (10) and 5 (200) the threshold 100 sits 90/190 of the way.
        let xs: Vec<f64> = pts.iter().filter(|p| p[0] < 2.4).map(|p| p[0]).collect();
        assert_eq!(xs.len(), 100);
        let expect = (4.0 + 90.0 / 190.0) * 0.5;
        assert!(
            xs.iter().all(|x| (x - expect).abs() < 1e-9),
            "{} vs {expect}",
            xs[0]
        );
        let shape = solid_shape(&vol, &seg);
        assert!((shape.centroid[0] - 4.75).abs() < 1e-9);
        assert!((shape.extents_mm[0] - 4.5).abs() < 1e-9);
    }

    #[test]
    fn empty_and_full_thresholds() {
        let vol = cube();
        let e = segment(&vol, &Threshold::Value(250.0), 0.1).expect_err("empty");
        assert!(matches!(e, CtError::EmptyThreshold { .. }));
        assert!(e.to_string().contains("no voxel is at or above 250"), "{e}");
        let e = segment(&vol, &Threshold::Value(0.0), 0.1).expect_err("full");
        assert!(matches!(e, CtError::FullThreshold { .. }), "{e}");
    }

    #[test]
    fn shape_ratio() {
        let pts: Vec<[f64; 3]> = (0..1000)
            .map(|i| {
                [
                    (i % 10) as f64,
                    ((i / 10) % 10) as f64 * 2.0,
                    (i / 100) as f64 * 3.0,
                ]
            })
            .collect();
        let half: Vec<[f64; 3]> = pts.iter().map(|p| p.map(|v| v * 0.5)).collect();
        let a = PartShape::from_points(&pts);
        let b = PartShape::from_points(&half);
        assert_eq!(a.extents_mm, [27.0, 18.0, 9.0]);
        assert!((b.size_ratio(&a) - 0.5).abs() < 1e-12);
    }
}
