//! Detectors on synthetic views: powder noise, metal speckle and each anomaly drawn directly on
//! a 100 x 100 mm grid at 0.5 mm.

use super::*;
use crate::config::inspection::{Axis, InspectionConfig};

const N: usize = 200;

fn grid() -> Grid {
    Grid {
        x_min: -50.0,
        x_max: 50.0,
        y_min: -50.0,
        y_max: 50.0,
        pixel_mm: 0.5,
    }
}

/// Deterministic noise in [-1, 1).
fn noise(seed: u64, i: usize) -> f64 {
    let mut z = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (i as u64).wrapping_mul(0xBF58_476D);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f64 / (1u64 << 23) as f64 - 1.0
}

/// A view: powder 110 ± 8 with a gentle gradient, `metal` cells speckled 100 ± 45, then `paint`.
fn view(seed: u64, metal: &dyn Fn(f64, f64) -> bool, paint: &dyn Fn(f64, f64) -> f64) -> Cells {
    let g = grid();
    let px: Vec<u8> = (0..N * N)
        .map(|i| {
            let (x, y) = g.center_of((i / N) as f64, (i % N) as f64);
            let v = if metal(x, y) {
                100.0 + 45.0 * noise(seed ^ 77, i)
            } else {
                110.0 * (1.0 - 0.001 * y) + 8.0 * noise(seed, i)
            };
            (v + paint(x, y)).round().clamp(0.0, 255.0) as u8
        })
        .collect();
    Cells::from_samples(&px, N, N, &g, 1, 1.0)
}

fn clean(seed: u64) -> Cells {
    view(seed, &|_, _| false, &|_, _| 0.0)
}

fn all_valid() -> Mask {
    Mask {
        rows: N,
        cols: N,
        on: vec![true; N * N],
    }
}

fn cfg() -> InspectionConfig {
    InspectionConfig::default()
}

fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> impl Fn(f64, f64) -> bool {
    move |x, y| x >= x0 && x <= x1 && y >= y0 && y <= y1
}

fn part_mask(f: &dyn Fn(f64, f64) -> bool) -> Mask {
    let g = grid();
    Mask {
        rows: N,
        cols: N,
        on: (0..N * N)
            .map(|i| {
                let (x, y) = g.center_of((i / N) as f64, (i % N) as f64);
                f(x, y)
            })
            .collect(),
    }
}

#[test]
fn a_partial_streak_is_found_where_it_is_and_clean_powder_is_quiet() {
    let (g, c) = (grid(), cfg());
    for seed in 0..5 {
        let (none, _) = streak::streaks(&g, &clean(seed).mean, &all_valid(), Axis::X, &c);
        assert!(none.is_empty(), "seed {seed}: {none:?}");
    }
    let band = rect(-30.0, 12.0, 45.0, 13.0);
    let cells = view(3, &|_, _| false, &|x, y| if band(x, y) { 8.0 } else { 0.0 });
    let (found, best) = streak::streaks(&g, &cells.mean, &all_valid(), Axis::X, &c);
    assert_eq!(found.len(), 1, "{found:?}");
    let [x0, y0, x1, y1] = detect::box_mm(&g, found[0].cells);
    assert!(
        (y0 - 12.0).abs() <= 0.5 && (y1 - 13.0).abs() <= 0.5,
        "{y0} {y1}"
    );
    // Found per 33 mm segment: the streak's segments, not the plate's whole width.
    assert!((-50.0..=-17.0).contains(&x0) && x1 >= 40.0, "{x0} {x1}");
    assert!(found[0].score >= c.streak_z && best >= found[0].score);
    assert!(
        found[0].message.contains("at y = 12.5 mm"),
        "{}",
        found[0].message
    );
}

#[test]
fn a_short_fed_band_stands_out_against_earlier_layers() {
    let (g, c) = (grid(), cfg());
    let valid = all_valid();
    let earlier: Vec<detect::Profile> = (0..4)
        .map(|s| detect::profile(&clean(s), &valid, Axis::X))
        .collect();
    let quiet = detect::profile(&clean(9), &valid, Axis::X);
    let (none, _) = detect::short_feed(&g, &valid, &quiet, &earlier, Axis::X, &c).unwrap();
    assert!(none.is_empty(), "{none:?}");
    assert!(detect::short_feed(&g, &valid, &quiet, &earlier[..2], Axis::X, &c).is_none());
    let short = view(9, &|_, _| false, &|x, _| if x > 30.0 { -8.0 } else { 0.0 });
    let now = detect::profile(&short, &valid, Axis::X);
    let (found, _) = detect::short_feed(&g, &valid, &now, &earlier, Axis::X, &c).unwrap();
    assert_eq!(found.len(), 1, "{found:?}");
    let [x0, _, x1, _] = detect::box_mm(&g, found[0].cells);
    assert!((x0 - 30.0).abs() <= 1.0 && x1 >= 49.0, "{x0} {x1}");
}

#[test]
fn a_raised_edge_over_the_previous_footprint_is_elevation() {
    let (g, c) = (grid(), cfg());
    let foot = rect(-10.0, -6.0, 10.0, 6.0);
    let parts = vec![(7, part_mask(&foot))];
    let all = parts[0].1.clone();
    let (none, means) = detect::elevation(&g, &clean(1), &all_valid(), &parts, &all, &c);
    assert!(none.is_empty(), "{none:?}");
    assert_eq!(means.len(), 1);
    let edge = rect(-10.0, -6.0, -8.0, 6.0);
    let raised = view(1, &|_, _| false, &|x, y| {
        if edge(x, y) {
            12.0
        } else {
            0.0
        }
    });
    let (found, _) = detect::elevation(&g, &raised, &all_valid(), &parts, &all, &c);
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0].part, Some(7));
    let [x0, _, x1, _] = detect::box_mm(&g, found[0].cells);
    assert!(x0 >= -11.5 && x1 <= -6.5, "{x0} {x1}");
}

#[test]
fn fusion_finds_unfused_wide_and_stray_metal_and_passes_a_good_layer() {
    let (g, c) = (grid(), cfg());
    let a = rect(-30.0, -10.0, -10.0, 10.0);
    let b = rect(10.0, -5.0, 30.0, 5.0);
    let parts = vec![(1, part_mask(&a)), (2, part_mask(&b))];
    let all = parts[0].1.or(&parts[1].1);
    let good = view(2, &|x, y| a(x, y) || b(x, y), &|_, _| 0.0);
    let f = detect::fusion(&g, &good, &all_valid(), &parts, &all, &c);
    assert!(f.found.is_empty(), "{:?}", f.found);
    assert!(
        f.parts.iter().all(|m| m.iou > 0.85 && m.area_ratio > 0.9),
        "{:?}",
        f.parts
    );

    let wide_b = rect(8.0, -7.0, 32.0, 7.0);
    let bad = view(
        2,
        &|x, y| wide_b(x, y) || ((x - 0.0).powi(2) + (y - 35.0).powi(2)) < 1.0,
        &|_, _| 0.0,
    );
    let f = detect::fusion(&g, &bad, &all_valid(), &parts, &all, &c);
    let kinds: Vec<(FlagKind, Option<i64>)> = f.found.iter().map(|x| (x.kind, x.part)).collect();
    assert_eq!(
        kinds,
        vec![
            (FlagKind::UnderFusion, Some(1)),
            (FlagKind::OverFusion, Some(2)),
            (FlagKind::Spatter, None)
        ],
        "{:?}",
        f.found
    );
    assert!(f.found[0].score > 0.9 && f.found[0].message.contains("not fused"));
    let [x0, y0, x1, y1] = detect::box_mm(&g, f.found[2].cells);
    assert!(x0 > -2.0 && x1 < 2.0 && y0 > 33.0 && y1 < 37.0);
}

#[test]
fn the_inspector_waits_for_its_views_and_inspects_layers_in_order() {
    let c = cfg();
    let views = crate::config::ViewsConfig::default().all();
    let mut inspector = Inspector::new(&c, grid(), &views, None);
    let at = chrono::DateTime::from_timestamp(0, 0).unwrap();
    let pre = View {
        phase: Phase::Pre,
        light: c.pre_light,
    };
    let side = View {
        phase: Phase::Pre,
        light: c.elevation_light,
    };
    let post = View {
        phase: Phase::Post,
        light: c.post_light,
    };
    assert!(inspector.needs(pre) && inspector.needs(side) && inspector.needs(post));
    assert!(inspector.add(1, pre, clean(1), at).is_empty());
    assert!(inspector.add(2, pre, clean(2), at).is_empty());
    assert!(inspector.add(2, side, clean(3), at).is_empty());
    let done = inspector.add(2, post, clean(4), at);
    // Layer 1 never got its other views: inspected with what it has, before layer 2.
    assert_eq!(done.iter().map(|r| r.layer).collect::<Vec<_>>(), vec![1, 2]);
    assert_eq!(done[0].views, vec!["pre_top".to_string()]);
    assert!(done.iter().all(|r| r.flags.is_empty()), "{done:?}");
    assert!(
        inspector.add(2, pre, clean(5), at).is_empty(),
        "done layers stay done"
    );
    // The first layers are the bed's baseline; a streak that appears after them is flagged,
    // and the same streak on the next layer persists.
    inspector.add(3, pre, clean(6), at);
    let band = rect(-30.0, 12.0, 45.0, 13.0);
    let streaked = |seed| {
        view(seed, &|_, _| false, &|x, y| {
            if band(x, y) {
                6.0
            } else {
                0.0
            }
        })
    };
    inspector.add(4, pre, streaked(7), at);
    inspector.add(5, pre, streaked(8), at);
    let last = inspector.flush(at);
    assert_eq!(last.len(), 3);
    assert!(last[0].flags.is_empty(), "{:?}", last[0].flags);
    assert_eq!(last[1].flags.len(), 1, "{:?}", last[1].flags);
    assert_eq!(last[2].flags.len(), 1, "{:?}", last[2].flags);
    assert_eq!(last[2].flags[0].since, Some(4));
    let flag = &last[1].flags[0];
    assert_eq!(flag.kind, FlagKind::Streak);
    assert_eq!(flag.view, "pre_top");
    assert!(describe(4, flag).starts_with("layer 4: recoater streak across x = "));
    // Grid pixels of the series grid: rows of y = 12..13 mm.
    assert!(
        flag.bbox_px[1] >= 72 && flag.bbox_px[3] <= 77,
        "{:?}",
        flag.bbox_px
    );
}

#[test]
fn a_layer_completed_by_a_faster_lane_waits_for_the_earlier_layers_views_in_flight() {
    let c = cfg();
    let views = crate::config::ViewsConfig::default().all();
    let at = chrono::DateTime::from_timestamp(0, 0).unwrap();
    let needed = [
        View {
            phase: Phase::Pre,
            light: c.pre_light,
        },
        View {
            phase: Phase::Pre,
            light: c.elevation_light,
        },
        View {
            phase: Phase::Post,
            light: c.post_light,
        },
    ];
    let [pre, side, post] = needed;
    let layers = |records: &[InspectionRecord]| records.iter().map(|r| r.layer).collect::<Vec<_>>();
    for lands in [true, false] {
        let mut inspector = Inspector::new(&c, grid(), &views, None);
        assert!(inspector.add(1, pre, clean(1), at).is_empty());
        assert!(inspector.add(1, side, clean(2), at).is_empty());
        // Layer 1's last view is on one lane while other lanes finish all of layer 2's.
        let late = inspector
            .begin(1, post)
            .expect("a view the inspection takes");
        let early: Vec<InFlight> = needed
            .iter()
            .map(|v| inspector.begin(2, *v).unwrap())
            .collect();
        for (i, f) in early.into_iter().enumerate() {
            let got = inspector.land(f, clean(3 + i as u64), at);
            assert!(
                got.is_empty(),
                "layer 2 went before layer 1: {:?}",
                layers(&got)
            );
        }
        let done = if lands {
            inspector.land(late, clean(9), at)
        } else {
            inspector.give_up(late, at)
        };
        assert_eq!(layers(&done), vec![1, 2]);
        let expected = if lands { 3 } else { 2 };
        assert_eq!(done[0].views.len(), expected, "{:?}", done[0].views);
        assert_eq!(done[1].views.len(), 3);
        // Nothing is held back any more: the next layer goes as soon as its views are in.
        for (i, v) in needed.iter().enumerate() {
            let got = inspector.add(3, *v, clean(10 + i as u64), at);
            assert_eq!(layers(&got), if i == 2 { vec![3] } else { vec![] });
        }
        // A done layer's view is not taken, so it holds nothing back.
        assert!(inspector.begin(1, post).is_none());
    }
}
