//! `layerwise register ct` end to end, as a user runs it: a CLI vector file of a part, a synthetic
//! GE phoenix CT (.vol + .pcr) of that part placed with a known rotation and translation (partial
//! volume, noise, the bottom slab lost), three clicked point pairs off by 0.2 mm.

use crate::common;
use crate::common::layerwise;
use layerwise::vectors::{Direction, Format, Header, Layer, Polyline, VectorFile};
use std::f64::consts::PI;

const LAYERS: usize = 50;
const DZ: f64 = 0.06;

/// A cylinder r = 4 mm at (20, 30) and a separate 1.5 x 6 mm fin at x 26..27.5: the fin breaks the
/// cylinder's symmetry without overlapping its contour.
fn inside_part(p: [f64; 3]) -> bool {
    if p[2] <= 0.0 || p[2] > LAYERS as f64 * DZ {
        return false;
    }
    let cyl = (p[0] - 20.0).powi(2) + (p[1] - 30.0).powi(2) <= 16.0;
    let fin = (26.0..=27.5).contains(&p[0]) && (27.0..=33.0).contains(&p[1]);
    cyl || fin
}

fn vectors(path: &std::path::Path) {
    let mut file = VectorFile {
        header: Header::new(Format::Ascii, 0.001),
        layers: Vec::new(),
    };
    file.header.labels.push((1, "cylinder with fin".into()));
    for k in 0..LAYERS {
        let mut layer = Layer::new(k, DZ * (k + 1) as f64);
        let circle: Vec<[f64; 2]> = (0..=256)
            .map(|i| 2.0 * PI * i as f64 / 256.0)
            .map(|a| [20.0 + 4.0 * a.cos(), 30.0 + 4.0 * a.sin()])
            .collect();
        layer.polylines.push(Polyline {
            part: 1,
            direction: Direction::CounterClockwise,
            points: circle,
        });
        let fin = vec![
            [26.0, 27.0],
            [27.5, 27.0],
            [27.5, 33.0],
            [26.0, 33.0],
            [26.0, 27.0],
        ];
        layer.polylines.push(Polyline {
            part: 1,
            direction: Direction::CounterClockwise,
            points: fin,
        });
        file.layers.push(layer);
    }
    let mut out = std::fs::File::create(path).unwrap();
    layerwise::vectors::write_ascii(&file, &mut out).unwrap();
}

/// CT → build: 25° about (1, 2, 3)/|..|, then a translation.
fn truth() -> [[f64; 4]; 4] {
    let axis = [1.0, 2.0, 3.0f64];
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let (x, y, z) = (axis[0] / n, axis[1] / n, axis[2] / n);
    let (s, c) = (25f64.to_radians().sin(), 25f64.to_radians().cos());
    let t = 1.0 - c;
    let r = [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ];
    // The CT grid's center (8, 8, 8) mm lands on the part's center (22, 30, 1.5).
    let center = [8.0, 8.0, 8.0];
    let target = [22.0, 30.0, 1.5];
    let mut m = [[0.0; 4]; 4];
    for i in 0..3 {
        m[i][..3].copy_from_slice(&r[i]);
        m[i][3] = target[i] - (0..3).map(|j| r[i][j] * center[j]).sum::<f64>();
    }
    m[3][3] = 1.0;
    m
}

fn apply(m: &[[f64; 4]; 4], p: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * p[0] + m[i][1] * p[1] + m[i][2] * p[2] + m[i][3])
}

#[test]
fn registers_a_synthetic_ct_to_the_vectors() {
    let dir = tempfile::tempdir().unwrap();
    let cli = dir.path().join("part.cli");
    vectors(&cli);
    let (n, voxel) = (160usize, 0.1);
    let t = truth();
    // Partial volume from 2x2x2 samples, noise, and the bottom 0.2 mm lost when cut off the plate.
    let mut data = vec![0u16; n * n * n];
    let mut seed = 0x1234_5678_9abc_def0u64;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let mut hits = 0;
                for s in 0..8 {
                    let o = [(s & 1) as f64, ((s >> 1) & 1) as f64, ((s >> 2) & 1) as f64]
                        .map(|v| (v - 0.5) * 0.5);
                    let q = apply(
                        &t,
                        [
                            (i as f64 + o[0]) * voxel,
                            (j as f64 + o[1]) * voxel,
                            (k as f64 + o[2]) * voxel,
                        ],
                    );
                    if q[2] > 0.2 && inside_part(q) {
                        hits += 1;
                    }
                }
                seed ^= seed << 13;
                seed ^= seed >> 7;
                seed ^= seed << 17;
                let noise = (seed % 200) as f64 - 100.0;
                data[(k * n + j) * n + i] =
                    (1000.0 + 3000.0 * hits as f64 / 8.0 + noise).max(0.0) as u16;
            }
        }
    }
    let vol = dir.path().join("scan.vol");
    std::fs::write(
        &vol,
        data.iter()
            .flat_map(|v| v.to_le_bytes())
            .collect::<Vec<u8>>(),
    )
    .unwrap();
    std::fs::write(
        dir.path().join("scan.pcr"),
        format!("[VolumeData]\nVolume_SizeX={n}\nVolume_SizeY={n}\nVolume_SizeZ={n}\nVoxelSizeRec={voxel}\nFormat=5\n"),
    )
    .unwrap();
    // Three clicks: CT points of known build landmarks, off by 0.2 mm.
    let inv = |q: [f64; 3]| {
        let d = [q[0] - t[0][3], q[1] - t[1][3], q[2] - t[2][3]];
        [0, 1, 2].map(|c| (0..3).map(|r| t[r][c] * d[r]).sum::<f64>())
    };
    let mut points = String::from("# cx cy cz bx by bz\n");
    for (b, e) in [
        ([20.0, 34.0, 2.5], 0.2),
        ([27.5, 33.0, 1.0], -0.2),
        ([16.0, 30.0, 0.5], 0.15),
    ] {
        let c = inv(b);
        points.push_str(&format!(
            "{} {} {} {} {} {}\n",
            c[0] + e,
            c[1] - e,
            c[2] + e,
            b[0],
            b[1],
            b[2]
        ));
    }
    std::fs::write(dir.path().join("points.txt"), points).unwrap();

    let out = dir.path().join("ct.toml");
    let ply = dir.path().join("surface.ply");
    let dicom = dir.path().join("ct_dicom");
    let run = layerwise()
        .args(["register", "ct", "--vectors"])
        .arg(&cli)
        .arg("--ct")
        .arg(dir.path().join("scan.pcr"))
        .arg("--init")
        .arg(dir.path().join("points.txt"))
        .arg("--out")
        .arg(&out)
        .arg("--surface-ply")
        .arg(&ply)
        .arg("--resample-dicom")
        .arg(&dicom)
        .output()
        .unwrap();
    common::assert_success(&run);
    // It says where it wrote the surface and the resampled series; the fin breaks the
    // cylinder's symmetry, so no rotation is left undetermined.
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(
        said.contains(&format!("distance to {}", ply.display()))
            && said.contains(&format!("build grid to {}", dicom.display())),
        "{said}"
    );
    assert!(!said.contains("not determined"), "{said}");
    let result: toml::Table = std::fs::read_to_string(&out).unwrap().parse().unwrap();
    assert!(!result.contains_key("free_rotation"));
    let found: Vec<Vec<f64>> = result["transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|row| {
            row.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_float().unwrap())
                .collect()
        })
        .collect();
    // Rotation error from R_found · R_trueᵀ; displacement at the part's center.
    let mut trace = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            trace += found[i][j] * t[i][j];
        }
    }
    let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
    let center = [8.0, 8.0, 8.0];
    let a = apply(&t, center);
    let b = [0, 1, 2].map(|i| {
        found[i][0] * center[0] + found[i][1] * center[1] + found[i][2] * center[2] + found[i][3]
    });
    let shift_um =
        ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt() * 1000.0;
    eprintln!("register ct: rotation error {angle:.5}°, translation error {shift_um:.3} µm");
    assert!(angle <= 0.05, "rotation error {angle}°");
    assert!(shift_um <= 5.0, "translation error {shift_um} µm");
    let mean_um = result["mean_abs_distance_um"].as_float().unwrap();
    assert!(mean_um < 30.0, "mean |distance| {mean_um} µm");
    assert!(std::fs::read_to_string(&ply).unwrap().starts_with("ply"));
    assert!(
        std::fs::read_dir(&dicom).unwrap().count() > 10,
        "the resampled CT series"
    );
    // The export puts the registered CT in the build's study, on the export grid.
    let build = dir.path().join("build");
    let demo = layerwise()
        .args(["demo", "--layers", "2", "--out"])
        .arg(&build)
        .output()
        .unwrap();
    common::assert_success(&demo);
    let exported = dir.path().join("export");
    let run = layerwise()
        .args(["export", "--build"])
        .arg(&build)
        .arg("--out")
        .arg(&exported)
        .arg("--ct")
        .arg(&out)
        .output()
        .unwrap();
    common::assert_success(&run);
    assert!(
        String::from_utf8_lossy(&run.stdout).contains("ct "),
        "{}",
        String::from_utf8_lossy(&run.stdout)
    );
    let info = layerwise()
        .args(["dicom", "info", "--json"])
        .arg(&exported)
        .output()
        .unwrap();
    let series: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let all = series.as_array().unwrap();
    let ct = all
        .iter()
        .find(|s| s["description"] == "ct")
        .expect("a ct series");
    assert_eq!(ct["slices"], 2);
    assert!(all
        .iter()
        .all(|s| s["study_instance_uid"] == ct["study_instance_uid"]
            && s["frame_of_reference_uid"] == ct["frame_of_reference_uid"]));
    assert!(
        all.iter()
            .all(|s| s["rows"] == ct["rows"] && s["first_position"][0] == ct["first_position"][0]),
        "one grid"
    );

    // NRRD too: the CT volume on the same grid as the views.
    let nrrd = dir.path().join("nrrd");
    let run = layerwise()
        .args(["export", "--format", "nrrd", "--build"])
        .arg(&build)
        .arg("--out")
        .arg(&nrrd)
        .arg("--ct")
        .arg(&out)
        .output()
        .unwrap();
    common::assert_success(&run);
    let header = |name: &str| -> String {
        let bytes = std::fs::read(nrrd.join(name)).unwrap();
        let end = bytes.windows(2).position(|w| w == b"\n\n").unwrap();
        String::from_utf8_lossy(&bytes[..end]).to_string()
    };
    let ct_header = header("ct.nrrd");
    assert!(
        ct_header.contains("sizes: 1100 1100 2")
            && ct_header.contains("type: uint16")
            && ct_header.contains("encoding: gzip"),
        "{ct_header}"
    );
    let view = header("post_top.nrrd");
    let origin = |h: &str| {
        h.lines()
            .find(|l| l.starts_with("space origin"))
            .unwrap_or("")
            .to_string()
    };
    assert_eq!(origin(&ct_header), origin(&view), "one grid");

    // locate: a CT point in the build frame and back to its voxel.
    let run = layerwise()
        .args(["locate", "--json", "--ct-point", "8,8,8", "--build"])
        .arg(&build)
        .arg("--ct")
        .arg(&out)
        .output()
        .unwrap();
    common::assert_success(&run);
    let loc: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    let b: Vec<f64> = loc["build_mm"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        (b[0] - 22.0).abs() < 0.01 && (b[1] - 30.0).abs() < 0.01 && (b[2] - 1.5).abs() < 0.01,
        "{b:?}"
    );
    let ct_voxel: Vec<f64> = loc["ct"]["voxel"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert!(
        ct_voxel.iter().all(|v| (v - 80.0).abs() < 1e-6),
        "{ct_voxel:?}"
    );
    // The demo build has 2 layers: z = 1.5 mm is above it, said so, while the CT voxel is found.
    assert_eq!(loc["layer"], serde_json::Value::Null);
    assert!(
        loc["outside"]
            .as_str()
            .unwrap_or("")
            .contains("above the last layer of the build"),
        "{loc}"
    );

    // A wrong voxel size is refused with the ratio.
    std::fs::write(
        dir.path().join("scan.pcr"),
        format!("[VolumeData]\nVolume_SizeX={n}\nVolume_SizeY={n}\nVolume_SizeZ={n}\nVoxelSizeRec={}\nFormat=5\n", voxel / 2.0),
    )
    .unwrap();
    let run = layerwise()
        .args(["register", "ct", "--vectors"])
        .arg(&cli)
        .arg("--ct")
        .arg(dir.path().join("scan.pcr"))
        .arg("--out")
        .arg(dir.path().join("bad.toml"))
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(1));
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("voxel size") && err.contains("0.5"), "{err}");
}

/// A plain cylinder (r = 4 mm, 3 mm tall) turned 30° about its axis in the CT: the registration
/// fits it, but the angle about the axis is arbitrary, and register ct says so (WARN on stderr,
/// a WARNING line in its report, a [[free_rotation]] note in ct.toml).
#[test]
fn an_axisymmetric_part_is_registered_with_a_warning_about_its_axis() {
    use layerwise::ct::phantom;
    let dir = tempfile::tempdir().unwrap();
    let mut file = VectorFile {
        header: Header::new(Format::Ascii, 0.001),
        layers: Vec::new(),
    };
    for k in 0..LAYERS {
        let mut layer = Layer::new(k, DZ * (k + 1) as f64);
        layer.polylines.push(Polyline {
            part: 1,
            direction: Direction::CounterClockwise,
            points: (0..=256)
                .map(|i| 2.0 * PI * i as f64 / 256.0)
                .map(|a| [20.0 + 4.0 * a.cos(), 30.0 + 4.0 * a.sin()])
                .collect(),
        });
        file.layers.push(layer);
    }
    let cli = dir.path().join("cylinder.cli");
    layerwise::vectors::write_ascii(&file, &mut std::fs::File::create(&cli).unwrap()).unwrap();
    let height = LAYERS as f64 * DZ;
    let sdf = |p: [f64; 3]| {
        let d = [
            (p[0] - 20.0).hypot(p[1] - 30.0) - 4.0,
            (p[2] - height / 2.0).abs() - height / 2.0,
        ];
        d[0].max(d[1]).min(0.0) + d[0].max(0.0).hypot(d[1].max(0.0))
    };
    let (s, c) = 30f64.to_radians().sin_cos();
    let rotation = nalgebra::Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
    let spec = phantom::ScanSpec {
        voxel_mm: 0.1,
        margin_mm: 0.5,
        supersample: 2,
        blur_voxels: 0.6,
        noise: 0.03,
        seed: 4,
    };
    let (volume, truth) = phantom::render(
        &sdf,
        ([16.0, 26.0, 0.0], [24.0, 34.0, height]),
        &rotation,
        &spec,
    );
    let pcr = dir.path().join("cylinder.pcr");
    layerwise::ct::volume::write_phoenix(&pcr, &volume).unwrap();
    let out = dir.path().join("ct.toml");
    let run = layerwise()
        .args(["register", "ct", "--vectors"])
        .arg(&cli)
        .arg("--ct")
        .arg(&pcr)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    common::assert_success(&run);
    let said = String::from_utf8_lossy(&run.stdout);
    assert!(
        said.contains("WARNING: the rotation about the axis") && said.contains("not determined"),
        "{said}"
    );
    let log = String::from_utf8_lossy(&run.stderr);
    assert!(
        log.contains("WARN") && log.contains("not determined"),
        "{log}"
    );
    let result: toml::Table = std::fs::read_to_string(&out).unwrap().parse().unwrap();
    let free = result["free_rotation"]
        .as_array()
        .expect("[[free_rotation]]");
    assert_eq!(free.len(), 1, "{free:?}");
    let axis: Vec<f64> = free[0]["axis"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_float().unwrap())
        .collect();
    assert!(axis[2].abs() > 0.999, "the cylinder's axis is z: {axis:?}");
    assert!(free[0]["note"].as_str().unwrap().contains("not determined"));
    // What is determined is right: the CT's axis lands on the vectors' axis, its top on the top.
    let found: Vec<Vec<f64>> = result["transform"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            r.as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_float().unwrap())
                .collect()
        })
        .collect();
    // The CT point that the truth puts on the cylinder's axis at mid-height.
    let ct_point = {
        let q = [20.0, 30.0, height / 2.0];
        let d = [q[0] - truth[0][3], q[1] - truth[1][3], q[2] - truth[2][3]];
        [0, 1, 2].map(|c| (0..3).map(|r| truth[r][c] * d[r]).sum::<f64>())
    };
    let p = [0, 1, 2].map(|i| {
        found[i][0] * ct_point[0]
            + found[i][1] * ct_point[1]
            + found[i][2] * ct_point[2]
            + found[i][3]
    });
    let miss =
        ((p[0] - 20.0).powi(2) + (p[1] - 30.0).powi(2) + (p[2] - height / 2.0).powi(2)).sqrt();
    assert!(miss < 0.03, "the axis point lands {miss} mm off");
}
