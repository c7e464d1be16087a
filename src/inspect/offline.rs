//! Inspection after the fact: the originals of a stored build (from its journal), a folder of
//! frames named as docs/frames.md says, or any folder of pictures (taken in name order as
//! consecutive layers of one view), decoded and rectified exactly as the daemon's worker does
//! (the build's calibration, grid, interpolation and fill), inspected in layer order. Without a
//! calibration the frames are taken as top-down views ([`top_down`]).

use super::Inspector;
use crate::build_dir::inspection::InspectionRecord;
use crate::build_dir::{Journal, JournalError};
use crate::rectify::{Rectifier, RectifyError};
use crate::shot::Shot;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum OfflineError {
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error("cannot read {path}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot decode the frame")]
    Decode {
        path: PathBuf,
        #[source]
        source: RectifyError,
    },
    #[error(transparent)]
    Original(#[from] crate::build_dir::original::OriginalError),
    #[error("{path}: no frames named L{{layer:05}}_{{phase}}_{{light}}.{{ext}} (docs/frames.md)")]
    NoFrames { path: PathBuf },
    #[error("{path}: no pictures (.jpg, .jpeg, .png, .tif, .tiff, .nef) in the folder")]
    NoPictures { path: PathBuf },
    #[error("{path}: {count} pictures, more than the {max} layers a build can have")]
    TooMany {
        path: PathBuf,
        count: usize,
        max: u32,
    },
    #[error("--pixel-mm {0}: must be a finite number above 0")]
    PixelSize(f64),
}

/// Extensions of the pictures a plain folder is read for (any case).
const PICTURES: [&str; 6] = ["jpg", "jpeg", "png", "tif", "tiff", "nef"];

/// Any folder of frames: named as docs/frames.md says when some are, else every picture in name
/// order as layers 1, 2, … of `view`.
pub fn any_frames(dir: &Path, view: crate::shot::View) -> Result<Frames, OfflineError> {
    match folder_frames(dir) {
        Err(OfflineError::NoFrames { .. }) => plain_frames(dir, view),
        other => other,
    }
}

/// Every picture of a folder in name order, as consecutive layers of `view` from 1.
pub fn plain_frames(dir: &Path, view: crate::shot::View) -> Result<Frames, OfflineError> {
    let entries = std::fs::read_dir(dir).map_err(|source| OfflineError::Read {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut pictures: Vec<PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_file())
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| PICTURES.iter().any(|k| e.eq_ignore_ascii_case(k)))
        })
        .collect();
    pictures.sort();
    if pictures.is_empty() {
        return Err(OfflineError::NoPictures {
            path: dir.to_path_buf(),
        });
    }
    if pictures.len() > crate::shot::MAX_LAYER as usize {
        return Err(OfflineError::TooMany {
            path: dir.to_path_buf(),
            count: pictures.len(),
            max: crate::shot::MAX_LAYER,
        });
    }
    Ok(as_layers(&pictures, view))
}

/// `pictures` as consecutive layers of `view` from 1, in the order given (a folder's frames,
/// taken as they are).
pub fn as_layers(pictures: &[PathBuf], view: crate::shot::View) -> Frames {
    let paths = pictures
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let shot = Shot {
                layer: i as u32 + 1,
                phase: view.phase,
                light: view.light,
            };
            (shot, p.clone())
        })
        .collect();
    Frames {
        paths,
        of_build: false,
    }
}

/// Plate millimetres across the wider side of a frame taken as top-down without a pixel size:
/// the plate's side (the frame is assumed to show about the plate). Only the sizes in mm of the
/// report depend on it; the checks' scales (segments, widths, areas) follow it.
pub const TOP_DOWN_SPAN_MM: f64 = 2.0 * crate::geometry::PLATE_HALF_MM;

/// The calibration and grid of a frame of `width` x `height` pixels taken as a top-down view:
/// the frame's centre at the build origin, x to the right, y up (docs/frames.md), `pixel_mm` a
/// pixel (default: the wider side spans [`TOP_DOWN_SPAN_MM`]); the grid is the frame's own
/// pixels.
pub fn top_down(
    width: u32,
    height: u32,
    pixel_mm: Option<f64>,
) -> Result<(crate::rectify::Calibration, crate::geometry::Grid), OfflineError> {
    let p = pixel_mm.unwrap_or(TOP_DOWN_SPAN_MM / f64::from(width.max(height).max(1)));
    if !(p.is_finite() && p > 0.0) {
        return Err(OfflineError::PixelSize(p));
    }
    let (w, h) = (f64::from(width) * p, f64::from(height) * p);
    let build_from_image = crate::geometry::Homography::from_matrix([
        [p, 0.0, -w / 2.0],
        [0.0, -p, h / 2.0],
        [0.0, 0.0, 1.0],
    ]);
    let grid = crate::geometry::Grid {
        x_min: -w / 2.0,
        x_max: w / 2.0,
        y_min: -h / 2.0,
        y_max: h / 2.0,
        pixel_mm: p,
    };
    Ok((
        crate::rectify::Calibration {
            build_from_image,
            distortion: None,
            grid: Some(grid),
            fit: None,
        },
        grid,
    ))
}

/// The size of the first frame of `frames`, decoded.
pub fn frame_size(frames: &BTreeMap<Shot, PathBuf>) -> Result<(u32, u32), OfflineError> {
    let Some(path) = frames.values().next() else {
        return Ok((0, 0));
    };
    let bytes = std::fs::read(path).map_err(|source| OfflineError::Read {
        path: path.clone(),
        source,
    })?;
    let luma =
        crate::rectify::decode_frame_luma(&bytes).map_err(|source| OfflineError::Decode {
            path: path.clone(),
            source,
        })?;
    Ok(match luma {
        crate::rectify::FrameLuma::Gamma8(g) => g.dimensions(),
        crate::rectify::FrameLuma::Linear16(g) => g.dimensions(),
    })
}

/// The frames to inspect, per shot, and where they come from.
pub struct Frames {
    pub paths: BTreeMap<Shot, PathBuf>,
    /// The originals of a build: each read only with its sidecar, which it must match
    /// (build_dir::original); a folder's frames are taken as they are.
    pub of_build: bool,
}

/// The first takes of a stored build, from its journal: each record's file only if it is the
/// shot's own name in `raw/` (a record naming anything else is refused).
pub fn build_frames(dir: &Path) -> Result<Frames, OfflineError> {
    let replay = Journal::read(&dir.join(crate::build_dir::JOURNAL))?;
    let paths = replay
        .frames
        .iter()
        .map(|(shot, entry)| {
            crate::build_dir::original::recorded_path(dir, shot, 1, &entry.file)
                .map(|path| (*shot, path))
        })
        .collect::<Result<_, _>>()?;
    Ok(Frames {
        paths,
        of_build: true,
    })
}

/// Frames in a folder named `L00042_post_top.jpg` (retakes `….r2.jpg` and sidecars left out).
pub fn folder_frames(dir: &Path) -> Result<Frames, OfflineError> {
    let entries = std::fs::read_dir(dir).map_err(|source| OfflineError::Read {
        path: dir.to_path_buf(),
        source,
    })?;
    let frames: BTreeMap<Shot, PathBuf> = entries
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e != "json"))
        .filter_map(|p| {
            let stem = p.file_stem()?.to_str()?;
            let shot = Shot::from_stem(stem)?;
            (shot.stem() == stem).then_some((shot, p))
        })
        .collect();
    if frames.is_empty() {
        return Err(OfflineError::NoFrames {
            path: dir.to_path_buf(),
        });
    }
    Ok(Frames {
        paths: frames,
        of_build: false,
    })
}

/// A frame that could not be inspected (the rest go on, as in the daemon).
#[derive(Debug)]
pub struct Skipped {
    pub shot: Shot,
    /// [`OfflineError::Read`] or [`OfflineError::Decode`].
    pub error: OfflineError,
}

/// Inspects the layers `from..=to` of `frames` in order; returns the records and the frames
/// that could not be read or decoded.
pub fn run(
    inspector: &mut Inspector,
    rectifier: &Rectifier,
    frames: &Frames,
    from: u32,
    to: u32,
    at: chrono::DateTime<chrono::Utc>,
) -> (Vec<InspectionRecord>, Vec<Skipped>) {
    let reducer = inspector.reducer();
    let mut by_layer: BTreeMap<u32, Vec<(Shot, &PathBuf)>> = BTreeMap::new();
    for (shot, path) in frames.paths.range(
        Shot {
            layer: from,
            phase: crate::shot::Phase::Pre,
            light: crate::shot::Light::Front,
        }..,
    ) {
        if shot.layer > to {
            break;
        }
        if reducer.needs(shot.view()) {
            by_layer.entry(shot.layer).or_default().push((*shot, path));
        }
    }
    let mut records = Vec::new();
    let mut skipped = Vec::new();
    for (layer, shots) in by_layer {
        let cells: Vec<_> = shots
            .par_iter()
            .map(|(shot, path)| {
                let bytes = if frames.of_build {
                    crate::build_dir::original::read(path)
                        .map(|original| original.bytes)
                        .map_err(OfflineError::from)
                } else {
                    crate::fsutil::read_regular(path).map_err(|source| OfflineError::Read {
                        path: path.to_path_buf(),
                        source,
                    })
                };
                let cells = bytes
                    .and_then(|bytes| {
                        crate::rectify::decode_frame_luma(&bytes).map_err(|source| {
                            OfflineError::Decode {
                                path: path.to_path_buf(),
                                source,
                            }
                        })
                    })
                    .map(|luma| reducer.cells(&luma.rectified(rectifier)));
                (*shot, cells)
            })
            .collect();
        for (shot, c) in cells {
            match c {
                Ok(cells) => records.extend(inspector.add(layer, shot.view(), cells, at)),
                Err(error) => skipped.push(Skipped { shot, error }),
            }
        }
    }
    records.extend(inspector.flush(at));
    (records, skipped)
}
