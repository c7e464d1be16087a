//! Running a model: a picture's class with every class's probability and the per-tile
//! probabilities (the class map), an evaluation over a labelled folder, and the heat map.

use super::data::{read_item, Dataset, Item, Part};
use super::error::LearnError;
use super::file::{Model, Use};
use super::input::{Gray, Input, CHANNELS};
use super::metrics::Metrics;
use super::net;
use image::{GrayImage, Rgb, RgbImage};
use rayon::prelude::*;
use serde::Serialize;
use std::path::Path;

/// A picture's class.
#[derive(Clone, Debug, Serialize)]
pub struct Prediction {
    pub class: String,
    pub probability: f64,
    /// Every class's probability, in the model's class order.
    pub probabilities: Vec<(String, f64)>,
    /// Per tile of the class map: `[rows][cols][classes]`.
    #[serde(skip)]
    pub tiles: Vec<Vec<Vec<f32>>>,
}

impl Model {
    /// The model's input of a picture (frames squared and resampled, patches centre-cropped).
    pub fn input(&self, img: &Gray) -> Option<Input> {
        let spec = &self.header.input;
        spec.canonical(img).map(|c| spec.input(&c))
    }

    /// Class and tile probabilities of an input.
    pub fn classify(&self, input: &Input) -> Result<Prediction, LearnError> {
        let x = net::tensor(input, CHANNELS.len())?;
        let cam = self.net.cam(&x)?;
        let p = net::softmax(&self.net.pool(&cam)?)?.remove(0);
        let tiles = net::tile_probabilities(&cam)?;
        let best = (0..p.len())
            .max_by(|&a, &b| p[a].total_cmp(&p[b]))
            .unwrap_or(0);
        Ok(Prediction {
            class: self.header.classes[best].clone(),
            probability: f64::from(p[best]),
            probabilities: self
                .header
                .classes
                .iter()
                .cloned()
                .zip(p.iter().map(|v| f64::from(*v)))
                .collect(),
            tiles,
        })
    }

    /// Reads and classifies one picture.
    pub fn predict_file(&self, path: &Path) -> Result<(Gray, Prediction), LearnError> {
        let img = super::data::read_picture(path)?;
        self.check_use(self.use_for(&img))?;
        let input = self
            .input(&img)
            .ok_or_else(|| LearnError::data(path, "smaller than the model's input"))?;
        let p = self.classify(&input)?;
        Ok((img, p))
    }

    fn use_for(&self, img: &Gray) -> Use {
        if self.header.input.frame_px.is_some() {
            Use::Frames
        } else {
            Use::Patches {
                w: img.width,
                h: img.height,
            }
        }
    }

    /// A part of the split is held out only if the model was not refit on every picture.
    pub fn check_part(&self, part: Option<Part>) -> Result<(), LearnError> {
        match part {
            Some(p) if self.header.training.refit.is_some() => Err(LearnError::RefitPart {
                path: self.path.clone(),
                part: match p {
                    Part::Train => "training",
                    Part::Val => "validation",
                    Part::Dropped => "left-out",
                },
            }),
            _ => Ok(()),
        }
    }

    /// Evaluates on a labelled folder (its classes must be the model's); `part` limits it to the
    /// training or the validation part of the split the model was trained with.
    pub fn evaluate(&self, data: &Dataset, part: Option<Part>) -> Result<Metrics, LearnError> {
        let classes = &self.header.classes;
        if let Some(unknown) = data.classes.iter().find(|c| !classes.contains(c)) {
            return Err(LearnError::data(
                &data.root,
                format!("class {unknown} is not one the model knows ({classes:?})"),
            ));
        }
        self.check_part(part)?;
        let parts = data.split(self.header.training.split.val_fraction);
        let items: Vec<_> = data
            .items
            .iter()
            .zip(&parts)
            .filter(|(_, p)| part.is_none_or(|want| **p == want))
            .map(|(i, _)| i)
            .collect();
        let pairs = self.classify_items(data, &items)?;
        Ok(Metrics::new(classes, &pairs))
    }

    /// (true, predicted) class indices, in the model's class order, of `items` of `data`.
    pub fn classify_items(
        &self,
        data: &Dataset,
        items: &[&Item],
    ) -> Result<Vec<(usize, usize)>, LearnError> {
        let classes = &self.header.classes;
        items
            .par_iter()
            .map(|item| {
                let img = read_item(item)?;
                self.check_use(self.use_for(&img))?;
                let input = self.input(&img).ok_or_else(|| {
                    LearnError::data(&item.path, "smaller than the model's input")
                })?;
                let p = self.classify(&input)?;
                let truth = classes
                    .iter()
                    .position(|c| *c == data.classes[item.class])
                    .unwrap_or(0);
                let predicted = classes.iter().position(|c| *c == p.class).unwrap_or(0);
                Ok((truth, predicted))
            })
            .collect()
    }
}

/// A heat map over the picture: the picture in grey, tinted red by each tile's probability of
/// not being the normal class (bilinear between tile centres), over the canonical square.
pub fn heatmap(model: &Model, img: &Gray, prediction: &Prediction) -> RgbImage {
    let spec = &model.header.input;
    let canonical = spec.canonical(img).unwrap_or_else(|| img.clone());
    let normal = model
        .header
        .classes
        .iter()
        .position(|c| *c == model.header.normal_class)
        .unwrap_or(0);
    let (th, tw) = (
        prediction.tiles.len(),
        prediction.tiles.first().map_or(0, |r| r.len()),
    );
    let score: Vec<f32> = prediction
        .tiles
        .iter()
        .flatten()
        .map(|p| 1.0 - p[normal])
        .collect();
    let map = Gray::new(
        tw.max(1),
        th.max(1),
        if score.is_empty() { vec![0.0] } else { score },
    );
    let (w, h) = (canonical.width, canonical.height);
    let grey = GrayImage::from_fn(w as u32, h as u32, |x, y| {
        image::Luma([canonical.at(x as usize, y as usize).clamp(0.0, 255.0) as u8])
    });
    RgbImage::from_fn(w as u32, h as u32, |x, y| {
        let g = f32::from(grey.get_pixel(x, y)[0]);
        let s = map.bilinear(
            (x as f64 + 0.5) * tw as f64 / w as f64 - 0.5,
            (y as f64 + 0.5) * th as f64 / h as f64 - 0.5,
        );
        let a = 0.6 * s;
        Rgb([
            (g * (1.0 - a) + 255.0 * a) as u8,
            (g * (1.0 - a)) as u8,
            (g * (1.0 - a)) as u8,
        ])
    })
}
