//! `layerwise flaws` end to end, as a user runs it: synthetic CTs of a part with known spherical
//! pores (radius 2 to 5 voxels), a pore-free control and an open pit at the surface, as a GE
//! phoenix raw volume (.vol + .pcr) and as a DICOM series, registered by a ct.toml holding the
//! true transform; then a demo build with a CT of one of its parts, where the patches must sit on
//! the pores in every view of their layers and the controls must hold none.

#![allow(clippy::needless_range_loop)]

use crate::common;
use crate::common::{layerwise, Run};
use layerwise::ct::{synth, CtRegistration, CtSource};
use layerwise::geometry::Rigid3;
use std::path::{Path, PathBuf};

const VOID: f64 = 1000.0;
const MATERIAL: f64 = 20000.0;

/// A part in build mm: a union of boxes (lo, hi) minus spherical voids (pores, or pits cut into
/// its faces).
struct Scene {
    boxes: Vec<([f64; 3], [f64; 3])>,
    voids: Vec<([f64; 3], f64)>,
}

impl Scene {
    fn sdf(&self, q: [f64; 3]) -> f64 {
        let mut d = f64::INFINITY;
        for (lo, hi) in &self.boxes {
            let mut out = 0.0f64;
            let mut inside = f64::NEG_INFINITY;
            for a in 0..3 {
                let c = 0.5 * (lo[a] + hi[a]);
                let e = (q[a] - c).abs() - 0.5 * (hi[a] - lo[a]);
                out += e.max(0.0).powi(2);
                inside = inside.max(e);
            }
            d = d.min(out.sqrt() + inside.min(0.0));
        }
        for (c, r) in &self.voids {
            let dist =
                ((q[0] - c[0]).powi(2) + (q[1] - c[1]).powi(2) + (q[2] - c[2]).powi(2)).sqrt();
            d = d.max(r - dist);
        }
        d
    }

    /// The boxes' bounds.
    fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let lo = std::array::from_fn(|a| {
            self.boxes
                .iter()
                .map(|b| b.0[a])
                .fold(f64::INFINITY, f64::min)
        });
        let hi = std::array::from_fn(|a| {
            self.boxes
                .iter()
                .map(|b| b.1[a])
                .fold(f64::NEG_INFINITY, f64::max)
        });
        (lo, hi)
    }
}

/// A CT of a scene: voxel index → CT physical mm (`patient`), CT mm → build mm (`truth`).
struct Scan {
    dims: [usize; 3],
    voxel: f64,
    data: Vec<u16>,
    /// Patient position of voxel (0, 0, 0) and the sign of the row axis (DICOM rows go −y).
    origin: [f64; 3],
    y_sign: f64,
    truth: Rigid3,
}

fn rotation(axis: [f64; 3], deg: f64) -> [[f64; 3]; 3] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let (x, y, z) = (axis[0] / n, axis[1] / n, axis[2] / n);
    let (s, c) = deg.to_radians().sin_cos();
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

/// Renders `scene` at `voxel` mm, the part rotated by `rot` (CT → build), centred in the volume
/// with `margin` mm around it: partial volume from 4³ samples near the surface, the scanner's
/// blur (σ 0.6 voxel) and noise (±4 % of the contrast).
fn scan(
    scene: &Scene,
    voxel: f64,
    rot: [[f64; 3]; 3],
    margin: f64,
    dicom: bool,
    seed: u64,
) -> Scan {
    let (lo, hi) = scene.bounds();
    let center: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]));
    let half: [f64; 3] = std::array::from_fn(|a| 0.5 * (hi[a] - lo[a]));
    // Half extent of the rotated box along each CT axis: Σ |Rᵀ| · half.
    let dims: [usize; 3] = std::array::from_fn(|j| {
        let e: f64 = (0..3).map(|i| rot[i][j].abs() * half[i]).sum();
        (2.0 * (e + margin) / voxel).ceil() as usize + 1
    });
    let (origin, y_sign) = if dicom {
        ([-3.25, 4.5, 100.0], -1.0)
    } else {
        ([0.0; 3], 1.0)
    };
    let patient = |p: [f64; 3]| {
        [
            origin[0] + p[0] * voxel,
            origin[1] + y_sign * p[1] * voxel,
            origin[2] + p[2] * voxel,
        ]
    };
    let mid = patient(std::array::from_fn(|a| (dims[a] - 1) as f64 / 2.0));
    let t: [f64; 3] =
        std::array::from_fn(|i| center[i] - (0..3).map(|j| rot[i][j] * mid[j]).sum::<f64>());
    let truth = Rigid3::from_rotation_translation(rot, t);
    let to_build = |p: [f64; 3]| truth.apply(patient(p));
    let [nx, ny, nz] = dims;
    let mut cover = vec![0f32; nx * ny * nz];
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let p = [i as f64, j as f64, k as f64];
                let d = scene.sdf(to_build(p));
                cover[i + nx * (j + ny * k)] = if d.abs() > voxel {
                    f32::from(d < 0.0)
                } else {
                    let mut n = 0;
                    for s in 0..64 {
                        let o = [s & 3, (s >> 2) & 3, s >> 4].map(|v| (v as f64 + 0.5) / 4.0 - 0.5);
                        if scene.sdf(to_build([p[0] + o[0], p[1] + o[1], p[2] + o[2]])) < 0.0 {
                            n += 1;
                        }
                    }
                    n as f32 / 64.0
                };
            }
        }
    }
    let blurred = synth::gaussian_blur(cover, dims, 0.6);
    let data = blurred
        .iter()
        .enumerate()
        .map(|(i, &c)| {
            let noise = 0.04 * (MATERIAL - VOID) * synth::uniform(seed, i as u64);
            (VOID + c as f64 * (MATERIAL - VOID) + noise).round() as u16
        })
        .collect();
    Scan {
        dims,
        voxel,
        data,
        origin,
        y_sign,
        truth,
    }
}

/// ct.toml with the true transform, naming the CT.
fn write_ct_toml(path: &Path, scan: &Scan, source: Option<CtSource>) {
    let reg = CtRegistration::given(scan.truth, 0.5 * (VOID + MATERIAL));
    std::fs::write(path, reg.to_toml_string_with(source)).unwrap();
}

/// The scan as a GE phoenix volume; returns the .pcr.
fn write_phoenix(dir: &Path, scan: &Scan) -> PathBuf {
    let bytes: Vec<u8> = scan.data.iter().flat_map(|v| v.to_le_bytes()).collect();
    std::fs::write(dir.join("scan.vol"), bytes).unwrap();
    let [x, y, z] = scan.dims;
    let pcr = dir.join("scan.pcr");
    std::fs::write(
        &pcr,
        format!(
            "[VolumeData]\nVolume_SizeX={x}\nVolume_SizeY={y}\nVolume_SizeZ={z}\nVoxelSizeRec={}\nFormat=5\n",
            scan.voxel
        ),
    )
    .unwrap();
    pcr
}

/// The scan as a DICOM CT series (rows along −y: ImageOrientationPatient 1\0\0\0\-1\0).
fn write_dicom(dir: &Path, scan: &Scan) {
    use layerwise::dicom::{self, Compression, Plane, Series, Slice, Study};
    assert_eq!(scan.y_sign, -1.0);
    let uid = dicom::new_uid();
    let study = Study {
        frame_of_reference_uid: dicom::derived_uid(&uid, "frame"),
        study_instance_uid: uid,
        date: "20261201".into(),
        time: "120000".into(),
        patient_name: "flaws^".into(),
        patient_id: "ct".into(),
        study_id: "1".into(),
        description: "synthetic CT".into(),
    };
    let series = Series::named(&study, 1, "ct");
    let [nx, ny, nz] = scan.dims;
    for k in 0..nz {
        let slice = Slice {
            layer: k as u32 + 1,
            plane: Plane {
                origin: [
                    scan.origin[0],
                    scan.origin[1],
                    scan.origin[2] + k as f64 * scan.voxel,
                ],
                pixel_mm: scan.voxel,
                rows: ny,
                columns: nx,
                thickness_mm: scan.voxel,
            },
            pixels: (&scan.data[k * nx * ny..(k + 1) * nx * ny]).into(),
            acquired: None,
            window: (10000.0, 20000.0),
            derivation: "synthetic",
        };
        dicom::write_slice(
            &dir.join(format!("S{k:04}.dcm")),
            &study,
            &series,
            &slice,
            Compression::None,
        )
        .unwrap();
    }
}

/// The part of the first tests: 4 x 3 x 2 mm, pores of radius 2, 3, 4 and 5 voxels (50 µm) and
/// a pit of radius 0.2 mm open at the +y face.
fn part(pores: bool) -> (Scene, Vec<([f64; 3], f64)>) {
    let truth = if pores {
        vec![
            ([10.93, 21.02, 0.61], 0.10),
            ([12.47, 21.88, 1.33], 0.15),
            ([13.12, 20.71, 0.97], 0.20),
            ([11.61, 22.27, 1.38], 0.25),
        ]
    } else {
        Vec::new()
    };
    let mut voids = truth.clone();
    voids.push(([12.0, 23.0, 1.0], 0.2));
    (
        Scene {
            boxes: vec![([10.0, 20.0, 0.0], [14.0, 23.0, 2.0])],
            voids,
        },
        truth,
    )
}

/// `layerwise flaws --registration REGISTRATION --out OUT`, more arguments to add.
fn flaws_command(registration: &Path, out: &Path) -> std::process::Command {
    let mut command = layerwise();
    command
        .arg("flaws")
        .arg("--registration")
        .arg(registration)
        .arg("--out")
        .arg(out);
    command
}

fn flaws_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("flaws.json")).unwrap()).unwrap()
}

fn vec3(v: &serde_json::Value) -> [f64; 3] {
    std::array::from_fn(|a| v[a].as_f64().unwrap())
}

/// Every pore found once, within a voxel in build mm and 20 % in volume; nothing else.
fn check_pores(table: &serde_json::Value, truth: &[([f64; 3], f64)], voxel: f64, thickness: f64) {
    let flaws = table["flaws"].as_array().unwrap();
    assert_eq!(flaws.len(), truth.len(), "{table:#}");
    for (c, r) in truth {
        let f = flaws
            .iter()
            .min_by(|a, b| {
                let d = |f: &serde_json::Value| {
                    let p = vec3(&f["centroid_mm"]);
                    (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>()
                };
                d(a).total_cmp(&d(b))
            })
            .unwrap();
        let p = vec3(&f["centroid_mm"]);
        let err = (0..3).map(|a| (p[a] - c[a]).powi(2)).sum::<f64>().sqrt();
        let v = f["volume_mm3"].as_f64().unwrap();
        let v_true = 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
        println!(
            "pore r = {:.0} voxels: centroid error {:.1} µm, volume {v:.5} mm³ vs {v_true:.5} ({:+.1} %), {}, elongation {:.2}",
            r / voxel,
            err * 1e3,
            100.0 * (v / v_true - 1.0),
            f["kind"],
            f["elongation"].as_f64().unwrap()
        );
        assert!(
            err <= voxel,
            "pore at {c:?}: centroid {p:?} is {err} mm off"
        );
        assert!(
            (v / v_true - 1.0).abs() <= 0.2,
            "pore at {c:?}: volume {v} vs {v_true}"
        );
        assert_eq!(f["kind"], "gas_pore", "{f:#}");
        // Layers: the pore's z range (thickness per layer, layer k on top at k · thickness).
        let first = ((c[2] - r) / thickness).ceil() as u64;
        let last = ((c[2] + r) / thickness).ceil() as u64;
        let (a, b) = (
            f["first_layer"].as_u64().unwrap(),
            f["last_layer"].as_u64().unwrap(),
        );
        assert!(
            a >= first && b <= last && a <= b && b - a + 2 >= last - first,
            "pore at {c:?}: layers {a}-{b}, its extent {first}-{last}"
        );
        assert_eq!(f["sections"].as_array().unwrap().len() as u64, b - a + 1);
    }
}

/// The label of the voxel of flaws.nrrd nearest to `p` (build mm).
fn nrrd_label(path: &Path, p: [f64; 3]) -> u16 {
    use std::io::Read;
    let bytes = std::fs::read(path).unwrap();
    let end = bytes.windows(2).position(|w| w == b"\n\n").unwrap();
    let header = String::from_utf8_lossy(&bytes[..end]).to_string();
    assert!(
        header.contains("encoding: gzip") && header.contains("type: uint16"),
        "{header}"
    );
    let field = |key: &str| -> Vec<f64> {
        let line = header.lines().find(|l| l.starts_with(key)).unwrap();
        line[key.len()..]
            .split(|c: char| !(c.is_ascii_digit() || c == '.' || c == '-' || c == 'e'))
            .filter(|s| !s.is_empty())
            .map(|s| s.parse().unwrap())
            .collect()
    };
    let sizes = field("sizes:");
    let origin = field("space origin:");
    let step = field("space directions:")[0];
    let mut data = Vec::new();
    flate2::read::GzDecoder::new(&bytes[end + 2..])
        .read_to_end(&mut data)
        .unwrap();
    let idx: Vec<usize> = (0..3)
        .map(|a| ((p[a] - origin[a]) / step).round() as usize)
        .collect();
    let i = idx[0] + sizes[0] as usize * (idx[1] + sizes[1] as usize * idx[2]);
    u16::from_le_bytes([data[2 * i], data[2 * i + 1]])
}

#[test]
fn pores_in_a_raw_ct_are_found_and_measured_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let voxel = 0.05;
    let rot = rotation([1.0, 2.0, 3.0], 20.0);
    for pores in [true, false] {
        let (scene, truth) = part(pores);
        let scan = scan(&scene, voxel, rot, 0.4, false, 3);
        let ct_dir = dir.path().join(if pores { "pores" } else { "clean" });
        std::fs::create_dir_all(&ct_dir).unwrap();
        let pcr = write_phoenix(&ct_dir, &scan);
        let ct_toml = ct_dir.join("ct.toml");
        let source = CtSource {
            path: pcr.display().to_string(),
            voxel_mm: None,
            size: None,
            dtype: None,
        };
        write_ct_toml(&ct_toml, &scan, Some(source));
        let out = ct_dir.join("out");
        // The CT comes from ct.toml's record of it.
        let text = flaws_command(&ct_toml, &out)
            .args(["--layer-thickness-mm", "0.1"])
            .stdout_ok();
        println!("{text}");
        let table = flaws_json(&out);
        check_pores(&table, &truth, voxel, 0.1);
        assert!(
            table["rejected_surface"].as_u64().is_some(),
            "the table says what it left out"
        );
        if !pores {
            assert!(text.contains("0 flaws"), "{text}");
            assert!(!out.join("flaws.nrrd").exists());
            continue;
        }
        // The label volume: the voxel at each pore holds its id.
        let flaws = table["flaws"].as_array().unwrap();
        for f in flaws {
            let id = f["id"].as_u64().unwrap() as u16;
            assert_eq!(
                nrrd_label(&out.join("flaws.nrrd"), vec3(&f["centroid_mm"])),
                id
            );
        }
        // Ids in order of z, and the CSV agrees with the JSON.
        let zs: Vec<f64> = flaws.iter().map(|f| vec3(&f["centroid_mm"])[2]).collect();
        assert!(zs.windows(2).all(|w| w[0] <= w[1]), "{zs:?}");
        let csv = std::fs::read_to_string(out.join("flaws.csv")).unwrap();
        assert_eq!(csv.lines().count(), flaws.len() + 1, "{csv}");
        assert!(csv.starts_with("id,kind,part,x_mm,y_mm,z_mm"), "{csv}");
        // Deterministic: the same inputs (here given as --ct) give the same table.
        let again = ct_dir.join("again");
        flaws_command(&ct_toml, &again)
            .args(["--layer-thickness-mm", "0.1", "--ct"])
            .arg(&pcr)
            .succeeds();
        assert_eq!(
            csv,
            std::fs::read_to_string(again.join("flaws.csv")).unwrap()
        );
    }
}

#[test]
fn pores_in_a_dicom_ct_are_found_and_measured() {
    let dir = tempfile::tempdir().unwrap();
    let voxel = 0.05;
    let (scene, truth) = part(true);
    let scan = scan(
        &scene,
        voxel,
        rotation([-0.4, 0.9, 0.2], 35.0),
        0.4,
        true,
        5,
    );
    let series = dir.path().join("series");
    write_dicom(&series, &scan);
    let ct_toml = dir.path().join("ct.toml");
    write_ct_toml(&ct_toml, &scan, None);
    let out = dir.path().join("out");
    let text = flaws_command(&ct_toml, &out)
        .args(["--layer-thickness-mm", "0.1", "--part", "3", "--ct"])
        .arg(&series)
        .stdout_ok();
    println!("{text}");
    let table = flaws_json(&out);
    check_pores(&table, &truth, voxel, 0.1);
    assert!(table["flaws"]
        .as_array()
        .unwrap()
        .iter()
        .all(|f| f["part"] == 3));
}

#[test]
fn a_wrong_or_missing_registration_is_refused_with_its_name() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("nowhere.toml");
    let out = dir.path().join("out");
    let err = flaws_command(&missing, &out).fails();
    assert!(
        err.contains("nowhere.toml") && err.contains("register ct"),
        "{err}"
    );
    assert_eq!(err.lines().count(), 1, "one line: {err}");
    let wrong = dir.path().join("calibration.toml");
    std::fs::write(&wrong, "homography = [[1.0, 0.0, 0.0]]\n").unwrap();
    let err = flaws_command(&wrong, &out).fails();
    assert!(
        err.contains("calibration.toml")
            && err.contains("register ct")
            && err.contains("transform"),
        "{err}"
    );
    // A registration without a recorded CT needs --ct.
    let (scene, _) = part(false);
    let small = scan(&scene, 0.2, rotation([0.0, 0.0, 1.0], 0.0), 0.4, false, 1);
    let bare = dir.path().join("ct.toml");
    write_ct_toml(&bare, &small, None);
    let err = flaws_command(&bare, &out).fails();
    assert!(
        err.contains("records no CT") && err.contains("--ct"),
        "{err}"
    );
}

/// A demo build (20 layers of 0.1 mm, 320 x 214 mock frames, six views) and a CT of its
/// 20 x 12 mm block with two pores in known layers: patches of every view of each pore's layers
/// centred on the pore through the grid's contract, controls in the part without a pore.
#[test]
fn patches_of_a_build_sit_on_the_pores_and_controls_hold_none() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = common::calibrated_config(&build, 20, layerwise::dicom::Compression::None);
    config.build.layer_thickness_mm = 0.1;
    let config_path = dir.path().join("config.toml");
    common::write_config(&config, &config_path);
    common::run_build(&config_path);

    let pores = vec![([45.3, 48.1, 0.75], 0.3), ([54.6, 52.4, 1.35], 0.2)];
    let scene = Scene {
        boxes: vec![([40.0, 44.0, 0.0], [60.0, 56.0, 2.0])],
        voids: pores.clone(),
    };
    let scan = scan(&scene, 0.1, rotation([0.1, 0.2, 1.0], 8.0), 0.4, false, 9);
    let pcr = write_phoenix(dir.path(), &scan);
    let ct_toml = dir.path().join("ct.toml");
    write_ct_toml(&ct_toml, &scan, None);
    let out = dir.path().join("labelled");
    let cut = |patch_px: &str, out: &Path| {
        let mut command = flaws_command(&ct_toml, out);
        command
            .args(["--patch-px", patch_px, "--ct"])
            .arg(&pcr)
            .arg("--build")
            .arg(&build);
        command
    };
    let text = cut("9", &out).stdout_ok();
    println!("{text}");
    let table = flaws_json(&out);
    check_pores(&table, &pores, 0.1, 0.1);
    let flaws = table["flaws"].as_array().unwrap();
    let truth_of = |id: u64| {
        let f = flaws.iter().find(|f| f["id"] == id).unwrap();
        let p = vec3(&f["centroid_mm"]);
        *pores
            .iter()
            .min_by(|a, b| {
                let d = |c: &[f64; 3]| (c[0] - p[0]).powi(2) + (c[1] - p[1]).powi(2);
                d(&a.0).total_cmp(&d(&b.0))
            })
            .unwrap()
    };

    let labels: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("labels.json")).unwrap()).unwrap();
    let images = labels["images"].as_array().unwrap();
    let annotations = labels["annotations"].as_array().unwrap();
    let sections: usize = flaws
        .iter()
        .map(|f| f["sections"].as_array().unwrap().len())
        .sum();
    let of_kind = |k: &str| images.iter().filter(|i| i["kind"] == k).count();
    assert_eq!(of_kind("flaw"), 6 * sections, "every view of every layer");
    assert_eq!(of_kind("control"), 6 * sections, "one control per patch");
    let pixel = common::plate_grid().pixel_mm;
    for image in images {
        let g = &image["grid"];
        let (x_min, y_max) = (g["x_min"].as_f64().unwrap(), g["y_max"].as_f64().unwrap());
        let (w, h) = (
            image["width"].as_u64().unwrap(),
            image["height"].as_u64().unwrap(),
        );
        assert_eq!((w, h), (9, 9));
        // docs/frames.md: pixel (r, c) is centred at x_min + (c + ½)·p, y_max − (r + ½)·p.
        let centre = [x_min + 4.5 * pixel, y_max - 4.5 * pixel];
        let png = image::open(out.join(image["file_name"].as_str().unwrap())).unwrap();
        assert_eq!(png.color(), image::ColorType::L16);
        assert_eq!((png.width(), png.height()), (9, 9));
        let layer = image["layer"].as_u64().unwrap();
        let (c, r) = truth_of(image["flaw_id"].as_u64().unwrap());
        let mine: Vec<_> = annotations
            .iter()
            .filter(|a| a["image_id"] == image["id"])
            .collect();
        if image["kind"] == "flaw" {
            for a in 0..2 {
                assert!(
                    (centre[a] - c[a]).abs() <= pixel / 2.0 + 0.1,
                    "{image:#}: centre {centre:?}, pore {c:?}"
                );
            }
            // The pore's layers (top at 0.1 mm · layer) hold its section.
            let z_top = layer as f64 * 0.1;
            assert!(
                z_top > c[2] - r - 0.1 && z_top - 0.1 < c[2] + r + 0.1,
                "{image:#}"
            );
            assert_eq!(mine.len(), 1, "{image:#}");
            let b: Vec<f64> = (0..4)
                .map(|k| mine[0]["bbox"][k].as_f64().unwrap())
                .collect();
            // The section's box reaches into the centre pixel (columns and rows 4 to 5).
            assert!(
                b[0] < 5.0 && b[0] + b[2] > 4.0 && b[1] < 5.0 && b[1] + b[3] > 4.0,
                "{:#}",
                mine[0]
            );
        } else {
            assert!(mine.is_empty(), "{image:#}");
            let (x_max, y_min) = (x_min + 9.0 * pixel, y_max - 9.0 * pixel);
            for (p, r) in &pores {
                let clear =
                    p[0] + r < x_min || p[0] - r > x_max || p[1] + r < y_min || p[1] - r > y_max;
                assert!(clear, "control {image:#} holds the pore at {p:?}");
            }
            assert!(
                (40.0..60.0).contains(&centre[0]) && (44.0..56.0).contains(&centre[1]),
                "control {centre:?} outside the part"
            );
        }
    }
    let csv = std::fs::read_to_string(out.join("labels.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 12 * sections, "{csv}");
    let sheet = image::open(out.join("contact_sheet.png")).unwrap();
    assert!(sheet.height() as usize >= sections * 9 && sheet.width() >= 7 * 9);

    // The tutorial's picture (docs/tutorial.md):
    // `LAYERWISE_FLAWS_SHEET=docs/flaws_contact_sheet.png cargo test …` keeps a contact sheet of
    // wider patches.
    if let Some(picture) = std::env::var_os("LAYERWISE_FLAWS_SHEET") {
        let wide = dir.path().join("wide");
        cut("41", &wide).succeeds();
        std::fs::copy(wide.join("contact_sheet.png"), picture).unwrap();
    }

    // locate --flaw: the flaw's centroid in every modality and its patches as one sheet.
    let mark = dir.path().join("flaw1.png");
    let loc = layerwise()
        .args([
            "locate",
            "--json",
            "--flaw",
            "1",
            "--patch-px",
            "9",
            "--flaws",
        ])
        .arg(&out)
        .arg("--build")
        .arg(&build)
        .arg("--mark")
        .arg(&mark)
        .json_ok();
    let f1 = &flaws[0];
    assert_eq!(vec3(&loc["build_mm"]), vec3(&f1["centroid_mm"]));
    let layer = loc["layer"].as_u64().unwrap();
    assert!(
        (f1["first_layer"].as_u64().unwrap()..=f1["last_layer"].as_u64().unwrap()).contains(&layer)
    );
    let sheet = image::open(&mark).unwrap();
    assert_eq!(
        sheet.height() as usize,
        f1["sections"].as_array().unwrap().len()
            * (9 * 14 + layerwise::raster::sheet::LABEL_PX as usize + 4)
            + 4
    );
    let err = layerwise()
        .args(["locate", "--flaw", "99", "--flaws"])
        .arg(&out)
        .arg("--build")
        .arg(&build)
        .fails();
    assert!(
        err.contains("no flaw 99") && err.contains("ids 1 to 2"),
        "{err}"
    );
}

/// The block of the first tests as laser vectors: 20 layers of 0.1 mm, one rectangle of part 1.
fn block_vectors(path: &Path) {
    use layerwise::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};
    let mut file = VectorFile {
        header: Header::new(Format::Ascii, 0.001),
        layers: Vec::new(),
    };
    for k in 0..20 {
        let mut layer = Layer::new(k, 0.1 * (k + 1) as f64);
        layer.polylines.push(Polyline {
            part: 1,
            direction: Direction::CounterClockwise,
            points: vec![
                [10.0, 20.0],
                [14.0, 20.0],
                [14.0, 23.0],
                [10.0, 23.0],
                [10.0, 20.0],
            ],
        });
        file.layers.push(layer);
    }
    let mut out = std::fs::File::create(path).unwrap();
    layerwise::vectors::write_ascii(&file, &mut out).unwrap();
}

/// A CT that kept a slab of the plate under the part, with a void in it: an internal void of the
/// CT, but not a flaw of the part; the vectors' signed distance leaves it out.
#[test]
fn a_void_in_the_plate_slab_is_no_flaw_of_the_part() {
    let dir = tempfile::tempdir().unwrap();
    let (mut scene, truth) = part(true);
    scene.boxes.push(([9.5, 19.5, -0.6], [14.5, 23.5, 0.0]));
    scene.voids.push(([12.0, 21.5, -0.3], 0.12));
    let scan = scan(
        &scene,
        0.05,
        rotation([1.0, -1.0, 2.0], 10.0),
        0.3,
        false,
        11,
    );
    let pcr = write_phoenix(dir.path(), &scan);
    let ct_toml = dir.path().join("ct.toml");
    write_ct_toml(&ct_toml, &scan, None);
    let out = dir.path().join("all");
    flaws_command(&ct_toml, &out)
        .arg("--ct")
        .arg(&pcr)
        .succeeds();
    assert_eq!(
        flaws_json(&out)["flaws"].as_array().unwrap().len(),
        truth.len() + 1,
        "without the vectors the slab's void is a void of the CT"
    );
    let cli = dir.path().join("block.cli");
    block_vectors(&cli);
    let out = dir.path().join("part");
    let text = flaws_command(&ct_toml, &out)
        .args(["--layer-thickness-mm", "0.1", "--part", "1", "--ct"])
        .arg(&pcr)
        .arg("--vectors")
        .arg(&cli)
        .stdout_ok();
    let table = flaws_json(&out);
    assert_eq!(table["rejected_outside_part"], 1, "{text}");
    check_pores(&table, &truth, 0.05, 0.1);
}
