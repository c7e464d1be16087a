//! The whole `layerwise flaws` run: the registered CT read, its flaws found and written, and
//! with a build the patches cut.

use std::path::{Path, PathBuf};

use super::patches::CtContext;
use super::{
    cut_patches, detect, write_nrrd, write_table, FlawParams, FlawTable, FlawsError, PatchOptions,
    PatchSummary, Result,
};
use crate::ct::{CtRegistration, CtSource};
use crate::series::{BuildRecord, LayerHeights};

/// What `layerwise flaws` is asked to do.
#[derive(Debug, Clone)]
pub struct FlawsRequest {
    /// The CT volume; `None` reads the one ct.toml records.
    pub ct: Option<CtSource>,
    /// ct.toml of `layerwise register ct`.
    pub registration: PathBuf,
    pub part: Option<i64>,
    pub out: PathBuf,
    pub build: Option<PathBuf>,
    /// The laser vectors (default: the build's): flaws outside the nominal part (the signed
    /// distance of `part`'s vectors, or all of them) are left out.
    pub vectors: Option<PathBuf>,
    /// Layer thickness when there is no build to give the layers.
    pub layer_thickness_mm: f64,
    pub params: FlawParams,
    pub patches: PatchOptions,
}

/// What it wrote.
#[derive(Debug, Clone)]
pub struct FlawsReport {
    pub table: FlawTable,
    pub files: Vec<PathBuf>,
    pub nrrd_sizes: Option<[usize; 3]>,
    pub patches: Option<PatchSummary>,
}

/// Reads the CT and the registration, finds the flaws, writes the table, the label volume and,
/// with a build, the patches.
pub fn run(request: &FlawsRequest) -> Result<FlawsReport> {
    let registration = CtRegistration::read_toml(&request.registration).map_err(|source| {
        FlawsError::Registration {
            path: request.registration.clone(),
            source: Box::new(source),
        }
    })?;
    let source = match (&request.ct, &registration.source) {
        (Some(s), _) | (None, Some(s)) => s.clone(),
        (None, None) => {
            return Err(FlawsError::Invalid(format!(
                "{} records no CT: give the CT with --ct",
                request.registration.display()
            )))
        }
    };
    let volume = source.read()?;
    let record = request
        .build
        .as_deref()
        .map(BuildRecord::open)
        .transpose()?;
    let heights = record.as_ref().map_or_else(
        || LayerHeights::uniform(request.layer_thickness_mm),
        |r| r.heights.clone(),
    );
    let mut found = detect(
        &volume,
        &registration.build_from_ct,
        &heights,
        request.part,
        &request.params,
    )?;
    let vectors = request
        .vectors
        .clone()
        .or_else(|| record.as_ref().and_then(|r| r.config.build.vectors.clone()));
    let rejected_outside_part = match &vectors {
        Some(path) => {
            let nominal = |e: Box<dyn std::error::Error + Send + Sync>| FlawsError::Nominal {
                path: path.clone(),
                source: e,
            };
            let file = crate::vectors::read(path).map_err(|e| nominal(e.into()))?;
            let params = crate::tsdf::TsdfParams {
                voxel_mm: volume.voxel_mm[0].clamp(0.02, 0.1),
                part: request.part,
                ..Default::default()
            };
            let field = crate::tsdf::build(&file, &params).map_err(|e| nominal(e.into()))?;
            found.retain(|f| field.sample(f.centroid_mm).is_some_and(|d| d < 0.0))
        }
        None => 0,
    };
    let table = FlawTable {
        ct: source.path.clone(),
        registration: display(&request.registration),
        threshold: found.threshold,
        void_level: found.void_level,
        material_level: found.material_level,
        voxel_mm: volume.voxel_mm,
        min_volume_voxels: request.params.min_volume_voxels,
        clearance_voxels: request.params.clearance_voxels,
        rejected_small: found.rejected_small,
        rejected_surface: found.rejected_surface,
        rejected_outside_part,
        flaws: found.flaws,
    };
    write_table(&request.out, &table)?;
    let out = &request.out;
    let mut files = vec![out.join(super::FLAWS_CSV), out.join(super::FLAWS_JSON)];
    let nrrd = out.join(super::FLAWS_NRRD);
    let nrrd_sizes = write_nrrd(&nrrd, &table, &found.labels)?;
    if nrrd_sizes.is_some() {
        files.push(nrrd);
    }
    let patches = match &record {
        Some(record) => {
            let ct = CtContext {
                volume: &volume,
                labels: &found.labels,
                void_level: table.void_level,
                material_level: table.material_level,
            };
            let summary = cut_patches(record, &table, Some(&ct), &request.patches, out)?;
            files.push(out.join(super::patches::LABELS_JSON));
            files.push(out.join(super::patches::LABELS_CSV));
            files.extend(summary.sheet.clone());
            Some(summary)
        }
        None => None,
    };
    Ok(FlawsReport {
        table,
        files,
        nrrd_sizes,
        patches,
    })
}

fn display(path: &Path) -> String {
    std::fs::canonicalize(path)
        .unwrap_or_else(|_| path.to_path_buf())
        .display()
        .to_string()
}

impl std::fmt::Display for FlawsReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = &self.table;
        writeln!(
            f,
            "{} flaws in {} (threshold {:.1}; void {:.1}, material {:.1}; {} components too small, {} at the part surface, {} outside the nominal part)",
            t.flaws.len(),
            t.ct,
            t.threshold,
            t.void_level,
            t.material_level,
            t.rejected_small,
            t.rejected_surface,
            t.rejected_outside_part
        )?;
        for flaw in &t.flaws {
            let [x, y, z] = flaw.centroid_mm;
            let layers = match (flaw.first_layer, flaw.last_layer) {
                (Some(a), Some(b)) if a == b => format!("layer {a}"),
                (Some(a), Some(b)) => format!("layers {a}-{b}"),
                _ => "outside the layers".into(),
            };
            writeln!(
                f,
                "  {:>4}  {:<14} ({x:.3}, {y:.3}, {z:.3}) mm  {:.5} mm³  ESD {:.3} mm  elongation {:.2}  {layers}",
                flaw.id, flaw.kind, flaw.volume_mm3, flaw.esd_mm, flaw.elongation
            )?;
        }
        if let Some(p) = &self.patches {
            writeln!(
                f,
                "patches: {} of flaws, {} controls ({} sections without a control), {} frames missing",
                p.flaw_patches, p.control_patches, p.controls_not_found, p.missing_frames
            )?;
        }
        for file in &self.files {
            writeln!(f, "wrote {}", file.display())?;
        }
        Ok(())
    }
}
