//! Augmentation that keeps the defect and takes away what should not decide the class: the
//! framing (a small rotation, scale and shift), the light (gain, contrast, gamma, a smooth
//! illumination gradient), the grain (a blur, added noise) and the camera's compression (a JPEG
//! re-compression at a low to middling quality, as another camera's files may have). Frames of
//! an oblique camera are only flipped left-right (the view, the light and the recoating direction
//! are not symmetric top to bottom); top-down patches and views also flip and turn by quarter
//! turns.

use super::input::Gray;
use super::rng::Rng;

/// What may be done to a picture.
#[derive(Clone, Copy, Debug)]
pub struct Augment {
    /// Vertical flips and quarter turns too (top-down pictures).
    pub isotropic: bool,
}

impl Augment {
    /// The recipe's name for the model file.
    pub fn describe(&self) -> String {
        format!(
            "{}; rotate ±3°, scale 0.92-1.08, shift ±4 % (reflected); gain 0.8-1.2, contrast 0.8-1.25, gamma 0.8-1.25, gradient ±15 %; blur (p 0.5), noise σ 0-4; JPEG quality 30-90 (p 0.3)",
            if self.isotropic { "flips and quarter turns" } else { "left-right flip" }
        )
    }

    /// An augmented copy of `img`.
    pub fn apply(&self, img: &Gray, rng: &mut Rng) -> Gray {
        let (w, h) = (img.width, img.height);
        let flip_x = rng.chance(0.5);
        let flip_y = self.isotropic && rng.chance(0.5);
        let turn = self.isotropic && w == h && rng.chance(0.5);
        let angle = rng.range(-3.0, 3.0).to_radians();
        let scale = rng.range(0.92, 1.08);
        let (dx, dy) = (
            rng.range(-0.04, 0.04) * w as f64,
            rng.range(-0.04, 0.04) * h as f64,
        );
        let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let (s, c) = (angle.sin() / scale, angle.cos() / scale);
        let gain = rng.range(0.8, 1.2) as f32;
        let contrast = rng.range(0.8, 1.25) as f32;
        let gamma = rng.range(0.8, 1.25) as f32;
        let (ga, gb, gc) = (
            rng.range(-0.15, 0.15),
            rng.range(-0.15, 0.15),
            rng.range(-0.1, 0.1),
        );
        let mean = img.px.iter().sum::<f32>() / img.px.len().max(1) as f32;
        // The gamma curve as a table of quarter grey levels (powf per pixel is the slow part).
        let curve: Vec<f32> = (0..=1020)
            .map(|q| 255.0 * (q as f32 / 1020.0).powf(gamma))
            .collect();
        let reflect = |v: f64, n: usize| {
            let m = (n - 1) as f64;
            if m <= 0.0 {
                return 0.0;
            }
            let p = v.rem_euclid(2.0 * m);
            if p > m {
                2.0 * m - p
            } else {
                p
            }
        };
        let mut px = vec![0f32; w * h];
        for (y, row) in px.chunks_mut(w).enumerate() {
            for (x, out) in row.iter_mut().enumerate() {
                // Output pixel → source pixel: undo shift, rotation and scale about the centre.
                let (mut u, mut v) = (x as f64 - cx - dx, y as f64 - cy - dy);
                if turn {
                    (u, v) = (v, -u);
                }
                let sx = c * u + s * v + cx;
                let sy = -s * u + c * v + cy;
                let sx = if flip_x { (w as f64 - 1.0) - sx } else { sx };
                let sy = if flip_y { (h as f64 - 1.0) - sy } else { sy };
                let value = img.bilinear(reflect(sx, w), reflect(sy, h));
                let (nx, ny) = ((x as f64 - cx) / w as f64, (y as f64 - cy) / h as f64);
                let light = 1.0 + ga * nx + gb * ny + gc * (nx * nx + ny * ny);
                let v = (mean + (value - mean) * contrast) * gain * light as f32;
                *out = curve[((v * 4.0).round() as usize).min(1020)];
            }
        }
        let mut out = Gray::new(w, h, px);
        if rng.chance(0.5) {
            out = blur3(&out);
        }
        let sigma = rng.range(0.0, 4.0);
        if sigma > 0.0 {
            for v in &mut out.px {
                *v = (*v + (rng.normal() * sigma) as f32).clamp(0.0, 255.0);
            }
        }
        if rng.chance(0.3) {
            out = recompress(&out, rng.range(30.0, 90.0).round() as u8);
        }
        out
    }
}

/// `img` through a JPEG of `quality` and back (8-bit grey; unchanged should the codec fail).
fn recompress(img: &Gray, quality: u8) -> Gray {
    let bytes: Vec<u8> = img
        .px
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let mut jpeg = Vec::new();
    let encoded = image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, quality).encode(
        &bytes,
        img.width as u32,
        img.height as u32,
        image::ExtendedColorType::L8,
    );
    let decoded = encoded
        .ok()
        .and_then(|()| image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg).ok())
        .map(|d| d.into_luma8());
    match decoded {
        Some(g) if g.width() as usize == img.width && g.height() as usize == img.height => {
            Gray::new(
                img.width,
                img.height,
                g.as_raw().iter().map(|&v| f32::from(v)).collect(),
            )
        }
        _ => img.clone(),
    }
}

/// A 3 x 3 box blur (edges clamped).
fn blur3(img: &Gray) -> Gray {
    let (w, h) = (img.width, img.height);
    let mut px = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut sum = 0f32;
            let mut n = 0f32;
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    sum += img.px[yy * w + xx];
                    n += 1.0;
                }
            }
            px[y * w + x] = sum / n;
        }
    }
    Gray::new(w, h, px)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn augmentation_is_seeded_and_keeps_the_size_and_range() {
        let img = Gray::new(32, 24, (0..768).map(|i| (i % 32 * 8) as f32).collect());
        let aug = Augment { isotropic: false };
        let a = aug.apply(&img, &mut Rng::new(3));
        let b = aug.apply(&img, &mut Rng::new(3));
        assert_eq!(a.px, b.px);
        assert_eq!((a.width, a.height), (32, 24));
        assert!(a.px.iter().all(|v| (0.0..=255.0).contains(v)));
        assert_ne!(a.px, aug.apply(&img, &mut Rng::new(4)).px);
    }

    #[test]
    fn recompression_keeps_the_picture_and_adds_blocks() {
        let img = Gray::new(
            64,
            48,
            (0..64 * 48)
                .map(|i| ((i % 64) * 3 + (i / 64) % 7 * 9) as f32)
                .collect(),
        );
        let low = recompress(&img, 30);
        assert_eq!((low.width, low.height), (64, 48));
        let diff = |a: &Gray| {
            a.px.iter()
                .zip(&img.px)
                .map(|(x, y)| (x - y).abs())
                .sum::<f32>()
                / img.px.len() as f32
        };
        let high = recompress(&img, 90);
        assert!(
            diff(&low) > diff(&high) && diff(&low) < 20.0 && diff(&high) > 0.0,
            "{} {}",
            diff(&low),
            diff(&high)
        );
    }
}
