//! Grids around a part: series stay small when only one part matters.

use super::Grid;

impl Grid {
    /// The smallest grid on this grid's pixel lattice that covers `bbox` ([x_min, y_min, x_max,
    /// y_max] mm) plus `margin_mm`, clipped to this grid. Pixels keep their centers, so a crop's
    /// pixel is exactly a pixel of the full view.
    pub fn around(&self, bbox: [f64; 4], margin_mm: f64) -> Grid {
        let p = self.pixel_mm;
        // The tolerance keeps an edge already on the lattice from moving a whole pixel because of
        // rounding in the division.
        let eps = 1e-9;
        let snap_down = |v: f64, origin: f64| origin + ((v - origin) / p + eps).floor() * p;
        let snap_up = |v: f64, origin: f64| origin + ((v - origin) / p - eps).ceil() * p;
        let x_min = snap_down(bbox[0] - margin_mm, self.x_min).max(self.x_min);
        let x_max = snap_up(bbox[2] + margin_mm, self.x_min).min(self.x_max);
        let y_min = snap_down(bbox[1] - margin_mm, self.y_max).max(self.y_min);
        let y_max = snap_up(bbox[3] + margin_mm, self.y_max).min(self.y_max);
        Grid {
            x_min,
            x_max: x_max.max(x_min + p),
            y_min,
            y_max: y_max.max(y_min + p),
            pixel_mm: p,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crops_keep_pixel_centers_on_the_plate_lattice() {
        let plate = Grid::plate();
        let crop = plate.around([-65.03, 34.97, -39.98, 45.01], 2.0);
        for v in [crop.x_min - plate.x_min, plate.y_max - crop.y_max] {
            let steps = v / plate.pixel_mm;
            assert!((steps - steps.round()).abs() < 1e-9, "{crop:?}");
        }
        assert!(
            crop.x_min <= -67.03
                && crop.x_max >= -37.98
                && crop.y_min <= 32.97
                && crop.y_max >= 47.01
        );
        assert!(crop.x_min > -67.03 - plate.pixel_mm && crop.y_max < 47.01 + plate.pixel_mm);
        let (r, c) = crop.pixel_of(-60.0, 40.0);
        let (x, y) = crop.center_of(r.round(), c.round());
        let (pr, pc) = plate.pixel_of(x, y);
        assert!((pr - pr.round()).abs() < 1e-9 && (pc - pc.round()).abs() < 1e-9);
        let clipped = plate.around([100.0, 100.0, 200.0, 200.0], 5.0);
        assert_eq!((clipped.x_max, clipped.y_max), (137.5, 137.5));
    }
}
