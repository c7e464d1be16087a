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

use super::input::Gray;

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

    /// `img` framed and resampled to `side` x `side`.
    pub fn square(self, img: &Gray, side: usize) -> Gray {
        match self {
            Framing::CentreSquare => img.center_square().resize(side, side),
            Framing::Bed => bed(img).resize(side, side),
        }
    }
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

/// The bed's part of `img`: without the dark margins (module docs).
pub fn bed(img: &Gray) -> Gray {
    let (w, h) = (img.width, img.height);
    if w < 4 || h < 4 {
        return img.clone();
    }
    let mut centre: Vec<f32> = (h / 4..h - h / 4)
        .flat_map(|y| img.px[y * w + w / 4..y * w + w - w / 4].iter().copied())
        .collect();
    let level = MARGIN_SHARE * median(&mut centre);
    if level <= 0.0 {
        return img.clone();
    }
    let (xs, ys) = (
        h.div_ceil(MEDIAN_SAMPLES).max(1),
        w.div_ceil(MEDIAN_SAMPLES).max(1),
    );
    let column = |x: usize| {
        let mut v: Vec<f32> = (0..h).step_by(xs).map(|y| img.px[y * w + x]).collect();
        median(&mut v)
    };
    let row = |y: usize| {
        let mut v: Vec<f32> = img.px[y * w..(y + 1) * w]
            .iter()
            .step_by(ys)
            .copied()
            .collect();
        median(&mut v)
    };
    let (x0, x1) = span(w, level, column);
    let (y0, y1) = span(h, level, row);
    if (x0, x1, y0, y1) == (0, w, 0, h) {
        return img.clone();
    }
    let px = (y0..y1)
        .flat_map(|y| img.px[y * w + x0..y * w + x1].iter().copied())
        .collect();
    Gray::new(x1 - x0, y1 - y0, px)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bed of grain (grey 90-110) with a dark band of uneven powder near its left edge.
    fn bed_picture(w: usize, h: usize) -> Gray {
        Gray::new(
            w,
            h,
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
                .collect(),
        )
    }

    /// `img` placed at (`x`, `y`) in a `w` x `h` surround of grey `level`.
    fn surrounded(img: &Gray, w: usize, h: usize, x: usize, y: usize, level: f32) -> Gray {
        let mut px = vec![level; w * h];
        for r in 0..img.height {
            px[(y + r) * w + x..(y + r) * w + x + img.width]
                .copy_from_slice(&img.px[r * img.width..(r + 1) * img.width]);
        }
        Gray::new(w, h, px)
    }

    #[test]
    fn the_bed_is_found_in_any_dark_surround_and_its_edge_band_kept() {
        let b = bed_picture(200, 160);
        // The bed alone: nothing cut (the dark band is under half the centre's median only in
        // some rows, so its columns' medians stay above).
        let alone = bed(&b);
        assert_eq!((alone.width, alone.height), (200, 160));
        assert_eq!(alone.px, b.px);
        // In a black surround, off-centre, and under a dim wall (30): the same bed back.
        for (x, y, level) in [(20, 30, 0.0), (3, 41, 0.0), (35, 2, 30.0)] {
            let found = bed(&surrounded(&b, 260, 210, x, y, level));
            assert_eq!((found.width, found.height), (200, 160), "{x} {y} {level}");
            assert_eq!(found.px, b.px);
        }
        // Both framings give the same canonical square for the bed in a surround.
        let a = Framing::Bed.square(&b, 64);
        let c = Framing::Bed.square(&surrounded(&b, 300, 170, 50, 5, 10.0), 64);
        assert_eq!(a.px, c.px);
        // The centre square of the surrounded frame is another picture.
        let d = Framing::CentreSquare.square(&surrounded(&b, 300, 170, 50, 5, 10.0), 64);
        assert_ne!(a.px, d.px);
    }

    #[test]
    fn a_picture_without_margins_or_mostly_dark_is_kept_whole() {
        let flat = Gray::new(50, 40, vec![0.0; 2000]);
        assert_eq!(bed(&flat).px, flat.px);
        // A bright spot in the centre of a dark frame: cutting would keep under half, so no cut.
        let mut px = vec![5.0; 100 * 100];
        for y in 30..70 {
            for x in 30..70 {
                px[y * 100 + x] = 200.0;
            }
        }
        let spot = Gray::new(100, 100, px);
        let found = bed(&spot);
        assert_eq!((found.width, found.height), (100, 100));
        assert_eq!(bed(&Gray::new(3, 3, vec![1.0; 9])).width, 3);
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
