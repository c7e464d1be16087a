//! Clipping of segments to an axis-aligned rectangle (the SVG figures, the raster's lines).

/// Liang-Barsky: the part of segment `a b` inside the closed rectangle
/// `[x_min, y_min, x_max, y_max]`, as its new end points; `None` if none of it is.
pub fn clip_segment(a: [f64; 2], b: [f64; 2], rect: [f64; 4]) -> Option<([f64; 2], [f64; 2])> {
    let d = [b[0] - a[0], b[1] - a[1]];
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for (p, q) in [
        (-d[0], a[0] - rect[0]),
        (d[0], rect[2] - a[0]),
        (-d[1], a[1] - rect[1]),
        (d[1], rect[3] - a[1]),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 <= t1).then(|| {
        let at = |t: f64| [a[0] + t * d[0], a[1] + t * d[1]];
        (at(t0), at(t1))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clips_to_the_rectangle() {
        let r = [0.0, 0.0, 10.0, 5.0];
        assert_eq!(
            clip_segment([-5.0, 2.0], [15.0, 2.0], r),
            Some(([0.0, 2.0], [10.0, 2.0]))
        );
        assert_eq!(
            clip_segment([1.0, 1.0], [2.0, 3.0], r),
            Some(([1.0, 1.0], [2.0, 3.0]))
        );
        assert_eq!(clip_segment([-5.0, 6.0], [15.0, 6.0], r), None);
        assert_eq!(clip_segment([-5.0, -1.0], [-1.0, 20.0], r), None);
        let (p, q) = clip_segment([-10.0, -5.0], [20.0, 10.0], r).unwrap();
        assert_eq!((p, q), ([0.0, 0.0], [10.0, 5.0]));
    }
}
