//! What the model sees: a grey picture reduced to cells (mean grey level and texture per cell, as
//! the inspection's cells are) and normalised per input so that neither the overall brightness
//! nor the overall grain level of a frame can decide its class (on the pblm collection each class
//! is one session, and those two numbers alone separate them: docs/learning.md).
//!
//! Two recipes, named in every model file ([`Normalisation`]):
//! - [`FLATFIELD`] (files before December 2026): mean channel, the cell mean less its 15 x 15-cell
//!   box mean (a flat field, so vignetting and the light's fall-off go), divided by 1.4826 x the
//!   median absolute value of that difference over the input (at least 0.5 grey levels), clipped
//!   to ±6; texture channel, ln((t + 0.5) / (median t + 0.5)) of the cell's standard deviation t
//!   over the cell grown by one pixel each side, clipped to ±6.
//! - [`EQUALISED`] (the default since): both channels freed of the camera's tone curve `g` (any
//!   order-keeping one: gamma, contrast, another camera's JPEG rendering), to first order. Near a
//!   grey level v, `g` multiplies differences and textures by g'(v). The mean channel's
//!   difference is divided by the box mean of the textures over the same 15 x 15 cells (the grain
//!   there), so it is a contrast against the powder's own grain; the texture is multiplied by the
//!   density of the picture's cell means at the cell's mean, F'(m) (the slope of the picture's
//!   equalisation: 255 x (2k / n) over the spread of the sorted means k below and k above m, k =
//!   n / 16), which `g` divides by g'(m). Then the scaling and clip above. What the model learns
//!   of one camera's frames carries to another's. (Ranks alone would not do: the darkest cells
//!   of clean powder rank as low as a streak, and the streak's contrast is lost.)

use serde::{Deserialize, Serialize};

use super::framing::{self, Framing};

/// The grey-level recipe's name (model files before December 2026).
pub const FLATFIELD: &str = "flatfield15-mad/log-texture-median/clip6";
/// The recipe unchanged by a tone curve, to first order.
pub const EQUALISED: &str = "flatfield15-over-grain15-mad/log-texture-density-median/clip6";
/// Input channels in order.
pub const CHANNELS: [&str; 2] = ["mean", "texture"];
const CLIP: f32 = 6.0;
const FLAT_RADIUS: usize = 7;

/// A grey picture, values on the 8-bit scale (16-bit values divided by 257).
#[derive(Clone, Debug)]
pub struct Gray {
    pub width: usize,
    pub height: usize,
    pub px: Vec<f32>,
}

impl Gray {
    pub fn new(width: usize, height: usize, px: Vec<f32>) -> Gray {
        debug_assert_eq!(px.len(), width * height);
        Gray { width, height, px }
    }

    pub fn from_luma(luma: &crate::rectify::FrameLuma) -> Gray {
        match luma {
            crate::rectify::FrameLuma::Gamma8(g) => Gray::new(
                g.width() as usize,
                g.height() as usize,
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            ),
            crate::rectify::FrameLuma::Linear16(g) => Gray::new(
                g.width() as usize,
                g.height() as usize,
                g.as_raw().iter().map(|&v| f32::from(v) / 257.0).collect(),
            ),
        }
    }

    pub fn at(&self, x: usize, y: usize) -> f32 {
        self.px[y * self.width + x]
    }

    /// The part of the picture `framing` reads (before it is resampled to the square).
    pub fn framed(&self, framing: Framing) -> Gray {
        match framing {
            Framing::CentreSquare => self.center_square(),
            Framing::Bed => {
                let p = framing::bed(self.width, self.height, &self.px);
                if (p.x0, p.x1, p.y0, p.y1) == (0, self.width, 0, self.height) {
                    return self.clone();
                }
                let px = (p.y0..p.y1)
                    .flat_map(|y| {
                        self.px[y * self.width + p.x0..y * self.width + p.x1]
                            .iter()
                            .copied()
                    })
                    .collect();
                Gray::new(p.x1 - p.x0, p.y1 - p.y0, px)
            }
        }
    }

    /// The centred square of side min(width, height).
    pub fn center_square(&self) -> Gray {
        let s = self.width.min(self.height);
        let (x0, y0) = ((self.width - s) / 2, (self.height - s) / 2);
        let mut px = Vec::with_capacity(s * s);
        for y in y0..y0 + s {
            px.extend_from_slice(&self.px[y * self.width + x0..y * self.width + x0 + s]);
        }
        Gray::new(s, s, px)
    }

    /// Resampled to `w` x `h`: area average when shrinking, bilinear when growing.
    pub fn resize(&self, w: usize, h: usize) -> Gray {
        if (w, h) == (self.width, self.height) {
            return self.clone();
        }
        let (sx, sy) = (self.width as f64 / w as f64, self.height as f64 / h as f64);
        let mut px = vec![0f32; w * h];
        if sx >= 1.0 && sy >= 1.0 {
            for (y, row) in px.chunks_mut(w).enumerate() {
                let y0 = (y as f64 * sy) as usize;
                let y1 = (((y + 1) as f64 * sy).ceil() as usize).clamp(y0 + 1, self.height);
                for (x, out) in row.iter_mut().enumerate() {
                    let x0 = (x as f64 * sx) as usize;
                    let x1 = (((x + 1) as f64 * sx).ceil() as usize).clamp(x0 + 1, self.width);
                    let mut sum = 0f32;
                    for yy in y0..y1 {
                        sum += self.px[yy * self.width + x0..yy * self.width + x1]
                            .iter()
                            .sum::<f32>();
                    }
                    *out = sum / ((y1 - y0) * (x1 - x0)) as f32;
                }
            }
        } else {
            for (y, row) in px.chunks_mut(w).enumerate() {
                let fy = ((y as f64 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f64);
                for (x, out) in row.iter_mut().enumerate() {
                    let fx = ((x as f64 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f64);
                    *out = self.bilinear(fx, fy);
                }
            }
        }
        Gray::new(w, h, px)
    }

    /// Bilinear sample at (x, y), clamped to the picture.
    pub fn bilinear(&self, x: f64, y: f64) -> f32 {
        let x = x.clamp(0.0, (self.width - 1) as f64);
        let y = y.clamp(0.0, (self.height - 1) as f64);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let a = self.at(x0, y0) * (1.0 - fx) + self.at(x1, y0) * fx;
        let b = self.at(x0, y1) * (1.0 - fx) + self.at(x1, y1) * fx;
        a * (1.0 - fy) + b * fy
    }
}

/// How cell means and textures become the model's input; recorded by its name in the model file
/// (`input.normalisation`), and a file naming a recipe this layerwise does not know is refused.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Normalisation {
    /// [`FLATFIELD`]: grey levels.
    #[serde(rename = "flatfield15-mad/log-texture-median/clip6")]
    Flatfield,
    /// [`EQUALISED`]: contrast against the grain, texture on the equalised scale.
    #[default]
    #[serde(rename = "flatfield15-over-grain15-mad/log-texture-density-median/clip6")]
    Equalised,
}

impl Normalisation {
    /// The name recorded in model files.
    pub fn name(self) -> &'static str {
        match self {
            Normalisation::Flatfield => FLATFIELD,
            Normalisation::Equalised => EQUALISED,
        }
    }

    /// The input of a `rows` x `cols` map of raw cell means and textures.
    pub fn apply(self, rows: usize, cols: usize, mean: &[f32], texture: &[f32]) -> Input {
        match self {
            Normalisation::Flatfield => {
                let flat = box_mean(rows, cols, mean, FLAT_RADIUS);
                let diff = mean.iter().zip(&flat).map(|(m, f)| m - f).collect();
                scaled(rows, cols, diff, texture.to_vec())
            }
            Normalisation::Equalised => {
                let flat = box_mean(rows, cols, mean, FLAT_RADIUS);
                let grain = box_mean(rows, cols, texture, FLAT_RADIUS);
                let density = Density::of(mean);
                let diff = mean
                    .iter()
                    .zip(&flat)
                    .zip(&grain)
                    .map(|((m, f), g)| (m - f) / g.max(1e-3))
                    .collect();
                let texture = mean
                    .iter()
                    .zip(texture)
                    .map(|(m, t)| t * density.slope(*m))
                    .collect();
                scaled(rows, cols, diff, texture)
            }
        }
    }
}

/// The largest input a model may take: cells a side, pixels a cell, and the side of the square a
/// frame is resampled to (a 4096 px square is 64 MiB of f32, its 1024 x 1024 cells 8 MiB a
/// channel). Training refuses options beyond them, and a model file that declares more is damaged.
pub const MAX_CELLS: usize = 1024;
pub const MAX_CELL_PX: usize = 64;
pub const MAX_FRAME_PX: usize = 4096;

/// How a picture becomes the model's input; recorded in the model file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// Channel names ([`CHANNELS`]).
    pub channels: Vec<String>,
    /// Cells of one input, rows x columns (whole frames and patches; a view is scanned at any size).
    pub cells: [usize; 2],
    /// Pixels per cell side of the canonical picture.
    pub cell_px: usize,
    /// Frames: the centred square is resampled to this many pixels a side before the cells
    /// (`None`: patches, taken as they are, centre-cropped to the cells).
    pub frame_px: Option<usize>,
    /// Millimetres per cell on the build plate, when the training data had a scale (flaws
    /// patches, build views); `None` for camera frames of unknown scale.
    pub cell_mm: Option<f64>,
    /// Cells per tile of the class map (the heat map's resolution).
    pub map_stride_cells: usize,
    /// The normalisation recipe.
    pub normalisation: Normalisation,
    /// Frames: what part of the picture becomes the canonical square (files without it: the
    /// centred square).
    #[serde(default, skip_serializing_if = "Framing::is_centre_square")]
    pub framing: Framing,
}

impl InputSpec {
    /// Whether this input is one that training writes for a network of `stride` cells a tile:
    /// the two channels, at least a tile and at most [`MAX_CELLS`] cells a side, 1 to
    /// [`MAX_CELL_PX`] px a cell, frames resampled to a square of exactly their cells (at most
    /// [`MAX_FRAME_PX`]), the class map's tile the network's stride, a positive scale. `Err`
    /// names the header's field and what is wrong with it.
    pub fn check(&self, stride: usize) -> Result<(), (&'static str, String)> {
        if self.channels.iter().map(String::as_str).ne(CHANNELS) {
            return Err((
                "input.channels",
                format!("{:?}; this layerwise computes {CHANNELS:?}", self.channels),
            ));
        }
        let least = stride.max(4);
        if self.cells.iter().any(|c| !(least..=MAX_CELLS).contains(c)) {
            return Err((
                "input.cells",
                format!(
                    "{:?} cells; {least} to {MAX_CELLS} a side for this network",
                    self.cells
                ),
            ));
        }
        if !(1..=MAX_CELL_PX).contains(&self.cell_px) {
            return Err((
                "input.cell_px",
                format!("{} px a cell; 1 to {MAX_CELL_PX}", self.cell_px),
            ));
        }
        if let Some(f) = self.frame_px {
            let [rows, cols] = self.cells;
            if rows != cols || f != rows * self.cell_px || f > MAX_FRAME_PX {
                return Err((
                    "input.frame_px",
                    format!(
                        "{f} px is not the square of {rows}x{cols} cells of {} px (at most {MAX_FRAME_PX} px)",
                        self.cell_px
                    ),
                ));
            }
        }
        if self.map_stride_cells != stride {
            return Err((
                "input.map_stride_cells",
                format!(
                    "{}; the network's class map has a tile every {stride} cells",
                    self.map_stride_cells
                ),
            ));
        }
        if let Some(mm) = self.cell_mm.filter(|mm| !(mm.is_finite() && *mm > 0.0)) {
            return Err((
                "input.cell_mm",
                format!("{mm} mm; a cell's size is positive"),
            ));
        }
        Ok(())
    }

    /// The input size in pixels of the canonical picture.
    pub fn input_px(&self) -> [usize; 2] {
        [self.cells[0] * self.cell_px, self.cells[1] * self.cell_px]
    }

    /// The model's input of a canonical picture ([`InputSpec::canonical`]).
    pub fn input(&self, canonical: &Gray) -> Input {
        cells(canonical, self.cell_px, self.normalisation)
    }

    /// The canonical picture of a frame or patch: frames are framed ([`Framing`]) and resampled
    /// to `frame_px`; patches are centre-cropped to the input size. `None` when a patch is smaller
    /// than the input.
    pub fn canonical(&self, img: &Gray) -> Option<Gray> {
        let [h, w] = self.input_px();
        match self.frame_px {
            Some(f) => Some(img.framed(self.framing).resize(f, f)),
            None => {
                if img.width < w || img.height < h {
                    return None;
                }
                let (x0, y0) = ((img.width - w) / 2, (img.height - h) / 2);
                let mut px = Vec::with_capacity(w * h);
                for y in y0..y0 + h {
                    px.extend_from_slice(&img.px[y * img.width + x0..y * img.width + x0 + w]);
                }
                Some(Gray::new(w, h, px))
            }
        }
    }
}

/// A normalised input: `channels` x `rows` x `cols`, channel-major.
#[derive(Clone, Debug)]
pub struct Input {
    pub rows: usize,
    pub cols: usize,
    pub data: Vec<f32>,
}

/// Cells of `cell_px` pixels over the whole picture (a partial last row or column dropped),
/// normalised by `recipe`: the model's input.
pub fn cells(img: &Gray, cell_px: usize, recipe: Normalisation) -> Input {
    let cp = cell_px.max(1);
    let (rows, cols) = ((img.height / cp).max(1), (img.width / cp).max(1));
    let (w, h) = (img.width, img.height);
    // Integral images of values and squares (f64: exact enough for millions of pixels).
    let mut s1 = vec![0f64; (w + 1) * (h + 1)];
    let mut s2 = vec![0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let (mut r1, mut r2) = (0f64, 0f64);
        for x in 0..w {
            let v = f64::from(img.px[y * w + x]);
            r1 += v;
            r2 += v * v;
            s1[(y + 1) * (w + 1) + x + 1] = s1[y * (w + 1) + x + 1] + r1;
            s2[(y + 1) * (w + 1) + x + 1] = s2[y * (w + 1) + x + 1] + r2;
        }
    }
    let rect = |s: &[f64], x0: usize, y0: usize, x1: usize, y1: usize| {
        s[y1 * (w + 1) + x1] - s[y0 * (w + 1) + x1] - s[y1 * (w + 1) + x0] + s[y0 * (w + 1) + x0]
    };
    let mut mean = vec![0f32; rows * cols];
    let mut texture = vec![0f32; rows * cols];
    for r in 0..rows {
        let (y0, y1) = ((r * cp).min(h - 1), ((r + 1) * cp).min(h));
        let (g0, g1) = (y0.saturating_sub(1), (y1 + 1).min(h));
        for c in 0..cols {
            let (x0, x1) = ((c * cp).min(w - 1), ((c + 1) * cp).min(w));
            let n = ((y1 - y0) * (x1 - x0)) as f64;
            mean[r * cols + c] = (rect(&s1, x0, y0, x1, y1) / n) as f32;
            let (e0, e1) = (x0.saturating_sub(1), (x1 + 1).min(w));
            let n = ((g1 - g0) * (e1 - e0)) as f64;
            let a = rect(&s1, e0, g0, e1, g1) / n;
            let b = rect(&s2, e0, g0, e1, g1) / n;
            texture[r * cols + c] = (b - a * a).max(0.0).sqrt() as f32;
        }
    }
    recipe.apply(rows, cols, &mean, &texture)
}

/// The slope of a picture's equalisation: the density of its cell means, 255 x (2k / n) over the
/// spread of the sorted means k below and k above a grey level (k = n / 16, at least 2).
struct Density {
    sorted: Vec<f32>,
    k: usize,
}

impl Density {
    fn of(mean: &[f32]) -> Density {
        let mut sorted = mean.to_vec();
        sorted.sort_unstable_by(f32::total_cmp);
        Density {
            k: (sorted.len() / 16).max(2),
            sorted,
        }
    }

    /// F'(v), in equalised grey levels (0-255 over the picture) per grey level.
    fn slope(&self, v: f32) -> f32 {
        let n = self.sorted.len();
        if n < 2 {
            return 1.0;
        }
        let j = self.sorted.partition_point(|&x| x < v);
        let (lo, hi) = (j.saturating_sub(self.k), (j + self.k).min(n - 1));
        // A spread of (almost) nothing is a run of equal means (a saturated or padded area): the
        // slope there is bounded by the floor, and the channels' clip bounds what it gives.
        let spread = (self.sorted[hi] - self.sorted[lo]).max(1e-3);
        255.0 * (hi - lo) as f32 / (n as f32 * spread)
    }
}

fn median(values: &mut [f32]) -> f32 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// The box mean of radius `r` cells (edge-clamped window) of a `rows` x `cols` map.
fn box_mean(rows: usize, cols: usize, v: &[f32], r: usize) -> Vec<f32> {
    let mut s = vec![0f64; (rows + 1) * (cols + 1)];
    for y in 0..rows {
        let mut run = 0f64;
        for x in 0..cols {
            run += f64::from(v[y * cols + x]);
            s[(y + 1) * (cols + 1) + x + 1] = s[y * (cols + 1) + x + 1] + run;
        }
    }
    let mut out = vec![0f32; rows * cols];
    for y in 0..rows {
        let (y0, y1) = (y.saturating_sub(r), (y + r + 1).min(rows));
        for x in 0..cols {
            let (x0, x1) = (x.saturating_sub(r), (x + r + 1).min(cols));
            let sum = s[y1 * (cols + 1) + x1] - s[y0 * (cols + 1) + x1] - s[y1 * (cols + 1) + x0]
                + s[y0 * (cols + 1) + x0];
            out[y * cols + x] = (sum / ((y1 - y0) * (x1 - x0)) as f64) as f32;
        }
    }
    out
}

/// The channels from flat-fielded differences and textures: the differences over 1.4826 x
/// their median absolute value (at least 0.5), the textures as ln((t + 0.5) / (median + 0.5)),
/// both clipped to ±6.
fn scaled(rows: usize, cols: usize, diff: Vec<f32>, texture: Vec<f32>) -> Input {
    let mut abs: Vec<f32> = diff.iter().map(|d| d.abs()).collect();
    let scale = (1.4826 * median(&mut abs)).max(0.5);
    let mut t = texture.clone();
    let tm = median(&mut t) + 0.5;
    let mut data = diff;
    for d in &mut data {
        *d = (*d / scale).clamp(-CLIP, CLIP);
    }
    data.extend(
        texture
            .iter()
            .map(|t| ((t + 0.5) / tm).ln().clamp(-CLIP, CLIP)),
    );
    Input { rows, cols, data }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn brightness_and_grain_level_do_not_change_the_input() {
        // A bright bar on a speckled ground; the same scene darker with twice the grain.
        let make = |gain: f32, grain: f32| {
            let px = (0..64 * 64)
                .map(|i| {
                    let (y, x) = (i / 64, i % 64);
                    let speckle = if (x * 7 + y * 13) % 5 == 0 {
                        grain
                    } else {
                        0.0
                    };
                    let bar = if (20..28).contains(&x) { 30.0 } else { 0.0 };
                    gain * (100.0 + bar + speckle)
                })
                .collect();
            cells(&Gray::new(64, 64, px), 4, Normalisation::Flatfield)
        };
        let (a, b) = (make(1.0, 4.0), make(0.5, 8.0));
        assert_eq!((a.rows, a.cols), (16, 16));
        let bar = |i: &Input| i.data[8 * 16 + 5];
        assert!(bar(&a) > 1.0, "{}", bar(&a));
        let t = |i: &Input| i.data[256 + 8 * 16 + 1];
        assert!((t(&a) - t(&b)).abs() < 0.5, "{} {}", t(&a), t(&b));
    }

    /// A bed of grain with a vignette, a bright streak and a rough patch.
    fn bed(size: usize) -> Gray {
        let mut state = 12345u64;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32 - 0.5
        };
        let c = size as f32 / 2.0;
        let px = (0..size * size)
            .map(|i| {
                let (y, x) = ((i / size) as f32, (i % size) as f32);
                let vignette = 1.0 - 0.6 * ((x - c).powi(2) + (y - c).powi(2)) / (c * c);
                let streak = if (40.0..46.0).contains(&x) { 25.0 } else { 0.0 };
                let rough = if (80.0..110.0).contains(&x) && (20.0..60.0).contains(&y) {
                    40.0
                } else {
                    8.0
                };
                (vignette * 170.0 + streak + rough * noise()).clamp(0.0, 255.0)
            })
            .collect();
        Gray::new(size, size, px)
    }

    #[test]
    fn the_equalised_input_does_not_change_under_a_tone_curve_and_grey_levels_do() {
        let img = bed(128);
        type Curve = fn(f32) -> f32;
        let curves: [(&str, Curve); 3] = [
            ("gamma 1.3", |v| 255.0 * (v / 255.0).powf(1.3)),
            ("gamma 0.8", |v| 255.0 * (v / 255.0).powf(0.8)),
            ("s-curve", |v| 255.0 / (1.0 + (-(v - 110.0) / 30.0).exp())),
        ];
        let change = |recipe: Normalisation, g: Curve| {
            let curved = Gray::new(
                img.width,
                img.height,
                img.px.iter().map(|&v| g(v)).collect(),
            );
            let (a, b) = (cells(&img, 4, recipe), cells(&curved, 4, recipe));
            let n = a.data.len() as f32;
            a.data
                .iter()
                .zip(&b.data)
                .map(|(x, y)| (x - y).abs())
                .sum::<f32>()
                / n
        };
        for (name, g) in curves {
            // A strong vignette (0.4 to 1 of the centre's level): the curve's slope differs
            // across the picture. Measured: the equalised input moves 0.35-0.44 of the grey
            // levels' (0.045 / 0.120 at gamma 1.3, 0.035 / 0.089 at 0.8, 0.113 / 0.259 s-curve).
            let (equalised, grey) = (
                change(Normalisation::Equalised, g),
                change(Normalisation::Flatfield, g),
            );
            assert!(
                equalised < grey / 2.0,
                "{name}: the equalised input moves {equalised}, grey levels {grey}"
            );
        }
        // The streak and the rough patch still stand out.
        let input = cells(&img, 4, Normalisation::Equalised);
        let (rows, cols) = (input.rows, input.cols);
        let at = |ch: usize, r: usize, c: usize| input.data[ch * rows * cols + r * cols + c];
        assert!(at(0, 16, 10) > 1.0, "streak {}", at(0, 16, 10));
        assert!(
            at(1, 10, 23) > at(1, 24, 23) + 0.5,
            "rough {} smooth {}",
            at(1, 10, 23),
            at(1, 24, 23)
        );
    }

    #[test]
    fn the_density_is_the_slope_of_the_equalisation_and_a_flat_input_is_finite() {
        // 640 means spread evenly over 0..64: 10 a grey level, so F' = 255 / 64 everywhere.
        let mean: Vec<f32> = (0..640).map(|i| i as f32 / 10.0).collect();
        let d = Density::of(&mean);
        for v in [5.0, 32.0, 60.0] {
            assert!(
                (d.slope(v) - 255.0 / 64.0).abs() < 0.1,
                "{v}: {}",
                d.slope(v)
            );
        }
        let flat = Normalisation::Equalised.apply(4, 4, &[7.0; 16], &[0.0; 16]);
        assert!(flat.data.iter().all(|v| v.is_finite()), "{:?}", flat.data);
    }

    #[test]
    fn a_bed_framed_frame_in_a_dark_surround_gives_the_frame_s_canonical_square() {
        let (w, h) = (120, 90);
        let frame = Gray::new(
            w,
            h,
            (0..w * h).map(|i| 90.0 + ((i * 7) % 23) as f32).collect(),
        );
        let mut px = vec![8.0; 170 * 130];
        for r in 0..h {
            px[(r + 31) * 170 + 12..(r + 31) * 170 + 12 + w]
                .copy_from_slice(&frame.px[r * w..(r + 1) * w]);
        }
        let wide = Gray::new(170, 130, px);
        let spec = |framing| InputSpec {
            channels: CHANNELS.map(String::from).to_vec(),
            cells: [8, 8],
            cell_px: 4,
            frame_px: Some(32),
            cell_mm: None,
            map_stride_cells: 2,
            normalisation: Normalisation::Equalised,
            framing,
        };
        let (bed, square) = (spec(Framing::Bed), spec(Framing::CentreSquare));
        let canonical = |s: &InputSpec, g: &Gray| s.canonical(g).unwrap().px;
        assert_eq!(canonical(&bed, &frame), canonical(&bed, &wide));
        assert_eq!(canonical(&bed, &frame), frame.resize(32, 32).px);
        assert_ne!(canonical(&square, &frame), canonical(&square, &wide));
    }

    #[test]
    fn frames_are_squared_and_resampled_patches_cropped() {
        let img = Gray::new(40, 20, (0..800).map(|i| (i % 40) as f32).collect());
        let sq = img.center_square();
        assert_eq!((sq.width, sq.height, sq.at(0, 0)), (20, 20, 10.0));
        let small = sq.resize(10, 10);
        assert!((small.at(0, 0) - 10.5).abs() < 1e-4);
        let spec = InputSpec {
            channels: CHANNELS.map(String::from).to_vec(),
            cells: [4, 4],
            cell_px: 2,
            frame_px: None,
            cell_mm: Some(0.1),
            map_stride_cells: 2,
            normalisation: Normalisation::Flatfield,
            framing: Framing::CentreSquare,
        };
        let c = spec.canonical(&img).unwrap();
        assert_eq!((c.width, c.height, c.at(0, 0)), (8, 8, 16.0));
        assert!(spec.canonical(&Gray::new(6, 6, vec![0.0; 36])).is_none());
    }
}
