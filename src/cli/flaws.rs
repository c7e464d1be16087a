//! `layerwise flaws`: the internal flaws of a registered CT, and with a build the labelled
//! patches of every view of the layers they sit in.

use anyhow::Result;
use clap::Args;
use layerwise::flaws::{FlawParams, FlawsRequest, PatchOptions};
use std::path::PathBuf;

#[derive(Args)]
pub struct FlawsArgs {
    /// The CT: a DICOM series folder, a phoenix .pcr/.vol, a VGStudio .vgi, a raw volume (with
    /// --size, --dtype, --voxel-mm) or a TIFF stack folder (with --voxel-mm); default: the CT
    /// ct.toml records.
    #[arg(long)]
    ct: Option<PathBuf>,
    /// ct.toml from `layerwise register ct` (CT mm → build mm).
    #[arg(long)]
    registration: PathBuf,
    /// The vector file's part the CT was registered to (recorded with each flaw).
    #[arg(long)]
    part: Option<i64>,
    /// Where to write flaws.csv, flaws.json, flaws.nrrd (and with --build the patches).
    #[arg(long)]
    out: PathBuf,
    /// The build: its layers, and patches of its views at every flaw.
    #[arg(long)]
    build: Option<PathBuf>,
    /// The laser vectors (default: the build's, if its configuration names them): flaws whose
    /// centroid is outside the nominal part (of --part) are left out (plate slab, supports).
    #[arg(long)]
    vectors: Option<PathBuf>,
    /// Components with fewer voxels below the threshold are noise.
    #[arg(long, default_value_t = 8)]
    min_volume_voxels: usize,
    /// Voxels around a flaw that must be part material (flaws at the surface are not internal).
    #[arg(long, default_value_t = 3)]
    clearance_voxels: usize,
    /// A fixed material/void threshold (physical units); default Otsu.
    #[arg(long)]
    threshold: Option<f64>,
    /// Layer thickness for the layers a flaw spans when there is no --build.
    #[arg(long, default_value_t = 0.03, value_parser = super::values::layer_thickness_mm)]
    layer_thickness_mm: f64,
    /// Patch side in pixels of the build's rectified grid (odd: the flaw is the centre pixel).
    #[arg(long, default_value_t = 65, value_parser = super::values::patch_px)]
    patch_px: usize,
    /// Patches of the views of this phase only (pre or post; default: every view). A flaw in a
    /// layer shows in its post-scan views, while the pre-scan views show the fresh powder over
    /// it: `--phase post` is the training set of a model that looks at post-scan views.
    #[arg(long)]
    phase: Option<layerwise::shot::Phase>,
    #[command(flatten)]
    layout: super::register::RawLayoutArgs,
}

impl FlawsArgs {
    pub fn run(self) -> Result<()> {
        let ct = match &self.ct {
            Some(path) => Some(self.layout.source(path)?),
            None => None,
        };
        let mut params = FlawParams {
            min_volume_voxels: self.min_volume_voxels,
            clearance_voxels: self.clearance_voxels,
            ..FlawParams::default()
        };
        params.window_voxels = params.window_voxels.min(self.clearance_voxels);
        if let Some(v) = self.threshold {
            params.threshold = layerwise::ct::Threshold::Value(v);
        }
        let request = FlawsRequest {
            ct,
            registration: self.registration,
            part: self.part,
            out: self.out,
            build: self.build,
            vectors: self.vectors,
            layer_thickness_mm: self.layer_thickness_mm,
            params,
            patches: PatchOptions {
                patch_px: self.patch_px,
                phase: self.phase,
                ..PatchOptions::default()
            },
        };
        let started = std::time::Instant::now();
        let report = layerwise::flaws::run(&request)?;
        print!("{report}");
        println!("in {:.1} s", started.elapsed().as_secs_f64());
        Ok(())
    }
}
