//! Which pixels of a frame the rectifier can read: per source row, the columns that any grid
//! pixel's interpolation neighbourhood may touch. The JPEG luma decoder leaves the rest of the
//! frame undecoded (its Huffman data is still read: it is sequential), so the blocks beside the
//! plate cost neither an IDCT nor memory traffic.
//!
//! The grid's sample positions fill the image of the rectangle of grid pixel centres. Where the
//! map from grid to image is one to one (every point in front of the camera and inside the
//! distortion's fold, which holding on the rectangle's boundary implies for its inside: the
//! homogeneous w is affine in the grid coordinates, and a convex quadrilateral inside the fold's
//! disc lies inside it), that image is a region bounded by the image of the rectangle's boundary,
//! and the leftmost and rightmost points of the region in any row lie on that boundary. So
//! walking the boundary densely, every row's extent is found; a margin covers the interpolation
//! neighbourhoods, the fixed-point rounding of the positions and the walk's steps.

use std::sync::{Arc, Mutex};

use crate::geometry::{BuildPoint, CameraModel, Grid};

/// Columns beyond a boundary sample's integer position taken on each side, and rows above and
/// below: bicubic reads from one pixel before to two after, positions are rounded to 1/2048 px
/// (the 8-lane f32 path is within a few thousandths of a pixel), and boundary samples are at most
/// [`MAX_STEP`] apart.
const MARGIN: i64 = 4;

/// Largest distance in pixels between consecutive boundary samples.
const MAX_STEP: f64 = 2.0;

/// Most boundary samples walked; a finer boundary than this (a grid far coarser than the frame's
/// pixels, which no calibration gives) means the whole frame is decoded.
const MAX_SAMPLES: usize = 1 << 22;

/// Per source row, the inclusive range of columns the rectifier may read (`None`: none).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Footprint {
    pub(crate) rows: Vec<Option<(u32, u32)>>,
}

impl Footprint {
    /// The columns of source rows `rows` together (`None` if no row of them is read).
    pub(crate) fn columns_of(&self, rows: std::ops::Range<usize>) -> Option<(u32, u32)> {
        self.rows
            .get(rows.start.min(self.rows.len())..rows.end.min(self.rows.len()))?
            .iter()
            .flatten()
            .fold(None, |acc, &(a, b)| match acc {
                None => Some((a, b)),
                Some((x, y)) => Some((x.min(a), y.max(b))),
            })
    }
}

/// A rectifier's footprint for the last frame size asked (a camera's frames have one size), so
/// that it is walked once, not for every frame; shared by the rectifier's clones.
#[derive(Clone, Default)]
pub(crate) struct FootprintCache(Arc<Mutex<Option<FootprintOfSize>>>);

type FootprintOfSize = ((usize, usize), Option<Arc<Footprint>>);

impl std::fmt::Debug for FootprintCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("FootprintCache")
    }
}

impl FootprintCache {
    /// The footprint of a `width` x `height` frame, walked by `walk` unless the last one asked
    /// was for that size. A poisoned lock (a thread panicked while storing) only means walking
    /// it again.
    pub(crate) fn get(
        &self,
        width: usize,
        height: usize,
        walk: impl FnOnce() -> Option<Footprint>,
    ) -> Option<Arc<Footprint>> {
        let size = (width, height);
        if let Ok(cached) = self.0.lock() {
            if let Some((_, found)) = cached.as_ref().filter(|(s, _)| *s == size) {
                return found.clone();
            }
        }
        let found = walk().map(Arc::new);
        if let Ok(mut cached) = self.0.lock() {
            *cached = Some((size, found.clone()));
        }
        found
    }
}

/// What a rectifier for `camera` onto `grid` reads of a `width` x `height` frame (see the
/// module docs), or `None` when it cannot be bounded (part of the grid beyond the horizon or
/// past the distortion's fold: then the whole frame is decoded).
pub(crate) fn walk(
    camera: &CameraModel,
    grid: Grid,
    width: usize,
    height: usize,
) -> Option<Footprint> {
    let (cols, rows) = (grid.columns(), grid.rows());
    if width == 0 || height == 0 || cols == 0 || rows == 0 {
        return None;
    }
    let (last_c, last_r) = ((cols - 1) as f64, (rows - 1) as f64);
    // The boundary of the rectangle of pixel centres, once around, as (row, col) at t in [0, 1).
    let perimeter = 2.0 * (last_c + last_r);
    let at = |t: f64| -> (f64, f64) {
        let d = t * perimeter;
        if d < last_c {
            (0.0, d)
        } else if d < last_c + last_r {
            (d - last_c, last_c)
        } else if d < 2.0 * last_c + last_r {
            (last_r, last_c - (d - last_c - last_r))
        } else {
            (last_r - (d - 2.0 * last_c - last_r), 0.0)
        }
    };
    let image_at = |t: f64| {
        let (r, c) = at(t);
        let (x, y) = grid.center_of(r, c);
        camera
            .image_point(BuildPoint { x, y })
            .filter(|p| p.u.is_finite() && p.v.is_finite())
    };
    let mut samples = ((perimeter.ceil() as usize) * 2).max(4);
    let points = loop {
        let points: Option<Vec<(f64, f64)>> = (0..=samples)
            .map(|k| image_at(k as f64 / samples as f64).map(|p| (p.u, p.v)))
            .collect();
        let points = points?;
        let step = points
            .windows(2)
            .map(|w| (w[1].0 - w[0].0).hypot(w[1].1 - w[0].1))
            .fold(0.0f64, f64::max);
        if step <= MAX_STEP {
            break points;
        }
        let finer = (samples as f64 * step / MAX_STEP * 1.5).ceil();
        if !finer.is_finite() || finer > MAX_SAMPLES as f64 {
            return None;
        }
        samples = finer as usize;
    };
    let mut spans: Vec<Option<(i64, i64)>> = vec![None; height];
    let (w_max, h_max) = (width as i64 - 1, height as i64 - 1);
    for (u, v) in points {
        // Far outside the frame a sample only says "up to the edge": clamp before converting.
        let (u, v) = (
            u.clamp(-1e9, 1e9).floor() as i64,
            v.clamp(-1e9, 1e9).floor() as i64,
        );
        let (c0, c1) = (
            (u - MARGIN).clamp(0, w_max),
            (u + MARGIN + 1).clamp(0, w_max),
        );
        let (r0, r1) = ((v - MARGIN).max(0), (v + MARGIN + 1).min(h_max));
        for span in spans
            .iter_mut()
            .take((r1 + 1).max(0) as usize)
            .skip(r0 as usize)
        {
            *span = Some(match *span {
                None => (c0, c1),
                Some((a, b)) => (a.min(c0), b.max(c1)),
            });
        }
    }
    // Rows between two rows the boundary crosses are inside the region's vertical extent
    // only where the boundary crosses them too (it is a closed curve walked densely), so a row
    // left empty here lies above or below the region: nothing of it is read.
    Some(Footprint {
        rows: spans
            .into_iter()
            .map(|s| s.map(|(a, b)| (a as u32, b as u32)))
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Homography, ImagePoint, RadialDistortion};

    /// The camera of the oblique view and the grid.
    struct Oblique {
        camera: CameraModel,
        grid: Grid,
    }

    impl Oblique {
        fn footprint(&self, w: usize, h: usize) -> Option<Footprint> {
            walk(&self.camera, self.grid, w, h)
        }

        fn grid(&self) -> Grid {
            self.grid
        }

        fn image_point(&self, p: BuildPoint) -> Option<ImagePoint> {
            self.camera.image_point(p)
        }
    }

    fn oblique(w: u32, h: u32, grid: Grid, distortion: Option<RadialDistortion>) -> Oblique {
        let truth = mock_camera::Homography::oblique_view(w, h);
        let camera = CameraModel::new(Homography::from_matrix(truth.m), distortion);
        Oblique { camera, grid }
    }

    /// Every position the rectifier samples, and its 4x4 neighbourhood, is in the footprint.
    fn check_covers(r: &Oblique, w: usize, h: usize) -> usize {
        let f = r.footprint(w, h).expect("bounded");
        let g = r.grid();
        let mut read = 0;
        for row in 0..g.rows() {
            for col in 0..g.columns() {
                let (x, y) = g.center_of(row as f64, col as f64);
                let Some(p) = r.image_point(BuildPoint { x, y }) else {
                    panic!("grid pixel ({row}, {col}) has no image point");
                };
                let (u, v) = (p.u.floor() as i64, p.v.floor() as i64);
                for dv in -1..=2 {
                    for du in -1..=2 {
                        let (uu, vv) = (u + du, v + dv);
                        if uu < 0 || vv < 0 || uu >= w as i64 || vv >= h as i64 {
                            continue;
                        }
                        let (a, b) = f.rows[vv as usize]
                            .unwrap_or_else(|| panic!("row {vv} not in the footprint"));
                        assert!(
                            (a as i64..=b as i64).contains(&uu),
                            "pixel ({uu}, {vv}) outside {a}..={b}"
                        );
                        read += 1;
                    }
                }
            }
        }
        read
    }

    #[test]
    fn the_footprint_covers_every_sample_and_leaves_the_frame_beside_the_plate() {
        let (w, h) = (736, 491);
        let grid = Grid {
            pixel_mm: 0.625,
            ..Grid::plate()
        };
        let r = oblique(w, h, grid, None);
        assert!(check_covers(&r, w as usize, h as usize) > 0);
        let f = r.footprint(w as usize, h as usize).unwrap();
        let covered: u64 = f
            .rows
            .iter()
            .flatten()
            .map(|&(a, b)| u64::from(b - a + 1))
            .sum();
        let share = covered as f64 / f64::from(w * h);
        // Walked once per frame size: the same again, another for another size.
        let cache = FootprintCache::default();
        let walked = |hh| r.footprint(w as usize, hh);
        let first = cache
            .get(w as usize, h as usize, || walked(h as usize))
            .unwrap();
        assert_eq!(*first, f);
        let again = cache.get(w as usize, h as usize, || panic!("walked again"));
        assert!(Arc::ptr_eq(&first, &again.unwrap()));
        let other = cache.get(w as usize, 300, || walked(300)).unwrap();
        assert_eq!(other.rows.len(), 300);
        // The plate's trapezoid in the oblique view: well inside the frame, far from all of it.
        assert!(
            (0.3..0.8).contains(&share),
            "footprint {share:.2} of the frame"
        );
        // With barrel distortion, and with a grid wider than the view (clamped at the frame).
        let d = RadialDistortion {
            center: [f64::from(w) / 2.0, f64::from(h) / 2.0],
            focal_px: f64::from(w),
            k1: -0.05,
            k2: 0.0,
        };
        check_covers(&oblique(w, h, grid, Some(d)), w as usize, h as usize);
        let wide = Grid {
            x_min: -400.0,
            x_max: 400.0,
            y_min: -400.0,
            y_max: 400.0,
            pixel_mm: 2.0,
        };
        let r = oblique(w, h, wide, None);
        check_covers(&r, w as usize, h as usize);
    }

    #[test]
    fn a_grid_beyond_the_horizon_has_no_footprint() {
        // Columns of the grid far behind the camera: the footprint cannot be bounded.
        let wide = Grid {
            x_min: -20000.0,
            x_max: 20000.0,
            y_min: -20000.0,
            y_max: 20000.0,
            pixel_mm: 100.0,
        };
        assert!(oblique(736, 491, wide, None).footprint(736, 491).is_none());
    }
}
