//! The powder bed the inspection judged (inspection.jsonl's `bed`), as the page draws it: a
//! faint outline over the pre-scan views, in fractions of the rectified picture (the frame of the
//! flags' boxes and of vectors.svg), from the layer the bed settled on.

use super::timeline::Timeline;
use crate::build_dir::inspection::BedRecord;
use crate::geometry::Grid;
use serde::Serialize;

/// The bed of a layer's detail (`GET /api/layers/N`, `bed`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PageBed {
    /// The layer the bed settled on (the inspection votes over its first layers, then keeps it).
    pub layer: u32,
    /// A closed polygon, `[x, y]` fractions of the rectified picture (x from the grid's `x_min`
    /// edge, y from its `y_max` edge); empty before the build's configuration snapshot exists.
    pub outline: Vec<[f64; 2]>,
    /// `[x_min, y_min, x_max, y_max]`, build mm.
    pub bbox_mm: [f64; 4],
    pub area_mm2: f64,
}

/// The bed judged on `layer`: the latest settled at or before it; none before it settled.
pub fn layer_bed(timeline: &Timeline, layer: u32, grid: Option<&Grid>) -> Option<PageBed> {
    let (settled, bed) = timeline.bed_at(layer)?;
    Some(PageBed {
        layer: settled,
        outline: grid.map(|g| outline(bed, g)).unwrap_or_default(),
        bbox_mm: bed.bbox_mm,
        area_mm2: bed.area_mm2,
    })
}

/// The bed's outline in fractions of the picture of `grid`. The recorded vertices are the
/// centres of the bed's border cells, half a cell inside its edge: the polygon is stretched onto
/// the bed's recorded box, so the line runs on the bed's edge and spans exactly its box.
pub fn outline(bed: &BedRecord, grid: &Grid) -> Vec<[f64; 2]> {
    let points = &bed.outline_mm;
    let extent = |k: usize| {
        points
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                (lo.min(p[k]), hi.max(p[k]))
            })
    };
    // Along axis k: the polygon's span [lo, hi] onto the box's [b0, b1].
    let onto = |v: f64, (lo, hi): (f64, f64), b0: f64, b1: f64| {
        if hi - lo > 1e-9 {
            b0 + (v - lo) * (b1 - b0) / (hi - lo)
        } else {
            v
        }
    };
    let (xs, ys) = (extent(0), extent(1));
    let [x0, y0, x1, y1] = bed.bbox_mm;
    let width = grid.columns().max(1) as f64 * grid.pixel_mm;
    let height = grid.rows().max(1) as f64 * grid.pixel_mm;
    let fraction = |v: f64| (v.clamp(0.0, 1.0) * 1e6).round() / 1e6;
    points
        .iter()
        .map(|p| {
            let x = onto(p[0], xs, x0, x1);
            let y = onto(p[1], ys, y0, y1);
            [
                fraction((x - grid.x_min) / width),
                fraction((grid.y_max - y) / height),
            ]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::timeline::Tails;
    use super::*;

    /// A bed of cells 10..=29 (columns) x 5..=14 (rows) on a 1 mm inspection grid over
    /// x -20..20, y -10..10: its box is the cells' outer edges, its outline their centres.
    #[test]
    fn the_outline_runs_on_the_beds_edge_in_picture_fractions_rows_from_the_far_edge() {
        let cell = |r: f64, c: f64| [-20.0 + c + 0.5, 10.0 - r - 0.5];
        let bed = BedRecord {
            bbox_mm: [-10.0, -5.0, 10.0, 5.0],
            area_mm2: 200.0,
            outline_mm: vec![
                cell(5.0, 29.0),
                cell(14.0, 29.0),
                cell(14.0, 20.0),
                cell(14.0, 10.0),
                cell(5.0, 10.0),
            ],
        };
        // The page's picture: the series grid (0.25 mm) over the same plate, 160 x 80 pixels.
        let grid = Grid {
            x_min: -20.0,
            x_max: 20.0,
            y_min: -10.0,
            y_max: 10.0,
            pixel_mm: 0.25,
        };
        let got = outline(&bed, &grid);
        // The centres' span (19 mm) stretched onto the box's (20 mm): column 20's centre, 0.5 mm
        // right of the middle, lands 0.526 mm right of it.
        let want = [
            [0.75, 0.25],
            [0.75, 0.75],
            [(20.0 + 10.0 / 19.0) / 40.0, 0.75],
            [0.25, 0.75],
            [0.25, 0.25],
        ];
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(want) {
            assert!(
                (g[0] - w[0]).abs() < 1e-6 && (g[1] - w[1]).abs() < 1e-6,
                "{got:?}"
            );
        }
        // A flag's box of the same cells (bbox_px / columns) has the same edges.
        let (cols, rows) = (grid.columns() as f64, grid.rows() as f64);
        assert_eq!((cols, rows), (160.0, 80.0));
        assert_eq!((40.0 / cols, (119.0 + 1.0) / cols), (0.25, 0.75));
        assert_eq!((20.0 / rows, (59.0 + 1.0) / rows), (0.25, 0.75));
    }

    #[test]
    fn a_layer_carries_the_latest_bed_settled_at_or_before_it() {
        use crate::build_dir::inspection::tests::record_with;
        let dir = tempfile::tempdir().unwrap();
        let bed = |x: f64, outline: bool| BedRecord {
            bbox_mm: [-x, -x, x, x],
            area_mm2: 4.0 * x * x,
            outline_mm: if outline {
                vec![[-x, -x], [x, -x], [x, x], [-x, x]]
            } else {
                vec![]
            },
        };
        let lines: String = [
            (1, Some(bed(50.0, false))),
            (3, Some(bed(60.0, true))),
            (4, Some(bed(60.0, false))),
            (9, Some(bed(70.0, true))),
            (10, None),
        ]
        .into_iter()
        .map(|(layer, b)| {
            let mut r = record_with(layer, vec![]);
            r.bed = b;
            serde_json::to_string(&r).unwrap() + "\n"
        })
        .collect();
        std::fs::write(dir.path().join(crate::build_dir::INSPECTION), lines).unwrap();
        let (mut timeline, mut tails) = (Timeline::default(), Tails::new(dir.path()));
        timeline.refresh(&mut tails).unwrap();
        let grid = Grid::plate();
        let at = |n| layer_bed(&timeline, n, Some(&grid)).map(|b| (b.layer, b.bbox_mm[2]));
        assert_eq!(at(1), None, "a provisional bed is not shown");
        assert_eq!(at(2), None);
        assert_eq!((at(3), at(8)), (Some((3, 60.0)), Some((3, 60.0))));
        assert_eq!((at(9), at(11)), (Some((9, 70.0)), Some((9, 70.0))));
        assert!(layer_bed(&timeline, 5, None).unwrap().outline.is_empty());
        // A new pass settling at layer 3 again (`layerwise inspect`) stands for the layers after.
        let mut again = record_with(3, vec![]);
        again.bed = Some(bed(65.0, true));
        let mut file = std::fs::OpenOptions::new()
            .append(true)
            .open(dir.path().join(crate::build_dir::INSPECTION))
            .unwrap();
        std::io::Write::write_all(
            &mut file,
            (serde_json::to_string(&again).unwrap() + "\n").as_bytes(),
        )
        .unwrap();
        timeline.refresh(&mut tails).unwrap();
        let at = |n| layer_bed(&timeline, n, Some(&grid)).map(|b| (b.layer, b.bbox_mm[2]));
        assert_eq!(at(11), Some((3, 65.0)));
    }
}
