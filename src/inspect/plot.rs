//! `layerwise inspect --plot OUT.svg|OUT.png`: per-part metrics against layer, one panel per
//! metric, with the layers that raised a flag at warning or above marked in red. One layout drawn
//! on two canvases: SVG text, or pixels encoded as PNG (its labels in the 5 x 7 bitmap font of
//! [`crate::raster::sheet`]).

use crate::build_dir::inspection::{FlagKind, InspectionRecord, PartMetrics, Severity};
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

const COLOURS: [[u8; 3]; 6] = [
    [0x1f, 0x77, 0xb4],
    [0x2c, 0xa0, 0x2c],
    [0x94, 0x67, 0xbd],
    [0x8c, 0x56, 0x4b],
    [0xe3, 0x77, 0xc2],
    [0x17, 0xbe, 0xcf],
];
/// The colour of a flagged layer's mark.
pub const FLAG: [u8; 3] = [0xff, 0x00, 0x00];
const FRAME: [u8; 3] = [0x99, 0x99, 0x99];
const INK: [u8; 3] = [0, 0, 0];

/// Size of the drawing and of its panels, in pixels.
const WIDTH: f64 = 960.0;
const PANEL_HEIGHT: f64 = 220.0;
const LEFT: f64 = 70.0;
const TOP: f64 = 30.0;
const RIGHT: f64 = 20.0;

/// Where a label sits against its `x`.
#[derive(Clone, Copy, PartialEq)]
enum Anchor {
    Start,
    Middle,
    End,
}

/// The letter marking a flag of `kind` above a flagged layer's mark, as the legend explains.
pub fn kind_letter(kind: FlagKind) -> char {
    match kind {
        FlagKind::Streak => 'S',
        FlagKind::ShortFeed => 'F',
        FlagKind::Coverage => 'C',
        FlagKind::Elevation => 'E',
        FlagKind::UnderFusion => 'U',
        FlagKind::OverFusion => 'O',
        FlagKind::Spatter => 'P',
        FlagKind::Drift => 'D',
        FlagKind::Model => 'M',
    }
}

/// Baseline of the drawing's title, and of the legend of the flag letters below it.
pub const TITLE_Y: f64 = 16.0;
pub const LEGEND_Y: f64 = 28.0;

/// What the layout draws with.
trait Canvas {
    fn frame(&mut self, x: f64, y: f64, w: f64, h: f64);
    /// A label with its baseline at `y`, placed against `x` by `anchor`.
    fn text(&mut self, x: f64, y: f64, text: &str, colour: [u8; 3], anchor: Anchor);
    /// A short straight line (a tick).
    fn tick(&mut self, from: (f64, f64), to: (f64, f64));
    /// A flagged layer's vertical mark.
    fn flag(&mut self, x: f64, y0: f64, y1: f64, layer: u32);
    fn polyline(&mut self, points: &[(f64, f64)], colour: [u8; 3], part: i64);
}

/// Where `layer` sits on the drawing's x axis, in pixels (the same in SVG and PNG).
pub fn layer_x(records: &[InspectionRecord], layer: u32) -> f64 {
    let (l0, l1) = span(records);
    LEFT + (f64::from(layer) - f64::from(l0)) / f64::from(l1 - l0) * (WIDTH - LEFT - RIGHT)
}

/// The rows `(top, bottom)` of each panel, in pixels.
pub fn panel_rows() -> Vec<(f64, f64)> {
    (0..PANELS.len())
        .map(|k| {
            let y0 = TOP + k as f64 * (PANEL_HEIGHT + 40.0) + 20.0;
            (y0, y0 + PANEL_HEIGHT)
        })
        .collect()
}

fn height() -> f64 {
    TOP + PANELS.len() as f64 * (PANEL_HEIGHT + 40.0) + 40.0
}

/// The layers labelled on the x axis: round numbers about a tenth of the span apart, with the
/// first and last layer.
pub fn layer_ticks(records: &[InspectionRecord]) -> Vec<u32> {
    let (l0, l1) = span(records);
    let raw = f64::from(l1 - l0) / 8.0;
    let magnitude = 10f64.powf(raw.max(1.0).log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * magnitude)
        .find(|s| *s >= raw)
        .unwrap_or(10.0 * magnitude)
        .max(1.0) as u32;
    let mut ticks = vec![l0];
    // Round layers between, none so close to an end that their labels would touch.
    let gap = step / 2;
    let mut t = (l0 / step + 1) * step;
    while t + gap <= l1 {
        if t >= l0 + gap {
            ticks.push(t);
        }
        t += step;
    }
    ticks.push(l1);
    ticks
}

/// The values labelled on a panel's y axis (bottom, middle, top).
fn value_ticks(lo: f64, hi: f64) -> [f64; 3] {
    [lo, (lo + hi) / 2.0, hi]
}

/// First and last layer (two apart at least, so the axis has a length).
fn span(records: &[InspectionRecord]) -> (u32, u32) {
    let l0 = records.iter().map(|r| r.layer).min().unwrap_or(1);
    let l1 = records.iter().map(|r| r.layer).max().unwrap_or(1);
    (l0, l1.max(l0 + 1))
}

fn draw(records: &[InspectionRecord], canvas: &mut impl Canvas) {
    let x_of = |l: u32| layer_x(records, l);
    canvas.text(
        LEFT,
        TITLE_Y,
        "Inspection: per-part metrics by layer (red: a flag at warning or above)",
        INK,
        Anchor::Start,
    );
    let legend: Vec<String> = FlagKind::ALL
        .iter()
        .map(|k| format!("{} {}", kind_letter(*k), k.name()))
        .collect();
    canvas.text(
        LEFT,
        LEGEND_Y,
        &format!("flags: {}", legend.join("  ")),
        FLAG,
        Anchor::Start,
    );
    for ((title, metric), (y0, y1)) in PANELS.iter().zip(panel_rows()) {
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
        let y_of = |v: f64| y1 - (v - lo) / (hi - lo) * PANEL_HEIGHT;
        canvas.frame(LEFT, y0, WIDTH - LEFT - RIGHT, PANEL_HEIGHT);
        canvas.text(LEFT, y0 - 4.0, title, INK, Anchor::Start);
        for v in value_ticks(lo, hi) {
            let y = y_of(v);
            canvas.tick((LEFT - 4.0, y), (LEFT, y));
            canvas.text(LEFT - 6.0, y + 3.5, &format!("{v:.2}"), INK, Anchor::End);
        }
        for r in records {
            let mut kinds: Vec<FlagKind> = r
                .flags
                .iter()
                .filter(|f| f.severity >= Severity::Warning)
                .map(|f| f.kind)
                .collect();
            if kinds.is_empty() {
                continue;
            }
            kinds.sort();
            kinds.dedup();
            canvas.flag(x_of(r.layer), y0, y1, r.layer);
            let letters: String = kinds.into_iter().map(kind_letter).collect();
            canvas.text(x_of(r.layer), y0 - 14.0, &letters, FLAG, Anchor::Middle);
        }
        for (i, (part, points)) in series.iter().enumerate() {
            let colour = COLOURS[i % COLOURS.len()];
            let path: Vec<(f64, f64)> = points.iter().map(|(l, v)| (x_of(*l), y_of(*v))).collect();
            canvas.polyline(&path, colour, *part);
            let label_y = y0 + 14.0 + 12.0 * i as f64;
            canvas.text(
                WIDTH - RIGHT - 6.0,
                label_y,
                &format!("part {part}"),
                colour,
                Anchor::End,
            );
        }
        for layer in layer_ticks(records) {
            let x = x_of(layer);
            canvas.tick((x, y1), (x, y1 + 4.0));
            canvas.text(x, y1 + 14.0, &layer.to_string(), INK, Anchor::Middle);
        }
    }
    let bottom = panel_rows().last().map_or(0.0, |r| r.1);
    canvas.text(
        (LEFT + WIDTH - RIGHT) / 2.0,
        bottom + 28.0,
        "layer",
        INK,
        Anchor::Middle,
    );
}

fn hex([r, g, b]: [u8; 3]) -> String {
    format!("#{r:02x}{g:02x}{b:02x}")
}

struct Svg(String);

impl Canvas for Svg {
    fn frame(&mut self, x: f64, y: f64, w: f64, h: f64) {
        let stroke = hex(FRAME);
        let _ = writeln!(
            self.0,
            r#"<rect x="{x}" y="{y}" width="{w}" height="{h}" fill="none" stroke="{stroke}"/>"#
        );
    }
    fn text(&mut self, x: f64, y: f64, text: &str, colour: [u8; 3], anchor: Anchor) {
        let anchor = match anchor {
            Anchor::Start => "",
            Anchor::Middle => r#" text-anchor="middle""#,
            Anchor::End => r#" text-anchor="end""#,
        };
        let _ = writeln!(
            self.0,
            r#"<text x="{x}" y="{y}" fill="{}"{anchor}>{text}</text>"#,
            hex(colour)
        );
    }
    fn tick(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64)) {
        let _ = writeln!(
            self.0,
            r#"<line x1="{x0:.1}" y1="{y0:.1}" x2="{x1:.1}" y2="{y1:.1}" stroke="{}"/>"#,
            hex(FRAME)
        );
    }
    fn flag(&mut self, x: f64, y0: f64, y1: f64, layer: u32) {
        let _ = writeln!(
            self.0,
            r#"<line x1="{x:.1}" y1="{y0}" x2="{x:.1}" y2="{y1}" stroke="{}" stroke-opacity="0.5"><title>layer {layer}</title></line>"#,
            hex(FLAG)
        );
    }
    fn polyline(&mut self, points: &[(f64, f64)], colour: [u8; 3], part: i64) {
        let path: Vec<String> = points
            .iter()
            .map(|(x, y)| format!("{x:.1},{y:.1}"))
            .collect();
        let _ = writeln!(
            self.0,
            r#"<polyline fill="none" stroke="{}" points="{}"><title>part {part}</title></polyline>"#,
            hex(colour),
            path.join(" ")
        );
    }
}

/// The SVG text.
pub fn svg(records: &[InspectionRecord]) -> String {
    let mut canvas = Svg(format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{}" font-family="sans-serif" font-size="11">"#,
        height()
    ));
    canvas.0.push('\n');
    draw(records, &mut canvas);
    canvas.0.push_str("</svg>\n");
    canvas.0
}

struct Raster(image::RgbImage);

impl Raster {
    fn put(&mut self, x: f64, y: f64, colour: [u8; 3]) {
        let (x, y) = (x.round(), y.round());
        if x >= 0.0 && y >= 0.0 && x < f64::from(self.0.width()) && y < f64::from(self.0.height()) {
            self.0.put_pixel(x as u32, y as u32, image::Rgb(colour));
        }
    }
    /// A straight line, one pixel wide, stepped along its longer axis.
    fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), colour: [u8; 3]) {
        let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0);
        for k in 0..=steps as u32 {
            let t = f64::from(k) / steps;
            self.put(x0 + t * (x1 - x0), y0 + t * (y1 - y0), colour);
        }
    }
}

impl Canvas for Raster {
    fn frame(&mut self, x: f64, y: f64, w: f64, h: f64) {
        let corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h), (x, y)];
        for pair in corners.windows(2) {
            self.line(pair[0], pair[1], FRAME);
        }
    }
    fn text(&mut self, x: f64, y: f64, text: &str, colour: [u8; 3], anchor: Anchor) {
        // The 5 x 7 font advances 6 pixels a character; its 7 rows end on the baseline.
        let width = text.chars().count() as f64 * 6.0 - 1.0;
        let left = match anchor {
            Anchor::Start => x,
            Anchor::Middle => x - width / 2.0,
            Anchor::End => x - width,
        };
        let (left, top) = (left.round().max(0.0), (y - 7.0).round().max(0.0));
        crate::raster::sheet::draw_text(
            &mut self.0,
            left as u32,
            top as u32,
            text,
            image::Rgb(colour),
        );
    }
    fn tick(&mut self, from: (f64, f64), to: (f64, f64)) {
        self.line(from, to, FRAME);
    }
    fn flag(&mut self, x: f64, y0: f64, y1: f64, _layer: u32) {
        self.line((x, y0), (x, y1), FLAG);
    }
    fn polyline(&mut self, points: &[(f64, f64)], colour: [u8; 3], _part: i64) {
        for pair in points.windows(2) {
            // Two pixels wide, so a line reads at a glance.
            self.line(pair[0], pair[1], colour);
            self.line(
                (pair[0].0, pair[0].1 + 1.0),
                (pair[1].0, pair[1].1 + 1.0),
                colour,
            );
        }
    }
}

/// The same drawing as PNG bytes.
pub fn png(records: &[InspectionRecord]) -> Result<Vec<u8>, image::ImageError> {
    let mut canvas = Raster(image::RgbImage::from_pixel(
        WIDTH as u32,
        height() as u32,
        image::Rgb([255, 255, 255]),
    ));
    draw(records, &mut canvas);
    let mut bytes = Vec::new();
    canvas.0.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )?;
    Ok(bytes)
}
