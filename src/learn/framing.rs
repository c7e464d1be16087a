//! How a camera frame is framed before it becomes the canonical square: what part of the picture
//! the model reads. Recorded in the model file (`input.framing`; files without it are
//! [`Framing::CentreSquare`], as every model before it).
//!
//! [`Framing::Bed`] reads the bed, not the camera's field: the dark margins around it (the
//! chamber's walls, the shadow above the recoater, a black surround) are cut off, then what is
//! left is stretched to the square. Another camera that sees more or less around the bed, or
//! frames it off-centre, then gives the model the same picture of the bed, as the daemon's views
//! rectified to the plate do by the calibration. A margin is a run of rows or columns at the
//! picture's edge whose median grey level is under half the median of the picture's central
//! half: the build's own statistics, no level fixed for one camera.

use serde::{Deserialize, Serialize};

/// A margin's median is under this share of the centre's median.
const MARGIN_SHARE: f32 = 0.5;
/// At most this many samples of a row or column are read for its median.
const MEDIAN_SAMPLES: usize = 1024;

/// What part of a frame becomes the canonical square.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Framing {
    /// The centred square of side min(width, height) (every model before the bed framing).
    #[default]
    #[serde(rename = "centre-square")]
    CentreSquare,
    /// The frame without its dark margins, stretched to the square.
    #[serde(rename = "bed-margins-under-half-centre-median/stretch")]
    Bed,
}

impl Framing {
    /// The name recorded in model files.
    pub fn name(self) -> &'static str {
        match self {
            Framing::CentreSquare => "centre-square",
            Framing::Bed => "bed-margins-under-half-centre-median/stretch",
        }
    }

    /// Whether this is the framing of files that do not name one (not written then).
    pub fn is_centre_square(&self) -> bool {
        *self == Framing::CentreSquare
    }
}

/// A part of a picture: columns `x0..x1`, rows `y0..y1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Part {
    pub x0: usize,
    pub x1: usize,
    pub y0: usize,
    pub y1: usize,
}

/// The median of `values` (reordered); 0 when empty.
fn median(values: &mut [f32]) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The first and one past the last of `n` lines whose median is at least `level`, when they
/// keep at least half of the lines; else all of them.
fn span(n: usize, level: f32, line_median: impl Fn(usize) -> f32) -> (usize, usize) {
    let first = (0..n).find(|&i| line_median(i) >= level);
    let last = (0..n).rev().find(|&i| line_median(i) >= level);
    match (first, last) {
        (Some(a), Some(b)) if (b + 1 - a) * 2 >= n => (a, b + 1),
        _ => (0, n),
    }
}

/// The bed's part of a `w` x `h` picture of row-major `px`: without the dark margins (module
/// docs); the whole picture when there are none.
pub fn bed(w: usize, h: usize, px: &[f32]) -> Part {
    let whole = Part {
        x0: 0,
        x1: w,
        y0: 0,
        y1: h,
    };
    if w < 4 || h < 4 || px.len() < w * h {
        return whole;
    }
    let mut centre: Vec<f32> = (h / 4..h - h / 4)
        .flat_map(|y| px[y * w + w / 4..y * w + w - w / 4].iter().copied())
        .collect();
    let level = MARGIN_SHARE * median(&mut centre);
    if level <= 0.0 {
        return whole;
    }
    let (xs, ys) = (
        h.div_ceil(MEDIAN_SAMPLES).max(1),
        w.div_ceil(MEDIAN_SAMPLES).max(1),
    );
    let column = |x: usize| {
        let mut v: Vec<f32> = (0..h).step_by(xs).map(|y| px[y * w + x]).collect();
        median(&mut v)
    };
    let row = |y: usize| {
        let mut v: Vec<f32> = px[y * w..(y + 1) * w].iter().step_by(ys).copied().collect();
        median(&mut v)
    };
    let (x0, x1) = span(w, level, column);
    let (y0, y1) = span(h, level, row);
    Part { x0, x1, y0, y1 }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bed of grain (grey 90-110) with a dark band of uneven powder near its left edge.
    fn bed_picture(w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let grain = ((x * 7 + y * 13) % 21) as f32;
                if (w / 20..w / 10).contains(&x) && y % 9 < 4 {
                    40.0 + grain
                } else {
                    90.0 + grain
                }
            })
            .collect()
    }

    /// A `bw` x `bh` picture placed at (`x`, `y`) in a `w` x `h` surround of grey `level`.
    fn surrounded(
        bw: usize,
        bh: usize,
        w: usize,
        h: usize,
        x: usize,
        y: usize,
        level: f32,
    ) -> Vec<f32> {
        let (img, mut px) = (bed_picture(bw, bh), vec![level; w * h]);
        for r in 0..bh {
            px[(y + r) * w + x..(y + r) * w + x + bw].copy_from_slice(&img[r * bw..(r + 1) * bw]);
        }
        px
    }

    #[test]
    fn the_bed_is_found_in_any_dark_surround_and_its_edge_band_kept() {
        // The bed alone: nothing cut (the dark band is under half the centre's median only in
        // some rows, so its columns' medians stay above).
        let whole = Part {
            x0: 0,
            x1: 200,
            y0: 0,
            y1: 160,
        };
        assert_eq!(bed(200, 160, &bed_picture(200, 160)), whole);
        // In a black surround, off-centre, and under a dim wall (30): exactly the bed.
        for (x, y, level) in [(20, 30, 0.0), (3, 41, 0.0), (35, 2, 30.0)] {
            let found = bed(260, 210, &surrounded(200, 160, 260, 210, x, y, level));
            assert_eq!(
                found,
                Part {
                    x0: x,
                    x1: x + 200,
                    y0: y,
                    y1: y + 160
                },
                "{x} {y} {level}"
            );
        }
    }

    #[test]
    fn a_picture_without_margins_or_mostly_dark_is_kept_whole() {
        let whole = |w, h| Part {
            x0: 0,
            x1: w,
            y0: 0,
            y1: h,
        };
        assert_eq!(bed(50, 40, &[0.0; 2000]), whole(50, 40));
        // A bright spot in the centre of a dark frame: cutting would keep under half, so no cut.
        let mut px = vec![5.0; 100 * 100];
        for y in 30..70 {
            for x in 30..70 {
                px[y * 100 + x] = 200.0;
            }
        }
        assert_eq!(bed(100, 100, &px), whole(100, 100));
        assert_eq!(bed(3, 3, &[1.0; 9]), whole(3, 3));
        // A buffer shorter than its size says is not read.
        assert_eq!(bed(10, 10, &[1.0; 50]), whole(10, 10));
    }

    #[test]
    fn framing_names_round_trip_and_files_without_one_are_centre_square() {
        for f in [Framing::CentreSquare, Framing::Bed] {
            let json = serde_json::to_string(&f).unwrap();
            assert_eq!(json, format!("\"{}\"", f.name()));
            assert_eq!(serde_json::from_str::<Framing>(&json).unwrap(), f);
        }
        assert!(serde_json::from_str::<Framing>("\"stretch\"").is_err());
        assert_eq!(Framing::default(), Framing::CentreSquare);
    }
}
