//! ASCII PLY of the registered CT surface coloured by signed distance (paper figures 11-14):
//! blue = subtractive error (CT surface inside the vectors, Ψ < 0), yellow-red = additive
//! error (Ψ > 0), white near 0.

use std::io::{BufWriter, Write};
use std::path::Path;

use super::{write_err, Result};

/// Colour of a signed distance `d` (mm) on a scale saturating at ±`range_mm`.
pub fn color(d: f64, range_mm: f64) -> [u8; 3] {
    let t = (d.abs() / range_mm.max(f64::MIN_POSITIVE)).min(1.0);
    let c = |v: f64| (255.0 * v).round().clamp(0.0, 255.0) as u8;
    if d < 0.0 {
        // white → blue
        [c(1.0 - t), c(1.0 - t), 255]
    } else {
        // white → yellow (t = ½) → red
        [
            255,
            c((2.0 - 2.0 * t).min(1.0)),
            c((1.0 - 2.0 * t).max(0.0)),
        ]
    }
}

/// Write `points` (build mm) with colours from `distances_mm`.
pub fn write_ply(
    path: &Path,
    points: &[[f64; 3]],
    distances_mm: &[f64],
    range_mm: f64,
) -> Result<()> {
    let file = std::fs::File::create(path).map_err(write_err(path))?;
    let mut w = BufWriter::new(file);
    write_ply_to(&mut w, points, distances_mm, range_mm)
        .and_then(|_| w.flush())
        .map_err(write_err(path))
}

pub fn write_ply_to(
    w: &mut impl Write,
    points: &[[f64; 3]],
    distances_mm: &[f64],
    range_mm: f64,
) -> std::io::Result<()> {
    let n = points.len().min(distances_mm.len());
    write!(
        w,
        "ply\nformat ascii 1.0\ncomment layerwise CT surface, build mm, coloured by TSDF distance \
         (blue subtractive, red additive, saturating at {range_mm} mm)\nelement vertex {n}\n\
         property float x\nproperty float y\nproperty float z\nproperty uchar red\n\
         property uchar green\nproperty uchar blue\nend_header\n"
    )?;
    for (p, d) in points.iter().zip(distances_mm) {
        let [r, g, b] = color(*d, range_mm);
        writeln!(w, "{:.5} {:.5} {:.5} {r} {g} {b}", p[0], p[1], p[2])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_follow_the_paper() {
        assert_eq!(color(0.0, 0.1), [255, 255, 255]);
        assert_eq!(color(-0.1, 0.1), [0, 0, 255]); // subtractive: blue
        assert_eq!(color(0.05, 0.1), [255, 255, 0]); // yellow
        assert_eq!(color(0.3, 0.1), [255, 0, 0]); // additive: red
    }

    #[test]
    fn ascii_layout() {
        let mut out = Vec::new();
        write_ply_to(&mut out, &[[1.0, 2.0, 3.0]], &[-0.2], 0.1).expect("write");
        let text = String::from_utf8(out).expect("utf8");
        assert!(text.contains("element vertex 1\n"));
        assert!(
            text.ends_with("end_header\n1.00000 2.00000 3.00000 0 0 255\n"),
            "{text}"
        );
    }
}
