//! DICOM CT series input: geometry of any orientation, signed pixels with a rescale, and an
//! end-to-end registration whose truth includes the DICOM patient frame.

#![allow(clippy::needless_range_loop)]

use std::path::Path;

use dicom_core::value::{PrimitiveValue, C};
use dicom_core::{DataElement, VR};
use dicom_dictionary_std::tags;
use dicom_object::{FileMetaTableBuilder, InMemDicomObject};
use layerwise::ct::{self, synth, volume, CtParams, InitialTransform, VoxelData};
use nalgebra::{Matrix3, Rotation3, Unit, Vector3};

fn ds(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:.10}"))
        .map(|s| s[..s.len().min(16)].to_string())
        .collect::<Vec<_>>()
        .join("\\")
}

/// Write slice `k` of a series: pixels stored as i16 = physical − 20000 (RescaleIntercept 20000).
#[allow(clippy::too_many_arguments)]
fn write_slice(
    dir: &Path,
    name: &str,
    k: usize,
    cols: usize,
    rows: usize,
    pixels: &[i16],
    iop: [f64; 6],
    ipp: [f64; 3],
    spacing: f64,
) {
    let uid = format!("1.2.826.0.1.3680043.10.1234.{k}");
    let text = |tag, vr, value: &str| DataElement::new(tag, vr, PrimitiveValue::from(value));
    let short = |tag, value: u16| DataElement::new(tag, VR::US, PrimitiveValue::from(value));
    // A scanner's series as layerwise's readers meet it: signed pixels with a rescale, any
    // orientation. dicom-rs encodes it; the test only says what the file holds.
    let o = InMemDicomObject::from_element_iter([
        text(tags::SOP_CLASS_UID, VR::UI, "1.2.840.10008.5.1.4.1.1.2"),
        text(tags::SOP_INSTANCE_UID, VR::UI, &uid),
        text(tags::MODALITY, VR::CS, "CT"),
        text(tags::INSTANCE_NUMBER, VR::IS, &(k + 1).to_string()),
        text(tags::IMAGE_ORIENTATION_PATIENT, VR::DS, &ds(&iop)),
        text(tags::IMAGE_POSITION_PATIENT, VR::DS, &ds(&ipp)),
        text(tags::PIXEL_SPACING, VR::DS, &ds(&[spacing, spacing])),
        short(tags::SAMPLES_PER_PIXEL, 1),
        text(tags::PHOTOMETRIC_INTERPRETATION, VR::CS, "MONOCHROME2"),
        short(tags::ROWS, rows as u16),
        short(tags::COLUMNS, cols as u16),
        short(tags::BITS_ALLOCATED, 16),
        short(tags::BITS_STORED, 16),
        short(tags::HIGH_BIT, 15),
        short(tags::PIXEL_REPRESENTATION, 1),
        text(tags::RESCALE_INTERCEPT, VR::DS, "20000"),
        text(tags::RESCALE_SLOPE, VR::DS, "1"),
        DataElement::new(
            tags::PIXEL_DATA,
            VR::OW,
            PrimitiveValue::I16(C::from_vec(pixels.to_vec())),
        ),
    ]);
    let meta = FileMetaTableBuilder::new()
        .media_storage_sop_class_uid("1.2.840.10008.5.1.4.1.1.2")
        .media_storage_sop_instance_uid(uid.as_str())
        .transfer_syntax("1.2.840.10008.1.2.1");
    o.with_meta(meta)
        .expect("meta")
        .write_to_file(dir.join(name))
        .expect("write dicom");
}

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("layerwise-ct-dicom-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("dir");
    d
}

/// An oblique patient frame: rows along `r`, columns along `c`, slices along r × c.
fn oblique() -> (Matrix3<f64>, [f64; 3]) {
    let rot = Rotation3::from_axis_angle(&Unit::new_normalize(Vector3::new(-0.4, 0.9, 0.2)), 0.7);
    (*rot.matrix(), [-120.0, 35.5, 812.25])
}

/// Write a synthetic volume as a DICOM series in the oblique frame (shuffled file names).
fn write_series(dir: &Path, vol: &ct::Volume) {
    let (r, p0) = oblique();
    let [nx, ny, nz] = vol.dims;
    let h = vol.voxel_mm[0];
    let VoxelData::U16(data) = &vol.data else {
        panic!("synthetic CTs are u16")
    };
    let iop = [
        r[(0, 0)],
        r[(1, 0)],
        r[(2, 0)],
        r[(0, 1)],
        r[(1, 1)],
        r[(2, 1)],
    ];
    for k in 0..nz {
        let ipp = Vector3::from(p0) + r.column(2) * (k as f64 * h);
        let px: Vec<i16> = data[k * nx * ny..(k + 1) * nx * ny]
            .iter()
            .map(|&v| (v as i32 - 20000) as i16)
            .collect();
        // Names not in slice order: the reader sorts by position.
        let name = format!("IM{:05}.dcm", (k * 7919) % 100_000);
        write_slice(dir, &name, k, nx, ny, &px, iop, [ipp.x, ipp.y, ipp.z], h);
    }
}

#[test]
fn oblique_signed_series_geometry_and_values() {
    let dir = scratch("small");
    let (nx, ny, nz, h) = (6usize, 5usize, 4usize, 0.2);
    let data: Vec<u16> = (0..nx * ny * nz)
        .map(|i| (20000 + i * 37 - 300) as u16)
        .collect();
    let vol =
        ct::Volume::new_scaled([nx, ny, nz], [h; 3], VoxelData::U16(data.clone())).expect("vol");
    write_series(&dir, &vol);
    std::fs::write(dir.join("README.txt"), "not dicom").expect("txt");
    let back = volume::read_dicom_series(&dir, volume::MAX_VOXELS).expect("read");
    assert_eq!(back.dims, [nx, ny, nz]);
    assert!(
        matches!(back.data, VoxelData::I16(_)),
        "signed pixels stay 16-bit"
    );
    for i in [0, 17, nx * ny * nz - 1] {
        assert_eq!(back.value(i), data[i] as f64, "voxel {i}: rescaled value");
    }
    let (r, p0) = oblique();
    for idx in [
        [0.0, 0.0, 0.0],
        [5.0, 0.0, 0.0],
        [0.0, 4.0, 0.0],
        [2.0, 3.0, 3.0],
    ] {
        let p = back.index_to_physical(idx);
        let expect = Vector3::from(p0) + r * Vector3::from(idx) * h;
        assert!(
            (Vector3::from(p) - expect).norm() < 1e-6,
            "{idx:?}: {p:?} vs {expect}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn dicom_errors_name_the_file() {
    let dir = scratch("errors");
    let e = volume::read_dicom_series(&dir, volume::MAX_VOXELS).expect_err("empty folder");
    assert!(e.to_string().contains("no DICOM image"), "{e}");
    let px = vec![0i16; 4];
    let (r, _) = oblique();
    let iop = [
        r[(0, 0)],
        r[(1, 0)],
        r[(2, 0)],
        r[(0, 1)],
        r[(1, 1)],
        r[(2, 1)],
    ];
    write_slice(&dir, "a.dcm", 0, 2, 2, &px, iop, [0.0, 0.0, 0.0], 0.1);
    write_slice(&dir, "b.dcm", 1, 2, 2, &px, iop, [0.0, 0.0, 0.0], 0.1);
    let e = volume::read_dicom_series(&dir, volume::MAX_VOXELS).expect_err("same position");
    assert!(e.to_string().contains("same slice position"), "{e}");
    // A position so far out that the slices' step overflowed to infinity (found by mutation
    // fuzzing: the volume was read with an infinite slice spacing).
    write_slice(&dir, "b.dcm", 1, 2, 2, &px, iop, [-1e308, 0.0, 1.0], 0.1);
    let e = volume::read_dicom_series(&dir, volume::MAX_VOXELS).expect_err("far away");
    let m = format!("{e:#}");
    assert!(
        m.contains("b.dcm") && m.contains("ImagePositionPatient"),
        "{m}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The synthetic scan written as an oblique DICOM series registers to the truth expressed in
/// patient coordinates: T_dicom = T_true · S · M⁻¹ (M: index → patient, S: index → CT mm).
#[test]
fn registration_through_an_oblique_dicom_series() {
    let part = synth::Part::parameter_cylinder([40.0, -25.0, 0.0], 1.0);
    let spec = synth::SynthSpec {
        voxel_mm: 0.15,
        ..Default::default()
    };
    let ct = synth::render(&part, &spec);
    let dir = scratch("series");
    write_series(&dir, &ct.volume);
    let vol = volume::read_dicom_series(&dir, volume::MAX_VOXELS).expect("read series");
    std::fs::remove_dir_all(&dir).ok();

    let (r_d, p0) = oblique();
    let (r_t, t_t) = (
        Matrix3::from_fn(|i, j| ct.ct_to_build[i][j]),
        Vector3::new(
            ct.ct_to_build[0][3],
            ct.ct_to_build[1][3],
            ct.ct_to_build[2][3],
        ),
    );
    // CT mm = R_dᵀ (P − p0) ⇒ build = R_t R_dᵀ P + (t_t − R_t R_dᵀ p0).
    let r = r_t * r_d.transpose();
    let t = t_t - r * Vector3::from(p0);
    let mut truth = [[0.0; 4]; 4];
    for i in 0..3 {
        for j in 0..3 {
            truth[i][j] = r[(i, j)];
        }
        truth[i][3] = t[i];
    }
    truth[3][3] = 1.0;

    let (lo, hi) = part.bounds();
    let field = synth::GridField::from_sdf(|p| part.sdf(p), lo, hi, 0.1, 1.0);
    let nominal = synth::nominal_shape(&part, 0.1);
    // Clicked points in patient coordinates.
    let pairs: Vec<_> = synth::landmark_pairs(&ct, 3, 0.3, 3)
        .into_iter()
        .map(|p| {
            let q = r_d * Vector3::from(p.ct) + Vector3::from(p0);
            ct::PointPair {
                ct: [q.x, q.y, q.z],
                build: p.build,
            }
        })
        .collect();
    let reg = ct::register(
        &vol,
        &field,
        &nominal,
        &InitialTransform::Points(pairs),
        &CtParams::default(),
    )
    .expect("register")
    .registration;
    let center = {
        let c = Vector3::new(40.0, -25.0, 5.0);
        let p = r.transpose() * (c - t);
        [p.x, p.y, p.z]
    };
    let (a, d) = synth::transform_error(reg.build_from_ct.matrix(), &truth, center);
    println!(
        "DICOM oblique: rotation error {a:.5}°, displacement {:.3} µm, mean |Ψ| {:.2} µm",
        d * 1e3,
        reg.mean_abs_um
    );
    assert!(
        a <= 0.05 && d <= 0.005,
        "rotation {a}°, displacement {} µm",
        d * 1e3
    );
}

/// Two slices of 64 x 64 in the axial frame: `spacing`, `iop`, and `pixels` values each.
fn write_pair(dir: &Path, spacing: f64, iop: [f64; 6], pixels: usize) {
    std::fs::create_dir_all(dir).expect("dir");
    let px = vec![0i16; pixels];
    for k in 0..2 {
        let name = format!("s{k}.dcm");
        write_slice(
            dir,
            &name,
            k,
            64,
            64,
            &px,
            iop,
            [0.0, 0.0, k as f64],
            spacing,
        );
    }
}

/// Issue 30: `dicom info` names what makes a series untrustworthy (zero or NaN spacing, a
/// non-orthogonal orientation, short pixel data) and exits 1; a sound series passes; a negative
/// PixelSpacing is refused by the CT reader (it would register the mirror image).
#[test]
fn dicom_info_names_unsound_series_and_register_ct_refuses_negative_spacing() {
    use crate::common::{self, Run};
    let tmp = tempfile::tempdir().expect("tmp");
    let axial = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
    let info = |dir: &Path| {
        let out = common::bounded(common::layerwise().args(["dicom", "info"]).arg(dir));
        (
            out.status.code(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            common::report(&out),
        )
    };
    let sound = tmp.path().join("sound");
    write_pair(&sound, 0.1, axial, 64 * 64);
    common::layerwise()
        .args(["dicom", "info"])
        .arg(&sound)
        .succeeds();
    for (name, spacing, iop, pixels, words) in [
        ("zero", 0.0, axial, 64 * 64, "PixelSpacing"),
        ("nan", f64::NAN, axial, 64 * 64, "PixelSpacing"),
        // Found by mutation fuzzing: a voxel of 1e-320 mm rounded to 0 through the reader.
        ("subnormal", 1e-320, axial, 64 * 64, "PixelSpacing"),
        (
            "skew",
            0.1,
            [1.0, 0.0, 0.0, 0.5, 0.5, 0.0],
            64 * 64,
            "not two orthonormal vectors",
        ),
        ("short", 0.1, axial, 16, "pixel data is short"),
    ] {
        let dir = tmp.path().join(name);
        write_pair(&dir, spacing, iop, pixels);
        let (code, stdout, report) = info(&dir);
        assert_eq!(code, Some(1), "{name}: {report}");
        assert!(
            stdout.contains("PROBLEM") && stdout.contains(words),
            "{name}: {report}"
        );
        assert!(
            report.contains("1 of 1 series have problems"),
            "{name}: {report}"
        );
    }
    for (name, spacing) in [("mirrored", -0.1), ("subnormal-ct", 1e-320)] {
        refused_by_register(tmp.path(), name, spacing, axial);
    }
}

/// `register ct` of a pair of slices at `spacing` is refused, naming the file and the tag.
fn refused_by_register(tmp: &Path, name: &str, spacing: f64, axial: [f64; 6]) {
    use crate::common;
    let mirrored = tmp.join(name);
    write_pair(&mirrored, spacing, axial, 64 * 64);
    let mut register = common::layerwise();
    register
        .current_dir(tmp)
        .args([
            "register",
            "ct",
            "--vectors",
            "v.cli",
            "--out",
            "ct.toml",
            "--ct",
        ])
        .arg(&mirrored);
    common::refused(
        &mut register,
        &["s0.dcm", "PixelSpacing", "must be positive"],
    );
    assert!(!tmp.join("ct.toml").exists());
}
