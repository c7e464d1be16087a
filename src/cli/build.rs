//! Commands on a finished build: `export` and `locate`.

use anyhow::{anyhow, bail, Result};
use clap::Args;
use layerwise::ct::CtFrame;
use layerwise::series::BuildRecord;
use std::path::PathBuf;

#[derive(Args)]
pub struct ExportArgs {
    /// The build directory (the daemon's build.output_dir).
    #[arg(long)]
    build: PathBuf,
    /// Where to write the study (created; re-running rewrites nothing already there).
    #[arg(long)]
    out: PathBuf,
    /// Crop every series to this part (needs the build's vector file) plus --margin-mm.
    #[arg(long)]
    part: Option<i64>,
    /// Margin around the part, with --part.
    #[arg(long, default_value_t = 5.0, allow_hyphen_values = true, value_parser = super::values::margin_mm)]
    margin_mm: f64,
    /// DICOM series, or NRRD volumes for 3D Slicer / napari.
    #[arg(long, value_enum, default_value = "dicom")]
    format: layerwise::export::ExportFormat,
    /// ct.toml from `layerwise register ct`: the CT joins the study, resampled onto the grid.
    #[arg(long)]
    ct: Option<PathBuf>,
}

impl ExportArgs {
    pub fn run(self) -> Result<()> {
        let request = layerwise::export::ExportRequest {
            build: self.build,
            out: self.out,
            part: self.part,
            margin_mm: self.margin_mm,
            format: self.format,
            ct: self.ct,
            progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
        };
        let summary = layerwise::export::export(&request)?;
        print!("{summary}");
        Ok(())
    }
}

#[derive(Args)]
pub struct LocateArgs {
    /// The build directory (the daemon's build.output_dir).
    #[arg(long)]
    build: PathBuf,
    /// x,y,z in build mm.
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_parser = super::values::coordinate_mm,
        required_unless_present_any = ["ct_point", "flaw"]
    )]
    point: Vec<f64>,
    /// x,y,z in CT mm (needs --ct).
    #[arg(
        long,
        value_delimiter = ',',
        allow_hyphen_values = true,
        value_parser = super::values::coordinate_mm,
        conflicts_with = "point",
        requires = "ct"
    )]
    ct_point: Vec<f64>,
    /// ct.toml from `layerwise register ct`: also where the point is in the CT.
    #[arg(long)]
    ct: Option<PathBuf>,
    /// One JSON object instead of text.
    #[arg(long)]
    json: bool,
    /// Draw the point in each view, side by side and labelled (PNG): the layer's vectors, with
    /// --ct the CT through the point in the layer plane, then each view rectified and original;
    /// with --flaw, the flaw's patches of every view of every layer it spans.
    #[arg(long)]
    mark: Option<PathBuf>,
    /// A flaw of `layerwise flaws` (its id in flaws.csv): locate its centroid.
    #[arg(long, requires = "flaws", conflicts_with_all = ["point", "ct_point"])]
    flaw: Option<u32>,
    /// The output folder (or flaws.json) of `layerwise flaws`, with --flaw.
    #[arg(long)]
    flaws: Option<PathBuf>,
    /// Patch side in pixels for --flaw --mark (odd).
    #[arg(long, default_value_t = 65, value_parser = super::values::patch_px)]
    patch_px: usize,
}

impl LocateArgs {
    pub fn run(self) -> Result<()> {
        let three = |v: Vec<f64>, flag: &str| -> Result<[f64; 3]> {
            v.try_into()
                .map_err(|_| anyhow!("{flag} takes x,y,z in mm"))
        };
        let frame = self.ct.as_deref().map(CtFrame::open).transpose()?;
        let flaw = match (self.flaw, &self.flaws) {
            (Some(id), Some(dir)) => Some(layerwise::flaws::find_flaw(dir, id)?),
            _ => None,
        };
        let point = match (&frame, &flaw) {
            (_, Some(flaw)) => flaw.centroid_mm,
            (Some(frame), None) if !self.ct_point.is_empty() => {
                frame.to_build(three(self.ct_point, "--ct-point")?)
            }
            _ => three(self.point, "--point")?,
        };
        let record = BuildRecord::open(&self.build)?;
        let mut location = layerwise::locate::locate(&record, point)?;
        location.ct = frame.map(|f| f.locate(point));
        if let (None, None, Some(why)) = (location.layer, &location.ct, &location.outside) {
            bail!("{why}: nothing to locate; give a point in the build (or a CT point with --ct)");
        }
        match (&self.mark, &flaw) {
            (Some(out), Some(flaw)) => {
                layerwise::flaws::flaw_sheet(&record, flaw, self.patch_px, out)?
            }
            (Some(out), None) => {
                // With --ct, a CT tile: the CT ct.toml names, through the point.
                let registration = match &self.ct {
                    Some(path) => Some(layerwise::ct::CtRegistration::read_toml(path)?),
                    None => None,
                };
                let volume = match registration.as_ref().and_then(|r| r.source.as_ref()) {
                    Some(source) => Some(source.read()?),
                    None => None,
                };
                let section = match (&registration, &volume) {
                    (Some(r), Some(volume)) => Some(layerwise::locate::CtSection {
                        volume,
                        build_from_ct: r.build_from_ct,
                    }),
                    _ => None,
                };
                layerwise::locate::mark(&record, &location, section.as_ref(), out)?
            }
            _ => {}
        }
        if self.json {
            println!("{}", serde_json::to_string_pretty(&location)?);
        } else {
            print!("{location}");
        }
        Ok(())
    }
}
