//! The files a demo build ships so that a new user can try every offline step on it: the vector
//! file of the parts the mock camera photographs (`sim::inject::demo_vectors`), a points file
//! of four clicks (part corners in the frame, as a user would click them: a few pixels off), and
//! a synthetic CT of the box (part 3) with two pores (or the lack-of-fusion pores of `--pores`,
//! which the camera then sees in the post-scan frames), in the CT's own frame.

use std::path::Path;

use mock_camera::{demo_parts, Homography, DEMO_LAYER_THICKNESS_MM};
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

use crate::config::UnfusedSpot;
use crate::ct::phantom::{self, ScanSpec};
use crate::ct::{CtError, Volume};
use crate::geometry::Rigid3;

/// Name of the vector file in a demo build directory.
pub const DEMO_VECTORS: &str = "demo-vectors.cli";
/// Name of the points file (`register images --init`) in a demo build directory.
pub const DEMO_POINTS: &str = "demo-points.txt";

/// Four clicks on part corners of the demo frame of a `width` x `height` mock camera: the true
/// image positions moved by up to 3 px, as a user's clicks are. Lines `u v x y` with a comment.
pub fn demo_points(width: u32, height: u32) -> String {
    let truth = Homography::oblique_view(width, height);
    let image_from_build = truth.inverse().expect("the mock's view is invertible");
    // Corners of the box, of the fin and of the wall (layer 1), clicked a little off.
    let clicks = [
        ((40.0, 44.0), (2.1, -1.4)),
        ((60.0, 56.0), (-1.8, 2.6)),
        ((-40.0, 40.5), (1.2, 1.9)),
        ((-9.0, -90.0), (-2.7, -0.8)),
    ];
    let mut text = String::from(
        "# Four part corners clicked in a demo frame: u v (image px) x y (build mm).\n\
         # register images --init reads this file; see docs/tutorial.md.\n",
    );
    // Click errors scale with the frame (a few pixels at 1472 px wide).
    let scale = f64::from(width) / 1472.0;
    for ((x, y), (du, dv)) in clicks {
        let (u, v) = image_from_build.apply(x, y).expect("in view");
        text += &format!("{:.1} {:.1} {x} {y}\n", u + scale * du, v + scale * dv);
    }
    text
}

/// Folder of the demo build's CT.
pub const DEMO_CT_DIR: &str = "ct";
/// The CT of the demo's box (part 3) as a GE phoenix volume: `ct/box.pcr` beside `ct/box.vol`.
pub const DEMO_CT: &str = "ct/box.pcr";
/// Point pairs `cx cy cz bx by bz` (CT mm, build mm) for `register ct --init`: the box's top
/// corners, clicked up to 0.1 mm off.
pub const DEMO_CT_POINTS: &str = "ct/box-points.txt";
/// The true transform and pores of the CT, for comparing with what the tools find.
pub const DEMO_CT_TRUTH: &str = "ct/box-truth.toml";
/// The part of the demo vectors the CT shows.
pub const DEMO_CT_PART: i64 = 3;
/// The CT needs this many layers (0.6 mm of part) to hold pores with material all around.
pub const DEMO_CT_MIN_LAYERS: u32 = 20;

/// A pore of the demo CT: a sphere (or, from `--pores`, a lens flat in the layer plane) of
/// missing material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemoPore {
    /// Centre in build mm.
    pub center_mm: [f64; 3],
    /// Radius in the layer plane.
    pub radius_mm: f64,
    /// Half its height (along build z): `radius_mm` for a sphere.
    pub half_height_mm: f64,
    /// The printer layer holding the centre.
    pub layer: u32,
}

impl DemoPore {
    fn new(center_mm: [f64; 3], radius_mm: f64, half_height_mm: f64) -> DemoPore {
        DemoPore {
            center_mm,
            radius_mm,
            half_height_mm,
            layer: (center_mm[2] / DEMO_LAYER_THICKNESS_MM).ceil() as u32,
        }
    }

    /// Signed distance to the pore's surface (negative inside; the ellipsoid bound
    /// k0 (k0 − 1) / k1, exact for a sphere and close to the surface of a lens).
    fn distance(&self, p: [f64; 3]) -> f64 {
        let c = self.center_mm;
        let r = [self.radius_mm, self.radius_mm, self.half_height_mm];
        let (mut k0, mut k1) = (0.0f64, 0.0f64);
        for a in 0..3 {
            let d = p[a] - c[a];
            k0 += (d / r[a]).powi(2);
            k1 += (d / (r[a] * r[a])).powi(2);
        }
        let (k0, k1) = (k0.sqrt(), k1.sqrt());
        if k1 == 0.0 {
            return -self.half_height_mm.min(self.radius_mm);
        }
        k0 * (k0 - 1.0) / k1
    }

    /// The pore's radius in layer `layer`'s slab (its widest cut there), if the slab meets it.
    pub fn radius_in_layer(&self, layer: u32) -> Option<f64> {
        let top = f64::from(layer) * DEMO_LAYER_THICKNESS_MM;
        let bottom = top - DEMO_LAYER_THICKNESS_MM;
        let z = self.center_mm[2];
        let dz = if z < bottom {
            bottom - z
        } else if z > top {
            z - top
        } else {
            0.0
        };
        let f = 1.0 - (dz / self.half_height_mm).powi(2);
        (f > 0.0).then(|| self.radius_mm * f.sqrt())
    }
}

/// The demo's CT of the box and its ground truth.
#[derive(Debug, Clone)]
pub struct DemoCt {
    pub volume: Volume,
    /// The true transform, CT physical mm → build mm (what `register ct` should find).
    pub build_from_ct: Rigid3,
    pub pores: Vec<DemoPore>,
    /// The box's height (its top in build z), mm.
    pub height_mm: f64,
}

/// The CT of the demo's box (20 x 12 mm, as tall as `layers` layers) as a scanner would give it:
/// turned 14° about an axis 4° off vertical and moved to the CT's own origin, 50 µm voxels (up to
/// 1/12 of the height for tall builds), partial volume, blur and noise, with two pores of 2 voxels'
/// radius at 47.5 % and 52.5 % of the height (layers 10 and 11 of the 20-layer demo). None below
/// [`DEMO_CT_MIN_LAYERS`] layers: too thin a part for pores with material around them.
pub fn demo_ct(layers: u32) -> Option<DemoCt> {
    if layers < DEMO_CT_MIN_LAYERS {
        return None;
    }
    let height = f64::from(layers) * DEMO_LAYER_THICKNESS_MM;
    let voxel_mm = (height / 12.0).max(0.05);
    let radius_mm = 2.0 * voxel_mm;
    let pores: Vec<DemoPore> = [(45.3, 48.1, 0.475), (54.6, 52.4, 0.525)]
        .into_iter()
        .map(|(x, y, f)| DemoPore::new([x, y, f * height], radius_mm, radius_mm))
        .collect();
    Some(scan_box(height, voxel_mm, pores))
}

/// Radii (in the layer plane) of the `--pores` pores, mm: wide enough for the camera's 0.25 mm
/// pixels to see them (2 to 3 pixels across at the least).
pub const LACK_OF_FUSION_RADIUS_MM: (f64, f64) = (0.55, 0.95);

/// The CT of the demo's box with `count` lack-of-fusion pores (`layerwise demo --pores`): lenses
/// flat in the layer plane, 1.1 to 1.9 mm across and 0.15 mm (3 voxels) high, so each spans a
/// handful of layers; their centres spread over the box's layers (one in each of `count` equal
/// slices of the height, drawn within it) and over the box (2 mm from its sides, never touching
/// each other), all drawn from `seed`. 50 µm voxels (up to 1/60 of the height for tall builds).
/// None below [`DEMO_CT_MIN_LAYERS`] layers, or when `count` lenses do not fit.
pub fn demo_ct_with_pores(layers: u32, count: u32, seed: u64) -> Option<DemoCt> {
    let pores = lack_of_fusion_pores(layers, count, seed)?;
    let height = f64::from(layers) * DEMO_LAYER_THICKNESS_MM;
    Some(scan_box(height, voxel_with_pores(height), pores))
}

fn voxel_with_pores(height: f64) -> f64 {
    (height / 60.0).max(0.05)
}

/// Where [`demo_ct_with_pores`] puts its pores.
pub fn lack_of_fusion_pores(layers: u32, count: u32, seed: u64) -> Option<Vec<DemoPore>> {
    if layers < DEMO_CT_MIN_LAYERS {
        return None;
    }
    let height = f64::from(layers) * DEMO_LAYER_THICKNESS_MM;
    let voxel = voxel_with_pores(height);
    let half_height = 1.5 * voxel;
    // Material above and below: the flaw finder's clearance (3 voxels) and the scanner's blur.
    let (z0, z1) = (
        half_height + 5.0 * voxel,
        height - half_height - 5.0 * voxel,
    );
    let (x0, y0, x1, y1) = demo_parts(1)[DEMO_CT_PART as usize - 1].bbox();
    let margin = 2.0;
    let mut rng = crate::learn::rng::Rng::new(seed);
    let mut pores: Vec<DemoPore> = Vec::new();
    for i in 0..count {
        let slice = (z1 - z0) / f64::from(count);
        let placed = (0..200).find_map(|_| {
            let z = z0 + slice * (f64::from(i) + rng.unit());
            let (lo, hi) = LACK_OF_FUSION_RADIUS_MM;
            let pore = DemoPore::new(
                [
                    rng.range(x0 + margin, x1 - margin),
                    rng.range(y0 + margin, y1 - margin),
                    z,
                ],
                rng.range(lo, hi),
                half_height,
            );
            // Apart from every other pore by 0.3 mm of material at least, across or above.
            let apart = pores.iter().all(|q| {
                let across =
                    (pore.center_mm[0] - q.center_mm[0]).hypot(pore.center_mm[1] - q.center_mm[1]);
                let above = (pore.center_mm[2] - q.center_mm[2]).abs();
                across > pore.radius_mm + q.radius_mm + 0.3
                    || above > pore.half_height_mm + q.half_height_mm + 0.3
            });
            apart.then_some(pore)
        })?;
        pores.push(placed);
    }
    Some(pores)
}

/// The box `height` mm tall with `pores`, scanned at `voxel_mm`.
fn scan_box(height: f64, voxel_mm: f64, pores: Vec<DemoPore>) -> DemoCt {
    let (x0, y0, x1, y1) = demo_parts(1)[DEMO_CT_PART as usize - 1].bbox();
    let sdf = |p: [f64; 3]| {
        let (lo, hi) = ([x0, y0, 0.0], [x1, y1, height]);
        let (mut outside, mut inside) = (0.0f64, f64::NEG_INFINITY);
        for a in 0..3 {
            let e = (p[a] - 0.5 * (lo[a] + hi[a])).abs() - 0.5 * (hi[a] - lo[a]);
            outside += e.max(0.0).powi(2);
            inside = inside.max(e);
        }
        let mut d = outside.sqrt() + inside.min(0.0);
        for pore in &pores {
            let c = pore.center_mm;
            // Far from a pore (beyond the partial-volume band) it changes nothing.
            let reach = pore.radius_mm.max(pore.half_height_mm) + 4.0 * voxel_mm;
            if (p[0] - c[0]).abs() > reach
                || (p[1] - c[1]).abs() > reach
                || (p[2] - c[2]).abs() > reach
            {
                continue;
            }
            d = d.max(-pore.distance(p));
        }
        d
    };
    let axis = Unit::new_normalize(Vector3::new(0.06, -0.04, 1.0));
    let rotation: Matrix3<f64> = *Rotation3::from_axis_angle(&axis, 14f64.to_radians()).matrix();
    let spec = ScanSpec {
        voxel_mm,
        margin_mm: 0.4,
        supersample: 3,
        blur_voxels: 0.7,
        noise: 0.04,
        seed: 18,
    };
    let (volume, m) = phantom::render(&sdf, ([x0, y0, 0.0], [x1, y1, height]), &rotation, &spec);
    DemoCt {
        volume,
        build_from_ct: Rigid3::from_matrix_unchecked(m),
        pores,
        height_mm: height,
    }
}

impl DemoCt {
    /// Every pore cut by every layer it spans, as the camera sees it after that layer's scan:
    /// unfused powder as wide as the pore's widest cut in the layer's slab.
    pub fn unfused_spots(&self) -> Vec<UnfusedSpot> {
        let t = DEMO_LAYER_THICKNESS_MM;
        let mut spots = Vec::new();
        for (k, pore) in self.pores.iter().enumerate() {
            let [x, y, z] = pore.center_mm;
            let first = ((z - pore.half_height_mm) / t).ceil().max(1.0) as u32;
            let last = ((z + pore.half_height_mm) / t).ceil() as u32;
            spots.extend((first..=last).filter_map(|layer| {
                pore.radius_in_layer(layer).map(|radius_mm| UnfusedSpot {
                    layer,
                    center_mm: [x, y],
                    radius_mm,
                    shape_seed: k as u64,
                })
            }));
        }
        spots
    }

    /// The box's top corners in CT mm and build mm, each CT point moved up to 0.1 mm (a user's
    /// clicks), as `register ct --init` reads them.
    pub fn points(&self) -> String {
        let (x0, y0, x1, y1) = demo_parts(1)[DEMO_CT_PART as usize - 1].bbox();
        let top = self.height_mm;
        let ct_from_build = self.build_from_ct.inverse();
        let clicks = [
            [0.08, -0.05, 0.03],
            [-0.06, 0.09, -0.04],
            [0.1, 0.04, 0.05],
            [-0.03, -0.1, -0.02],
        ];
        let mut text = String::from(
            "# Four top corners of the box (part 3) clicked in the CT: cx cy cz (CT mm) bx by bz (build mm).\n\
             # register ct --init reads this file; see docs/tutorial.md.\n",
        );
        for (b, e) in [[x0, y0, top], [x1, y0, top], [x1, y1, top], [x0, y1, top]]
            .into_iter()
            .zip(clicks)
        {
            let c = ct_from_build.apply(b);
            text += &format!(
                "{:.3} {:.3} {:.3} {} {} {:.2}\n",
                c[0] + e[0],
                c[1] + e[1],
                c[2] + e[2],
                b[0],
                b[1],
                b[2]
            );
        }
        text
    }

    /// The ground truth as TOML: the transform (CT mm → build mm, rows) and the pores.
    pub fn truth_toml(&self) -> String {
        let m = self.build_from_ct.matrix();
        let mut text = String::from(
            "# The demo CT's ground truth: what `register ct` and `flaws` should find.\n\
             # transform: CT physical mm -> build mm, 4x4 rows.\n",
        );
        text += &format!("part = {DEMO_CT_PART}\ntransform = [\n");
        for row in m {
            text += &format!("  [{}, {}, {}, {}],\n", row[0], row[1], row[2], row[3]);
        }
        text += "]\n";
        for p in &self.pores {
            let [x, y, z] = p.center_mm;
            text += &format!(
                "\n[[pores]]\ncenter_mm = [{x}, {y}, {z}]\nradius_mm = {}\nlayer = {}\n",
                p.radius_mm, p.layer
            );
            if p.half_height_mm != p.radius_mm {
                text += &format!("half_height_mm = {}\n", p.half_height_mm);
            }
        }
        text
    }
}

/// Writes the demo's CT into `build` (`ct/box.pcr`, `.vol`, the points and the truth) when the
/// build has enough layers for it; returns it. `pores`: `(count, seed)` of
/// [`demo_ct_with_pores`] in place of the two pores of [`demo_ct`].
pub fn write_demo_ct(
    build: &Path,
    layers: u32,
    pores: Option<(u32, u64)>,
) -> Result<Option<DemoCt>, CtError> {
    let ct = match pores {
        Some((count, seed)) => demo_ct_with_pores(layers, count, seed),
        None => demo_ct(layers),
    };
    let Some(ct) = ct else {
        return Ok(None);
    };
    let dir = build.join(DEMO_CT_DIR);
    std::fs::create_dir_all(&dir).map_err(|source| CtError::Io {
        path: dir.clone(),
        action: "create",
        source,
    })?;
    crate::ct::volume::write_phoenix(&build.join(DEMO_CT), &ct.volume)?;
    for (name, text) in [
        (DEMO_CT_POINTS, ct.points()),
        (DEMO_CT_TRUTH, ct.truth_toml()),
    ] {
        let path = build.join(name);
        crate::fsutil::write_atomic(&path, text.as_bytes(), false).map_err(|e| CtError::Io {
            path: e.path,
            action: "write",
            source: e.source,
        })?;
    }
    Ok(Some(ct))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_points_parse_and_land_near_the_truth() {
        let text = demo_points(320, 214);
        let points =
            crate::calibrate::parse_points(&text, std::path::Path::new("demo-points.txt")).unwrap();
        assert_eq!(points.len(), 4);
        let truth = Homography::oblique_view(320, 214);
        for p in points {
            let (x, y) = truth.apply(p.image.u, p.image.v).unwrap();
            assert!((x - p.build.x).hypot(y - p.build.y) < 2.0);
        }
    }

    #[test]
    fn the_demo_ct_has_its_pores_in_known_layers_and_clicks_near_the_truth() {
        assert!(demo_ct(DEMO_CT_MIN_LAYERS - 1).is_none());
        let ct = demo_ct(20).expect("20 layers hold the CT");
        let layers: Vec<u32> = ct.pores.iter().map(|p| p.layer).collect();
        assert_eq!(layers, [10, 11]);
        assert_eq!(ct.volume.voxel_mm, [0.05; 3]);
        // The clicks start a registration within 0.2 mm of the truth over the box.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("points.txt");
        std::fs::write(&path, ct.points()).unwrap();
        let pairs = crate::ct::read_points_file(&path).unwrap();
        assert_eq!(pairs.len(), 4);
        let start = crate::ct::horn(&pairs).unwrap();
        let inverse = ct.build_from_ct.inverse();
        for corner in [[40.0, 44.0, 0.0], [60.0, 56.0, 0.6]] {
            let b = start.apply(inverse.apply(corner));
            let miss = (0..3)
                .map(|a| (b[a] - corner[a]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(miss < 0.2, "{corner:?}: {miss} mm");
        }
        // The pore centres are void in the CT, the box's material around them is not.
        let index = crate::ct::resample::index_from_ct(&ct.volume).unwrap();
        let value = |p: [f64; 3]| {
            let [i, j, k] = index.apply(inverse.apply(p)).map(|v| v.round() as usize);
            let [nx, ny, _] = ct.volume.dims;
            ct.volume.value(i + nx * (j + ny * k))
        };
        for pore in &ct.pores {
            let c = pore.center_mm;
            assert!(value(c) < 12000.0, "pore at {c:?}: {}", value(c));
            assert!(value([c[0] + 1.0, c[1], c[2]]) > 28000.0);
        }
    }

    #[test]
    fn pores_spread_over_the_layers_and_the_box_are_void_in_the_ct_and_cut_into_spots() {
        assert!(demo_ct_with_pores(DEMO_CT_MIN_LAYERS - 1, 3, 1).is_none());
        assert!(
            lack_of_fusion_pores(20, 400, 1).is_none(),
            "400 pores do not fit apart"
        );
        let pores = lack_of_fusion_pores(40, 8, 5).unwrap();
        assert_eq!(pores, lack_of_fusion_pores(40, 8, 5).unwrap());
        assert_ne!(pores, lack_of_fusion_pores(40, 8, 6).unwrap());
        let mut layers: Vec<u32> = pores.iter().map(|p| p.layer).collect();
        layers.dedup();
        assert!(
            layers.len() >= 6 && layers.windows(2).all(|w| w[0] < w[1]),
            "{layers:?}"
        );
        assert!(
            layers[0] <= 14 && layers[layers.len() - 1] >= 27,
            "{layers:?}"
        );
        let xs: Vec<f64> = pores.iter().map(|p| p.center_mm[0]).collect();
        let spread = xs.iter().cloned().fold(f64::MIN, f64::max)
            - xs.iter().cloned().fold(f64::MAX, f64::min);
        assert!(spread > 6.0, "{xs:?}");
        for p in &pores {
            let [x, y, _] = p.center_mm;
            assert!(
                (42.0..=58.0).contains(&x) && (46.0..=54.0).contains(&y),
                "{p:?}"
            );
        }

        let ct = demo_ct_with_pores(30, 4, 2).unwrap();
        assert_eq!(ct.volume.voxel_mm, [0.05; 3]);
        assert!(ct.truth_toml().contains("half_height_mm = 0.075"));
        let index = crate::ct::resample::index_from_ct(&ct.volume).unwrap();
        let inverse = ct.build_from_ct.inverse();
        let value = |p: [f64; 3]| {
            let [i, j, k] = index.apply(inverse.apply(p)).map(|v| v.round() as usize);
            let [nx, ny, _] = ct.volume.dims;
            ct.volume.value(i + nx * (j + ny * k))
        };
        let spots = ct.unfused_spots();
        for pore in &ct.pores {
            let c = pore.center_mm;
            assert!(value(c) < 12000.0, "pore at {c:?}: {}", value(c));
            // Flat: material 0.15 mm above and below the centre.
            assert!(value([c[0], c[1], c[2] + 0.15]) > 28000.0, "{pore:?}");
            assert!(value([c[0], c[1], c[2] - 0.15]) > 28000.0, "{pore:?}");
            // Seen in the layers it spans (a handful), widest in its own.
            let seen: Vec<&UnfusedSpot> = spots
                .iter()
                .filter(|s| s.center_mm == [c[0], c[1]])
                .collect();
            assert!((5..=7).contains(&seen.len()), "{seen:?}");
            let widest = seen
                .iter()
                .max_by(|a, b| a.radius_mm.total_cmp(&b.radius_mm))
                .unwrap();
            assert_eq!(widest.layer, pore.layer);
            assert_eq!(widest.radius_mm, pore.radius_mm);
        }
    }
}
