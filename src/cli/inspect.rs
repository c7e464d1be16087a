//! `layerwise inspect`: the daemon's per-layer inspection over a stored build or a folder of
//! frames, with the same results as the live run.

use anyhow::{anyhow, Context, Result};
use clap::Args;
use layerwise::build_dir::inspection::{FlagKind, Severity};
use layerwise::config::inspection::InspectionConfig;
use layerwise::config::model::ModelConfig;
use layerwise::config::Config;
use layerwise::inspect::{offline, Inspector};
use layerwise::rectify::{Calibration, Grid, Rectifier};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(Args)]
pub struct InspectArgs {
    /// A build directory (the daemon's build.output_dir): its originals, configuration,
    /// calibration and vectors.
    #[arg(long, required_unless_present = "frames", conflicts_with = "frames")]
    build: Option<PathBuf>,
    /// Instead of a build: a folder of frames named L{layer:05}_{phase}_{light}.{ext}
    /// (docs/frames.md), or any folder of pictures, taken in name order as consecutive layers
    /// of --view. Without --calibration the frames are taken as top-down views; without
    /// --vectors only the plate-wide checks run.
    #[arg(long)]
    frames: Option<PathBuf>,
    /// The view a folder of plainly named pictures shows.
    #[arg(long, default_value = "pre_top", value_parser = parse_view)]
    view: layerwise::shot::View,
    /// Without --calibration: plate millimetres a frame pixel covers (default: the frame's
    /// wider side taken as the 275 mm plate).
    #[arg(long, conflicts_with = "calibration")]
    pixel_mm: Option<f64>,
    /// The build's laser vector file (default: the build's build.vectors).
    #[arg(long)]
    vectors: Option<PathBuf>,
    /// calibration.toml (default: the build's copy); its grid is the rectified grid.
    #[arg(long)]
    calibration: Option<PathBuf>,
    /// A layerwise.toml whose [inspection], [rectify] and [views] to use (default: the build's).
    #[arg(long)]
    config: Option<PathBuf>,
    /// First layer to inspect (printer layers, from 1).
    #[arg(long, default_value_t = 1)]
    from: u32,
    /// Last layer to inspect (default: the last one there is).
    #[arg(long)]
    to: Option<u32>,
    /// One JSON record per layer, as inspection.jsonl holds them, instead of text.
    #[arg(long)]
    json: bool,
    /// A trained defect model to run after the classical checks (default: the configuration's
    /// [inspection.model] file; its other settings, the probabilities and views, are kept).
    #[arg(long)]
    model: Option<PathBuf>,
    /// The model's mm per cell when it was trained on frames of unknown scale.
    #[arg(long)]
    model_cell_mm: Option<f64>,
    /// Draw per-part metrics against layer with the flagged layers marked in red: SVG, or PNG
    /// when the name ends in .png.
    #[arg(long)]
    plot: Option<PathBuf>,
}

impl InspectArgs {
    pub fn run(self) -> Result<()> {
        let given = self.config.as_deref().map(Config::load).transpose()?;
        let (frames, calibration, grid, interpolation, fill, cfg, views, vectors) = match &self
            .build
        {
            Some(dir) => {
                let record = layerwise::series::BuildRecord::open(dir)?;
                let config = given.unwrap_or(record.config.clone());
                let calibration = match &self.calibration {
                    Some(path) => Calibration::load(path)?,
                    None => record.calibration.clone().ok_or_else(|| {
                        anyhow!(
                            "{}: the build has no calibration.toml; pass --calibration",
                            dir.display()
                        )
                    })?,
                };
                (
                    offline::build_frames(dir)?,
                    calibration,
                    record.grid,
                    config.calibration.interpolation,
                    config.calibration.fill,
                    config.inspection.clone(),
                    config.views.all(),
                    self.vectors.clone().or(config.build.vectors.clone()),
                )
            }
            None => {
                let dir = self.frames.as_ref().context("--build or --frames")?;
                let frames = offline::any_frames(dir, self.view)?;
                let (calibration, grid) = match &self.calibration {
                    Some(path) => {
                        let calibration = Calibration::load(path)?;
                        let grid = match &given {
                            Some(c) => c.rectify,
                            None => calibration.grid.unwrap_or_else(Grid::plate),
                        };
                        (calibration, grid)
                    }
                    None => {
                        let (w, h) = offline::frame_size(&frames.paths)?;
                        let (calibration, grid) = offline::top_down(w, h, self.pixel_mm)?;
                        eprintln!(
                                "no --calibration: the frames are taken as top-down views of {w} x {h} pixels, {:.3} mm a pixel{}",
                                grid.pixel_mm,
                                if self.pixel_mm.is_some() { "" } else { " (the wider side taken as the 275 mm plate; --pixel-mm sets it)" }
                            );
                        (calibration, grid)
                    }
                };
                let (mut cfg, interpolation, fill) = match &given {
                    Some(c) => (
                        c.inspection.clone(),
                        c.calibration.interpolation,
                        c.calibration.fill,
                    ),
                    None => (InspectionConfig::default(), Default::default(), 0),
                };
                let views: Vec<layerwise::shot::View> = frames
                    .paths
                    .keys()
                    .map(|s| s.view())
                    .collect::<std::collections::BTreeSet<_>>()
                    .into_iter()
                    .collect();
                if views == [self.view] && self.view.phase == layerwise::shot::Phase::Pre {
                    cfg.pre_light = self.view.light;
                }
                (
                    frames,
                    calibration,
                    grid,
                    interpolation,
                    fill,
                    cfg,
                    views,
                    self.vectors.clone(),
                )
            }
        };
        let index = vectors
            .as_deref()
            .map(layerwise::vectors::LayerIndex::build)
            .transpose()?;
        let rectifier = Rectifier::new(&calibration.camera(), grid, interpolation, fill)
            .context("calibration")?;
        let mut inspector = Inspector::new(&cfg, grid, &views, index);
        if let Some(footprint) = layerwise::inspect::camera_footprint_mm(rectifier.camera(), &grid)
        {
            inspector.resolve_camera(footprint);
        }
        let to = self.to.unwrap_or(u32::MAX);
        let model = self.model_config(&cfg)?;
        let (mut records, skipped) = offline::run(
            &mut inspector,
            &rectifier,
            &frames,
            self.from,
            to,
            chrono::Utc::now(),
        );
        if let Some(model) = &model {
            let live = layerwise::learn::live::LiveModel::open(model, &grid)
                .context("the inspection model")?;
            let unread = layerwise::learn::live::apply_offline(
                &live,
                &rectifier,
                &grid,
                &frames.paths,
                &mut records,
                &move |luma, bin| {
                    let c = layerwise::inspect::cells::Cells::from_luma(luma, &grid, bin);
                    (c.rows, c.cols, c.mean, c.texture)
                },
            );
            for u in &unread {
                eprintln!(
                    "model skipped {}: {}",
                    u.shot,
                    layerwise::logging::Chain(&u.error)
                );
            }
        }
        for s in &skipped {
            eprintln!(
                "skipped {}: {}",
                s.shot,
                layerwise::logging::Chain(&s.error)
            );
        }
        if let Some(out) = &self.plot {
            let png = out
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("png"));
            let bytes = if png {
                layerwise::inspect::plot::png(&records)
                    .with_context(|| format!("--plot {}: cannot encode the PNG", out.display()))?
            } else {
                layerwise::inspect::plot::svg(&records).into_bytes()
            };
            layerwise::fsutil::write_atomic(out, &bytes, false)?;
        }
        if self.json {
            for r in &records {
                println!("{}", serde_json::to_string(r)?);
            }
            return Ok(());
        }
        let mut kinds: BTreeMap<FlagKind, usize> = BTreeMap::new();
        let mut critical = 0;
        let mut persisting = 0;
        for r in &records {
            for n in &r.notes {
                println!("layer {}: {}: {}", r.layer, n.level, n.message);
            }
            for f in r.flags.iter().filter(|f| f.severity >= Severity::Warning) {
                if f.since.is_some() {
                    persisting += 1;
                    continue;
                }
                println!("{}", layerwise::inspect::describe(r.layer, f));
                *kinds.entry(f.kind).or_default() += 1;
                critical += usize::from(f.severity == Severity::Critical);
            }
        }
        let span = match (records.first(), records.last()) {
            (Some(a), Some(b)) => format!(" ({}..{})", a.layer, b.layer),
            _ => String::new(),
        };
        let per_kind: Vec<String> = kinds.iter().map(|(k, n)| format!("{n} {k}")).collect();
        let axis = records
            .iter()
            .rev()
            .find_map(|r| r.axis.as_ref())
            .map(|a| format!("; recoater axis {} ({})", a.axis, a.source))
            .unwrap_or_default();
        let flagged = records
            .iter()
            .filter(|r| r.flags.iter().any(|f| f.severity >= Severity::Warning))
            .count();
        println!(
            "inspected {} layers{span}: {} new flags ({critical} critical){}{}; {persisting} times a flag persisted from the layer before; {flagged} layers flagged{axis}",
            records.len(),
            kinds.values().sum::<usize>(),
            if per_kind.is_empty() { "" } else { ": " },
            per_kind.join(", ")
        );
        Ok(())
    }
}

fn parse_view(text: &str) -> std::result::Result<layerwise::shot::View, String> {
    let (phase, light) = text
        .split_once('_')
        .ok_or_else(|| format!("`{text}`: a view is phase_light, e.g. pre_top"))?;
    Ok(layerwise::shot::View {
        phase: phase.parse().map_err(|e| format!("{e}"))?,
        light: light.parse().map_err(|e| format!("{e}"))?,
    })
}

impl InspectArgs {
    /// `--model` (with `--model-cell-mm`) or the configuration's `[inspection.model]`; a
    /// `--model` keeps the configuration's thresholds and views.
    fn model_config(&self, cfg: &InspectionConfig) -> Result<Option<ModelConfig>> {
        let mut model = match &self.model {
            // Another file, judged as the configuration judges its model.
            Some(file) => Some(match &cfg.model {
                Some(configured) => ModelConfig {
                    file: file.clone(),
                    ..configured.clone()
                },
                None => ModelConfig::for_file(file.clone()),
            }),
            None => cfg.model.clone(),
        };
        if let (Some(m), Some(mm)) = (&mut model, self.model_cell_mm) {
            m.cell_mm = Some(mm);
        }
        if let Some(m) = &model {
            m.validate()
                .map_err(|e| anyhow!("--model: {}", layerwise::logging::chain(&e)))?;
        }
        Ok(model)
    }
}
