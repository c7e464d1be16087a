//! The paper's figures 3 and 4 as one SVG: the side view without tilt (slab-shaped depth of
//! field that misses the plate's edges) next to the Scheimpflug view (wedge-shaped depth of
//! field hinged at P, plane of focus on the plate). Written as text to keep the crate free of
//! drawing dependencies; shapes are clipped here rather than with `clipPath` so simple
//! renderers (ImageMagick's) draw the same picture as browsers.

use super::{OpticsInput, OpticsReport, SideView};
use crate::geometry::clip_segment;
use std::fmt::Write;

const PANEL_W: f64 = 640.0;
const GAP: f64 = 20.0;
const TOP: f64 = 56.0;
const CAPTION: f64 = 60.0;
const WIDTH: f64 = 2.0 * PANEL_W + 3.0 * GAP;

const PLATE: &str = "stroke=\"#444\" stroke-width=\"7\"";
const IN_FOCUS: &str = "stroke=\"#17701a\" stroke-width=\"7\"";
const AXIS: &str = "stroke=\"#555\" stroke-width=\"1.2\" stroke-dasharray=\"10 4 2 4\"";
const CONE: &str = "stroke=\"#bbb\" stroke-width=\"1\"";
const LIMIT: &str = "stroke=\"#2ca02c\" stroke-width=\"1.5\" stroke-dasharray=\"6 4\"";
const DOF: &str = "fill=\"#2ca02c\" fill-opacity=\"0.22\" stroke=\"none\"";
const LENS: &str = "stroke=\"#1f77b4\" stroke-width=\"4\" stroke-linecap=\"round\"";
const LENS_PLANE: &str = "stroke=\"#1f77b4\" stroke-width=\"1\" stroke-dasharray=\"4 4\"";
const IMAGE: &str = "stroke=\"#d62728\" stroke-width=\"3\"";
const IMAGE_PLANE: &str = "stroke=\"#d62728\" stroke-width=\"1\" stroke-dasharray=\"4 4\"";
const FOCUS_PLANE: &str = "stroke=\"#444\" stroke-width=\"1\" stroke-dasharray=\"2 3\"";
const NORMAL: &str = "stroke=\"#888\" stroke-width=\"1\" stroke-dasharray=\"1 3\"";
const SCALE_BAR: &str = "stroke=\"#000\" stroke-width=\"2\"";

fn esc(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn finite(p: [f64; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

/// Text at SVG coordinates (titles, captions).
fn text_at(out: &mut String, x: f64, y: f64, anchor: &str, extra: &str, text: &str) {
    let _ = writeln!(
        out,
        "<text x=\"{x:.1}\" y=\"{y:.1}\" text-anchor=\"{anchor}\"{extra}>{}</text>",
        esc(text)
    );
}

/// Sutherland-Hodgman: the polygon clipped to `[x0, y0, x1, y1]`.
fn clip_polygon(points: &[[f64; 2]], r: [f64; 4]) -> Vec<[f64; 2]> {
    // Each edge as (axis, bound, keep the side below the bound).
    let edges = [
        (0, r[0], false),
        (0, r[2], true),
        (1, r[1], false),
        (1, r[3], true),
    ];
    let mut poly = points.to_vec();
    for (axis, bound, below) in edges {
        let inside = |p: &[f64; 2]| {
            if below {
                p[axis] <= bound
            } else {
                p[axis] >= bound
            }
        };
        let cross = |a: [f64; 2], b: [f64; 2]| {
            let t = (bound - a[axis]) / (b[axis] - a[axis]);
            [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]
        };
        let input = std::mem::take(&mut poly);
        for (i, &cur) in input.iter().enumerate() {
            let prev = input[(i + input.len() - 1) % input.len()];
            match (inside(&prev), inside(&cur)) {
                (true, true) => poly.push(cur),
                (true, false) => poly.push(cross(prev, cur)),
                (false, true) => {
                    poly.push(cross(prev, cur));
                    poly.push(cur);
                }
                (false, false) => {}
            }
        }
    }
    poly
}

/// One panel: lens-frame points turned so the plate is horizontal (as in the paper's
/// figures), scaled to fit the extent, and clipped to the panel.
struct Panel {
    view: SideView,
    rect: [f64; 4],
    min_x: f64,
    max_y: f64,
    scale: f64,
    off: [f64; 2],
    svg: String,
}

impl Panel {
    /// Plate-aligned world coordinates: X along the plate from its center toward the far edge,
    /// Y along the plate normal toward the camera.
    fn world(view: &SideView, p: [f64; 2]) -> [f64; 2] {
        let (sin, cos) = view.theta.sin_cos();
        let d = [p[0], p[1] - view.s];
        [d[0] * cos + d[1] * sin, d[0] * sin - d[1] * cos]
    }

    /// World bounding box of the extent, padded; `[min_x, min_y, max_x, max_y]`.
    fn bounds(view: &SideView, extent: &[[f64; 2]]) -> [f64; 4] {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for w in extent
            .iter()
            .map(|&p| Panel::world(view, p))
            .filter(|&w| finite(w))
        {
            b = [
                b[0].min(w[0]),
                b[1].min(w[1]),
                b[2].max(w[0]),
                b[3].max(w[1]),
            ];
        }
        let pad = 0.08 * (b[2] - b[0]).max(b[3] - b[1]);
        [b[0] - pad, b[1] - pad, b[2] + pad, b[3] + pad]
    }

    fn new(view: SideView, left: f64, height: f64, b: [f64; 4]) -> Panel {
        let scale = (PANEL_W / (b[2] - b[0])).min(height / (b[3] - b[1]));
        Panel {
            view,
            rect: [left, TOP, left + PANEL_W, TOP + height],
            min_x: b[0],
            max_y: b[3],
            scale,
            off: [
                left + (PANEL_W - (b[2] - b[0]) * scale) / 2.0,
                TOP + (height - (b[3] - b[1]) * scale) / 2.0,
            ],
            svg: String::new(),
        }
    }

    fn px(&self, p: [f64; 2]) -> [f64; 2] {
        let w = Panel::world(&self.view, p);
        [
            self.off[0] + (w[0] - self.min_x) * self.scale,
            self.off[1] + (self.max_y - w[1]) * self.scale,
        ]
    }

    fn inside(&self, p: [f64; 2]) -> bool {
        finite(p)
            && (self.rect[0]..=self.rect[2]).contains(&p[0])
            && (self.rect[1]..=self.rect[3]).contains(&p[1])
    }

    fn line(&mut self, a: [f64; 2], b: [f64; 2], style: &str) {
        let (a, b) = (self.px(a), self.px(b));
        if !finite(a) || !finite(b) {
            return;
        }
        if let Some((a, b)) = clip_segment(a, b, self.rect) {
            let _ = writeln!(
                self.svg,
                "<line x1=\"{:.1}\" y1=\"{:.1}\" x2=\"{:.1}\" y2=\"{:.1}\" {style}/>",
                a[0], a[1], b[0], b[1]
            );
        }
    }

    fn polygon(&mut self, points: &[[f64; 2]], style: &str) {
        let points: Vec<[f64; 2]> = points.iter().map(|&p| self.px(p)).collect();
        if !points.iter().all(|&p| finite(p)) {
            return;
        }
        let points = clip_polygon(&points, self.rect);
        if points.len() >= 3 {
            let list: Vec<String> = points
                .iter()
                .map(|p| format!("{:.1},{:.1}", p[0], p[1]))
                .collect();
            let _ = writeln!(self.svg, "<polygon points=\"{}\" {style}/>", list.join(" "));
        }
    }

    /// A label `dx`, `dy` pixels from a lens-frame point, if the point is on the panel.
    fn label(&mut self, at: [f64; 2], offset: [f64; 2], anchor: &str, text: &str) {
        let p = self.px(at);
        if self.inside(p) {
            text_at(
                &mut self.svg,
                p[0] + offset[0],
                p[1] + offset[1],
                anchor,
                "",
                text,
            );
        }
    }

    fn marker(&mut self, at: [f64; 2], fill: &str) {
        let p = self.px(at);
        if self.inside(p) {
            let _ = writeln!(
                self.svg,
                "<circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{fill}\"/>",
                p[0], p[1]
            );
        }
    }

    /// A 1, 2 or 5 x 10^k mm bar about a fifth of the panel wide, bottom left: the two panels
    /// are scaled independently.
    fn scale_bar(&mut self) {
        let target = PANEL_W / 5.0 / self.scale;
        if !(target.is_finite() && target > 0.0) {
            return;
        }
        let decade = 10f64.powf(target.log10().floor());
        let mm = [5.0, 2.0, 1.0]
            .into_iter()
            .map(|k| k * decade)
            .find(|&mm| mm <= target)
            .unwrap_or(decade);
        let (x, y) = (self.rect[0] + 14.0, self.rect[3] - 14.0);
        let _ = writeln!(
            self.svg,
            "<line x1=\"{x:.1}\" y1=\"{y:.1}\" x2=\"{:.1}\" y2=\"{y:.1}\" {SCALE_BAR}/>",
            x + mm * self.scale
        );
        text_at(&mut self.svg, x, y - 6.0, "start", "", &format!("{mm} mm"));
    }
}

/// Point on the line from `a` through `b` at axial distance `z`.
fn at_z(a: [f64; 2], b: [f64; 2], z: f64) -> [f64; 2] {
    let k = (z - a[1]) / (b[1] - a[1]);
    [a[0] + k * (b[0] - a[0]), z]
}

fn far_label(report: &OpticsReport) -> String {
    match report.far_mm {
        Some(far) => format!("D_far {far:.1} mm"),
        None => "D_far = ∞".to_string(),
    }
}

/// What both panels share.
struct Scene {
    view: SideView,
    /// Tangent of the in-plane half field of view (half the sensor height over `v`).
    tan_half_fov: f64,
    sensor_h: f64,
    /// Where the two edge rays of the field of view end (a bit past the plate).
    cone_ends: [[f64; 2]; 2],
    /// Axial distance where slab-shaped regions stop when D_far is far away or infinite.
    z_end: f64,
}

impl Scene {
    fn new(input: &OpticsInput, report: &OpticsReport) -> Scene {
        let view = SideView::new(input);
        let v = view.v();
        let sensor_h = f64::from(input.sensor_px.1) * input.pixel_um / 1000.0;
        let tan_half_fov = sensor_h / 2.0 / v;
        let z_end = report.plate_far_edge_mm + 0.15 * view.s;
        let (sin, cos) = view.theta.sin_cos();
        // Edge ray x = ±z T meets the plate (t cos θ, s + t sin θ) at t = ±s T / (cos θ ∓ T sin θ).
        let cone_end = |sign: f64| {
            let denom = cos - sign * tan_half_fov * sin;
            let z = if denom > 0.0 {
                let t = sign * view.s * tan_half_fov / denom;
                (1.15 * (view.s + t * sin)).min(2.0 * z_end)
            } else {
                2.0 * z_end
            };
            [sign * z * tan_half_fov, z]
        };
        Scene {
            view,
            tan_half_fov,
            sensor_h,
            cone_ends: [cone_end(-1.0), cone_end(1.0)],
            z_end,
        }
    }

    fn normal_tip(&self) -> [f64; 2] {
        let (sin, cos) = self.view.theta.sin_cos();
        let c = self.view.plate_point(0.0);
        let up = 0.3 * self.view.s;
        [c[0] + up * sin, c[1] - up * cos]
    }

    /// Points every panel must show: plate, camera, image plane, field of view.
    fn extent(&self) -> Vec<[f64; 2]> {
        let half = self.view.half_plate;
        vec![
            self.view.plate_point(-half),
            self.view.plate_point(half),
            [0.0, 0.0],
            [0.0, -1.6 * self.view.v()],
            self.cone_ends[0],
            self.cone_ends[1],
            self.normal_tip(),
        ]
    }

    /// The slab of equations 3 and 4 inside the field of view.
    fn slab(&self, report: &OpticsReport) -> [[f64; 2]; 4] {
        let t = self.tan_half_fov;
        let near = report.near_mm;
        let far = report.far_mm.unwrap_or(f64::INFINITY).min(self.z_end);
        [
            [-near * t, near],
            [near * t, near],
            [far * t, far],
            [-far * t, far],
        ]
    }

    /// S and P are worth framing only when they are within reach of the plate.
    fn hinge_in_reach(&self) -> bool {
        let s = self.view.s;
        self.view
            .scheimpflug_point()
            .is_some_and(|p| p[0].hypot(s) <= 4.0 * s)
    }
}

/// Draws the paper's figures 3 (no tilt) and 4 (Scheimpflug tilt) side by side.
pub fn plot_svg(input: &OpticsInput, report: &OpticsReport) -> String {
    let scene = Scene::new(input, report);
    let view = scene.view;

    let mut extent_a = scene.extent();
    extent_a.extend(scene.slab(report));
    let mut extent_b = scene.extent();
    if scene.hinge_in_reach() {
        extent_b.extend(view.scheimpflug_point());
        extent_b.extend(view.hinge_point());
    }
    let (bounds_a, bounds_b) = (
        Panel::bounds(&view, &extent_a),
        Panel::bounds(&view, &extent_b),
    );
    // One height for both panels, enough for the taller-looking extent at full width.
    let aspect = |b: [f64; 4]| (b[3] - b[1]) / (b[2] - b[0]);
    let height = (PANEL_W * aspect(bounds_a).max(aspect(bounds_b))).clamp(300.0, 620.0);
    let total_height = TOP + height + CAPTION;

    let mut out = String::new();
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{WIDTH:.0}\" height=\"{total_height:.0}\" \
         viewBox=\"0 0 {WIDTH:.0} {total_height:.0}\" font-family=\"sans-serif\" font-size=\"12\">"
    );
    let _ = writeln!(
        out,
        "<rect x=\"0\" y=\"0\" width=\"{WIDTH:.0}\" height=\"{total_height:.0}\" fill=\"white\"/>"
    );
    let mut a = Panel::new(view, GAP, height, bounds_a);
    panel_no_tilt(&mut a, &scene, input, report);
    out.push_str(&a.svg);
    let mut b = Panel::new(view, 2.0 * GAP + PANEL_W, height, bounds_b);
    panel_tilt(&mut b, &scene, input, report);
    out.push_str(&b.svg);
    let _ = writeln!(out, "</svg>");
    out
}

/// Frame, title and what both panels draw alike: field of view, axis, lens, plate normal.
fn panel_start(panel: &mut Panel, scene: &Scene, title: &str) {
    let [x0, y0, x1, y1] = panel.rect;
    let _ = writeln!(
        panel.svg,
        "<rect x=\"{x0:.1}\" y=\"{y0:.1}\" width=\"{:.1}\" height=\"{:.1}\" fill=\"none\" stroke=\"#ccc\"/>",
        x1 - x0,
        y1 - y0
    );
    text_at(
        &mut panel.svg,
        (x0 + x1) / 2.0,
        TOP - 16.0,
        "middle",
        " font-size=\"15\" font-weight=\"bold\"",
        title,
    );
    let view = scene.view;
    for end in scene.cone_ends {
        panel.line([0.0, 0.0], end, CONE);
    }
    panel.line([0.0, -1.6 * view.v()], [0.0, scene.z_end], AXIS);
    panel.label([0.0, 0.5 * view.s], [8.0, 0.0], "start", "optical axis");
    let lens = 0.05 * view.s;
    panel.line([-lens, 0.0], [lens, 0.0], LENS);
    panel.label([lens, 0.0], [8.0, 4.0], "start", "lens");
    let tip = scene.normal_tip();
    panel.line(view.plate_point(0.0), tip, NORMAL);
    panel.label(
        tip,
        [0.0, -4.0],
        "middle",
        &format!(
            "plate normal ({}° to the axis)",
            view.theta.to_degrees().round()
        ),
    );
}

/// The plate drawn over everything, green where it is sharp.
fn plate(panel: &mut Panel, sharp: Option<(f64, f64)>, plate_mm: f64) {
    let view = panel.view;
    let half = view.half_plate;
    panel.line(view.plate_point(-half), view.plate_point(half), PLATE);
    if let Some((from, to)) = sharp {
        if to > from {
            panel.line(view.plate_point(from), view.plate_point(to), IN_FOCUS);
        }
    }
    panel.label(
        view.plate_point(0.0),
        [0.0, 22.0],
        "middle",
        &format!("build plate {plate_mm} mm"),
    );
}

fn caption(panel: &mut Panel, lines: &[String]) {
    for (i, text) in lines.iter().enumerate() {
        let y = panel.rect[3] + 20.0 + 16.0 * i as f64;
        text_at(&mut panel.svg, panel.rect[0] + 8.0, y, "start", "", text);
    }
}

fn panel_no_tilt(panel: &mut Panel, scene: &Scene, input: &OpticsInput, report: &OpticsReport) {
    panel_start(panel, scene, "Fig. 3: no tilt (conventional image)");
    let view = scene.view;
    let slab = scene.slab(report);
    panel.polygon(&slab, DOF);
    // Limit planes a little wider than the field of view; labels at opposite ends.
    let wide = |z: f64| 1.25 * z * scene.tan_half_fov;
    let (near, far) = (slab[0][1], slab[2][1]);
    panel.line([-wide(near), near], [wide(near), near], LIMIT);
    panel.label(
        [-wide(near), near],
        [-4.0, 4.0],
        "end",
        &format!("D_near {near:.1} mm"),
    );
    if report.far_mm.is_some() {
        panel.line([-wide(far), far], [wide(far), far], LIMIT);
    }
    panel.label([wide(far), far], [4.0, 4.0], "start", &far_label(report));
    // Image plane perpendicular to the axis at v.
    let v = view.v();
    let h = scene.sensor_h / 2.0;
    panel.line([-h, -v], [h, -v], IMAGE);
    panel.label([h, -v], [8.0, 4.0], "start", "image plane");
    // Plate coordinates whose axial distance lies inside [D_near, D_far].
    let sin = view.theta.sin();
    let half = view.half_plate;
    let sharp = if sin > 0.0 {
        let from = ((report.near_mm - view.s) / sin).max(-half);
        let to = ((report.far_mm.unwrap_or(f64::INFINITY) - view.s) / sin).min(half);
        Some((from, to))
    } else {
        report.plate_in_focus_without_tilt.then_some((-half, half))
    };
    plate(panel, sharp, input.plate_mm);
    panel.scale_bar();
    caption(
        panel,
        &[
            format!(
                "f = {} mm at f/{}, s = {} mm, H = {:.0} mm; plate edges at {:.1} and {:.1} mm",
                input.focal_mm,
                input.f_number,
                input.distance_mm,
                report.hyperfocal_mm,
                report.plate_near_edge_mm,
                report.plate_far_edge_mm
            ),
            format!(
                "depth of field between planes perpendicular to the axis; whole plate sharp: {}",
                if report.plate_in_focus_without_tilt {
                    "yes"
                } else {
                    "no"
                }
            ),
        ],
    );
}

fn panel_tilt(panel: &mut Panel, scene: &Scene, input: &OpticsInput, report: &OpticsReport) {
    panel_start(
        panel,
        scene,
        &format!(
            "Fig. 4: Scheimpflug tilt α = {:.2}°",
            report.scheimpflug_tilt_deg
        ),
    );
    let view = scene.view;
    let v = view.v();
    let q0 = [0.0, -v];
    let e = view.image_plane_dir();
    let h = scene.sensor_h / 2.0;
    let half = view.half_plate;
    let focus_end = view.plate_point(1.25 * half);
    match (view.hinge_point(), view.scheimpflug_point()) {
        (Some(hinge), Some(sp)) => {
            // The wedge: planes through the hinge line and the axial limits of eq. 3 and 4,
            // drawn as far as the plane of focus is.
            let near_end = at_z(hinge, [0.0, report.near_mm], focus_end[1]);
            let far_end = match report.far_mm {
                Some(far) => at_z(hinge, [0.0, far], focus_end[1]),
                None => [hinge[0], focus_end[1]],
            };
            panel.polygon(&[hinge, near_end, far_end], DOF);
            panel.line(hinge, near_end, LIMIT);
            panel.line(hinge, far_end, LIMIT);
            // The wedge is a few degrees wide: one label below its middle.
            let middle = at_z(hinge, [0.0, report.near_mm], (hinge[1] + view.s) / 2.0);
            panel.label(
                middle,
                [0.0, 18.0],
                "middle",
                "depth of field (D_near to D_far)",
            );
            // Lens plane, image plane and plane of focus all run to S.
            panel.line([0.0, 0.0], sp, LENS_PLANE);
            panel.line(q0, sp, IMAGE_PLANE);
            panel.line(sp, focus_end, FOCUS_PLANE);
            panel.marker(sp, "#000");
            panel.marker(hinge, "#2ca02c");
            panel.label(sp, [0.0, 20.0], "middle", "S (Scheimpflug line)");
            panel.label(hinge, [0.0, -10.0], "middle", "P (hinge line)");
            panel.label(focus_end, [0.0, -10.0], "end", "plane of focus");
        }
        // The plate is perpendicular to the axis: no tilt needed, the slab of figure 3 again.
        _ => panel.polygon(&scene.slab(report), DOF),
    }
    let (a, b) = (
        [q0[0] - h * e[0], q0[1] - h * e[1]],
        [q0[0] + h * e[0], q0[1] + h * e[1]],
    );
    panel.line(a, b, IMAGE);
    panel.label(b, [8.0, 4.0], "start", "image plane (tilted)");
    plate(panel, Some((-half, half)), input.plate_mm);
    panel.scale_bar();
    let mut lines = vec![format!(
        "tan α = M tan θ = {:.5} · tan {}°; image plane, lens plane and plane of focus meet at S",
        report.magnification, input.angle_deg
    )];
    lines.push(
        match (report.hinge_distance_mm, report.scheimpflug_line_mm) {
            (Some(j), Some(sl)) => format!(
                "wedge through P (J = f / sin α = {j:.0} mm) and the axis at {:.1} mm and {}; S {sl:.0} mm from the lens{}",
                report.near_mm,
                report.far_mm.map_or("infinity".to_string(), |far| format!("{far:.1} mm")),
                if scene.hinge_in_reach() { "" } else { " (off the panel)" }
            ),
            _ => "plate perpendicular to the axis: no tilt needed".to_string(),
        },
    );
    caption(panel, &lines);
}
