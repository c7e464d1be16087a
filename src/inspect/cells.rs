//! A rectified view reduced to the inspection grid: per cell the mean grey level of its block of
//! series pixels and the texture (standard deviation over the block grown by one pixel each
//! side, so a cell of one pixel still sees 3 x 3). Powder is smooth, fused metal speckled: the
//! texture tells them apart whatever the light's gain.

use crate::geometry::Grid;
use crate::rectify::FrameLuma;
use rayon::prelude::*;

/// The inspection grid over `view` (the series grid): the same origin, `bin` x `bin` pixels a
/// cell with `bin` the nearest whole number to `pixel_mm / view.pixel_mm` (at least 1); a
/// partial last row or column of cells is dropped.
pub fn inspection_grid(view: &Grid, pixel_mm: f64) -> (Grid, usize) {
    let bin = ((pixel_mm / view.pixel_mm).round() as usize).max(1);
    let (rows, cols) = ((view.rows() / bin).max(1), (view.columns() / bin).max(1));
    let p = view.pixel_mm * bin as f64;
    let grid = Grid {
        x_min: view.x_min,
        x_max: view.x_min + cols as f64 * p,
        y_min: view.y_max - rows as f64 * p,
        y_max: view.y_max,
        pixel_mm: p,
    };
    (grid, bin)
}

/// Mean and texture of every cell of the inspection grid.
#[derive(Clone, Debug)]
pub struct Cells {
    pub rows: usize,
    pub cols: usize,
    pub mean: Vec<f32>,
    pub texture: Vec<f32>,
}

impl Cells {
    /// Reduces a rectified view (on `view`, the series grid) to `grid` of `bin`-pixel cells.
    /// Linear 16-bit luminance is scaled by 1/257 to the 8-bit range, so thresholds on grey
    /// levels read the same for both.
    pub fn from_luma(luma: &FrameLuma, view: &Grid, bin: usize) -> Cells {
        match luma {
            FrameLuma::Gamma8(g) => Cells::from_samples(
                g.as_raw(),
                g.width() as usize,
                g.height() as usize,
                view,
                bin,
                1.0,
            ),
            FrameLuma::Linear16(g) => Cells::from_samples(
                g.as_raw(),
                g.width() as usize,
                g.height() as usize,
                view,
                bin,
                1.0 / 257.0,
            ),
        }
    }

    /// From row-major samples `w` x `h` (8 or 16 bits: sums stay integer, so the pass is cheap).
    pub fn from_samples<T: Copy + Into<u32> + Sync>(
        px: &[T],
        w: usize,
        h: usize,
        view: &Grid,
        bin: usize,
        scale: f64,
    ) -> Cells {
        let bin = bin.max(1);
        let (rows, cols) = ((view.rows() / bin).max(1), (view.columns() / bin).max(1));
        let mut mean = vec![0f32; rows * cols];
        let mut texture = vec![0f32; rows * cols];
        if w == 0 || h == 0 || px.len() < w * h {
            return Cells {
                rows,
                cols,
                mean,
                texture,
            };
        }
        mean.par_chunks_mut(cols)
            .zip(texture.par_chunks_mut(cols))
            .enumerate()
            .for_each(|(i, (mean_row, tex_row))| {
                let r0 = (i * bin).min(h - 1);
                let r1 = ((i + 1) * bin).min(h);
                let (e0, e1) = (r0.saturating_sub(1), (r1 + 1).min(h));
                // Per column: sum over the cell's rows; sum and sum of squares over the grown rows.
                let mut core = vec![0u64; w];
                let mut s1 = vec![0u64; w];
                let mut s2 = vec![0u64; w];
                for r in e0..e1 {
                    let line = &px[r * w..(r + 1) * w];
                    if r >= r0 && r < r1 {
                        for (((&v, a), b), c) in
                            line.iter().zip(&mut s1).zip(&mut s2).zip(&mut core)
                        {
                            let v = u64::from(v.into());
                            *a += v;
                            *b += v * v;
                            *c += v;
                        }
                    } else {
                        for ((&v, a), b) in line.iter().zip(&mut s1).zip(&mut s2) {
                            let v = u64::from(v.into());
                            *a += v;
                            *b += v * v;
                        }
                    }
                }
                let core_rows = (r1 - r0).max(1);
                for (j, (mean_cell, tex_cell)) in
                    mean_row.iter_mut().zip(tex_row.iter_mut()).enumerate()
                {
                    let c0 = (j * bin).min(w - 1);
                    let c1 = ((j + 1) * bin).min(w).max(c0 + 1);
                    let sum: u64 = core[c0..c1].iter().sum();
                    *mean_cell = (scale * sum as f64 / ((c1 - c0) * core_rows) as f64) as f32;
                    let (g0, g1) = (c0.saturating_sub(1), (c1 + 1).min(w));
                    let n = ((g1 - g0) * (e1 - e0)) as f64;
                    let a = s1[g0..g1].iter().sum::<u64>() as f64 / n;
                    let b = s2[g0..g1].iter().sum::<u64>() as f64 / n;
                    *tex_cell = (scale * (b - a * a).max(0.0).sqrt()) as f32;
                }
            });
        Cells {
            rows,
            cols,
            mean,
            texture,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_bins_and_cells_average_and_measure_texture() {
        let view = Grid {
            x_min: -10.0,
            x_max: 10.0,
            y_min: -10.0,
            y_max: 10.0,
            pixel_mm: 0.25,
        };
        let (grid, bin) = inspection_grid(&view, 0.5);
        assert_eq!((bin, grid.rows(), grid.columns()), (2, 40, 40));
        assert_eq!(grid.pixel_mm, 0.5);
        let (w, h) = (80, 80);
        // Left half flat 100, right half a checkerboard 50/150 (texture 50).
        let px: Vec<u8> = (0..w * h)
            .map(|i| {
                let (r, c) = (i / w, i % w);
                if c < 40 {
                    100
                } else if (r + c) % 2 == 0 {
                    50
                } else {
                    150
                }
            })
            .collect();
        let cells = Cells::from_samples(&px, w, h, &view, bin, 1.0);
        assert_eq!((cells.rows, cells.cols), (40, 40));
        assert_eq!(cells.mean[5 * 40 + 3], 100.0);
        assert_eq!(cells.texture[5 * 40 + 3], 0.0);
        assert_eq!(cells.mean[5 * 40 + 30], 100.0);
        assert!((cells.texture[5 * 40 + 30] - 50.0).abs() < 1.0);
    }
}
