//! Every parser, fed mutated inputs: a deterministic mutational fuzzer that runs in CI on the
//! stable toolchain. The coverage-guided libFuzzer targets of the same functions are in `fuzz/`
//! (`bash fuzz/run.sh SEEDS SECONDS`, in tests/run.sh): with `LAYERWISE_FUZZ_SEEDS=DIR` set,
//! these tests also write their seeds there, one folder per fuzz target, as that corpus.
//! `LAYERWISE_FUZZ_MUTANTS=N` runs N mutants per seed instead of the default (a longer run).
//! Seeds are valid inputs made by code; each mutant (bit flips,
//! extreme bytes, cuts, repeated spans, huge or odd numbers spliced into text) must give `Ok` or
//! an error, never a panic (an allocation sized by a wild header shows up as a capacity panic or
//! an abort). A mutant that panics is kept in target/fuzz-smoke/ and named in the failure.

use crate::common;
use crate::common::Rng;

#[path = "../../fuzz/fuzz_targets/build_dir_readers.rs"]
mod build_dir_readers;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// Mutants per seed.
const MUTANTS: u64 = 250;
/// Mutants of the DICOM seed: a mutated element length makes dicom-rs take up to ~2 s on a 2 KB
/// file (it sizes its read by the header), so fewer of those keep CI short.
const DICOM_MUTANTS: u64 = 40;

const SPLICES: &[&str] = &[
    "4294967295",
    "-1",
    "0",
    "1e308",
    "-1e308",
    "nan",
    "inf",
    "99999999999999999999",
    "1e-320",
    "\u{0}",
    "\"",
    "[",
    "]]",
    "=",
    "\n",
    ",",
    "//",
    "$$LAYER/",
    "$$POLYLINE/1,1,99999999",
];

/// One mutant of `seed`: 1 to 4 edits.
fn mutate(seed: &[u8], rng: &mut Rng) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let len = b.len();
        match rng.below(7) {
            0 if len > 0 => {
                let i = rng.below(len);
                b[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                b[i] = [0x00, 0xFF, 0x7F, 0x80, b'9', b'-'][rng.below(6)];
            }
            2 => b.truncate(rng.below(len + 1)),
            3 if len > 0 => {
                let (a, n) = (rng.below(len), 1 + rng.below(64));
                let span: Vec<u8> = b[a..(a + n).min(len)].to_vec();
                let at = rng.below(len);
                b.splice(at..at, span);
            }
            4 => {
                let at = rng.below(len + 1);
                let s = SPLICES[rng.below(SPLICES.len())].as_bytes();
                b.splice(at..at, s.iter().copied());
            }
            5 if len >= 4 => {
                // A 32-bit little-endian field set to an extreme (binary headers, counts).
                let i = rng.below(len - 3);
                let v: u32 = [u32::MAX, 0x7FFF_FFFF, 0x8000_0000, 0, 0xFFFF][rng.below(5)];
                b[i..i + 4].copy_from_slice(&v.to_le_bytes());
            }
            _ => {
                // Replace a digit run with a huge number (text formats).
                if let Some(i) = (0..len)
                    .map(|k| (k + rng.below(len)) % len)
                    .find(|&k| b[k].is_ascii_digit())
                {
                    let end = (i..len).find(|&k| !b[k].is_ascii_digit()).unwrap_or(len);
                    let s = SPLICES[rng.below(8)].as_bytes();
                    b.splice(i..end, s.iter().copied());
                }
            }
        }
    }
    b
}

/// Runs `parse` on every mutant of every seed; returns the mutants that panicked (saved).
fn fuzz(name: &str, seeds: &[Vec<u8>], parse: impl FnMut(&[u8])) -> Vec<PathBuf> {
    fuzz_n(name, seeds, MUTANTS, parse)
}

/// The fuzz target (in fuzz/) that reads what the seeds of `name` are, and the byte that picks
/// the reader in a target that holds several.
fn fuzz_target_of(name: &str) -> (&'static str, Option<u8>) {
    match name {
        "config" => ("config", None),
        "calibration" | "points" => ("calibration", None),
        "frames" => ("frames", None),
        "journal" | "ct-toml" | "build-dir" => ("journal", None),
        "scan.pcr" => ("ct_volume", Some(0)),
        "scan.vgi" => ("ct_volume", Some(1)),
        "tiff" => ("ct_volume", Some(2)),
        "dicom" | "dicom-ct" => ("ct_volume", Some(3)),
        "web-request" => ("web_request", None),
        _ => ("vectors", None),
    }
}

/// With `LAYERWISE_FUZZ_SEEDS=DIR`: the seeds of `name` written to DIR/<fuzz target>/.
fn save_seeds(name: &str, seeds: &[Vec<u8>]) {
    let Some(root) = std::env::var_os("LAYERWISE_FUZZ_SEEDS") else {
        return;
    };
    let (target, selector) = fuzz_target_of(name);
    let dir = Path::new(&root).join(target);
    std::fs::create_dir_all(&dir).unwrap();
    for (s, seed) in seeds.iter().enumerate() {
        let bytes: Vec<u8> = selector.into_iter().chain(seed.iter().copied()).collect();
        std::fs::write(dir.join(format!("{name}-{s}")), bytes).unwrap();
    }
}

fn fuzz_n(
    name: &str,
    seeds: &[Vec<u8>],
    mutants: u64,
    mut parse: impl FnMut(&[u8]),
) -> Vec<PathBuf> {
    save_seeds(name, seeds);
    let mutants = std::env::var("LAYERWISE_FUZZ_MUTANTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(mutants);
    let mut failures = Vec::new();
    let keep = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-smoke");
    for (s, seed) in seeds.iter().enumerate() {
        // The seed itself must parse without a panic too.
        let mut rng = Rng(0x9E37_79B9_7F4A_7C15 ^ (s as u64 + 1) ^ name.len() as u64);
        for i in 0..=mutants {
            let input = if i == 0 {
                seed.clone()
            } else {
                mutate(seed, &mut rng)
            };
            let started = std::time::Instant::now();
            let panicked = catch_unwind(AssertUnwindSafe(|| parse(&input))).is_err();
            if started.elapsed().as_secs_f64() > 0.5 {
                eprintln!(
                    "{name} seed {s} mutant {i}: {:.2} s for {} bytes",
                    started.elapsed().as_secs_f64(),
                    input.len()
                );
            }
            if panicked {
                std::fs::create_dir_all(&keep).unwrap();
                let path = keep.join(format!("{name}-seed{s}-mutant{i}.bin"));
                std::fs::write(&path, &input).unwrap();
                failures.push(path);
            }
        }
    }
    failures
}

fn assert_no_panics(failures: Vec<PathBuf>) {
    assert!(
        failures.is_empty(),
        "{} mutant(s) panicked; inputs kept: {failures:#?}",
        failures.len()
    );
}

#[test]
fn vector_files() {
    let file = layerwise::vectors::synth::generate(3, 6, 8);
    let (mut ascii, mut binary) = (Vec::new(), Vec::new());
    layerwise::vectors::write_ascii(&file, &mut ascii).unwrap();
    layerwise::vectors::write_binary(&file, &mut binary).unwrap();
    assert_no_panics(fuzz("vectors", &[ascii, binary], |b| {
        let _ = layerwise::vectors::read_bytes(b, "fuzz.cli");
    }));
}

#[test]
fn configuration_calibration_and_points_files() {
    let configs = vec![
        include_bytes!("../../config/demo.toml").to_vec(),
        include_bytes!("../../config/layerwise.toml").to_vec(),
    ];
    assert_no_panics(fuzz("config", &configs, |b| {
        let _ = layerwise::config::Config::parse(&String::from_utf8_lossy(b), Path::new("f.toml"));
    }));
    let calibration = layerwise::rectify::Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix([
            [0.34, -0.0004, -250.0],
            [-0.0003, -0.397, 194.4],
            [-3.5e-6, 0.000385, 1.0],
        ]),
        distortion: Some(layerwise::geometry::RadialDistortion {
            center: [735.5, 490.5],
            focal_px: 1840.0,
            k1: -0.1,
            k2: 0.01,
        }),
        grid: Some(layerwise::geometry::Grid::plate()),
        fit: None,
    };
    assert_no_panics(fuzz(
        "calibration",
        &[calibration.to_toml().into_bytes()],
        |b| {
            let _ = layerwise::rectify::Calibration::parse(
                &String::from_utf8_lossy(b),
                Path::new("c.toml"),
            );
        },
    ));
    let points = layerwise::sim::demo::demo_points(1472, 982).into_bytes();
    assert_no_panics(fuzz("points", &[points], |b| {
        let _ = layerwise::calibrate::parse_points(&String::from_utf8_lossy(b), Path::new("p.txt"));
    }));
}

#[test]
fn camera_frames_jpeg_and_nef() {
    let dir = tempfile::tempdir().unwrap();
    let view = common::SmallView::new(dir.path());
    let jpeg = view.jpeg();
    let nef = mock_camera::nef::encode_nef(&view.picture(), &Default::default());
    assert_no_panics(fuzz("frames", &[jpeg, nef], |b| {
        let _ = layerwise::rectify::decode_frame_luma(b);
        let _ = layerwise::rectify::decode_frame(b);
    }));
}

/// The build directory's own files (issue 30), each reader given every mutant as its file: the
/// seeds are the files a small calibrated build wrote (journal, status.json, build.json,
/// inspection.jsonl), an alarm line and a current-build.toml. As the `journal` fuzz target.
#[test]
fn build_dir_readers() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let config = common::calibrated_config(&build, 2, layerwise::dicom::Compression::None);
    let mut options = layerwise::acquisition::RunOptions::new();
    options.drain_at_end = true;
    common::run_daemon(&config, options).expect("the build runs");
    let mut seeds: Vec<Vec<u8>> = [
        "journal.jsonl",
        "status.json",
        "build.json",
        "inspection.jsonl",
    ]
    .iter()
    .map(|name| std::fs::read(build.join(name)).expect(name))
    .collect();
    seeds.push(
        br#"{"at":"2026-01-01T00:00:00Z","event":"raised","layer":3,"kind":"streak","note":"x"}"#
            .to_vec(),
    );
    seeds.push(
        b"folder = \"b-20260101\"\nname = \"b\"\nstarted_at = 2026-01-01T00:00:00Z\n".to_vec(),
    );
    let scratch = dir.path().join("mutant");
    std::fs::create_dir_all(&scratch).unwrap();
    // Fewer mutants: each runs every reader, `status`'s report among them.
    assert_no_panics(fuzz_n("build-dir", &seeds, 100, |b| {
        build_dir_readers::read_all(&scratch, b)
    }));
}

#[test]
fn journal_and_ct_toml() {
    use layerwise::build_dir::journal::{Journal, Record};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("journal.jsonl");
    {
        let (mut journal, _) = Journal::open(&path, false).unwrap();
        let at = chrono::Utc::now();
        journal
            .append(&Record::Start {
                at,
                pid: 7,
                version: "0.1.0".into(),
            })
            .unwrap();
        let (phase, light) = (layerwise::shot::Phase::Post, layerwise::shot::Light::Top);
        journal
            .append(&Record::Event {
                layer: 1,
                phase,
                at,
            })
            .unwrap();
        journal
            .append(&Record::Frame {
                layer: 1,
                phase,
                light,
                file: "raw/L00001_post_top.jpg".into(),
                bytes: 1234,
                sha256: "00".repeat(32),
                at,
            })
            .unwrap();
        journal
            .append(&Record::Processed {
                layer: 1,
                phase,
                light,
                at,
            })
            .unwrap();
    }
    let seed = std::fs::read(&path).unwrap();
    let target = dir.path().join("mutant.jsonl");
    assert_no_panics(fuzz("journal", &[seed], |b| {
        std::fs::write(&target, b).unwrap();
        let _ = Journal::read(&target);
    }));

    let registration = layerwise::ct::CtRegistration {
        build_from_ct: layerwise::geometry::Rigid3::IDENTITY,
        iterations: 3,
        termination: layerwise::ct::Termination::SmallStep,
        threshold: 100.0,
        points_used: 10,
        points_total: 12,
        points_excluded_plate: 1,
        points_outside: 1,
        mean_abs_um: 1.0,
        median_abs_um: 1.0,
        p95_abs_um: 2.0,
        max_abs_um: 3.0,
        rms_um: 1.5,
    };
    let ct_toml = dir.path().join("ct.toml");
    assert_no_panics(fuzz(
        "ct-toml",
        &[registration.to_toml_string().into_bytes()],
        |b| {
            std::fs::write(&ct_toml, b).unwrap();
            let _ = layerwise::ct::CtRegistration::read_toml(&ct_toml);
        },
    ));
}

#[test]
fn ct_volume_headers() {
    use layerwise::ct::volume::{read_volume, VolumeSource};
    let dir = tempfile::tempdir().unwrap();
    let n = 6usize;
    let voxels: Vec<u8> = (0..n * n * n)
        .flat_map(|i| (i as u16).to_le_bytes())
        .collect();
    std::fs::write(dir.path().join("scan.vol"), &voxels).unwrap();
    std::fs::write(dir.path().join("scan.raw"), &voxels).unwrap();
    let pcr = format!(
        "[VolumeData]\nVolume_SizeX={n}\nVolume_SizeY={n}\nVolume_SizeZ={n}\nVoxelSizeRec=0.05\nFormat=5\n"
    );
    let vgi = format!(
        "{{volume1}}\n[representation]\nsize = {n} {n} {n}\ndatatype = unsigned integer\ndatarange = 0 65535\nbitsperelement = 16\n[file1]\nName = scan.raw\nFileFormat = raw\nSize = {n} {n} {n}\nDatatype = unsigned integer\nBitsPerElement = 16\n{{scene}}\n[geometry]\nresolution = 0.05 0.05 0.05\n"
    );
    for (name, seed) in [("scan.pcr", pcr), ("scan.vgi", vgi)] {
        let path = dir.path().join(name);
        assert_no_panics(fuzz(name, &[seed.into_bytes()], |b| {
            std::fs::write(&path, b).unwrap();
            if let Ok(source) = VolumeSource::detect(&path, None) {
                let _ = read_volume(&source);
            }
        }));
    }
}

#[test]
fn ct_tiff_slices() {
    use layerwise::ct::volume::{read_volume, VolumeSource};
    let dir = tempfile::tempdir().unwrap();
    let stack = dir.path().join("stack");
    std::fs::create_dir(&stack).unwrap();
    let mut seeds = Vec::new();
    for (k, img) in [
        image::DynamicImage::ImageLuma16(image::ImageBuffer::from_fn(6, 5, |x, y| {
            image::Luma([(x * 1000 + y) as u16])
        })),
        image::DynamicImage::ImageLuma8(image::ImageBuffer::from_fn(4, 4, |x, y| {
            image::Luma([(x * 30 + y) as u8])
        })),
    ]
    .into_iter()
    .enumerate()
    {
        let path = dir.path().join(format!("seed{k}.tif"));
        img.save(&path).unwrap();
        seeds.push(std::fs::read(&path).unwrap());
    }
    let target = stack.join("s000.tif");
    assert_no_panics(fuzz("tiff", &seeds, |b| {
        std::fs::write(&target, b).unwrap();
        let _ = read_volume(&VolumeSource::Tiff(stack.clone(), 0.05));
    }));
}

#[test]
fn dicom_slices() {
    let dir = tempfile::tempdir().unwrap();
    let view = common::SmallView::new(dir.path());
    let frame = dir.path().join("frame.jpg");
    std::fs::write(&frame, view.jpeg()).unwrap();
    let slice = dir.path().join("slice.dcm");
    let small = layerwise::geometry::Grid {
        x_min: -20.0,
        x_max: 20.0,
        y_min: -20.0,
        y_max: 20.0,
        pixel_mm: 2.0,
    };
    layerwise::rectify::rectify_file(&view.calibration, &frame, &slice, 1, 0.03, small).unwrap();
    let seed = std::fs::read(&slice).unwrap();
    let series = dir.path().join("series");
    std::fs::create_dir_all(&series).unwrap();
    let target = series.join("L00001.dcm");
    // The same slice deflated: its lengths are walked as the data set inflates. It reads.
    let deflated = deflated(&seed);
    std::fs::write(&target, &deflated).unwrap();
    let info = layerwise::dicom::series_info(&series).expect("the deflated seed reads");
    assert_eq!(info.len(), 1);
    let seeds = [seed, deflated];
    assert_no_panics(fuzz_n("dicom", &seeds, DICOM_MUTANTS, |b| {
        std::fs::write(&target, b).unwrap();
        let _ = layerwise::dicom::series_info(&series);
        // The CT reader of the same folder (pixels too).
        let _ = layerwise::ct::volume::read_volume(&layerwise::ct::volume::VolumeSource::Dicom(
            series.clone(),
        ));
    }));
}

/// `file` (explicit VR little endian, its meta group led by the group length) with its data set
/// deflated (transfer syntax 1.2.840.10008.1.2.1.99, PS3.5 A.5).
fn deflated(file: &[u8]) -> Vec<u8> {
    use std::io::Write;
    let u16_at = |at: usize| usize::from(u16::from_le_bytes([file[at], file[at + 1]]));
    let group = u32::from_le_bytes(file[140..144].try_into().unwrap()) as usize;
    let (meta_end, mut at) = (144 + group, 144);
    let mut meta = Vec::new();
    while at < meta_end {
        let (element, vr) = (u16_at(at + 2), &file[at + 4..at + 6]);
        let long = !matches!(vr, b"UI" | b"UL" | b"SH" | b"AE" | b"CS");
        let (header, len) = if long {
            (
                12,
                u32::from_le_bytes(file[at + 8..at + 12].try_into().unwrap()) as usize,
            )
        } else {
            (8, u16_at(at + 6))
        };
        if element == 0x0010 {
            let uid = b"1.2.840.10008.1.2.1.99";
            meta.extend(&file[at..at + 6]);
            meta.extend((uid.len() as u16).to_le_bytes());
            meta.extend(uid);
        } else {
            meta.extend(&file[at..at + header + len]);
        }
        at += header + len;
    }
    let mut out = file[..140].to_vec();
    out.extend((meta.len() as u32).to_le_bytes());
    out.extend(meta);
    let mut z = flate2::write::DeflateEncoder::new(out, flate2::Compression::default());
    z.write_all(&file[meta_end..]).unwrap();
    z.finish().unwrap()
}

/// Found by the libFuzzer target `frames` (fuzz/run.sh): the seeds' NEF with 7,579 bytes of its
/// compressed data replaced by a span of the seeds' JPEG makes rawler panic ("Can't refill
/// bitpump, buffer exhausted"). The frame decoders catch that and return an error, so `rectify`
/// and the daemon see a bad frame, not a crash.
#[test]
fn nef_with_damaged_compressed_data_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let view = common::SmallView::new(dir.path());
    let (jpeg, nef) = (
        view.jpeg(),
        mock_camera::nef::encode_nef(&view.picture(), &Default::default()),
    );
    assert!(layerwise::rectify::decode_frame_luma(&nef).is_ok());
    let mut damaged = nef.clone();
    damaged[14145..21724].copy_from_slice(&jpeg[4920..4920 + 7579]);
    let luma = catch_unwind(|| layerwise::rectify::decode_frame_luma(&damaged).map(|_| ()));
    let colour = catch_unwind(|| layerwise::rectify::decode_frame(&damaged).map(|_| ()));
    assert!(
        matches!(luma, Ok(Err(_))) && matches!(colour, Ok(Err(_))),
        "{:?} {:?}",
        luma.map(|r| r.err().map(|e| e.to_string())),
        colour.map(|r| r.err().map(|e| e.to_string()))
    );
}

/// Requests as a browser and a script send them, each on one connection: the page, its JSON,
/// pictures and crops, an original, the vectors, the event stream, a calibration body (plain
/// and chunked), the token in each place it is looked for, two requests pipelined.
fn page_request_seeds() -> Vec<Vec<u8>> {
    let get = |path: &str, headers: &str| {
        format!("GET {path} HTTP/1.1\r\nHost: localhost\r\n{headers}\r\n").into_bytes()
    };
    let body = r#"{"layer":1,"view":"post_top","points":[{"fx":0.2,"fy":0.2,"x":-60,"y":-50},{"fx":0.8,"fy":0.2,"x":60,"y":-50},{"fx":0.8,"fy":0.8,"x":60,"y":50},{"fx":0.2,"fy":0.8,"x":-60,"y":50}]}"#;
    let mut seeds = vec![
        get("/", ""),
        get("/app.js", "Accept-Encoding: gzip\r\n"),
        get("/api/status", "Authorization: Bearer 0123456789abcdef0123\r\n"),
        get("/api/layers?from=1", "Cookie: a=b; layerwise_token=0123456789abcdef\r\n"),
        get("/api/layers/2", ""),
        get("/api/layers/2/vectors.svg", ""),
        get("/api/layers/2/post_top/picture.jpg", ""),
        get(
            "/api/layers/1/post_top/picture.jpg?kind=raw&x=0.25&y=0.25&w=0.5&h=0.5",
            "",
        ),
        get("/api/layers/2/post_side/picture.jpg?kind=raw", ""),
        get("/api/layers/1/pre_top/original", ""),
        get("/api/events?token=0123456789abcdef0123", ""),
        get("/api/calibration/20260101T000000000/overlay.png", ""),
        format!(
            "POST /api/calibration HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        )
        .into_bytes(),
        format!(
            "POST /api/calibration HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n{:x}\r\n{body}\r\n0\r\n\r\n",
            body.len()
        )
        .into_bytes(),
    ];
    let mut pipelined = get("/api/layers/1", "");
    pipelined.extend(get(
        "/api/layers/1/post_top/picture.jpg?kind=raw",
        "Connection: close\r\n",
    ));
    seeds.push(pipelined);
    seeds
}

/// The page's request path (`web::harness`: hyper's parser, the limits, the routes, the files)
/// on a build with a link to /etc/passwd and a FIFO planted among its frames.
#[test]
fn page_requests() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = common::finished_build(tmp.path(), 2);
    let raw = dir.join("raw");
    std::fs::remove_file(raw.join("L00002_post_side.jpg")).unwrap();
    std::os::unix::fs::symlink("/etc/passwd", raw.join("L00002_post_side.jpg")).unwrap();
    std::fs::remove_file(raw.join("L00002_pre_top.jpg")).unwrap();
    let fifo = std::ffi::CString::new(raw.join("L00002_pre_top.jpg").to_str().unwrap()).unwrap();
    // SAFETY: a NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(fifo.as_ptr(), 0o600) }, 0);
    let config = layerwise::config::WebConfig::default();
    let page = layerwise::web::harness::Harness::new(&dir, &config).unwrap();
    let seeds = page_request_seeds();
    let answer = String::from_utf8_lossy(&page.answer(&seeds[4])).into_owned();
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer:.300}");
    let answer = String::from_utf8_lossy(&page.answer(&seeds[8])).into_owned();
    assert!(answer.starts_with("HTTP/1.1 403"), "{answer:.300}");
    let answer = page.answer(seeds.last().unwrap());
    let answers = String::from_utf8_lossy(&answer)
        .matches("HTTP/1.1 200")
        .count();
    assert_eq!(answers, 2, "both pipelined requests answered");
    assert_no_panics(fuzz_n("web-request", &seeds, 30, |b| {
        let _ = page.answer(b);
    }));
}
