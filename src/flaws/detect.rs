//! Segmentation and measurement: low-density voxels inside the part, 26-connected components
//! with a union-find, a minimum size and a clearance from the part's exterior, then each
//! component measured with partial-volume fractions (volume, centroid) and its second moments
//! (shape, kind), and cut by the printer's layers.

use rayon::prelude::*;

use super::{Flaw, FlawKind, Result, Section};
use crate::ct::surface::{self, Bitset, Threshold};
use crate::ct::volume::{with_voxels, Voxel};
use crate::ct::Volume;
use crate::geometry::{Affine3, Rigid3};
use crate::series::LayerHeights;

/// Tuning knobs; the defaults suit pores of a few voxels in a part of a few hundred.
#[derive(Debug, Clone)]
pub struct FlawParams {
    /// Material / void threshold (Otsu by default, as for the registration).
    pub threshold: Threshold,
    /// The part: 6-connected components with at least this fraction of the largest one.
    pub keep_fraction: f64,
    /// Components with fewer voxels below the threshold are noise.
    pub min_volume_voxels: usize,
    /// Every voxel within this many voxels (Chebyshev) of a flaw must be part material: flaws at
    /// the part's surface (pits, partial-volume voxels) are not internal flaws.
    pub clearance_voxels: usize,
    /// Partial-volume fractions are summed over the flaw grown by this many voxels (≥ the
    /// scanner's blur, ≤ the clearance).
    pub window_voxels: usize,
}

impl Default for FlawParams {
    fn default() -> Self {
        Self {
            threshold: Threshold::Otsu,
            keep_fraction: 0.1,
            min_volume_voxels: 8,
            clearance_voxels: 3,
            window_voxels: 2,
        }
    }
}

/// Where the flaws are in the CT, for the label volume, the masks and the controls.
#[derive(Debug, Clone)]
pub struct CtLabels {
    pub dims: [usize; 3],
    pub build_from_ct: Rigid3,
    pub index_from_ct: Affine3,
    /// The part (material and its internal voids).
    pub solid: Bitset,
    /// (linear voxel index, flaw id), sorted by index.
    pub labels: Vec<(usize, u32)>,
}

impl CtLabels {
    /// The voxel nearest to a build point, if inside the volume.
    pub fn voxel_at(&self, build_mm: [f64; 3]) -> Option<usize> {
        let ct = self.build_from_ct.inverse().apply(build_mm);
        self.voxel_at_ct(ct)
    }

    pub(crate) fn voxel_at_ct(&self, ct_mm: [f64; 3]) -> Option<usize> {
        let f = self.index_from_ct.apply(ct_mm);
        let mut idx = [0usize; 3];
        for a in 0..3 {
            let r = f[a].round();
            if !(r >= 0.0 && r < self.dims[a] as f64) {
                return None;
            }
            idx[a] = r as usize;
        }
        Some(idx[0] + self.dims[0] * (idx[1] + self.dims[1] * idx[2]))
    }

    /// Whether a build point is in the part's material (or an internal void).
    pub fn inside(&self, build_mm: [f64; 3]) -> bool {
        self.voxel_at(build_mm).is_some_and(|i| self.solid.get(i))
    }

    /// The flaw at a build point.
    pub fn label(&self, build_mm: [f64; 3]) -> Option<u32> {
        self.voxel_at(build_mm).and_then(|i| self.label_of(i))
    }

    pub fn label_of(&self, voxel: usize) -> Option<u32> {
        self.labels
            .binary_search_by_key(&voxel, |l| l.0)
            .ok()
            .map(|k| self.labels[k].1)
    }
}

/// What [`detect`] found.
#[derive(Debug, Clone)]
pub struct Detection {
    pub flaws: Vec<Flaw>,
    pub threshold: f64,
    pub void_level: f64,
    pub material_level: f64,
    pub rejected_small: usize,
    pub rejected_surface: usize,
    pub labels: CtLabels,
}

impl Detection {
    /// Keeps the flaws for which `keep` holds, renumbered in their order; returns how many went.
    pub fn retain(&mut self, keep: impl Fn(&Flaw) -> bool) -> usize {
        let mut new_id = vec![0u32; self.flaws.len() + 1];
        let before = self.flaws.len();
        self.flaws.retain(|f| keep(f));
        for (i, f) in self.flaws.iter_mut().enumerate() {
            new_id[f.id as usize] = i as u32 + 1;
            f.id = i as u32 + 1;
        }
        self.labels.labels.retain_mut(|(_, id)| {
            *id = new_id[*id as usize];
            *id != 0
        });
        before - self.flaws.len()
    }
}

/// Finds and measures the internal flaws of a registered CT.
pub fn detect(
    volume: &Volume,
    build_from_ct: &Rigid3,
    heights: &LayerHeights,
    part: Option<i64>,
    params: &FlawParams,
) -> Result<Detection> {
    if params.window_voxels > params.clearance_voxels {
        return Err(super::FlawsError::Invalid(format!(
            "the partial-volume window ({} voxels) must not exceed the surface clearance ({})",
            params.window_voxels, params.clearance_voxels
        )));
    }
    let seg = surface::segment(volume, &params.threshold, params.keep_fraction)?;
    let (void_level, material_level) = surface::class_levels(volume)?;
    let t = seg.threshold;
    let dims = volume.dims;
    let cand = candidates(volume, &seg.solid, t);
    let roots = union_find(&cand, dims);

    // Components in order of their first voxel; each a sorted voxel list.
    let mut order: Vec<usize> = (0..cand.len()).collect();
    order.sort_by_key(|&k| (roots[k], k));
    let mut comps: Vec<Vec<usize>> = Vec::new();
    let mut last = u32::MAX;
    for &k in &order {
        if roots[k] != last {
            comps.push(Vec::new());
            last = roots[k];
        }
        comps.last_mut().expect("pushed").push(cand[k]);
    }
    comps.sort_by_key(|c| c[0]);
    let index_from_ct = crate::ct::resample::index_from_ct(volume)?;
    let ctx = Context {
        volume,
        solid: &seg.solid,
        cand: &cand,
        build_from_ct,
        heights,
        params,
        void_level,
        material_level,
    };
    let small = comps
        .iter()
        .filter(|c| c.len() < params.min_volume_voxels.max(1))
        .count();
    let measured: Vec<Option<Flaw>> = comps
        .par_iter()
        .filter(|c| c.len() >= params.min_volume_voxels.max(1))
        .map(|c| ctx.measure(c, part))
        .collect();
    let surface_rejected = measured.iter().filter(|m| m.is_none()).count();
    let kept: Vec<(Flaw, &Vec<usize>)> = measured
        .into_iter()
        .zip(
            comps
                .iter()
                .filter(|c| c.len() >= params.min_volume_voxels.max(1)),
        )
        .filter_map(|(m, c)| m.map(|f| (f, c)))
        .collect();
    let mut kept = kept;
    kept.sort_by(|a, b| {
        let (p, q) = (a.0.centroid_mm, b.0.centroid_mm);
        p[2].total_cmp(&q[2])
            .then(p[1].total_cmp(&q[1]))
            .then(p[0].total_cmp(&q[0]))
            .then(a.1[0].cmp(&b.1[0]))
    });
    let mut labels = Vec::new();
    let mut flaws = Vec::with_capacity(kept.len());
    for (i, (mut flaw, voxels)) in kept.into_iter().enumerate() {
        flaw.id = i as u32 + 1;
        labels.extend(voxels.iter().map(|&v| (v, flaw.id)));
        flaws.push(flaw);
    }
    labels.sort_unstable();
    Ok(Detection {
        flaws,
        threshold: t,
        void_level,
        material_level,
        rejected_small: small,
        rejected_surface: surface_rejected,
        labels: CtLabels {
            dims,
            build_from_ct: *build_from_ct,
            index_from_ct,
            solid: seg.solid,
            labels,
        },
    })
}

/// Voxels of the part (solid) below the threshold, sorted.
fn candidates(volume: &Volume, solid: &Bitset, t: f64) -> Vec<usize> {
    fn run<T: Voxel>(
        v: &[T],
        dims: [usize; 3],
        solid: &Bitset,
        s: f64,
        c: f64,
        t: f64,
    ) -> Vec<usize> {
        let plane = dims[0] * dims[1];
        let slices: Vec<Vec<usize>> = (0..dims[2])
            .into_par_iter()
            .map(|z| {
                let mut out = Vec::new();
                for i in z * plane..(z + 1) * plane {
                    if solid.get(i) && (v[i].to_f32() as f64) * s + c < t {
                        out.push(i);
                    }
                }
                out
            })
            .collect();
        slices.concat()
    }
    let (s, c) = (volume.rescale_slope, volume.rescale_intercept);
    with_voxels!(&volume.data, v => run(v, volume.dims, solid, s, c, t))
}

/// The root (smallest candidate position) of each candidate's 26-connected component.
fn union_find(cand: &[usize], dims: [usize; 3]) -> Vec<u32> {
    let n = cand.len();
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn find(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let p = parent[parent[i as usize] as usize];
            parent[i as usize] = p;
            i = p;
        }
        i
    }
    let [nx, ny, _] = dims;
    let plane = nx * ny;
    for (k, &v) in cand.iter().enumerate() {
        let (x, y, z) = (v % nx, (v / nx) % ny, v / plane);
        // The 13 neighbours that come before v in memory order.
        for dz in -1i64..=0 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    if dz == 0 && (dy > 0 || (dy == 0 && dx >= 0)) {
                        continue;
                    }
                    let (qx, qy, qz) = (x as i64 + dx, y as i64 + dy, z as i64 + dz);
                    if qx < 0 || qy < 0 || qz < 0 || qx >= nx as i64 || qy >= ny as i64 {
                        continue;
                    }
                    let q = qx as usize + nx * (qy as usize + ny * qz as usize);
                    if let Ok(j) = cand[..k].binary_search(&q) {
                        let (a, b) = (find(&mut parent, k as u32), find(&mut parent, j as u32));
                        if a != b {
                            let (lo, hi) = (a.min(b), a.max(b));
                            parent[hi as usize] = lo;
                        }
                    }
                }
            }
        }
    }
    (0..n as u32).map(|i| find(&mut parent, i)).collect()
}

struct Context<'a> {
    volume: &'a Volume,
    solid: &'a Bitset,
    cand: &'a [usize],
    build_from_ct: &'a Rigid3,
    heights: &'a LayerHeights,
    params: &'a FlawParams,
    void_level: f64,
    material_level: f64,
}

/// `mask` grown by `r` voxels (Chebyshev), in a box of `dims`.
fn dilate(mask: &[bool], dims: [usize; 3], r: usize) -> Vec<bool> {
    let mut cur = mask.to_vec();
    let strides = [1, dims[0], dims[0] * dims[1]];
    for axis in 0..3 {
        let mut next = vec![false; cur.len()];
        for (i, out) in next.iter_mut().enumerate() {
            let p = (i / strides[axis]) % dims[axis];
            let lo = p.saturating_sub(r);
            let hi = (p + r).min(dims[axis] - 1);
            let base = i - p * strides[axis];
            *out = (lo..=hi).any(|q| cur[base + q * strides[axis]]);
        }
        cur = next;
    }
    cur
}

impl Context<'_> {
    fn to_build(&self, idx: [f64; 3]) -> [f64; 3] {
        self.build_from_ct.apply(self.volume.index_to_physical(idx))
    }

    /// Measures one component; `None` when it is within the clearance of the part's exterior
    /// or of the volume's border.
    fn measure(&self, comp: &[usize], part: Option<i64>) -> Option<Flaw> {
        let dims = self.volume.dims;
        let [nx, ny, _] = dims;
        let plane = nx * ny;
        let ijk = |v: usize| [v % nx, (v / nx) % ny, v / plane];
        let mut lo = [usize::MAX; 3];
        let mut hi = [0usize; 3];
        for &v in comp {
            let p = ijk(v);
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let r = self.params.clearance_voxels;
        if (0..3).any(|a| lo[a] < r || hi[a] + r >= dims[a]) {
            return None;
        }
        let b0: [usize; 3] = std::array::from_fn(|a| lo[a] - r);
        let bd: [usize; 3] = std::array::from_fn(|a| hi[a] + r - b0[a] + 1);
        let local =
            |p: [usize; 3]| (p[0] - b0[0]) + bd[0] * ((p[1] - b0[1]) + bd[1] * (p[2] - b0[2]));
        let global = |i: usize| {
            let (x, y, z) = (i % bd[0], (i / bd[0]) % bd[1], i / (bd[0] * bd[1]));
            (b0[0] + x) + nx * ((b0[1] + y) + ny * (b0[2] + z))
        };
        let mut mask = vec![false; bd[0] * bd[1] * bd[2]];
        for &v in comp {
            mask[local(ijk(v))] = true;
        }
        let w = self.params.window_voxels;
        let window = dilate(&mask, bd, w);
        let clear = dilate(&window, bd, r - w);
        if clear
            .iter()
            .enumerate()
            .any(|(i, &c)| c && !self.solid.get(global(i)))
        {
            return None;
        }
        // The material around the flaw (the shell between the window and the clearance): the
        // local level, robust to beam hardening and to the partial-volume voxels that pull the
        // global class median down.
        let (mut shell_sum, mut shell_n) = (0.0, 0usize);
        for (i, (&c, &inw)) in clear.iter().zip(&window).enumerate() {
            let g = global(i);
            if c && !inw && self.cand.binary_search(&g).is_err() {
                shell_sum += self.volume.value(g);
                shell_n += 1;
            }
        }
        let material = if shell_n > 0 {
            shell_sum / shell_n as f64
        } else {
            self.material_level
        };
        // Partial-volume void fractions over the window (not over other flaws' voxels).
        let contrast = (material - self.void_level).max(f64::MIN_POSITIVE);
        let (mut sum, mut sp) = (0.0, [0.0; 3]);
        for (i, &inw) in window.iter().enumerate() {
            if !inw {
                continue;
            }
            let g = global(i);
            if !mask[i] && self.cand.binary_search(&g).is_ok() {
                continue;
            }
            let f = (material - self.volume.value(g)) / contrast;
            let p = ijk(g);
            sum += f;
            for a in 0..3 {
                sp[a] += f * p[a] as f64;
            }
        }
        let h = self.volume.voxel_mm;
        let voxel_volume = h[0] * h[1] * h[2];
        // Binary moments in the build frame (the shape), and the binary centroid as a fallback.
        let pts: Vec<[f64; 3]> = comp
            .iter()
            .map(|&v| {
                let p = ijk(v);
                self.to_build([p[0] as f64, p[1] as f64, p[2] as f64])
            })
            .collect();
        let n = pts.len() as f64;
        let mean: [f64; 3] = std::array::from_fn(|a| pts.iter().map(|p| p[a]).sum::<f64>() / n);
        let hm = (h[0] * h[1] * h[2]).cbrt();
        let cov = nalgebra::Matrix3::from_fn(|a, b| {
            pts.iter()
                .map(|p| (p[a] - mean[a]) * (p[b] - mean[b]))
                .sum::<f64>()
                / n
                + if a == b { hm * hm / 12.0 } else { 0.0 }
        });
        let eig = cov.symmetric_eigen();
        let mut ev: Vec<(f64, [f64; 3])> = (0..3)
            .map(|k| {
                let c = eig.eigenvectors.column(k);
                (eig.eigenvalues[k].max(0.0), [c[0], c[1], c[2]])
            })
            .collect();
        ev.sort_by(|a, b| b.0.total_cmp(&a.0));
        let semi: [f64; 3] = std::array::from_fn(|k| (5.0 * ev[k].0).sqrt());
        let (volume_mm3, centroid_voxel) = if sum > 0.0 {
            (sum * voxel_volume, sp.map(|s| s / sum))
        } else {
            let c: [f64; 3] =
                std::array::from_fn(|a| comp.iter().map(|&v| ijk(v)[a] as f64).sum::<f64>() / n);
            (n * voxel_volume, c)
        };
        let centroid_ct_mm = self.volume.index_to_physical(centroid_voxel);
        let centroid_mm = self.build_from_ct.apply(centroid_ct_mm);
        let ellipsoid = 4.0 / 3.0 * std::f64::consts::PI * semi[0] * semi[1] * semi[2];
        let fill = if ellipsoid > 0.0 {
            volume_mm3 / ellipsoid
        } else {
            0.0
        };
        let elongation = if ev[2].0 > 0.0 {
            (ev[0].0 / ev[2].0).sqrt()
        } else {
            f64::INFINITY
        };
        let kind = if elongation < 1.5 && fill > 0.6 {
            FlawKind::GasPore
        } else {
            FlawKind::LackOfFusion
        };
        // Build-frame bounds from the index box's corners.
        let mut bmin = [f64::INFINITY; 3];
        let mut bmax = [f64::NEG_INFINITY; 3];
        for k in 0..8 {
            let c = std::array::from_fn(|a| {
                if k >> a & 1 == 0 {
                    lo[a] as f64 - 0.5
                } else {
                    hi[a] as f64 + 0.5
                }
            });
            let p = self.to_build(c);
            for a in 0..3 {
                bmin[a] = bmin[a].min(p[a]);
                bmax[a] = bmax[a].max(p[a]);
            }
        }
        let sections = self.sections(&pts, hm);
        Some(Flaw {
            id: 0,
            kind,
            part,
            centroid_mm,
            centroid_ct_mm,
            centroid_voxel,
            bbox_min_mm: bmin,
            bbox_max_mm: bmax,
            voxel_min: lo,
            voxel_max: hi,
            voxels: comp.len(),
            volume_mm3,
            esd_mm: (6.0 * volume_mm3.max(0.0) / std::f64::consts::PI).cbrt(),
            elongation,
            fill,
            semi_axes_mm: semi,
            flat_in_layer: ev[2].1[2].abs(),
            first_layer: sections.first().map(|s| s.layer),
            last_layer: sections.last().map(|s| s.layer),
            sections,
        })
    }

    /// The flaw cut by each layer it spans (voxel centres `pts` in build mm, voxel size `h`).
    fn sections(&self, pts: &[[f64; 3]], h: f64) -> Vec<Section> {
        let zmin = pts.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
        let zmax = pts.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
        let (Some(first), Some(last)) = (self.heights.layer_at(zmin), self.heights.layer_at(zmax))
        else {
            return Vec::new();
        };
        // Each voxel centre in the layer whose slab holds it (as the layers spanned are found).
        let layers: Vec<Option<u32>> = pts.iter().map(|p| self.heights.layer_at(p[2])).collect();
        (first..=last)
            .map(|layer| {
                let top = self.heights.z(layer);
                let bottom = top - self.heights.thickness(layer);
                let mut sel: Vec<&[f64; 3]> = pts
                    .iter()
                    .zip(&layers)
                    .filter(|(_, l)| **l == Some(layer))
                    .map(|(p, _)| p)
                    .collect();
                if sel.is_empty() {
                    // A slab thinner than a voxel: the voxels within half a voxel of it.
                    sel = pts
                        .iter()
                        .filter(|p| p[2] > bottom - h / 2.0 && p[2] <= top + h / 2.0)
                        .collect();
                }
                if sel.is_empty() {
                    sel = pts.iter().collect();
                }
                let n = sel.len() as f64;
                let cx = sel.iter().map(|p| p[0]).sum::<f64>() / n;
                let cy = sel.iter().map(|p| p[1]).sum::<f64>() / n;
                let mut bbox = [
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ];
                for p in &sel {
                    bbox[0] = bbox[0].min(p[0] - h / 2.0);
                    bbox[1] = bbox[1].min(p[1] - h / 2.0);
                    bbox[2] = bbox[2].max(p[0] + h / 2.0);
                    bbox[3] = bbox[3].max(p[1] + h / 2.0);
                }
                Section {
                    layer,
                    center_mm: [cx, cy],
                    bbox_mm: bbox,
                    voxels: sel.len(),
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ct::VoxelData;

    /// A 32³ u8 volume at 0.1 mm: a solid cube (200) over indices 4..28 in a background of 10,
    /// with voids of 10: two 2³ cubes touching at a corner (one 26-connected flaw), a 3³ pore, a
    /// 7 x 7 x 1 plate, a 2³ void two voxels under the surface and a lone voxel.
    fn phantom() -> Volume {
        let n = 32;
        let mut v = vec![10u8; n * n * n];
        let mut fill = |lo: [usize; 3], hi: [usize; 3], value: u8| {
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    for x in lo[0]..hi[0] {
                        v[x + n * (y + n * z)] = value;
                    }
                }
            }
        };
        fill([4; 3], [28; 3], 200);
        fill([8; 3], [10; 3], 10);
        fill([10; 3], [12; 3], 10);
        fill([18; 3], [21; 3], 10);
        fill([8, 8, 22], [15, 15, 23], 10);
        fill([5, 14, 14], [7, 16, 16], 10);
        fill([20, 10, 10], [21, 11, 11], 10);
        Volume::new_scaled([n; 3], [0.1; 3], VoxelData::U8(v)).expect("volume")
    }

    fn found() -> Detection {
        let identity = Rigid3::from_rotation_translation(
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3],
        );
        detect(
            &phantom(),
            &identity,
            &LayerHeights::uniform(0.1),
            Some(7),
            &FlawParams::default(),
        )
        .expect("detect")
    }

    #[test]
    fn components_are_26_connected_sized_and_kept_off_the_surface() {
        let d = found();
        assert_eq!(d.flaws.len(), 3, "{:#?}", d.flaws);
        assert_eq!(d.rejected_small, 1, "the lone voxel");
        assert_eq!(d.rejected_surface, 1, "the void under the surface");
        let voxels: Vec<usize> = d.flaws.iter().map(|f| f.voxels).collect();
        assert_eq!(voxels, [16, 27, 49], "ids in order of z");
        assert!(d.flaws.iter().all(|f| f.part == Some(7)));
        assert_eq!(d.labels.labels.len(), 16 + 27 + 49);
    }

    #[test]
    fn a_cube_pore_is_measured_exactly() {
        let d = found();
        let pore = &d.flaws[1];
        assert_eq!(pore.id, 2);
        assert_eq!(pore.kind, FlawKind::GasPore);
        assert!(
            (pore.volume_mm3 - 0.027).abs() < 1e-9,
            "{}",
            pore.volume_mm3
        );
        for a in 0..3 {
            assert!(
                (pore.centroid_mm[a] - 1.9).abs() < 1e-9,
                "{:?}",
                pore.centroid_mm
            );
        }
        assert_eq!(pore.voxel_min, [18; 3]);
        assert_eq!(pore.voxel_max, [20; 3]);
        assert!(
            (pore.bbox_min_mm[0] - 1.75).abs() < 1e-9 && (pore.bbox_max_mm[2] - 2.05).abs() < 1e-9
        );
        // Voxel centres at z 1.8, 1.9, 2.0: layers 18 to 20 of 0.1 mm.
        assert_eq!((pore.first_layer, pore.last_layer), (Some(18), Some(20)));
        assert_eq!(pore.sections.len(), 3);
        assert!(pore.sections.iter().all(|s| s.voxels == 9));
        assert_eq!(d.labels.label([1.9, 1.9, 1.9]), Some(2));
        assert!(d.labels.inside([1.0, 2.5, 1.0]) && !d.labels.inside([0.1, 0.1, 0.1]));
    }

    #[test]
    fn flaws_left_out_are_renumbered_with_their_labels() {
        let mut d = found();
        assert_eq!(d.retain(|f| f.voxels != 27), 1);
        let ids: Vec<(u32, usize)> = d.flaws.iter().map(|f| (f.id, f.voxels)).collect();
        assert_eq!(ids, [(1, 16), (2, 49)]);
        assert_eq!(d.labels.label([1.9, 1.9, 1.9]), None);
        assert_eq!(d.labels.label([1.0, 1.0, 2.2]), Some(2));
        assert_eq!(d.labels.labels.len(), 16 + 49);
    }

    #[test]
    fn a_flat_void_in_the_layer_plane_is_lack_of_fusion() {
        let d = found();
        let plate = &d.flaws[2];
        assert_eq!(plate.kind, FlawKind::LackOfFusion);
        assert!(plate.elongation > 3.0, "{}", plate.elongation);
        assert!(plate.flat_in_layer > 0.99, "{}", plate.flat_in_layer);
        assert_eq!((plate.first_layer, plate.last_layer), (Some(22), Some(22)));
    }
}
