//! Inspection against known truth: 200-layer mock builds rendered in-process (the mock camera's
//! frames, JPEG-encoded, decoded, rectified and inspected exactly as the daemon's worker does,
//! without the daemon around them), one with at least 10 injections of each anomaly at varied
//! positions and strengths, one clean. Prints recall and false alarms per kind (the table of
//! docs/benchmarks.md): `cargo test --release --test it inspection:: -- --nocapture`.

use crate::common;
use layerwise::build_dir::inspection::{FlagKind, InspectionRecord, Severity};
use layerwise::config::inspection::{InjectKind, InspectionConfig, MockInjection};
use layerwise::inspect::Inspector;
use layerwise::rectify::{Calibration, Grid, Rectifier};
use layerwise::shot::{Light, Phase, View};
use std::collections::BTreeMap;

const LAYERS: u32 = 200;
const WIDTH: u32 = 960;
const HEIGHT: u32 = 640;

fn grid() -> Grid {
    common::plate_grid()
}

/// Renders, encodes, decodes, rectifies and inspects every layer.
fn run_build(injections: &[MockInjection], vectors: &std::path::Path) -> Vec<InspectionRecord> {
    let cfg = InspectionConfig::default();
    let views = layerwise::config::ViewsConfig::default().all();
    let index = layerwise::vectors::LayerIndex::build(vectors).expect("vectors");
    let mut inspector = Inspector::new(&cfg, grid(), &views, Some(index));
    let truth = mock_camera::Homography::oblique_view(WIDTH, HEIGHT);
    let calibration = Calibration {
        build_from_image: layerwise::geometry::Homography::from_matrix(truth.m),
        distortion: None,
        grid: Some(grid()),
        fit: None,
    };
    let rectifier =
        Rectifier::new(&calibration.camera(), grid(), Default::default(), 0).expect("rectifier");
    let mut renderer = mock_camera::Renderer::new(WIDTH, HEIGHT, truth);
    renderer.seed = 7;
    let needed: Vec<View> = views.into_iter().filter(|v| inspector.needs(*v)).collect();
    let at = chrono::DateTime::from_timestamp(1_800_000_000, 0).expect("time");
    let mut records = Vec::new();
    for layer in 1..=LAYERS {
        for view in &needed {
            let (fused, defects) = layerwise::sim::inject::scene(injections, layer, view.phase);
            renderer.defects = defects;
            let jpeg = renderer.render_jpeg(
                &mock_camera::Scene {
                    layer,
                    fused: &fused,
                    scanned: view.phase == Phase::Post,
                    illumination: match view.light {
                        Light::Front => mock_camera::Illumination::Front,
                        Light::Side => mock_camera::Illumination::Side,
                        Light::Top => mock_camera::Illumination::Top,
                    },
                },
                90,
            );
            let luma = layerwise::rectify::decode_frame_luma(&jpeg).expect("decode");
            let cells = inspector.cells(&luma.rectified(&rectifier));
            records.extend(inspector.add(layer, *view, cells, at));
        }
    }
    records.extend(inspector.flush(at));
    records
}

fn flag_kind(kind: InjectKind) -> FlagKind {
    match kind {
        InjectKind::Streak => FlagKind::Streak,
        InjectKind::ShortFeed => FlagKind::ShortFeed,
        InjectKind::Elevation => FlagKind::Elevation,
        InjectKind::NoFusion => FlagKind::UnderFusion,
        InjectKind::WideFusion => FlagKind::OverFusion,
        InjectKind::Spatter => FlagKind::Spatter,
        InjectKind::Drift => FlagKind::Drift,
    }
}

/// At least 10 of each kind, spread over the build, positions and strengths varied at or above
/// the detectability stated in docs/benchmarks.md.
fn injections() -> Vec<MockInjection> {
    let mut list = Vec::new();
    for k in 0..12u32 {
        let layer = 8 + 16 * k;
        let f = f64::from(k);
        let streak_y = -110.0 + 19.0 * f;
        list.push(format!(
            "streak@{layer}/y={streak_y}/from={}/to={}/w={}/c={}",
            -120.0 + 5.0 * f,
            40.0 + 7.0 * f,
            1.0 + 0.25 * (f % 3.0),
            if k % 2 == 0 {
                6.0 + f % 4.0
            } else {
                -(6.0 + f % 4.0)
            }
        ));
        list.push(format!(
            "no-fusion@{}/part={}",
            layer + 1,
            if k % 2 == 0 { 1 } else { 3 }
        ));
        list.push(format!(
            "short-feed@{}/x={}/c={}",
            layer + 4,
            60.0 + 5.0 * f,
            6.0 + 2.0 * (f % 4.0)
        ));
        list.push(format!(
            "wide-fusion@{}/part={}/d={}",
            layer + 5,
            if k % 2 == 0 { 3 } else { 1 },
            1.5 + 0.25 * (f % 3.0)
        ));
        list.push(format!(
            "elevation@{}/part={}/w={}/c={}",
            layer + 8,
            if k % 2 == 0 { 3 } else { 1 },
            1.5 + 0.5 * (f % 2.0),
            15.0 + 5.0 * (f % 4.0)
        ));
        list.push(format!(
            "spatter@{}/n={}/r={}/x={}/y={}",
            layer + 11,
            1 + k % 4,
            0.8 + 0.2 * (f % 3.0),
            -80.0 + 14.0 * f,
            if k % 2 == 0 { -20.0 } else { 90.0 }
        ));
        // A ramp over the 8 layers after the slot's elevation, on a part no other injection
        // touches then, brighter or darker.
        list.push(format!(
            "drift@{}..{}/part={}/c={}",
            layer + 9,
            layer + 16,
            if k % 2 == 0 { 3 } else { 1 },
            if k % 2 == 0 { 1.0 } else { -1.0 } * (44.0 + 4.0 * (f % 3.0))
        ));
    }
    list.into_iter()
        .map(|s| s.parse().expect("injection"))
        .filter(|i: &MockInjection| i.last <= LAYERS)
        .collect()
}

#[test]
fn recall_and_false_alarms_per_kind_on_200_layer_mock_builds() {
    let dir = tempfile::tempdir().expect("tmp");
    let vectors = dir.path().join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, LAYERS).expect("vectors");

    // The clean and the injected build side by side: each is mostly one thread (JPEG encode
    // and decode), and this is the longest test of the suite.
    let list = injections();
    let (clean, records) = std::thread::scope(|s| {
        let clean = s.spawn(|| run_build(&[], &vectors));
        let records = run_build(&list, &vectors);
        (clean.join().expect("clean build"), records)
    });
    assert_eq!(clean.len(), LAYERS as usize);
    let clean_flags: Vec<String> = clean
        .iter()
        .flat_map(|r| {
            r.flags
                .iter()
                .filter(|f| f.severity >= Severity::Warning)
                .map(move |f| layerwise::inspect::describe(r.layer, f))
        })
        .collect();

    let by_layer: BTreeMap<u32, &InspectionRecord> = records.iter().map(|r| (r.layer, r)).collect();
    let injected: std::collections::BTreeSet<u32> =
        list.iter().flat_map(|i| i.first..=i.last).collect();
    println!("| anomaly | injected | found | recall | false alarms (clean build) | false alarms (other layers of the injected build) |");
    println!("| --- | --- | --- | --- | --- | --- |");
    let mut failures = Vec::new();
    for kind in InjectKind::ALL {
        let of_kind: Vec<&MockInjection> = list.iter().filter(|i| i.kind == kind).collect();
        let want = flag_kind(kind);
        // A single-layer anomaly is found on its layer; a drift somewhere along its ramp, on
        // its part, before the ramp ends.
        let hit = |i: &MockInjection| {
            let part = (kind == InjectKind::Drift).then(|| i.get("part") as i64);
            let last = if part.is_some() { i.last } else { i.first };
            (i.first..=last).any(|l| {
                by_layer.get(&l).is_some_and(|r| {
                    r.flags
                        .iter()
                        .any(|f| f.kind == want && (part.is_none() || f.part == part))
                })
            })
        };
        let found = of_kind.iter().filter(|i| hit(i)).count();
        let missed: Vec<String> = of_kind
            .iter()
            .filter(|i| !hit(i))
            .map(|i| i.to_string())
            .collect();
        let false_clean = clean
            .iter()
            .flat_map(|r| &r.flags)
            .filter(|f| f.kind == want && f.severity >= Severity::Warning)
            .count();
        let false_other = records
            .iter()
            .filter(|r| !injected.contains(&r.layer))
            .flat_map(|r| &r.flags)
            .filter(|f| f.kind == want)
            .count();
        let other_layers = LAYERS as usize - injected.len();
        println!(
            "| {} | {} | {found} | {:.0}% | {false_clean} in {LAYERS} layers | {false_other} in {other_layers} layers |",
            kind.name(),
            of_kind.len(),
            100.0 * found as f64 / of_kind.len() as f64
        );
        if !missed.is_empty() {
            println!("  missed: {}", missed.join(", "));
        }
        for i in of_kind
            .iter()
            .filter(|i| !hit(i) && i.kind == InjectKind::Drift)
        {
            let part = i.get("part") as i64;
            for l in i.first.saturating_sub(3)..=i.last {
                let Some(r) = by_layer.get(&l) else { continue };
                let m = r.parts.iter().find(|m| m.part == part);
                let flags: Vec<String> = r.flags.iter().map(|f| f.message.clone()).collect();
                println!(
                    "    layer {l}: part {part} post_mean {:?} flags {flags:?}",
                    m.map(|m| m.post_mean)
                );
            }
        }
        assert!(
            of_kind.len() >= 10,
            "{kind:?}: only {} injections",
            of_kind.len()
        );
        if (found as f64) < 0.95 * of_kind.len() as f64 {
            failures.push(format!("{}: recall {found}/{}", kind.name(), of_kind.len()));
        }
        if false_other * 100 > other_layers {
            failures.push(format!("{}: {false_other} false alarms", kind.name()));
        }
    }
    let ms: Vec<f64> = records.iter().map(|r| r.ms).collect();
    println!(
        "inspection per layer (3 views on {} x {} cells): median {:.1} ms",
        inspector_cells(),
        inspector_cells(),
        median(ms)
    );
    assert!(
        clean_flags.is_empty(),
        "clean build flagged: {clean_flags:#?}"
    );
    assert!(failures.is_empty(), "{failures:?}");
}

fn inspector_cells() -> usize {
    grid().rows()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v.get(v.len() / 2).copied().unwrap_or(0.0)
}

/// A calibrated mock build of `layers` layers in `dir` whose part 3 is left unfused on layer 6,
/// with its vectors, the alarm on a mock light, and the printer's script ending in `tail`.
fn unfused_part_build(
    tmp: &std::path::Path,
    dir: &std::path::Path,
    layers: u32,
    tail: &str,
) -> layerwise::config::Config {
    use layerwise::config::{CameraConfig, LightsConfig};
    let mut config = common::calibrated_config(dir, layers, layerwise::dicom::Compression::None);
    let (w, h) = (640, 427);
    if let CameraConfig::Mock(mock) = &mut config.camera {
        mock.width = w;
        mock.height = h;
        mock.inject = vec!["no-fusion@6/part=3".parse().expect("injection")];
    }
    config.calibration.file = Some(common::write_true_calibration(
        tmp,
        &mock_camera::Homography::oblique_view(w, h),
    ));
    let vectors = tmp.join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, layers).expect("vectors");
    config.build.vectors = Some(vectors);
    let script: String = (1..=layers)
        .map(|n| format!("LAYER {n} PRE\nLAYER {n} POST\n"))
        .collect::<String>()
        + tail;
    common::mock_printer(&mut config, tmp, &script);
    config.inspection.alarm.output = LightsConfig::Mock;
    config
}

/// A stack light whose relay never answers.
struct DeadRelay;

impl layerwise::hardware::lights::Lights for DeadRelay {
    fn switch(
        &mut self,
        _: Light,
        _: bool,
    ) -> Result<(), layerwise::hardware::lights::LightsError> {
        Err(layerwise::hardware::lights::LightsError::Serial {
            port: "/dev/ttyUSB9".into(),
            source: std::io::Error::other("no answer"),
        })
    }
    fn all_off(&mut self) -> Result<(), layerwise::hardware::lights::LightsError> {
        Ok(())
    }
}

/// The alarm raised on a stack light that refuses: the build goes on, the alarm is raised in
/// its history, and the lights' health says the alarm's light is at fault (before: a line in
/// the log, and every part of the status "ok").
#[test]
fn an_alarm_light_that_refuses_shows_in_the_lights_health() {
    use crate::common::Run;
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path().join("build");
    let config = unfused_part_build(tmp.path(), &dir, 8, "");
    let mut options = layerwise::acquisition::RunOptions::new();
    options.drain_at_end = true;
    let summary = common::run_daemon_with(&config, options, |machine, _| {
        machine.alarm = Box::new(DeadRelay);
    })
    .expect("the build runs to its end");
    assert_eq!(summary.missing, 0);
    let status = common::read_json(&dir.join("status.json"));
    let lights = &status["health"]["lights"];
    assert_eq!(lights["state"], "error", "{status}");
    let warning = lights["warning"].as_str().unwrap_or_default();
    assert!(
        warning.starts_with(
            "inspection alarm: cannot switch the stack light (top) on: lights relay /dev/ttyUSB9"
        ),
        "{warning}"
    );
    let shown = common::layerwise()
        .args(["status", "--build"])
        .arg(&dir)
        .stdout_ok();
    assert!(shown.contains("RAISED since layer 6"), "{shown}");
}

/// The daemon through the binary: a part left unfused on layer 6 shows in inspection.jsonl, as a
/// WARN line in the log, in `layerwise status`, and raises the alarm: the (mock) stack light goes
/// on, the printer gets one message on its serial line (a pty pair), `status` says it is raised,
/// `layerwise alarm ack` acknowledges it and the running daemon switches the light off. Then
/// `layerwise inspect --build` over the stored build finds the same flags and plots them (PNG).
#[test]
fn the_daemon_flags_an_unfused_part_everywhere_raises_the_alarm_and_inspect_agrees() {
    use crate::common::pty::{PtyPair, PtyReader};
    use crate::common::Run;
    use std::time::{Duration, Instant};
    let tmp = tempfile::tempdir().expect("tmp");
    let pair = PtyPair::start(tmp.path());
    let printer = PtyReader::start(&pair.printer);
    let dir = tmp.path().join("build");
    let layers = 8;
    // The printer keeps the daemon waiting after the last layer, as a real build between layers.
    let mut config = unfused_part_build(tmp.path(), &dir, layers, "WAIT 120000\n");
    config.inspection.alarm.serial = Some(layerwise::config::inspection::AlarmSerialConfig {
        port: pair.daemon.display().to_string(),
        baud: 9600,
        message: "LAYERWISE ALARM {layer} {kind}\n".into(),
    });
    let path = tmp.path().join("layerwise.toml");
    common::write_config(&config, &path);
    let log_path = tmp.path().join("daemon.log");
    // Eight lanes on any machine: a layer's views are processed beside the next layer's, and a
    // lane that finishes a later layer first must not have the earlier one inspected without
    // the view still on its lane.
    let child = common::run_command(&path)
        .env("RAYON_NUM_THREADS", "8")
        .stderr(std::fs::File::create(&log_path).expect("log"))
        .spawn()
        .expect("layerwise run starts");
    let wait_for_log = |text: &str| {
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            let log = std::fs::read_to_string(&log_path).unwrap_or_default();
            if log.contains(text) {
                return log;
            }
            assert!(Instant::now() < deadline, "no {text:?} in the log: {log}");
            std::thread::sleep(Duration::from_millis(50));
        }
    };

    printer.wait_for("\n", Duration::from_secs(120));
    let status = || {
        common::layerwise()
            .args(["status", "--build"])
            .arg(&dir)
            .stdout_ok()
    };
    let raised = status();
    assert!(
        raised.contains("alarm      RAISED since layer 6") && raised.contains("under_fusion"),
        "{raised}"
    );
    let ack = common::layerwise()
        .args([
            "alarm",
            "ack",
            "--by",
            "ana",
            "--note",
            "build stopped",
            "--build",
        ])
        .arg(&dir)
        .stdout_ok();
    assert!(ack.contains("acknowledged by ana at"), "{ack}");
    wait_for_log("inspection alarm off: acknowledged by ana");
    let after = status();
    assert!(
        after.contains("alarm      acknowledged by ana at")
            && after.contains("(raised at layer 6): build stopped"),
        "{after}"
    );
    // A second acknowledgement has nothing to acknowledge.
    let again = common::layerwise()
        .args(["alarm", "ack", "--build"])
        .arg(&dir)
        .output()
        .expect("runs");
    assert!(
        common::assert_exit_1(&again).contains("the alarm is not raised"),
        "{again:?}"
    );
    let deadline = Instant::now() + Duration::from_secs(60);
    while layerwise::build_dir::inspection::InspectionLog::read(
        &dir.join(layerwise::build_dir::INSPECTION),
    )
    .map_or(0, |r| r.len())
        < layers as usize
    {
        assert!(Instant::now() < deadline, "not every layer inspected");
        std::thread::sleep(Duration::from_millis(50));
    }
    let out = common::terminate(child);
    common::assert_success(&out);
    assert_eq!(
        printer.text(),
        "LAYERWISE ALARM 6 under_fusion\n",
        "one message for the one raise"
    );
    pair.stop();
    let log = std::fs::read_to_string(&log_path).expect("log");

    let live = layerwise::build_dir::inspection::InspectionLog::read(
        &dir.join(layerwise::build_dir::INSPECTION),
    )
    .expect("inspection.jsonl");
    assert_eq!(
        live.iter().map(|r| r.layer).collect::<Vec<_>>(),
        (1..=layers).collect::<Vec<_>>()
    );
    for r in &live {
        assert_eq!(
            r.views.len(),
            3,
            "layer {} inspected with {:?}",
            r.layer,
            r.views
        );
    }
    let flagged: Vec<(u32, FlagKind, Option<i64>)> = live
        .iter()
        .flat_map(|r| r.flags.iter().map(move |f| (r.layer, f.kind, f.part)))
        .filter(|(_, kind, _)| *kind == FlagKind::UnderFusion)
        .collect();
    assert_eq!(
        flagged,
        vec![(6, FlagKind::UnderFusion, Some(3))],
        "{live:#?}"
    );
    let flag = live[5]
        .flags
        .iter()
        .find(|f| f.kind == FlagKind::UnderFusion)
        .expect("flag");
    assert_eq!(flag.severity, Severity::Critical);
    let [x0, y0, x1, y1] = flag.bbox_mm;
    assert!(
        (x0 - 40.0).abs() < 1.0 && (x1 - 60.0).abs() < 1.0,
        "{:?}",
        flag.bbox_mm
    );
    assert!(
        (y0 - 44.0).abs() < 1.0 && (y1 - 56.0).abs() < 1.0,
        "{:?}",
        flag.bbox_mm
    );
    assert!(
        log.contains("layer 6: part 3 at x = 40..60 mm, y = 44..56 mm is not fused"),
        "{log}"
    );
    assert!(log.contains("WARN"), "{log}");
    assert!(log.contains("inspection alarm ON: layer 6"), "{log}");

    let status = common::layerwise()
        .args(["status", "--build"])
        .arg(&dir)
        .stdout_ok();
    assert!(
        status.contains("L00006 under_fusion (critical): part 3"),
        "{status}"
    );

    let plot = tmp.path().join("plot.png");
    let again = common::layerwise()
        .args(["inspect", "--json", "--plot"])
        .arg(&plot)
        .arg("--build")
        .arg(&dir)
        .stdout_ok();
    let offline: Vec<InspectionRecord> = again
        .lines()
        .map(|l| serde_json::from_str(l).expect("record"))
        .collect();
    let flags =
        |records: &[InspectionRecord]| -> Vec<(u32, layerwise::build_dir::inspection::Flag)> {
            records
                .iter()
                .flat_map(|r| r.flags.iter().map(move |f| (r.layer, f.clone())))
                .collect()
        };
    assert_eq!(flags(&offline), flags(&live));
    let parts = |records: &[InspectionRecord]| -> Vec<_> {
        records.iter().map(|r| r.parts.clone()).collect()
    };
    assert_eq!(parts(&offline), parts(&live));
    assert_flags_marked(&plot, &offline);
}

/// The PNG decodes, and in every panel the columns of the layers with a flag at warning or above
/// hold the flag colour while the others do not; its labels are drawn: the title and the flag
/// letters' legend, each panel's value ticks and layer ticks, each flagged layer's letter.
fn assert_flags_marked(plot: &std::path::Path, records: &[InspectionRecord]) {
    use layerwise::inspect::plot;
    let image = image::open(plot).expect("the PNG decodes").to_rgb8();
    // Pixels of `colour` in the box x0..x1, y0..y1 (the rows of a label on its baseline y1).
    let count = |colour: [u8; 3], (x0, x1): (f64, f64), (y0, y1): (f64, f64)| {
        let (x0, x1) = (x0.max(0.0) as u32, (x1 as u32).min(image.width() - 1));
        (y0.max(0.0) as u32..=y1 as u32)
            .flat_map(|y| (x0..=x1).map(move |x| (x, y)))
            .filter(|&(x, y)| image.get_pixel(x, y).0 == colour)
            .count()
    };
    let ink = [0, 0, 0];
    let text_rows = |baseline: f64| (baseline - 7.0, baseline);
    assert!(
        count(ink, (70.0, 500.0), text_rows(plot::TITLE_Y)) > 100,
        "the title"
    );
    assert!(
        count(plot::FLAG, (70.0, 700.0), text_rows(plot::LEGEND_Y)) > 100,
        "the legend of the flag letters"
    );
    let ticks = plot::layer_ticks(records);
    assert!(ticks.len() >= 3, "{ticks:?}");
    for (top, bottom) in plot::panel_rows() {
        for y in [top, bottom] {
            assert!(
                count(ink, (2.0, 66.0), (y - 4.0, y + 4.0)) > 15,
                "value tick label at row {y}"
            );
        }
        for &layer in &ticks {
            let x = plot::layer_x(records, layer);
            assert!(
                count(ink, (x - 12.0, x + 12.0), text_rows(bottom + 14.0)) > 8,
                "layer tick label {layer} under the panel at row {bottom}"
            );
        }
        for r in records {
            let x = plot::layer_x(records, r.layer);
            let letter = count(plot::FLAG, (x - 4.0, x + 4.0), text_rows(top - 14.0));
            if r.flags.iter().any(|f| f.severity >= Severity::Warning) {
                assert!(letter > 8, "layer {}: no flag letter", r.layer);
            }
        }
    }
    let flagged: Vec<u32> = records
        .iter()
        .filter(|r| r.flags.iter().any(|f| f.severity >= Severity::Warning))
        .map(|r| r.layer)
        .collect();
    assert!(flagged.contains(&6), "{flagged:?}");
    for r in records {
        let x = plot::layer_x(records, r.layer).round() as u32;
        for (top, bottom) in plot::panel_rows() {
            let red = (top as u32 + 2..bottom as u32 - 2)
                .filter(|&y| image.get_pixel(x, y).0 == plot::FLAG)
                .count();
            let height = (bottom - top) as usize;
            if flagged.contains(&r.layer) {
                assert!(red > height / 2, "layer {}: {red} red pixels", r.layer);
            } else {
                assert_eq!(red, 0, "layer {} is not flagged", r.layer);
            }
        }
    }
}

#[test]
fn demo_refuses_an_unknown_anomaly_and_names_the_choices() {
    let tmp = tempfile::tempdir().expect("tmp");
    let out = common::layerwise()
        .args([
            "demo",
            "--layers",
            "1",
            "--inject",
            "streak@2,blob@3",
            "--out",
        ])
        .arg(tmp.path().join("demo"))
        .output()
        .expect("runs");
    let text = common::assert_exit_1(&out);
    assert!(
        text.contains("--inject: blob@3: unknown anomaly `blob` (one of streak, short-feed"),
        "{text}"
    );
    assert!(!tmp.path().join("demo").exists(), "nothing written");
}

/// The processing worker says what each frame's steps took, the figures
/// `benches/signal_to_screen.rs` reads: one `frame processed` line at DEBUG per frame of an
/// inspected build, with the read, decode, rectify, encode, write, commit and cells times in ms.
#[test]
fn each_processed_frame_says_what_its_steps_took_at_debug() {
    use crate::common::Run;
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path().join("build");
    let layers = 2;
    let mut config =
        common::calibrated_config(&dir, layers, layerwise::dicom::Compression::Deflate);
    let vectors = tmp.path().join("demo.cli");
    layerwise::sim::inject::write_demo_vectors(&vectors, layers).expect("vectors");
    config.build.vectors = Some(vectors);
    let path = tmp.path().join("layerwise.toml");
    common::write_config(&config, &path);
    let out = common::run_command(&path)
        .env("RUST_LOG", "info,layerwise=debug")
        .succeeds();
    let log = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("frame processed"))
        .collect();
    let frames = common::originals(&dir).len();
    assert!(frames >= 2 * layers as usize, "{frames} originals");
    assert_eq!(lines.len(), frames, "one line per frame: {log}");
    for line in lines {
        let field = |key: &str| -> f64 {
            let token = line
                .split_whitespace()
                .find_map(|t| t.strip_prefix(&format!("{key}=")))
                .unwrap_or_else(|| panic!("no {key} in {line}"));
            token
                .parse()
                .unwrap_or_else(|_| panic!("{key}={token} in {line}"))
        };
        for key in [
            "read_ms",
            "decode_ms",
            "rectify_ms",
            "encode_ms",
            "write_ms",
            "commit_ms",
            "cells_ms",
        ] {
            let ms = field(key);
            assert!(ms.is_finite() && (0.0..60_000.0).contains(&ms), "{line}");
        }
        // Said once the slice is committed (fsync, rename) on the worker's commit thread.
        assert!(
            field("decode_ms") > 0.0 && field("encode_ms") > 0.0 && field("commit_ms") > 0.0,
            "{line}"
        );
    }
}

/// The daemon through the binary: the last layer's post-scan top view never comes (the camera
/// fails on it for good), so that layer waits for a view; at the build's end it is inspected with
/// the views it has, and its record is in inspection.jsonl beside the complete layer's.
#[test]
fn at_the_build_end_a_last_layer_missing_a_view_is_inspected_with_the_views_it_has() {
    let dir = tempfile::tempdir().unwrap();
    let build = dir.path().join("build");
    let mut config = common::calibrated_config(&build, 2, layerwise::dicom::Compression::Deflate);
    config.rectify.pixel_mm = 2.0;
    common::add_fault(&mut config, "fail", 2, "post", "top", 0, 0);
    let config_path = dir.path().join("layerwise.toml");
    common::write_config(&config, &config_path);
    let out = common::run_command(&config_path).output().unwrap();
    common::assert_success(&out);
    let log =
        String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    let records = layerwise::build_dir::inspection::InspectionLog::read(
        &build.join(layerwise::build_dir::INSPECTION),
    )
    .expect("inspection.jsonl");
    let views: Vec<(u32, Vec<String>)> =
        records.iter().map(|r| (r.layer, r.views.clone())).collect();
    assert_eq!(views.len(), 2, "{views:?}\n{log}");
    assert_eq!(views[0].0, 1);
    assert!(views[0].1.contains(&"post_top".to_string()), "{views:?}");
    assert_eq!(views[1].0, 2);
    assert!(!views[1].1.is_empty(), "{views:?}");
    assert!(!views[1].1.contains(&"post_top".to_string()), "{views:?}");
    assert!(
        log.contains("the build ended; its last layers are inspected with the views they have"),
        "{log}"
    );
}
