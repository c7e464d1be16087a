//! `layerwise learn compare`: the model side by side with the classical inspection on the same
//! labelled frames. Each frame is squared and resampled as the model sees it and handed to the
//! daemon's inspector as the pre-scan top view of one layer (the frames of a sequence are its
//! layers, in order, so the short-feed reference builds up as in a build); a frame is *found*
//! when the inspection raises a flag at warning or above on it, and when the model's class is
//! not the normal one. For a defect class that is a find, for the normal class a false alarm.

use anyhow::Result;
use clap::{Args, ValueEnum};
use layerwise::build_dir::inspection::{InspectionRecord, Severity};
use layerwise::config::inspection::{InspectionConfig, RecoatAxis};
use layerwise::inspect::Inspector;
use layerwise::learn::{self, Model, Part};
use layerwise::rectify::{FrameLuma, Grid};
use layerwise::shot::{Light, Phase, View};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum Which {
    All,
    Train,
    Val,
}

#[derive(Clone, Copy, ValueEnum)]
enum Recoat {
    Auto,
    X,
    Y,
}

#[derive(Args)]
pub struct CompareArgs {
    /// The model file.
    #[arg(long)]
    model: PathBuf,
    /// Labelled frames in class folders (as for `learn train`).
    #[arg(long)]
    data: PathBuf,
    /// Which frames are counted: the validation part of the model's split (default), the
    /// training part, or all. The inspection sees every frame of a sequence either way.
    #[arg(long, value_enum, default_value = "val")]
    part: Which,
    /// Along which picture axis the recoater travels (x: left-right, y: top-bottom; auto: found
    /// from the frames, as `recoat_axis = "auto"`).
    #[arg(long, value_enum, default_value = "auto")]
    recoat_axis: Recoat,
}

#[derive(Default)]
struct Row {
    frames: usize,
    model_found: usize,
    model_right: usize,
    classical_found: usize,
    kinds: BTreeMap<String, usize>,
}

impl CompareArgs {
    pub fn run(self) -> Result<()> {
        let model = Model::load(&self.model)?;
        model.check_use(learn::Use::Frames)?;
        let data = learn::source::open(&self.data, Some(&model.header.normal_class))?;
        let parts = data.split(model.header.training.split.val_fraction);
        let want = match self.part {
            Which::All => None,
            Which::Train => Some(Part::Train),
            Which::Val => Some(Part::Val),
        };
        model.check_part(want)?;
        let spec = &model.header.input;
        let side = spec.frame_px.unwrap_or(512);
        let grid = Grid {
            pixel_mm: 2.0 * layerwise::geometry::PLATE_HALF_MM / side as f64,
            ..Grid::plate()
        };
        let cfg = InspectionConfig {
            recoat_axis: match self.recoat_axis {
                Recoat::Auto => RecoatAxis::Auto,
                Recoat::X => RecoatAxis::X,
                Recoat::Y => RecoatAxis::Y,
            },
            ..InspectionConfig::default()
        };
        let pre_top = View {
            phase: Phase::Pre,
            light: Light::Top,
        };
        let mut sequences: BTreeMap<(usize, String), Vec<usize>> = BTreeMap::new();
        for (i, item) in data.items.iter().enumerate() {
            sequences
                .entry((item.class, item.seq.clone()))
                .or_default()
                .push(i);
        }
        let mut rows: BTreeMap<String, Row> = BTreeMap::new();
        let at = chrono::Utc::now();
        for ((class, _), mut items) in sequences {
            items.sort_by_key(|&i| data.items[i].order);
            let mut inspector = Inspector::new(&cfg, grid, &[pre_top], None);
            let truth = data.classes[class].clone();
            for (k, &i) in items.iter().enumerate() {
                let item = &data.items[i];
                let img = learn::data::read_item(item)?;
                let canonical = spec.canonical(&img).unwrap_or(img);
                let grey = image::GrayImage::from_fn(
                    canonical.width as u32,
                    canonical.height as u32,
                    |x, y| {
                        image::Luma([canonical.at(x as usize, y as usize).clamp(0.0, 255.0) as u8])
                    },
                );
                let cells = inspector.cells(&FrameLuma::Gamma8(grey));
                let layer = k as u32 + 1;
                let mut records: Vec<InspectionRecord> = inspector.add(layer, pre_top, cells, at);
                records.extend(inspector.flush(at));
                if want.is_some_and(|w| parts[i] != w) {
                    continue;
                }
                let prediction = model.classify(&spec.input(&canonical))?;
                let row = rows.entry(truth.clone()).or_default();
                row.frames += 1;
                row.model_found += usize::from(prediction.class != model.header.normal_class);
                row.model_right += usize::from(prediction.class == truth);
                let flags: Vec<_> = records
                    .iter()
                    .filter(|r| r.layer == layer)
                    .flat_map(|r| &r.flags)
                    .filter(|f| f.severity >= Severity::Warning)
                    .collect();
                row.classical_found += usize::from(!flags.is_empty());
                for f in flags {
                    *row.kinds.entry(f.kind.to_string()).or_default() += 1;
                }
            }
        }
        let normal = &model.header.normal_class;
        println!(
            "| class | frames | model: flagged | model: right class | classical: flagged | classical flags |"
        );
        println!("| --- | --- | --- | --- | --- | --- |");
        for (class, r) in &rows {
            let what = if class == normal {
                "false alarms"
            } else {
                "found"
            };
            let kinds: Vec<String> = r.kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
            println!(
                "| {class} | {} | {} {what} ({:.0} %) | {} | {} {what} ({:.0} %) | {} |",
                r.frames,
                r.model_found,
                100.0 * r.model_found as f64 / r.frames.max(1) as f64,
                r.model_right,
                r.classical_found,
                100.0 * r.classical_found as f64 / r.frames.max(1) as f64,
                if kinds.is_empty() {
                    "-".to_string()
                } else {
                    kinds.join(", ")
                }
            );
        }
        Ok(())
    }
}
