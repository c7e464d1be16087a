//! Reading written files back: the series summaries behind `layerwise dicom info`, the take a
//! slice was made from, the SOP instance UID a file names.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dicom_core::Tag;
use dicom_dictionary_std::tags;
use dicom_object::{DefaultDicomObject, InMemDicomObject, OpenFileOptions};

use super::error::DicomError;
use super::lengths::check_lengths_until;

/// The take of the original a slice file was made from (its ImageComments,
/// [`SliceSource`](super::SliceSource)): `None` when there is no readable file; a slice written
/// without the comment is take 1.
pub fn slice_take(path: &Path) -> Option<u32> {
    if !path.is_file() {
        return None;
    }
    let obj = read_until(path, tags::PIXEL_DATA).ok()?;
    let Some(comments) = text(&obj, tags::IMAGE_COMMENTS) else {
        return Some(1);
    };
    comments
        .strip_prefix("take ")?
        .split(' ')
        .next()?
        .parse()
        .ok()
}

/// The SOP Instance UID a DICOM file's meta header names (None when it cannot be read).
pub fn file_instance_uid(path: &Path) -> Option<String> {
    let obj = read_until(path, tags::SOP_CLASS_UID).ok()?;
    // As the push reads it (pacs::Instance), so the two compare equal.
    Some(obj.meta().media_storage_sop_instance_uid().to_string())
}

/// The file at `path` read up to the top-level element `until` (excluded), once the lengths
/// dicom-rs will read that far are checked.
fn read_until(path: &Path, until: Tag) -> Result<DefaultDicomObject, DicomError> {
    check_lengths_until(path, Some(until))?;
    OpenFileOptions::new()
        .read_until(until)
        .open_file(path)
        .map_err(|e| DicomError::Read {
            path: path.to_path_buf(),
            source: Box::new(e),
        })
}

/// What `layerwise dicom info` reports of one series.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SeriesSummary {
    pub series_instance_uid: String,
    pub number: String,
    pub description: String,
    pub study_instance_uid: String,
    pub frame_of_reference_uid: String,
    pub files: Vec<PathBuf>,
    pub slices: usize,
    pub rows: u32,
    pub columns: u32,
    pub pixel_spacing_mm: [f64; 2],
    pub orientation: [f64; 6],
    pub first_position: [f64; 3],
    pub z_min: f64,
    pub z_max: f64,
    pub transfer_syntax: String,
    pub instance_numbers: (i64, i64),
    /// What makes the series' geometry or pixels untrustworthy (spacing, orientation, short
    /// pixel data), each with the first file it was seen in; empty when it is sound.
    pub problems: Vec<String>,
}

/// What is wrong with one file's geometry or pixel data: PixelSpacing not two positive finite
/// numbers, ImageOrientationPatient not two orthonormal vectors, uncompressed pixel data
/// shorter than Rows x Columns x samples x bytes (told by the file's size).
fn file_problems(obj: &InMemDicomObject, path: &Path, ts: &str) -> Vec<String> {
    let mut problems = Vec::new();
    let spacing = floats(obj, tags::PIXEL_SPACING);
    if spacing.len() != 2
        || spacing
            .iter()
            .any(|s| !(s.is_finite() && *s >= super::MIN_PIXEL_SPACING_MM))
    {
        problems.push(format!(
            "PixelSpacing {:?} is not two positive numbers of mm, each at least {}",
            text(obj, tags::PIXEL_SPACING).unwrap_or_default(),
            super::MIN_PIXEL_SPACING_MM
        ));
    }
    let o = floats(obj, tags::IMAGE_ORIENTATION_PATIENT);
    let orthonormal = o.len() == 6 && {
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let (row, col) = o.split_at(3);
        (dot(row, row) - 1.0).abs() < 1e-3
            && (dot(col, col) - 1.0).abs() < 1e-3
            && dot(row, col).abs() < 1e-3
    };
    if !orthonormal {
        problems.push(format!(
            "ImageOrientationPatient {:?} is not two orthonormal vectors",
            text(obj, tags::IMAGE_ORIENTATION_PATIENT).unwrap_or_default()
        ));
    }
    let uint = |tag| {
        obj.element(tag)
            .ok()
            .and_then(|e| e.to_int::<u64>().ok())
            .unwrap_or(0)
    };
    let native = [
        "1.2.840.10008.1.2",
        "1.2.840.10008.1.2.1",
        "1.2.840.10008.1.2.2",
    ];
    let needed = uint(tags::ROWS)
        * uint(tags::COLUMNS)
        * uint(tags::SAMPLES_PER_PIXEL).max(1)
        * uint(tags::BITS_ALLOCATED).div_ceil(8);
    let size = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    if native.contains(&ts) && size < needed {
        problems.push(format!(
            "pixel data is short: {size} bytes in the file for {needed} bytes of pixels"
        ));
    }
    problems
}

fn text(obj: &InMemDicomObject, tag: Tag) -> Option<String> {
    obj.element(tag)
        .ok()?
        .to_str()
        .ok()
        .map(|s| s.trim().trim_end_matches('\0').to_string())
}

fn floats(obj: &InMemDicomObject, tag: Tag) -> Vec<f64> {
    text(obj, tag)
        .map(|s| {
            s.split('\\')
                .filter_map(|v| v.trim().parse().ok())
                .collect()
        })
        .unwrap_or_default()
}

/// Reads the headers (not the pixels) of every `.dcm` below `dir` and groups them by series.
pub fn series_info(dir: &Path) -> Result<Vec<SeriesSummary>, DicomError> {
    let mut files = Vec::new();
    collect_dcm(dir, &mut files, 0).map_err(|source| DicomError::Folder {
        path: dir.to_path_buf(),
        source,
    })?;
    files.sort();
    let mut series: BTreeMap<String, SeriesSummary> = BTreeMap::new();
    for path in files {
        let obj = read_until(&path, tags::PIXEL_DATA)?;
        let uid = text(&obj, tags::SERIES_INSTANCE_UID).unwrap_or_default();
        let position = floats(&obj, tags::IMAGE_POSITION_PATIENT);
        let [x, y, z] =
            <[f64; 3]>::try_from(position.as_slice()).map_err(|_| DicomError::Geometry {
                path: path.clone(),
                message: "no ImagePositionPatient with 3 values".into(),
            })?;
        let instance: i64 = text(&obj, tags::INSTANCE_NUMBER)
            .and_then(|s| s.parse().ok())
            .unwrap_or(0);
        let ts = obj
            .meta()
            .transfer_syntax()
            .trim_end_matches('\0')
            .to_string();
        let problems = file_problems(&obj, &path, &ts);
        let entry = series.entry(uid.clone()).or_insert_with(|| SeriesSummary {
            series_instance_uid: uid,
            number: text(&obj, tags::SERIES_NUMBER).unwrap_or_default(),
            description: text(&obj, tags::SERIES_DESCRIPTION).unwrap_or_default(),
            study_instance_uid: text(&obj, tags::STUDY_INSTANCE_UID).unwrap_or_default(),
            frame_of_reference_uid: text(&obj, tags::FRAME_OF_REFERENCE_UID).unwrap_or_default(),
            files: Vec::new(),
            slices: 0,
            rows: obj
                .element(tags::ROWS)
                .ok()
                .and_then(|e| e.to_int::<u32>().ok())
                .unwrap_or(0),
            columns: obj
                .element(tags::COLUMNS)
                .ok()
                .and_then(|e| e.to_int::<u32>().ok())
                .unwrap_or(0),
            pixel_spacing_mm: <[f64; 2]>::try_from(floats(&obj, tags::PIXEL_SPACING).as_slice())
                .unwrap_or([0.0; 2]),
            orientation: <[f64; 6]>::try_from(
                floats(&obj, tags::IMAGE_ORIENTATION_PATIENT).as_slice(),
            )
            .unwrap_or([0.0; 6]),
            first_position: [x, y, z],
            z_min: z,
            z_max: z,
            transfer_syntax: ts,
            instance_numbers: (instance, instance),
            problems: Vec::new(),
        });
        for problem in problems {
            // The first of each, ten at most: a thousand damaged slices make one line each.
            let seen = entry.problems.iter().any(|p| p.ends_with(&problem));
            if !seen && entry.problems.len() < 10 {
                entry
                    .problems
                    .push(format!("{}: {problem}", path.display()));
            }
        }
        entry.files.push(path);
        entry.slices += 1;
        entry.z_min = entry.z_min.min(z);
        entry.z_max = entry.z_max.max(z);
        entry.instance_numbers = (
            entry.instance_numbers.0.min(instance),
            entry.instance_numbers.1.max(instance),
        );
    }
    let mut out: Vec<SeriesSummary> = series.into_values().collect();
    out.sort_by(|a, b| {
        a.number
            .parse::<i64>()
            .unwrap_or(0)
            .cmp(&b.number.parse::<i64>().unwrap_or(0))
    });
    Ok(out)
}

/// The `.dcm` files below `dir`: real folders only (a symbolic link to a folder is not followed,
/// so a link loop cannot make the search endless), at most 32 levels deep, each file once (a
/// link to a file already listed is not counted again).
fn collect_dcm(dir: &Path, out: &mut Vec<PathBuf>, depth: usize) -> std::io::Result<()> {
    let mut seen = std::collections::HashSet::new();
    collect_dcm_once(dir, out, depth, &mut seen)
}

fn collect_dcm_once(
    dir: &Path,
    out: &mut Vec<PathBuf>,
    depth: usize,
    seen: &mut std::collections::HashSet<(u64, u64)>,
) -> std::io::Result<()> {
    use std::os::unix::fs::MetadataExt;
    if depth > 32 {
        return Err(std::io::Error::other(format!(
            "{} is more than 32 folders deep",
            dir.display()
        )));
    }
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        if entry.file_type()?.is_dir() {
            collect_dcm_once(&path, out, depth + 1, seen)?;
        } else if path.extension().is_some_and(|e| e == "dcm") {
            // A dangling link is listed (and named when it cannot be read).
            let id = std::fs::metadata(&path).map(|m| (m.dev(), m.ino())).ok();
            if id.is_none_or(|id| seen.insert(id)) {
                out.push(path);
            }
        }
    }
    Ok(())
}

impl std::fmt::Display for SeriesSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "series {} {:<12} {} slices, {} x {} px at {} x {} mm, z {} … {} mm, instances {} … {}",
            self.number,
            self.description,
            self.slices,
            self.columns,
            self.rows,
            self.pixel_spacing_mm[0],
            self.pixel_spacing_mm[1],
            self.z_min,
            self.z_max,
            self.instance_numbers.0,
            self.instance_numbers.1
        )?;
        writeln!(
            f,
            "  first pixel at ({}, {}, {}) mm, orientation {:?}, transfer syntax {}",
            self.first_position[0],
            self.first_position[1],
            self.first_position[2],
            self.orientation,
            self.transfer_syntax
        )?;
        writeln!(
            f,
            "  study {}  frame of reference {}",
            self.study_instance_uid, self.frame_of_reference_uid
        )?;
        for problem in &self.problems {
            writeln!(f, "  PROBLEM {problem}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder that cannot be searched and a file that cannot be read keep the OS error as
    /// their source; the hint stays in the message.
    #[test]
    fn io_errors_keep_the_os_error_as_their_source() {
        let e = series_info(Path::new("/nonexistent/layerwise-dicom")).unwrap_err();
        assert!(matches!(e, DicomError::Folder { .. }), "{e:?}");
        let cause = std::error::Error::source(&e)
            .expect("the OS error")
            .to_string();
        assert_eq!(
            crate::logging::chain(&e),
            format!(
                "/nonexistent/layerwise-dicom: cannot search this folder (give an existing \
                 folder of DICOM files): {cause}"
            )
        );
        let e = super::super::check_lengths(Path::new("/nonexistent/layerwise-dicom/L00001.dcm"))
            .unwrap_err();
        assert!(matches!(e, DicomError::Io { .. }), "{e:?}");
        let cause = std::error::Error::source(&e)
            .expect("the OS error")
            .to_string();
        assert_eq!(
            crate::logging::chain(&e),
            format!("/nonexistent/layerwise-dicom/L00001.dcm: cannot read: {cause}")
        );
    }
}
