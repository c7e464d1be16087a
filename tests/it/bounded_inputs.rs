//! Issue 13, "bounded resources": every hostile input of the list, made by code, given to the
//! binary the way a user would. Each must end in a refusal (exit 1) that names the file and the
//! place, within seconds, under a 2 GiB address-space limit (an allocation sized by a wild header
//! aborts the child instead of swapping the machine), never a panic, a hang or a silent exit 0.

use crate::common::{
    bounded, config_refused, config_with, layerwise, mkfifo, refused, report, section, SmallView,
};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// A small vector file for `register ct`.
fn vectors(dir: &Path) -> PathBuf {
    let file = layerwise::vectors::synth::generate(3, 6, 8);
    let path = dir.join("part.cli");
    let mut out = Vec::new();
    layerwise::vectors::write_ascii(&file, &mut out).unwrap();
    std::fs::write(&path, out).unwrap();
    path
}

/// `layerwise register ct --vectors … --ct CT --out …` plus `extra`.
fn register_ct(dir: &Path, ct: &Path, extra: &[&str]) -> Command {
    let mut c = layerwise();
    c.args(["register", "ct", "--vectors"])
        .arg(vectors(dir))
        .arg("--ct")
        .arg(ct)
        .arg("--out")
        .arg(dir.join("ct.toml"))
        .args(extra);
    c
}

// ---------------------------------------------------------------- CT readers

fn vgi_text(size: &str) -> String {
    format!(
        "{{volume1}}\n[representation]\nsize = {size}\ndatatype = unsigned integer\n\
         bitsperelement = 16\n[file1]\nName = scan.raw\nFileFormat = raw\nSize = {size}\n\
         Datatype = unsigned integer\nBitsPerElement = 16\n{{scene}}\n[geometry]\n\
         resolution = 0.05 0.05 0.05\n"
    )
}

#[test]
fn vgi_size_1e30_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("scan.raw"), [0u8; 64]).unwrap();
    let vgi = dir.path().join("scan.vgi");
    std::fs::write(&vgi, vgi_text("1e30 1 1")).unwrap();
    refused(
        &mut register_ct(dir.path(), &vgi, &[]),
        &["scan.vgi", "Size"],
    );
}

#[test]
fn pcr_of_2_pow_40_by_2_pow_24_with_an_empty_vol_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("scan.vol"), b"").unwrap();
    let pcr = dir.path().join("scan.pcr");
    std::fs::write(
        &pcr,
        format!(
            "[VolumeData]\nVolume_SizeX={}\nVolume_SizeY=1\nVolume_SizeZ={}\nVoxelSizeRec=0.05\n\
             Format=5\n",
            1u64 << 40,
            1u64 << 24
        ),
    )
    .unwrap();
    refused(&mut register_ct(dir.path(), &pcr, &[]), &["scan.vol"]);
}

/// A 256 x 256 colour TIFF and 40,000 links to it: 2.6 G voxels (10 GB of f32) that the reader
/// must refuse by count before it reserves anything or reads a slice.
#[test]
fn tiff_stack_of_links_is_refused_before_reserving_the_volume() {
    let dir = tempfile::tempdir().unwrap();
    let stack = dir.path().join("stack");
    std::fs::create_dir(&stack).unwrap();
    let slice = image::RgbImage::from_fn(256, 256, |x, y| image::Rgb([x as u8, y as u8, 7]));
    slice.save(stack.join("s00000.tif")).unwrap();
    for k in 1..40_000 {
        std::os::unix::fs::symlink("s00000.tif", stack.join(format!("s{k:05}.tif"))).unwrap();
    }
    let err = refused(
        &mut register_ct(dir.path(), &stack, &["--voxel-mm", "0.05"]),
        &["stack", "40000", "--max-voxels"],
    );
    assert!(err.contains("256"), "{err}");
}

/// An 8 GiB sparse raw file whose layout says 2048 x 2048 x 2048 u8: refused by the voxel cap
/// (with the flag that lifts it named), not read.
#[test]
fn sparse_raw_of_8_gib_is_refused_by_the_voxel_cap() {
    let dir = tempfile::tempdir().unwrap();
    let raw = dir.path().join("big.raw");
    std::fs::File::create(&raw)
        .unwrap()
        .set_len(8 << 30)
        .unwrap();
    let args = [
        "--size",
        "2048,2048,2048",
        "--dtype",
        "u8",
        "--voxel-mm",
        "0.05",
    ];
    refused(
        &mut register_ct(dir.path(), &raw, &args),
        &["big.raw", "--max-voxels"],
    );
    // The flag lifts the cap, and the size check still holds: a file of the wrong size is named.
    let mut wrong = args.to_vec();
    wrong[1] = "2048,2048,2047";
    wrong.extend(["--max-voxels", "9000000000"]);
    refused(&mut register_ct(dir.path(), &raw, &wrong), &["big.raw"]);
}

// ---------------------------------------------------------------- DICOM

/// One explicit-VR little-endian element; `length` overrides the value's length (a lie).
fn element(group: u16, elem: u16, vr: &[u8; 2], value: &[u8], length: Option<u32>) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend(group.to_le_bytes());
    out.extend(elem.to_le_bytes());
    out.extend(vr);
    let len = length.unwrap_or(value.len() as u32);
    if matches!(vr, b"OB" | b"OW" | b"UN" | b"SQ" | b"UT") {
        out.extend([0, 0]);
        out.extend(len.to_le_bytes());
    } else {
        out.extend((len as u16).to_le_bytes());
    }
    out.extend(value);
    out
}

/// A 4 x 4 CT slice, hand-written: `lie` gives a (group, element) whose stated length is
/// 0xFFFFFFF0 (a private OB element, or PixelData).
fn dicom_slice(lie: Option<(u16, u16)>, z: f64) -> Vec<u8> {
    dicom_slice_in(lie, z, false)
}

/// [`dicom_slice`], its data set deflated (transfer syntax 1.2.840.10008.1.2.1.99) when asked.
fn dicom_slice_in(lie: Option<(u16, u16)>, z: f64, deflated: bool) -> Vec<u8> {
    let ts: &[u8] = if deflated {
        b"1.2.840.10008.1.2.1.99"
    } else {
        b"1.2.840.10008.1.2.1\0"
    };
    let class = b"1.2.840.10008.5.1.4.1.1.2\0";
    let mut meta = Vec::new();
    meta.extend(element(2, 1, b"OB", &[0, 1], None));
    meta.extend(element(2, 2, b"UI", class, None));
    meta.extend(element(2, 3, b"UI", b"1.2.3.4.5", None));
    meta.extend(element(2, 0x10, b"UI", ts, None));
    let mut file = vec![0u8; 128];
    file.extend(b"DICM");
    file.extend(element(
        2,
        0,
        b"UL",
        &(meta.len() as u32).to_le_bytes(),
        None,
    ));
    file.extend(meta);
    let us = |v: u16| v.to_le_bytes().to_vec();
    let lie_len = |g, e| (lie == Some((g, e))).then_some(0xFFFF_FFF0);
    let mut ds = Vec::new();
    ds.extend(element(8, 0x16, b"UI", class, None));
    ds.extend(element(8, 0x18, b"UI", b"1.2.3.4.5", None));
    ds.extend(element(8, 0x60, b"CS", b"CT", None));
    ds.extend(element(9, 0x10, b"LO", b"ACME", None));
    ds.extend(element(9, 0x1000, b"OB", &[1, 2, 3, 4], lie_len(9, 0x1000)));
    // A sequence of undefined length holding an item of defined length: walked into.
    ds.extend(element(8, 0x1140, b"SQ", &[], Some(u32::MAX)));
    let referenced = element(8, 0x1150, b"UI", class, None);
    ds.extend([0xFE, 0xFF, 0x00, 0xE0]);
    ds.extend((referenced.len() as u32).to_le_bytes());
    ds.extend(referenced);
    ds.extend([0xFE, 0xFF, 0xDD, 0xE0, 0, 0, 0, 0]);
    ds.extend(element(0x20, 0x0D, b"UI", b"1.2.3.1\0", None));
    ds.extend(element(0x20, 0x0E, b"UI", b"1.2.3.2\0", None));
    ds.extend(element(0x20, 0x13, b"IS", b"1 ", None));
    let mut position = format!("0\\0\\{z}");
    if position.len() % 2 == 1 {
        position.push(' ');
    }
    ds.extend(element(0x20, 0x32, b"DS", position.as_bytes(), None));
    ds.extend(element(0x20, 0x37, b"DS", b"1\\0\\0\\0\\1\\0 ", None));
    ds.extend(element(0x28, 0x02, b"US", &us(1), None));
    ds.extend(element(0x28, 0x04, b"CS", b"MONOCHROME2 ", None));
    ds.extend(element(0x28, 0x10, b"US", &us(4), None));
    ds.extend(element(0x28, 0x11, b"US", &us(4), None));
    ds.extend(element(0x28, 0x30, b"DS", b"1\\1 ", None));
    ds.extend(element(0x28, 0x100, b"US", &us(16), None));
    ds.extend(element(0x28, 0x101, b"US", &us(16), None));
    ds.extend(element(0x28, 0x102, b"US", &us(15), None));
    ds.extend(element(0x28, 0x103, b"US", &us(0), None));
    ds.extend(element(0x28, 0x1052, b"DS", b"0 ", None));
    ds.extend(element(0x28, 0x1053, b"DS", b"1 ", None));
    let pixels: Vec<u8> = (0..16u16).flat_map(|v| (v * 100).to_le_bytes()).collect();
    ds.extend(element(0x7FE0, 0x10, b"OW", &pixels, lie_len(0x7FE0, 0x10)));
    if deflated {
        use std::io::Write;
        let mut z = flate2::write::DeflateEncoder::new(file, flate2::Compression::default());
        z.write_all(&ds).unwrap();
        return z.finish().unwrap();
    }
    file.extend(ds);
    // About 1 KB, as in the finding.
    file.resize(1024.max(file.len()), 0);
    file
}

fn dicom_folder(dir: &Path, lie: Option<(u16, u16)>) -> PathBuf {
    let folder = dir.join("series");
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(folder.join("slice.dcm"), dicom_slice(lie, 0.0)).unwrap();
    folder
}

/// The hand-written slice is valid DICOM when nothing lies: `dicom info` reads it.
#[test]
fn dicom_hand_written_slice_reads() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dicom_folder(dir.path(), None);
    let out = bounded(layerwise().args(["dicom", "info", "--json"]).arg(&folder));
    assert!(out.status.success(), "{}", report(&out));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json[0]["slices"], 1, "{json}");
    assert_eq!(json[0]["rows"], 4, "{json}");
}

fn check_dicom_length_lie(lie: (u16, u16), what: &str) {
    let dir = tempfile::tempdir().unwrap();
    let folder = dicom_folder(dir.path(), Some(lie));
    let started = Instant::now();
    refused(
        layerwise().args(["dicom", "info"]).arg(&folder),
        &["slice.dcm", what, "bytes"],
    );
    refused(
        &mut register_ct(dir.path(), &folder, &[]),
        &["slice.dcm", what],
    );
    // Refused from the file size, before the DICOM parser sizes a read by the header.
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn dicom_pixel_data_claiming_0xfffffff0_bytes_is_refused() {
    check_dicom_length_lie((0x7FE0, 0x10), "(7FE0,0010)");
}

#[test]
fn dicom_private_ob_claiming_0xfffffff0_bytes_is_refused() {
    check_dicom_length_lie((0x9, 0x1000), "(0009,1000)");
}

/// Found by the libFuzzer target `ct_volume` (a timeout: 13 s, 1.9 GB): an element whose VR is
/// unknown ("L~") has a 32-bit length, read from what was its value, so dicom-rs allocated
/// ~1.9 GB. The length walk reads unknown VRs the same way and refuses the length.
#[test]
fn dicom_unknown_vr_with_a_long_length_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dicom_folder(dir.path(), None);
    let slice = folder.join("slice.dcm");
    let mut bytes = std::fs::read(&slice).unwrap();
    let at = bytes
        .windows(8)
        .position(|w| w == b"LO\x04\x00ACME")
        .unwrap();
    bytes[at + 1] = b'~';
    std::fs::write(&slice, bytes).unwrap();
    refused(
        layerwise().args(["dicom", "info"]).arg(&folder),
        &["slice.dcm", "(0009,0010)", "bytes"],
    );
}

/// Found by mutation fuzzing: in a deflated file the lengths are inside the compressed stream,
/// so the file's size bounds none of them; an 835-byte file whose element claimed gigabytes had
/// dicom-rs reserve and fill 3.2 GB. The walk inflates the data set and checks each length
/// against what the stream holds.
#[test]
fn dicom_deflated_slice_claiming_0xfffffff0_bytes_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("series");
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::write(folder.join("slice.dcm"), dicom_slice_in(None, 0.0, true)).unwrap();
    let out = bounded(layerwise().args(["dicom", "info", "--json"]).arg(&folder));
    assert!(out.status.success(), "{}", report(&out));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json[0]["rows"], 4, "{json}");

    let lie = dicom_slice_in(Some((0x9, 0x1000)), 0.0, true);
    assert!(lie.len() < 1024, "{}", lie.len());
    std::fs::write(folder.join("slice.dcm"), lie).unwrap();
    let started = Instant::now();
    let words = [
        "slice.dcm",
        "(0009,1000)",
        "inflated data set",
        "4294967280",
    ];
    refused(layerwise().args(["dicom", "info"]).arg(&folder), &words);
    refused(&mut register_ct(dir.path(), &folder, &[]), &words);
    assert!(
        started.elapsed() < Duration::from_secs(10),
        "{:?}",
        started.elapsed()
    );
}

#[test]
fn dicom_symlink_loop_counts_each_file_once() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dicom_folder(dir.path(), None);
    std::os::unix::fs::symlink(".", folder.join("loop")).unwrap();
    std::os::unix::fs::symlink("slice.dcm", folder.join("again.dcm")).unwrap();
    let out = bounded(layerwise().args(["dicom", "info", "--json"]).arg(&folder));
    assert!(out.status.success(), "{}", report(&out));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json[0]["slices"], 1, "{json}");
}

// ---------------------------------------------------------------- frames and rectify

/// The SOF marker's offset in a JPEG (baseline or progressive).
fn sof(jpeg: &[u8]) -> usize {
    jpeg.windows(2)
        .position(|w| w[0] == 0xFF && matches!(w[1], 0xC0..=0xC2))
        .expect("a JPEG has a frame header")
}

#[test]
fn jpeg_whose_sof_claims_65500_by_65500_is_refused_to_png_and_to_dcm() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let mut jpeg = view.jpeg();
    let at = sof(&jpeg) + 5;
    jpeg[at..at + 2].copy_from_slice(&65500u16.to_be_bytes());
    jpeg[at + 2..at + 4].copy_from_slice(&65500u16.to_be_bytes());
    let image = dir.path().join("huge.jpg");
    std::fs::write(&image, &jpeg).unwrap();
    for out in ["out.png", "out.dcm"] {
        let started = Instant::now();
        refused(
            &mut rectify(&view, &image, &dir.path().join(out)),
            &["huge.jpg", "65500"],
        );
        assert!(started.elapsed() < Duration::from_secs(10), "{out}");
        assert!(!dir.path().join(out).exists());
    }
}

fn rectify(view: &SmallView, image: &Path, out: &Path) -> Command {
    view.rectify_command(image, out)
}

/// `layerwise rectify` of `image` to PNG and to DICOM (beside it): both refused, naming `words`.
fn rectify_refused(view: &SmallView, image: &Path, words: &[&str]) {
    for out in ["out.png", "out.dcm"] {
        refused(&mut rectify(view, image, &image.with_file_name(out)), words);
    }
}

#[test]
fn truncated_or_corrupt_jpeg_is_an_error_not_a_silent_exit_0() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let jpeg = view.jpeg();
    // The whole frame rectifies (so a refusal below is about the damage).
    let good = dir.path().join("good.jpg");
    std::fs::write(&good, &jpeg).unwrap();
    let out = bounded(&mut rectify(&view, &good, &dir.path().join("good.png")));
    assert!(out.status.success(), "{}", report(&out));
    let truncated = &jpeg[..jpeg.len() / 2];
    // Corrupt: the entropy data's second half replaced by an early end of image.
    let mut corrupt = truncated.to_vec();
    corrupt.extend([0xFF, 0xD9]);
    let mut overwritten = jpeg.clone();
    let scan = sof(&jpeg) + 200;
    for (i, b) in overwritten[scan..jpeg.len() - 2].iter_mut().enumerate() {
        *b = if i % 2 == 0 {
            0xFF
        } else {
            0xD0 + (i % 8) as u8
        };
    }
    for (name, bytes) in [
        ("truncated.jpg", truncated.to_vec()),
        ("early-eoi.jpg", corrupt),
        ("restart-markers.jpg", overwritten),
    ] {
        let image = dir.path().join(name);
        std::fs::write(&image, bytes).unwrap();
        rectify_refused(&view, &image, &[name]);
    }
}

/// A binary built without the `nef` feature (`--no-default-features`) refuses a Nikon raw frame
/// with the way out, rather than rectifying the small TIFF picture that opens it; a plain TIFF
/// frame still rectifies. Run by tests/run.sh with `--no-default-features`.
#[cfg(not(feature = "nef"))]
#[test]
fn nef_frame_on_a_binary_without_the_feature_names_the_feature() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let picture = view.picture();
    let nef = dir.path().join("frame.nef");
    std::fs::write(
        &nef,
        mock_camera::nef::encode_nef(&picture, &Default::default()),
    )
    .unwrap();
    rectify_refused(&view, &nef, &["frame.nef", "--features nef"]);
    let tiff = dir.path().join("frame.tif");
    picture.save(&tiff).unwrap();
    for out in ["tiff.png", "tiff.dcm"] {
        let out = bounded(&mut rectify(&view, &tiff, &dir.path().join(out)));
        assert!(out.status.success(), "{}", report(&out));
    }
}

/// The same 30 bytes as the finding: a TIFF header and one directory of one entry whose next
/// directory is itself (a decoder following the chain grows its list until it aborts at 3-4 GB).
fn self_pointing_tiff() -> Vec<u8> {
    let mut tiff = Vec::from(*b"II\x2A\0");
    tiff.extend(8u32.to_le_bytes());
    tiff.extend(1u16.to_le_bytes());
    // ImageWidth, SHORT, 1 value: 64.
    tiff.extend([0, 1, 3, 0, 1, 0, 0, 0, 64, 0, 0, 0]);
    tiff.extend(8u32.to_le_bytes());
    tiff.resize(30, 0);
    tiff
}

/// The finding: a 30-byte TIFF whose directory points to itself, stored as a frame, aborted
/// `rectify` and `register images` at 3-4 GB. Both refuse it by name, under the 2 GiB limit.
#[test]
fn tiff_whose_directory_points_to_itself_is_refused_by_rectify_and_register_images() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let image = dir.path().join("L00001_post_top.tif");
    std::fs::write(&image, self_pointing_tiff()).unwrap();
    let started = Instant::now();
    rectify_refused(&view, &image, &["L00001_post_top.tif", "loop"]);
    let points = dir.path().join("points.txt");
    std::fs::write(&points, "0 0 0 0\n100 0 10 0\n100 100 10 10\n0 100 0 10\n").unwrap();
    refused(
        layerwise()
            .args(["register", "images", "--layer", "1", "--vectors"])
            .arg(vectors(dir.path()))
            .arg("--image")
            .arg(&image)
            .arg("--init")
            .arg(&points)
            .arg("--out")
            .arg(dir.path().join("calibration-out.toml")),
        &["L00001_post_top.tif", "loop"],
    );
    assert!(!dir.path().join("calibration-out.toml").exists());
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "{:?}",
        started.elapsed()
    );
}

/// `picture` as a JPEG of quality 90 written by jpeg-encoder, progressive or baseline.
fn encode_jpeg(picture: &image::RgbImage, progressive: bool) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut out, 90);
    encoder.set_progressive(progressive);
    encoder
        .encode(
            picture.as_raw(),
            picture.width() as u16,
            picture.height() as u16,
            jpeg_encoder::ColorType::Rgb,
        )
        .unwrap();
    out
}

/// `picture` as a JPEG of quality 90, progressive or baseline, written by `writer`: jpeg-encoder
/// (in process), libjpeg-turbo's `cjpeg` (Debian's libjpeg-turbo-progs) or Pillow (the test venv).
fn written_by(writer: &str, picture: &image::RgbImage, dir: &Path, progressive: bool) -> Vec<u8> {
    let ppm = dir.join("picture.ppm");
    if writer != "jpeg-encoder" {
        // A binary PPM (P6), which both read.
        let mut bytes = format!("P6\n{} {}\n255\n", picture.width(), picture.height()).into_bytes();
        bytes.extend_from_slice(picture.as_raw());
        std::fs::write(&ppm, bytes).unwrap();
    }
    let out = match writer {
        "jpeg-encoder" => return encode_jpeg(picture, progressive),
        "cjpeg" => {
            let mut cjpeg = Command::new("cjpeg");
            cjpeg.args(["-quality", "90"]);
            if progressive {
                cjpeg.arg("-progressive");
            }
            cjpeg.arg(&ppm).output()
        }
        _ => Command::new(crate::common::python())
            .args([
                "-c",
                "import sys; from PIL import Image; \
                 Image.open(sys.argv[1]).save(sys.stdout.buffer, 'JPEG', quality=90, \
                 progressive=sys.argv[2] == '1')",
            ])
            .arg(&ppm)
            .arg(if progressive { "1" } else { "0" })
            .output(),
    }
    .unwrap_or_else(|e| panic!("{writer}: {e} (tests/run.sh installs it)"));
    assert!(out.status.success(), "{writer}: {}", report(&out));
    out.stdout
}

/// The finding: every progressive JPEG was refused with "Exhausted data in the image". A
/// progressive frame, written by jpeg-encoder, by libjpeg-turbo's cjpeg or by Pillow, rectifies,
/// to PNG and to DICOM, into the picture its baseline twin (the same writer, picture and
/// quality) gives.
#[test]
fn progressive_jpeg_rectifies_like_its_baseline_twin() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let picture = view.picture();
    for writer in ["jpeg-encoder", "cjpeg", "Pillow"] {
        let mut rectified = Vec::new();
        for (name, progressive) in [("progressive.jpg", true), ("baseline.jpg", false)] {
            let jpeg = written_by(writer, &picture, dir.path(), progressive);
            let marker = jpeg[sof(&jpeg) + 1];
            assert_eq!(
                marker == 0xC2,
                progressive,
                "{writer} {name}: SOF {marker:#x}"
            );
            let image = dir.path().join(name);
            std::fs::write(&image, &jpeg).unwrap();
            let png = image.with_extension("png");
            for out in [png.clone(), image.with_extension("dcm")] {
                let done = bounded(&mut rectify(&view, &image, &out));
                assert!(done.status.success(), "{writer} {name}: {}", report(&done));
            }
            rectified.push(image::open(&png).unwrap().to_luma8());
        }
        let (progressive, baseline) = (&rectified[0], &rectified[1]);
        assert_eq!(progressive.dimensions(), baseline.dimensions());
        let differences: Vec<u8> = progressive
            .as_raw()
            .iter()
            .zip(baseline.as_raw())
            .map(|(a, b)| a.abs_diff(*b))
            .collect();
        let mean =
            differences.iter().map(|&d| f64::from(d)).sum::<f64>() / differences.len() as f64;
        let max = differences.iter().max().copied().unwrap_or(0);
        assert!(mean < 0.5 && max <= 8, "{writer}: mean {mean}, max {max}");
        // Not a blank picture: the plate shows.
        let (lo, hi) = baseline
            .as_raw()
            .iter()
            .fold((255u8, 0u8), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        assert!(hi - lo > 50, "{writer}: {lo}..{hi}");
    }
}

fn grid_toml(side: f64) -> String {
    format!("[rectify]\nx_min = 0.0\nx_max = {side}\ny_min = 0.0\ny_max = {side}\npixel_mm = 1.0\n")
}

/// A 131072 x 131072 grid: each side within a per-side limit, the total (17 G px) refused where
/// it is used (the configuration), never allocated where it is not (an old calibration).
#[test]
fn calibration_grid_of_131072_squared_is_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let view = SmallView::new(dir.path());
    let calibration = std::fs::read_to_string(&view.calibration).unwrap();
    // The grid in calibration.toml (its [grid] table).
    let mut table: toml::Table = toml::from_str(&calibration).unwrap();
    table.insert(
        "grid".into(),
        toml::from_str::<toml::Table>(&grid_toml(131072.0))
            .unwrap()
            .remove("rectify")
            .unwrap(),
    );
    std::fs::write(&view.calibration, toml::to_string(&table).unwrap()).unwrap();
    let image = dir.path().join("frame.jpg");
    std::fs::write(&image, view.jpeg()).unwrap();
    // Since the grid moved to the configuration's [rectify], a calibration's [grid] is ignored
    // (with a note): rectify allocates the configured grid, not this one.
    let out = bounded(&mut rectify(&view, &image, &dir.path().join("out.png")));
    assert!(out.status.success(), "{}", report(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("131072") && stderr.contains("ignored"),
        "{stderr}"
    );
    let png = image::open(dir.path().join("out.png")).unwrap();
    assert_eq!((png.width(), png.height()), (550, 550));
    // The same grid in the configuration's [rectify]: check-config and rectify refuse it.
    let config = dir.path().join("big-grid.toml");
    let text = std::fs::read_to_string(&view.config).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    table.insert(
        "rectify".into(),
        toml::from_str::<toml::Table>(&grid_toml(131072.0))
            .unwrap()
            .remove("rectify")
            .unwrap(),
    );
    std::fs::write(&config, toml::to_string(&table).unwrap()).unwrap();
    refused(
        layerwise().arg("check-config").arg(&config),
        &["big-grid.toml", "131072", "rectify"],
    );
}

// ---------------------------------------------------------------- files that are not files

#[test]
fn check_config_of_dev_zero_is_a_bounded_read() {
    refused(
        layerwise().args(["check-config", "/dev/zero"]),
        &["/dev/zero"],
    );
}

#[test]
fn fifo_as_vector_file_is_refused_by_file_type() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("layers.cli");
    mkfifo(&fifo);
    refused(
        layerwise().args(["vectors", "info"]).arg(&fifo),
        &["layers.cli"],
    );
}

#[test]
fn vector_file_with_units_1e308_is_refused_as_non_finite() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("inf.cli");
    std::fs::write(
        &path,
        "$$HEADERSTART\n$$ASCII\n$$UNITS/1e308\n$$LAYERS/1\n$$HEADEREND\n$$GEOMETRYSTART\n\
         $$LAYER/0.03\n$$POLYLINE/1,1,3,0,0,10,0,10,10\n$$GEOMETRYEND\n",
    )
    .unwrap();
    refused(
        layerwise().args(["vectors", "info"]).arg(&path),
        &["inf.cli", "UNITS"],
    );
}

// ---------------------------------------------------------------- configurations

#[test]
fn config_the_demo_itself_passes_check_config() {
    let dir = tempfile::tempdir().unwrap();
    let path = config_with(dir.path(), "ok.toml", |_| {});
    let out = bounded(layerwise().arg("check-config").arg(&path));
    assert!(out.status.success(), "{}", report(&out));
}

#[test]
fn config_queue_capacity_1e12_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "queue.toml", "queue_capacity", |t| {
        section(t, "storage").insert("queue_capacity".into(), 1_000_000_000_000i64.into());
    });
}

#[test]
fn config_rectify_grid_of_131072_squared_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "grid.toml", "rectify", |t| {
        let r = section(t, "rectify");
        for (k, v) in [("x_min", 0.0), ("y_min", 0.0), ("pixel_mm", 1.0)] {
            r.insert(k.into(), v.into());
        }
        r.insert("x_max".into(), 131072.0.into());
        r.insert("y_max".into(), 131072.0.into());
    });
}

#[test]
fn config_mock_camera_4e9_wide_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "wide.toml", "width", |t| {
        section(t, "camera").insert("width".into(), 4_000_000_000i64.into());
    });
}

/// A binary built without the `gphoto` feature cannot drive a real camera: check-config says so
/// (the unit's ExecStartPre then stops the service instead of a restart loop). Run by
/// tests/run.sh with `--no-default-features`.
#[cfg(not(feature = "gphoto"))]
#[test]
fn config_gphoto2_camera_on_a_binary_without_the_feature_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "gphoto.toml", "gphoto", |t| {
        t.insert(
            "camera".into(),
            toml::from_str::<toml::Value>("kind = \"gphoto2\"").unwrap(),
        );
    });
}

/// A binary built without the `opcua` feature has no OPC UA server: check-config refuses a
/// `[opcua] listen` instead of a daemon that silently serves nothing. Run by tests/run.sh with
/// `--no-default-features`.
#[cfg(not(feature = "opcua"))]
#[test]
fn config_opcua_listen_on_a_binary_without_the_feature_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "opcua.toml", "`opcua` feature", |t| {
        t.insert(
            "opcua".into(),
            toml::from_str::<toml::Value>("listen = \"opc.tcp://127.0.0.1:4840\"").unwrap(),
        );
    });
}

#[test]
fn config_duplicate_phases_or_lights_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "phases.toml", "phases", |t| {
        section(t, "views").insert("phases".into(), vec!["pre", "post", "pre"].into());
    });
    config_refused(dir.path(), "lights.toml", "lights", |t| {
        section(t, "views").insert("lights".into(), vec!["top", "top"].into());
    });
}

#[test]
fn config_first_layer_4294967295_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "first.toml", "first_layer", |t| {
        section(t, "trigger").insert("first_layer".into(), 4_294_967_295i64.into());
    });
}

#[test]
fn config_layer_thickness_1e308_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "thick.toml", "layer_thickness_mm", |t| {
        section(t, "build").insert("layer_thickness_mm".into(), 1e308.into());
    });
}

#[test]
fn config_nul_or_newline_in_build_name_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    config_refused(dir.path(), "nul.toml", "build.name", |t| {
        section(t, "build").insert("name".into(), "part\u{0}one".into());
    });
    config_refused(dir.path(), "newline.toml", "build.name", |t| {
        section(t, "build").insert("name".into(), "part\none".into());
    });
}
