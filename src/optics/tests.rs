//! Values worked by hand from equations 1-4 for the paper's setup (45 mm at f/32, 4.88 µm
//! pixels, 30° off-normal, 275 mm plate), plus geometric checks of the Scheimpflug relations.

use super::*;

fn close(got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "got {got}, want {want} ± {tol} (off by {})",
        got - want
    );
}

fn paper(s: f64) -> OpticsReport {
    plan(&OpticsInput::paper_setup(s)).expect("the paper's setup plans")
}

// Shared by every distance:
//   D = f / N = 45 / 32 = 1.40625 mm, d = 4.88 µm = 0.00488 mm
//   D f / d = 1.40625 * 45 / 0.00488 = 63.28125 / 0.00488 = 12967.469 mm
//   H = D f / d + f = 12967.469 + 45 = 13012.469 mm  (eq. 2)
//   (the brief's 12,967.6 left out the + f)
//   so H - f = 12967.469, and the plate half-length projects to 137.5 sin 30° = 68.75 mm.
const DF_OVER_D: f64 = 12_967.469;

#[test]
fn hand_values_at_500_mm() {
    let r = paper(500.0);
    close(r.aperture_mm, 1.40625, 1e-12);
    close(r.hyperfocal_mm, DF_OVER_D + 45.0, 1e-3);
    // eq. 1: M = 45 / (500 - 45) = 45 / 455 = 0.0989011
    close(r.magnification, 0.098_901_1, 1e-7);
    // v = s M = 500 * 0.0989011 = 49.4505 mm
    close(r.image_distance_mm, 49.4505, 1e-4);
    // center: 4.88 / 0.0989011 = 4.88 * 455 / 45 = 49.3422 µm
    close(r.resolution_center_um, 49.3422, 1e-4);
    // edges at 500 ∓ 68.75 = 431.25 / 568.75 mm along the axis
    close(r.plate_near_edge_mm, 431.25, 1e-9);
    close(r.plate_far_edge_mm, 568.75, 1e-9);
    // near: 4.88 * (431.25 - 45) / 45 = 4.88 * 386.25 / 45 = 41.8867 µm
    close(r.resolution_near_um, 41.8867, 1e-4);
    // far: 4.88 * (568.75 - 45) / 45 = 4.88 * 523.75 / 45 = 56.7978 µm
    close(r.resolution_far_um, 56.7978, 1e-4);
    // eq. 3: 500 * 12967.469 / (13012.469 + 500 - 90) = 500 * 12967.469 / 13422.469
    //      = 500 * (1 - 455 / 13422.469) = 500 * 0.966101 = 483.05 mm
    close(r.near_mm, 483.05, 0.01);
    // eq. 4: 500 * 12967.469 / (13012.469 - 500) = 500 * 12967.469 / 12512.469
    //      = 500 * (1 + 455 / 12512.469) = 500 * 1.036364 = 518.18 mm
    close(r.far_mm.expect("500 < H"), 518.18, 0.01);
    // 431.25 < 483.05 and 568.75 > 518.18: both edges fall outside, as in the paper's fig. 3.
    assert!(!r.plate_in_focus_without_tilt);
    // tan α = M tan 30° = 0.0989011 * 0.577350 = 0.0571006 → α = 3.2681°
    close(r.scheimpflug_tilt_deg, 3.2681, 1e-4);
    // J = f / sin α = 45 / sin 3.2681° = 45 / 0.0570077 = 789.37 mm
    close(r.hinge_distance_mm.expect("tilted"), 789.37, 0.01);
    // S: s cot 30° = 500 * 1.732051 = 866.03 mm along the lens plane
    close(r.scheimpflug_line_mm.expect("tilted"), 866.03, 0.01);
    // sensor 7360 x 4.88 µm = 35.9168 mm, 4912 x 4.88 µm = 23.9706 mm; / M (x 455/45):
    // 363.159 x 242.369 mm
    close(r.field_of_view_mm.0, 363.159, 1e-3);
    close(r.field_of_view_mm.1, 242.369, 1e-3);
    // The near half of the plate images 13.6 mm off center (> 23.97 / 2): it does not fit.
    assert!(!r.plate_fits_in_view);
    // Airy: 2.44 * 0.55 * 32 = 42.944 µm, about 8.8 pixels.
    close(r.diffraction_blur_um, 42.944, 1e-9);
    assert!(r.diffraction_limited);
}

#[test]
fn hand_values_at_600_mm() {
    let r = paper(600.0);
    // M = 45 / 555 = 0.0810811; center 4.88 * 555 / 45 = 60.1867 µm
    close(r.magnification, 0.081_081_1, 1e-7);
    close(r.resolution_center_um, 60.1867, 1e-4);
    // edges 531.25 / 668.75 mm: 4.88 * 486.25 / 45 = 52.7311, 4.88 * 623.75 / 45 = 67.6422 µm
    close(r.resolution_near_um, 52.7311, 1e-4);
    close(r.resolution_far_um, 67.6422, 1e-4);
    // eq. 3: 600 * 12967.469 / (12967.469 + 555) = 600 * (1 - 555 / 13522.469) = 575.37 mm
    close(r.near_mm, 575.37, 0.01);
    // eq. 4: 600 * 12967.469 / (12967.469 - 555) = 600 * (1 + 555 / 12412.469) = 626.83 mm
    close(r.far_mm.expect("600 < H"), 626.83, 0.01);
    assert!(!r.plate_in_focus_without_tilt);
    // tan α = 0.0810811 * 0.577350 = 0.0468122 → α = 2.6802°; J = 45 / 0.0467610 = 962.34 mm
    close(r.scheimpflug_tilt_deg, 2.6802, 1e-4);
    close(r.hinge_distance_mm.expect("tilted"), 962.34, 0.01);
}

#[test]
fn paper_resolution_of_62_5_um_is_about_621_mm_away() {
    // 4.88 / M = 62.5 → M = 0.07808 → s = f / M + f = 576.33 + 45 = 621.33 mm
    let r = paper(621.3);
    close(r.resolution_center_um, 62.5, 0.1);
    // At that stand-off the plate just fits on the sensor once the lens is tilted.
    assert!(r.plate_fits_in_view);
    assert!(!r.plate_in_focus_without_tilt);
}

#[test]
fn far_limit_is_infinite_beyond_the_hyperfocal_distance() {
    let beyond = paper(20_000.0);
    assert_eq!(beyond.far_mm, None);
    let json = serde_json::to_value(&beyond).expect("serializes");
    assert!(json["far_mm"].is_null());
    // Exactly at H, eq. 4 divides by zero: reported as infinite too.
    let h = paper(500.0).hyperfocal_mm;
    assert_eq!(paper(h).far_mm, None);
    assert!(paper(h - 1.0).far_mm.is_some());
}

/// Intersection of the lines `a + λ u` and `b + μ w`.
fn meet(a: [f64; 2], u: [f64; 2], b: [f64; 2], w: [f64; 2]) -> [f64; 2] {
    let det = u[0] * (-w[1]) - u[1] * (-w[0]);
    let rhs = [b[0] - a[0], b[1] - a[1]];
    let lambda = (rhs[0] * (-w[1]) - rhs[1] * (-w[0])) / det;
    [a[0] + lambda * u[0], a[1] + lambda * u[1]]
}

#[test]
fn image_lens_and_focus_planes_meet_in_one_line() {
    for (s, angle) in [(500.0, 30.0), (621.3, 30.0), (300.0, 60.0), (1000.0, 5.0)] {
        let input = OpticsInput {
            angle_deg: angle,
            ..OpticsInput::paper_setup(s)
        };
        let r = plan(&input).expect("plans");
        let view = SideView::new(&input);
        let theta = f64::to_radians(angle);
        let alpha = r.scheimpflug_tilt_deg.to_radians();
        // Built independently of the module: the lens plane is z = 0; the plate passes through
        // (0, s) at θ to it; the image plane passes through (0, -v) at α to it, turned the
        // opposite way (the image is inverted).
        let v = s * 45.0 / (s - 45.0);
        let lens = ([0.0, 0.0], [1.0, 0.0]);
        let plate = ([0.0, s], [theta.cos(), theta.sin()]);
        let image = ([0.0, -v], [alpha.cos(), -alpha.sin()]);
        let a = meet(lens.0, lens.1, plate.0, plate.1);
        let b = meet(lens.0, lens.1, image.0, image.1);
        let scale = s / theta.tan();
        close(a[0], b[0], 1e-9 * scale);
        close(a[1], 0.0, 1e-9);
        close(-a[0], r.scheimpflug_line_mm.expect("tilted"), 1e-9 * scale);
        // And every plate point images onto that image plane (thin lens, 1/u + 1/v = 1/f).
        for t in [-137.5, -60.0, 0.0, 80.0, 137.5] {
            let p = view.plate_point(t);
            let q = view.image_of(p);
            let off = (q[0] - image.0[0]) * (-image.1[1]) + (q[1] - image.0[1]) * image.1[0];
            close(off, 0.0, 1e-9 * v);
            // Gaussian lens equation along the axis for the point's own depth.
            close(1.0 / p[1] + 1.0 / -q[1], 1.0 / 45.0, 1e-12);
        }
    }
}

#[test]
fn hinge_line_lies_on_focus_front_focal_and_parallel_to_film_planes() {
    let input = OpticsInput::paper_setup(500.0);
    let r = plan(&input).expect("plans");
    let view = SideView::new(&input);
    let p = view.hinge_point().expect("tilted");
    // On the front focal plane z = f.
    close(p[1], 45.0, 1e-12);
    // On the plane of focus (the plate line through (0, s) at 30°).
    let theta = 30f64.to_radians();
    close((p[1] - 500.0) * theta.cos() - p[0] * theta.sin(), 0.0, 1e-9);
    // On the plane through the lens center parallel to the image plane, at J from the center.
    let e = view.image_plane_dir();
    close(p[0] * e[1] - p[1] * e[0], 0.0, 1e-9);
    close(p[0].hypot(p[1]), r.hinge_distance_mm.expect("tilted"), 1e-9);
}

/// Blur width on the tilted image plane (in the tilt plane) of an object point, traced through
/// the edges of the aperture: the exact thin-lens version of the circle of confusion.
fn blur_on_tilted_sensor(view: &SideView, aperture: f64, x: [f64; 2]) -> f64 {
    let image = view.image_of(x);
    let e = view.image_plane_dir();
    let normal = [-e[1], e[0]];
    let c = normal[1] * -view.v();
    let hit = |a: f64| {
        let dir = [image[0] - a, image[1]];
        let lambda = (c - normal[0] * a) / (normal[0] * dir[0] + normal[1] * dir[1]);
        let y = [a + lambda * dir[0], lambda * dir[1]];
        y[0] * e[0] + y[1] * e[1]
    };
    (hit(aperture / 2.0) - hit(-aperture / 2.0)).abs()
}

#[test]
fn tilted_depth_of_field_wedge_matches_a_ray_trace() {
    // Points on the wedge planes through P and the axial limits of eq. 3 and 4 should blur by
    // one pixel on the tilted sensor.
    let input = OpticsInput::paper_setup(500.0);
    let r = plan(&input).expect("plans");
    let view = SideView::new(&input);
    let hinge = view.hinge_point().expect("tilted");
    for limit in [r.near_mm, r.far_mm.expect("finite")] {
        for z in [430.0, 480.0, 520.0, 570.0] {
            let k = (z - hinge[1]) / (limit - hinge[1]);
            let point = [hinge[0] + k * (0.0 - hinge[0]), z];
            let blur = blur_on_tilted_sensor(&view, r.aperture_mm, point);
            // The exact limits bend slightly with the ray's obliquity: 0.986 to 1.022 pixels
            // over the plate's depth range at s = 500.
            close(blur / 0.00488, 1.0, 0.025);
        }
    }
    // And the plate itself is sharp everywhere.
    for t in [-137.5, 0.0, 137.5] {
        close(
            blur_on_tilted_sensor(&view, r.aperture_mm, view.plate_point(t)),
            0.0,
            1e-9,
        );
    }
}

#[test]
fn foreshortened_resolution_matches_the_image_mapping() {
    let input = OpticsInput::paper_setup(500.0);
    let r = plan(&input).expect("plans");
    let view = SideView::new(&input);
    for (t, want) in [
        (0.0, r.resolution_along_center_um),
        (-137.5, r.resolution_along_near_um),
        (137.5, r.resolution_along_far_um),
    ] {
        // Central difference of the image position along the tilted image plane.
        let h = 1e-3;
        let a = view.image_of(view.plate_point(t - h));
        let b = view.image_of(view.plate_point(t + h));
        let scale = (b[0] - a[0]).hypot(b[1] - a[1]) / (2.0 * h);
        close(4.88 / scale, want, 1e-5);
    }
    // At the center this is d / (M sqrt(cos² θ + M² sin² θ)) ≈ d / (M cos θ):
    // 49.3422 / sqrt(0.75 + 0.0097812 * 0.25) = 49.3422 / 0.867434 = 56.883 µm
    close(r.resolution_along_center_um, 56.883, 1e-3);
    // Near edge 40.99 µm, far edge 75.37 µm: (z - f)² grows faster than across.
    close(r.resolution_along_near_um, 40.992, 1e-3);
    close(r.resolution_along_far_um, 75.371, 1e-3);
}

#[test]
fn plate_perpendicular_to_the_axis_needs_no_tilt() {
    let input = OpticsInput {
        angle_deg: 0.0,
        ..OpticsInput::paper_setup(500.0)
    };
    let r = plan(&input).expect("plans");
    assert_eq!(r.scheimpflug_tilt_deg, 0.0);
    assert_eq!(r.hinge_distance_mm, None);
    assert_eq!(r.scheimpflug_line_mm, None);
    assert!(r.plate_in_focus_without_tilt);
    assert_eq!(r.resolution_near_um, r.resolution_center_um);
    let svg = plot_svg(&input, &r);
    check_well_formed(&svg);
    assert!(!svg.contains("NaN") && !svg.contains("inf"));
}

#[test]
fn bad_inputs_are_refused_with_clear_errors() {
    let base = OpticsInput::paper_setup(500.0);
    let refused = |input: OpticsInput| plan(&input).expect_err("refused");
    assert_eq!(
        refused(OpticsInput {
            distance_mm: 45.0,
            ..base.clone()
        }),
        OpticsError::DistanceWithinFocalLength {
            distance_mm: 45.0,
            focal_mm: 45.0
        }
    );
    assert!(matches!(
        refused(OpticsInput {
            focal_mm: -45.0,
            ..base.clone()
        }),
        OpticsError::NotPositive {
            name: "focal length",
            ..
        }
    ));
    for (name, input) in [
        (
            "f-number",
            OpticsInput {
                f_number: 0.0,
                ..base.clone()
            },
        ),
        (
            "pixel pitch",
            OpticsInput {
                pixel_um: f64::NAN,
                ..base.clone()
            },
        ),
        (
            "object distance",
            OpticsInput {
                distance_mm: f64::INFINITY,
                ..base.clone()
            },
        ),
        (
            "plate size",
            OpticsInput {
                plate_mm: -1.0,
                ..base.clone()
            },
        ),
    ] {
        match refused(input) {
            OpticsError::NotPositive { name: got, .. } => assert_eq!(got, name),
            other => panic!("{name}: {other}"),
        }
    }
    for angle in [-1.0, 89.5, 90.0, f64::NAN] {
        assert!(matches!(
            refused(OpticsInput {
                angle_deg: angle,
                ..base.clone()
            }),
            OpticsError::Angle(_)
        ));
    }
    assert!(plan(&OpticsInput {
        angle_deg: 89.0,
        distance_mm: 1000.0,
        ..base.clone()
    })
    .is_ok());
    assert!(matches!(
        refused(OpticsInput {
            sensor_px: (0, 4912),
            ..base.clone()
        }),
        OpticsError::Sensor(_)
    ));
    // 100 - 68.75 = 31.25 mm < f: the near edge would sit inside the focal length.
    let err = refused(OpticsInput {
        distance_mm: 100.0,
        ..base
    });
    assert!(matches!(err, OpticsError::PlateWithinFocalLength { .. }));
    assert!(err.to_string().contains("focal length 45 mm"), "{err}");
}

#[test]
fn sensor_sizes_parse() {
    assert_eq!(parse_sensor("7360x4912"), Ok((7360, 4912)));
    assert_eq!(parse_sensor(" 7360 X 4912 "), Ok((7360, 4912)));
    assert_eq!(parse_sensor("7360×4912"), Ok((7360, 4912)));
    for bad in [
        "",
        "7360",
        "7360x",
        "x4912",
        "0x4912",
        "7360x-1",
        "7.5x3",
        "7360x4912x3",
    ] {
        assert_eq!(
            parse_sensor(bad),
            Err(OpticsError::Sensor(bad.to_string())),
            "{bad:?}"
        );
    }
}

#[test]
fn json_has_the_documented_keys() {
    let json = serde_json::to_value(paper(500.0)).expect("serializes");
    let keys: Vec<&str> = json
        .as_object()
        .expect("an object")
        .keys()
        .map(String::as_str)
        .collect();
    let mut want = vec![
        "magnification",
        "image_distance_mm",
        "aperture_mm",
        "resolution_center_um",
        "resolution_near_um",
        "resolution_far_um",
        "resolution_along_center_um",
        "resolution_along_near_um",
        "resolution_along_far_um",
        "hyperfocal_mm",
        "near_mm",
        "far_mm",
        "plate_near_edge_mm",
        "plate_far_edge_mm",
        "plate_in_focus_without_tilt",
        "scheimpflug_tilt_deg",
        "scheimpflug_line_mm",
        "hinge_distance_mm",
        "field_of_view_mm",
        "plate_image_mm",
        "plate_fits_in_view",
        "diffraction_blur_um",
        "diffraction_limited",
    ];
    want.sort_unstable();
    let mut keys = keys;
    keys.sort_unstable();
    assert_eq!(keys, want);
    assert_eq!(json["plate_in_focus_without_tilt"], false);
    assert!(json["field_of_view_mm"].is_array());
    // The input round-trips, so a saved plan can be re-run.
    let input = OpticsInput::paper_setup(500.0);
    let text = serde_json::to_string(&input).expect("serializes");
    assert_eq!(
        serde_json::from_str::<OpticsInput>(&text).expect("parses"),
        input
    );
}

#[test]
fn display_reads_with_units() {
    let text = paper(500.0).to_string();
    for want in [
        "0.098901",
        "49.34 µm/px",
        "13012.5 mm",
        "483.1 mm to 518.2 mm",
        "in focus without tilt  no",
        "3.268°",
        "789.4 mm",
        "does not fit",
        "diffraction-limited",
    ] {
        assert!(text.contains(want), "{want:?} missing from\n{text}");
    }
    assert!(paper(20_000.0).to_string().contains("to infinity"));
}

/// Balanced tags: every opened element is closed in order, nothing but the one root.
fn check_well_formed(svg: &str) {
    assert!(svg.starts_with("<svg "), "{}", &svg[..40.min(svg.len())]);
    let mut stack: Vec<String> = Vec::new();
    let mut roots = 0;
    let mut rest = svg;
    while let Some(open) = rest.find('<') {
        let text = &rest[..open];
        assert!(!text.contains('>'), "stray '>' in {text:?}");
        for (i, _) in text.match_indices('&') {
            let entity = &text[i..];
            assert!(
                ["&amp;", "&lt;", "&gt;"]
                    .iter()
                    .any(|e| entity.starts_with(e)),
                "bare & in {text:?}"
            );
        }
        let close = rest[open..].find('>').expect("unterminated tag") + open;
        let tag = &rest[open + 1..close];
        assert!(!tag.contains('<'), "nested '<' in {tag:?}");
        if let Some(name) = tag.strip_prefix('/') {
            assert_eq!(
                stack.pop().as_deref(),
                Some(name.trim()),
                "mismatched </{name}>"
            );
        } else {
            if stack.is_empty() {
                roots += 1;
            }
            if !tag.ends_with('/') {
                let name = tag.split_whitespace().next().unwrap_or_default();
                stack.push(name.to_string());
            }
        }
        assert_eq!(
            tag.matches('"').count() % 2,
            0,
            "unbalanced quotes in {tag:?}"
        );
        rest = &rest[close + 1..];
    }
    assert!(stack.is_empty(), "unclosed {stack:?}");
    assert_eq!(roots, 1);
    assert!(rest.trim().is_empty());
}

#[test]
fn svg_draws_both_figures() {
    for s in [500.0, 621.3, 20_000.0] {
        let input = OpticsInput::paper_setup(s);
        let svg = plot_svg(&input, &plan(&input).expect("plans"));
        check_well_formed(&svg);
        for want in [
            "Fig. 3: no tilt",
            "Fig. 4: Scheimpflug tilt α = ",
            "D_near",
            "D_far",
            "optical axis",
            "lens",
            "image plane",
            "build plate 275 mm",
            "plane of focus",
        ] {
            assert!(svg.contains(want), "s = {s}: {want:?} missing");
        }
        assert!(!svg.contains("NaN") && !svg.contains("inf\""), "s = {s}");
    }
    let svg = plot_svg(&OpticsInput::paper_setup(500.0), &paper(500.0));
    assert!(svg.contains("P (hinge line)") && svg.contains("S (Scheimpflug line)"));
    assert!(svg.contains("D_far 518.2 mm"));
    assert_eq!(svg.matches("<polygon").count(), 2, "slab and wedge");
}
