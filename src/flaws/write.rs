//! The flaw table as CSV and JSON, and the flaws as a label volume in the build frame (NRRD,
//! gzip) that 3D Slicer shows over the CT and the exported views.

use std::io::Write;
use std::path::Path;

use rayon::prelude::*;

use super::{write_err, CtLabels, FlawTable, FlawsError, Result};

pub const FLAWS_CSV: &str = "flaws.csv";
pub const FLAWS_JSON: &str = "flaws.json";
pub const FLAWS_NRRD: &str = "flaws.nrrd";

/// Largest label volume written, in voxels; coarser spacing beyond.
const MAX_LABEL_VOXELS: f64 = 64e6;

fn opt<T: std::fmt::Display>(v: Option<T>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// The table as CSV: one row per flaw, build mm unless the column says otherwise.
pub fn table_csv(table: &FlawTable) -> String {
    let mut out = String::from(
        "id,kind,part,x_mm,y_mm,z_mm,ct_x_mm,ct_y_mm,ct_z_mm,volume_mm3,esd_mm,elongation,fill,\
         voxels,first_layer,last_layer,bbox_x_min,bbox_y_min,bbox_z_min,bbox_x_max,bbox_y_max,\
         bbox_z_max\n",
    );
    for f in &table.flaws {
        let [x, y, z] = f.centroid_mm;
        let [cx, cy, cz] = f.centroid_ct_mm;
        let [a, b, c] = f.bbox_min_mm;
        let [d, e, g] = f.bbox_max_mm;
        out.push_str(&format!(
            "{},{},{},{x:.4},{y:.4},{z:.4},{cx:.4},{cy:.4},{cz:.4},{:.6},{:.4},{:.3},{:.3},{},{},{},\
             {a:.4},{b:.4},{c:.4},{d:.4},{e:.4},{g:.4}\n",
            f.id,
            f.kind,
            opt(f.part),
            f.volume_mm3,
            f.esd_mm,
            f.elongation,
            f.fill,
            f.voxels,
            opt(f.first_layer),
            opt(f.last_layer),
        ));
    }
    out
}

/// Writes flaws.csv and flaws.json into `dir` (created).
pub fn write_table(dir: &Path, table: &FlawTable) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(write_err(dir))?;
    let json = serde_json::to_string_pretty(table).map_err(|source| FlawsError::Table {
        path: dir.join(FLAWS_JSON),
        source,
    })?;
    for (name, text) in [(FLAWS_CSV, table_csv(table)), (FLAWS_JSON, json)] {
        let path = dir.join(name);
        crate::fsutil::write_atomic(&path, text.as_bytes(), false).map_err(FlawsError::from)?;
    }
    Ok(())
}

/// Reads a flaws.json back (`dir` or the file itself).
pub fn read_table(path: &Path) -> Result<FlawTable> {
    let file = if path.is_dir() {
        path.join(FLAWS_JSON)
    } else {
        path.to_path_buf()
    };
    let text =
        crate::fsutil::read_text_bounded(&file, 1 << 30).map_err(|source| FlawsError::Read {
            path: file.clone(),
            source,
        })?;
    serde_json::from_str(&text).map_err(|source| FlawsError::Table { path: file, source })
}

/// Flaw `id` of a flaws.json (`dir` or the file itself).
pub fn find_flaw(path: &Path, id: u32) -> Result<super::Flaw> {
    let table = read_table(path)?;
    let count = table.flaws.len();
    table
        .flaws
        .into_iter()
        .find(|f| f.id == id)
        .ok_or_else(|| FlawsError::NoSuchFlaw {
            id,
            path: path.to_path_buf(),
            count,
        })
}

/// The flaws as labels (voxel = flaw id, 0 elsewhere) on an axis-aligned grid of the build
/// frame around them (1 mm margin) at the CT's voxel size: uint16 NRRD, gzip. Returns the grid's
/// sizes, or `None` when there is no flaw (nothing is written).
pub fn write_nrrd(path: &Path, table: &FlawTable, labels: &CtLabels) -> Result<Option<[usize; 3]>> {
    if table.flaws.is_empty() {
        return Ok(None);
    }
    let margin = 1.0;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for f in &table.flaws {
        for a in 0..3 {
            lo[a] = lo[a].min(f.bbox_min_mm[a] - margin);
            hi[a] = hi[a].max(f.bbox_max_mm[a] + margin);
        }
    }
    let mut step = table.voxel_mm.iter().cloned().fold(f64::INFINITY, f64::min);
    let count = |s: f64| {
        (0..3)
            .map(|a| ((hi[a] - lo[a]) / s).ceil() + 1.0)
            .product::<f64>()
    };
    while count(step) > MAX_LABEL_VOXELS {
        step *= 1.25;
    }
    let dims: [usize; 3] = std::array::from_fn(|a| ((hi[a] - lo[a]) / step).ceil() as usize + 1);
    let plane = dims[0] * dims[1];
    let ct_from_build = labels.build_from_ct.inverse();
    let wide = table.flaws.len() > u16::MAX as usize;
    let bytes_per = if wide { 4 } else { 2 };
    let mut data = vec![0u8; plane * dims[2] * bytes_per];
    data.par_chunks_mut(plane * bytes_per)
        .enumerate()
        .for_each(|(z, slice)| {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let p = [
                        lo[0] + x as f64 * step,
                        lo[1] + y as f64 * step,
                        lo[2] + z as f64 * step,
                    ];
                    let ct = ct_from_build.apply(p);
                    let Some(id) = labels.voxel_at_ct(ct).and_then(|v| labels.label_of(v)) else {
                        continue;
                    };
                    let at = (x + dims[0] * y) * bytes_per;
                    if wide {
                        slice[at..at + 4].copy_from_slice(&id.to_le_bytes());
                    } else {
                        slice[at..at + 2].copy_from_slice(&(id as u16).to_le_bytes());
                    }
                }
            }
        });
    let header = format!(
        "NRRD0004\n# layerwise flaws: label = flaw id of flaws.csv; build frame of docs/frames.md, mm\n\
         type: {}\ndimension: 3\nspace dimension: 3\nsizes: {} {} {}\n\
         space directions: ({step},0,0) (0,{step},0) (0,0,{step})\nkinds: domain domain domain\n\
         endian: little\nencoding: gzip\nspace origin: ({},{},{})\nspace units: \"mm\" \"mm\" \"mm\"\n\n",
        if wide { "uint32" } else { "uint16" },
        dims[0],
        dims[1],
        dims[2],
        lo[0],
        lo[1],
        lo[2]
    );
    let mut out = header.into_bytes();
    let mut gz = flate2::write::GzEncoder::new(&mut out, flate2::Compression::fast());
    gz.write_all(&data)
        .and_then(|_| gz.finish().map(|_| ()))
        .map_err(write_err(path))?;
    crate::fsutil::write_atomic(path, &out, false).map_err(FlawsError::from)?;
    Ok(Some(dims))
}
