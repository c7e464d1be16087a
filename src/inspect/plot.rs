//! `layerwise inspect --plot OUT.svg`: per-part metrics against layer, one panel per metric, with
//! the layers that raised a flag at warning or above marked.

use crate::build_dir::inspection::{InspectionRecord, PartMetrics, Severity};
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// A panel: its title and the metric it draws.
type Panel = (&'static str, fn(&PartMetrics) -> Option<f64>);

const PANELS: [Panel; 3] = [
    ("fused area / vector area", |m| Some(m.area_ratio)),
    ("post-scan contrast (grey levels)", |m| {
        Some(m.post_contrast)
    }),
    ("pre-scan grey level over the part", |m| m.pre_mean),
];

const COLOURS: [&str; 6] = [
    "#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf",
];

/// The SVG text.
pub fn svg(records: &[InspectionRecord]) -> String {
    let (w, ph, left, top) = (960.0, 220.0, 70.0, 30.0);
    let h = top + PANELS.len() as f64 * (ph + 40.0) + 20.0;
    let layers: Vec<u32> = records.iter().map(|r| r.layer).collect();
    let (l0, l1) = (
        layers.iter().copied().min().unwrap_or(1),
        layers
            .iter()
            .copied()
            .max()
            .unwrap_or(1)
            .max(layers.first().copied().unwrap_or(1) + 1),
    );
    let x_of = |l: u32| left + (f64::from(l - l0) / f64::from(l1 - l0)) * (w - left - 20.0);
    let mut out = String::new();
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="11">"#
    );
    let _ = writeln!(
        out,
        r#"<text x="{left}" y="16" font-size="13">Inspection: per-part metrics by layer; red: a flag at warning or above</text>"#
    );
    for (k, (title, metric)) in PANELS.iter().enumerate() {
        let y0 = top + k as f64 * (ph + 40.0) + 20.0;
        let mut series: BTreeMap<i64, Vec<(u32, f64)>> = BTreeMap::new();
        for r in records {
            for m in &r.parts {
                if let Some(v) = metric(m).filter(|v| v.is_finite()) {
                    series.entry(m.part).or_default().push((r.layer, v));
                }
            }
        }
        let values = series.values().flatten().map(|(_, v)| *v);
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
        let (lo, hi) = if lo.is_finite() && hi > lo {
            (lo, hi)
        } else {
            (0.0, 1.0)
        };
        let y_of = |v: f64| y0 + ph - (v - lo) / (hi - lo) * ph;
        let _ = writeln!(
            out,
            r##"<rect x="{left}" y="{y0}" width="{}" height="{ph}" fill="none" stroke="#999"/><text x="{left}" y="{}">{title}</text><text x="4" y="{}">{hi:.2}</text><text x="4" y="{}">{lo:.2}</text>"##,
            w - left - 20.0,
            y0 - 4.0,
            y0 + 10.0,
            y0 + ph
        );
        for r in records {
            if r.flags.iter().any(|f| f.severity >= Severity::Warning) {
                let x = x_of(r.layer);
                let _ = writeln!(
                    out,
                    r#"<line x1="{x:.1}" y1="{y0}" x2="{x:.1}" y2="{}" stroke="red" stroke-opacity="0.5"><title>layer {}</title></line>"#,
                    y0 + ph,
                    r.layer
                );
            }
        }
        for (i, (part, points)) in series.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let path: Vec<String> = points
                .iter()
                .map(|(l, v)| format!("{:.1},{:.1}", x_of(*l), y_of(*v)))
                .collect();
            let _ = writeln!(
                out,
                r#"<polyline fill="none" stroke="{colour}" points="{}"><title>part {part}</title></polyline><text x="{}" y="{}" fill="{colour}">part {part}</text>"#,
                path.join(" "),
                w - 70.0,
                y0 + 14.0 + 12.0 * i as f64
            );
        }
        let _ = writeln!(
            out,
            r#"<text x="{left}" y="{}">layer {l0}</text><text x="{}" y="{}" text-anchor="end">layer {l1}</text>"#,
            y0 + ph + 14.0,
            w - 20.0,
            y0 + ph + 14.0
        );
    }
    out.push_str("</svg>\n");
    out
}
