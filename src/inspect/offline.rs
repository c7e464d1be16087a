//! Inspection after the fact: the originals of a stored build (from its journal) or a folder of
//! frames named as docs/frames.md says, decoded and rectified exactly as the daemon's worker does
//! (the build's calibration, grid, interpolation and fill), inspected in layer order.

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
