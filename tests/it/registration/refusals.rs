//! `register images` where the input cannot give a calibration (bad points files, a pre-scan
//! frame, a missing layer, clicks far off, a distortion the parts cannot show): a clear error and
//! nothing written; and the command line and the in-memory path against the file path.

use super::*;

fn error_of(setup: &Setup, request: &ImageRegistration) -> String {
    match register_images(request) {
        Ok(r) => panic!(
            "expected an error, got {:?}",
            r.calibration.build_from_image
        ),
        Err(e) => {
            let msg = e.to_string();
            eprintln!("{msg}");
            assert!(!setup.file("calibration.toml").exists(), "nothing written");
            msg
        }
    }
}

#[test]
fn bad_points_files_are_refused_with_file_and_line() {
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png("f.png", &render(truth, 1, &parts, true));
    let good = points_text(&truth, None, (0.0, 0.0));
    let lines: Vec<&str> = good.lines().collect();

    let three = setup.write_text("three.txt", &lines[..4].join("\n"));
    let msg = error_of(&setup, &setup.request(&[(&frame, 1)], &three));
    assert!(
        msg.contains("three.txt") && msg.contains("at least 4"),
        "{msg}"
    );

    // The 4th click on the line through the 2nd and 3rd (in build mm and in the image).
    let c = clicks_mm();
    let (x, y) = (0.5 * (c[1].0 + c[2].0), 0.5 * (c[1].1 + c[2].1));
    let (u, v) = true_pixel(&truth, None, x, y);
    let collinear = format!(
        "{}\n{}\n{}\n{u} {v} {x} {y}\n",
        lines[1], lines[2], lines[3]
    );
    let col = setup.write_text("collinear.txt", &collinear);
    let msg = error_of(&setup, &setup.request(&[(&frame, 1)], &col));
    assert!(
        msg.contains("collinear.txt")
            && msg.contains("lines 2, 3 and 4")
            && msg.contains("collinear"),
        "{msg}"
    );

    let dup = format!("{}\n{}\n{}\n{}\n", lines[1], lines[2], lines[3], lines[2]);
    let dup = setup.write_text("dup.txt", &dup);
    let msg = error_of(&setup, &setup.request(&[(&frame, 1)], &dup));
    assert!(
        msg.contains("duplicate") && msg.contains("lines 2 and 4"),
        "{msg}"
    );

    // A letter O for a zero in the y of line 3.
    let head: Vec<&str> = lines[2].split_whitespace().take(3).collect();
    let text = format!(
        "{}\n{}\n{} 1O.5\n{}\n{}\n",
        lines[0],
        lines[1],
        head.join(" "),
        lines[3],
        lines[4]
    );
    let typo = setup.write_text("typo.txt", &text);
    let msg = error_of(&setup, &setup.request(&[(&frame, 1)], &typo));
    assert!(
        msg.contains("typo.txt") && msg.contains("line 3") && msg.contains("\"1O.5\""),
        "{msg}"
    );

    let missing = setup.file("nope.txt");
    let msg = error_of(&setup, &setup.request(&[(&frame, 1)], &missing));
    assert!(
        msg.contains("nope.txt") && msg.contains("cannot read"),
        "{msg}"
    );
}

#[test]
fn a_pre_scan_frame_and_a_missing_layer_are_refused() {
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let setup = Setup::new(std::slice::from_ref(&parts));
    let pre = setup.write_png("L00001_pre_top.png", &render(truth, 1, &parts, false));
    let points = setup.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let msg = error_of(&setup, &setup.request(&[(&pre, 1)], &points));
    assert!(
        msg.contains("L00001_pre_top.png") && msg.contains("no fused part visible"),
        "{msg}"
    );

    let post = setup.write_png("post.png", &render(truth, 1, &parts, true));
    let msg = error_of(&setup, &setup.request(&[(&post, 7)], &points));
    assert!(
        msg.contains("build.cli") && msg.contains("no vectors for printer layer 7"),
        "{msg}"
    );

    // A frame whose layer has no fused area (an empty layer in the file).
    let setup2 = Setup::new(&[parts.clone(), Vec::new()]);
    let post2 = setup2.write_png("post.png", &render(truth, 1, &parts, true));
    let points2 = setup2.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let msg = error_of(&setup2, &setup2.request(&[(&post2, 2)], &points2));
    assert!(msg.contains("layer 2 has no fused area"), "{msg}");

    // Parts outside the frame under the start points.
    let far = setup.write_text("far.txt", &points_text(&truth, None, (900.0, 0.0)));
    let msg = error_of(&setup, &setup.request(&[(&post, 1)], &far));
    assert!(msg.contains("not in view"), "{msg}");
}

#[test]
fn clicks_200_px_off_converge_or_fail_clearly() {
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png("f.png", &render(truth, 1, &parts, true));
    let good = points_text(&truth, None, (0.0, 0.0));
    // Each click 200 px off in its own direction, then all clicks 200 px off the same way.
    let scattered = [(200.0, 0.0), (0.0, -200.0), (-141.0, 141.0), (141.0, 141.0)];
    let uniform = [(200.0, 0.0); 4];
    for (name, offsets) in [("scattered.txt", scattered), ("uniform.txt", uniform)] {
        let mut text = String::new();
        for (line, (du, dv)) in good.lines().skip(1).zip(offsets) {
            let f: Vec<f64> = line
                .split_whitespace()
                .map(|s| s.parse().expect("number"))
                .collect();
            text += &format!("{} {} {} {}\n", f[0] + du, f[1] + dv, f[2], f[3]);
        }
        let points = setup.write_text(name, &text);
        match register_images(&setup.request(&[(&frame, 1)], &points)) {
            Ok(report) => {
                print_report(name, &report);
                let (mean, max) = contour_error(&parts, &truth, None, mapping(&report.calibration));
                assert!(
                    mean <= 0.25 && max <= 0.5,
                    "{name}: converged wrongly: {mean} / {max} px"
                );
            }
            Err(e) => {
                let msg = e.to_string();
                eprintln!("{name}: {msg}");
                assert!(
                    [
                        "diverged",
                        "did not converge",
                        "no fused part visible",
                        "not in view"
                    ]
                    .iter()
                    .any(|k| msg.contains(k)),
                    "{name}: unclear error: {msg}"
                );
                assert!(msg.contains("start points"), "{msg}");
            }
        }
    }
}

#[test]
fn register_frames_in_memory_matches_the_file_path() {
    // The in-memory entry point (what a daemon-side caller would use) on the same data.
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let layer = layer_of(0, &parts);
    let img = DynamicImage::ImageRgb8(render(truth, 1, &parts, true));
    let pts = calibrate::parse_points(&points_text(&truth, None, (0.0, 0.0)), Path::new("inline"))
        .expect("points");
    let report = calibrate::register_frames(
        &[calibrate::Frame {
            name: "inline frame",
            image: &img,
            layer: &layer,
            layer_number: 1,
        }],
        &pts,
        Path::new("inline"),
        DistortionChoice::None,
        &RegistrationOptions::default(),
    )
    .expect("registers");
    let (mean, max) = contour_error(&parts, &truth, None, mapping(&report.calibration));
    assert!(mean <= 0.25 && max <= 0.5, "mean {mean} px, max {max} px");
    assert!(report.click_residuals_px.iter().all(|&c| c < 10.0));
}

#[test]
fn the_command_line_writes_the_calibration_or_names_the_problem() {
    let truth = Homography::oblique_view(W, H);
    let parts = parts();
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png("L00001_post_top.png", &render(truth, 1, &parts, true));
    let points = setup.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let out = setup.file("calibration.toml");
    let overlay = setup.file("overlay.png");
    let run = |layer: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
            .args(["register", "images", "--vectors"])
            .arg(&setup.vectors)
            .args(["--layer", layer, "--image"])
            .arg(&frame)
            .arg("--init")
            .arg(&points)
            .arg("--out")
            .arg(&out)
            .arg("--overlay")
            .arg(&overlay)
            .output()
            .expect("runs")
    };
    let ok = run("1");
    common::assert_success(&ok);
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        stdout.contains("level 0") && stdout.contains("wrote"),
        "{stdout}"
    );
    // The report across the plate: a row per corner and per part, and its verdict.
    assert!(
        stdout.contains("expected error across the plate")
            && stdout.contains("corner +x +y")
            && stdout.contains("part 1")
            && (stdout.contains("WARN:") || stdout.contains("within the limit 0.50 mm")),
        "{stdout}"
    );
    let cal = Calibration::load(&out).expect("calibration written");
    let (mean, max) = contour_error(&parts, &truth, None, mapping(&cal));
    assert!(mean <= 0.25 && max <= 0.5, "mean {mean} px, max {max} px");
    assert!(overlay.exists());

    std::fs::remove_file(&out).expect("remove");
    let bad = run("3");
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1));
    assert!(
        stderr.contains("error: ") && stderr.contains("no vectors for printer layer 3"),
        "{stderr}"
    );
    assert!(!out.exists());
}

/// One numbering (docs/frames.md): a vector file that starts with empty layers, as real files
/// do, pairs printer layer 150 (the frame `L00150_post_top.png`) with its 150th layer with
/// geometry: `register images --layer 150` registers against those vectors, and `vectors raster
/// --layer 150` draws the same layer as `--layer-match position` does at its file position.
#[test]
fn printer_layer_150_pairs_with_the_vectors_of_layer_150() {
    let truth = Homography::oblique_view(W, H);
    let all = parts();
    let (layer150, layer151) = (all[..4].to_vec(), all[2..].to_vec());
    let small = vec![Part::polygon(vec![rect(-5.0, -5.0, 5.0, 5.0)])];
    // 5 empty layers, then printer layers 1..=149 (a small square), 150 and 151.
    let mut layers: Vec<Vec<Part>> = vec![Vec::new(); 5];
    layers.extend(std::iter::repeat_n(small, 149));
    layers.push(layer150.clone());
    layers.push(layer151);
    let setup = Setup::new(&layers);
    let frame = setup.write_png("L00150_post_top.png", &render(truth, 150, &layer150, true));
    let points = setup.write_text("points.txt", &points_text(&truth, None, (0.0, 0.0)));
    let out = setup.file("calibration.toml");
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_layerwise"))
            .args(args)
            .output()
            .expect("runs")
    };
    let p = |path: &Path| path.to_str().expect("utf-8").to_string();
    let (vectors, frame, points, out_s) = (p(&setup.vectors), p(&frame), p(&points), p(&out));
    let ok = run(&[
        "register",
        "images",
        "--vectors",
        &vectors,
        "--layer",
        "150",
        "--image",
        &frame,
        "--init",
        &points,
        "--out",
        &out_s,
    ]);
    common::assert_success(&ok);
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        stdout.contains("L00150_post_top.png (layer 150)"),
        "{stdout}"
    );
    let cal = Calibration::load(&out).expect("calibration written");
    assert!(cal.grid.is_none(), "the calibration stores no grid");
    let (mean, max) = contour_error(&layer150, &truth, None, mapping(&cal));
    assert!(mean <= 0.25 && max <= 0.5, "mean {mean} px, max {max} px");

    let raster = |extra: &[&str], name: &str| {
        let png = p(&setup.file(name));
        let mut args = vec!["vectors", "raster", &vectors, "--extent", "--out", &png];
        args.extend_from_slice(extra);
        common::assert_success(&run(&args));
        image::open(&png).expect("png").to_luma8()
    };
    let by_geometry = raster(&["--layer", "150"], "g.png");
    let by_position = raster(&["--layer", "155", "--layer-match", "position"], "p.png");
    let next = raster(&["--layer", "151"], "n.png");
    assert_eq!(by_geometry, by_position);
    assert_ne!(by_geometry, next);
    let none = run(&[
        "vectors",
        "raster",
        &vectors,
        "--layer",
        "152",
        "--out",
        "/dev/null",
    ]);
    let stderr = String::from_utf8_lossy(&none.stderr);
    assert!(
        stderr.contains("no vectors for printer layer 152")
            && stderr.contains("printer layers 1 to 151"),
        "{stderr}"
    );
}

/// The runaway case: three small parts near the plate center, a lens with k1 = −0.3. The
/// contours there cannot tell the distortion from the homography, so `--distortion radial`
/// must not fit it as if they could: it refuses and says what is needed, or its result is no
/// worse than the homography alone.
#[test]
fn a_distortion_the_parts_cannot_show_is_not_fitted() {
    let truth = Homography::oblique_view(W, H);
    let true_d = RadialDistortion {
        center: [0.5 * (f64::from(W) - 1.0), 0.5 * (f64::from(H) - 1.0)],
        focal_px: FOCAL,
        k1: -0.3,
        k2: 0.0,
    };
    let (sn, cs) = 17f64.to_radians().sin_cos();
    let turned = |cx: f64, cy: f64, half: f64| {
        let ring = [(-half, -half), (half, -half), (half, half), (-half, half)]
            .iter()
            .map(|&(dx, dy)| (cx + cs * dx - sn * dy, cy + sn * dx + cs * dy))
            .collect();
        Part::polygon(vec![ring])
    };
    let parts = vec![
        turned(-15.0, 2.0, 4.0),
        turned(14.0, 9.0, 5.0),
        Part::circle(1.0, -14.0, 4.0),
    ];
    let setup = Setup::new(std::slice::from_ref(&parts));
    let frame = setup.write_png(
        "clustered.png",
        &distort_frame(&render(truth, 1, &parts, true), &true_d),
    );
    // Clicks on the parts' corners, a few pixels off.
    let mut text = String::new();
    for (&(x, y), &(du, dv)) in [
        parts[0].rings[0][0],
        parts[0].rings[0][2],
        parts[1].rings[0][1],
        parts[1].rings[0][3],
    ]
    .iter()
    .zip(CLICK_ERRORS.iter())
    {
        let (u, v) = true_pixel(&truth, Some(&true_d), x, y);
        text += &format!("{:.3} {:.3} {x} {y}\n", u + 0.4 * du, v + 0.4 * dv);
    }
    let points = setup.write_text("points.txt", &text);
    let mut request = setup.request(&[(&frame, 1)], &points);
    let plain = register_images(&request).expect("plain");
    let (pm, px) = contour_error(&parts, &truth, Some(&true_d), mapping(&plain.calibration));
    request.distortion = DistortionChoice::Radial {
        focal_px: Some(FOCAL),
    };
    match register_images(&request) {
        Err(e) => {
            let msg = e.to_string();
            eprintln!("radial refused: {msg}");
            assert!(
                msg.contains("cannot tell a lens distortion")
                    && msg.contains("several layers")
                    && msg.contains("--distortion none"),
                "{msg}"
            );
        }
        Ok(radial) => {
            let (rm, rx) =
                contour_error(&parts, &truth, Some(&true_d), mapping(&radial.calibration));
            eprintln!(
                "plain mean {pm:.3} max {px:.3}; radial mean {rm:.3} max {rx:.3}; {:?}",
                radial.calibration.distortion
            );
            assert!(
                rm <= pm + 0.02 && rx <= px + 0.1,
                "radial {rm}/{rx} vs plain {pm}/{px}"
            );
            if let Some(d) = radial.calibration.distortion {
                assert!(d.k1.abs() < 1.0 && d.k2.abs() < 1.0, "{d:?}");
            }
        }
    }
}
