//! The build manifest `build.json`: written once when the build starts; its UIDs survive restarts.

use super::MANIFEST;
use crate::dicom::Study;
use crate::fsutil::{write_atomic, WriteError};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Why `build.json` could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    #[error("{}: cannot read the build manifest", path.display())]
    Read {
        path: std::path::PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: not a build manifest (restore it from a backup, or move it away to start a new build in this folder)", path.display())]
    Parse {
        path: std::path::PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error(transparent)]
    Write(#[from] WriteError),
}

/// Facts of a build fixed at its start: one study, one frame of reference, one StudyDate/Time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BuildManifest {
    pub name: String,
    pub id: String,
    pub created_at: DateTime<Utc>,
    pub layers_expected: Option<u32>,
    pub views: Vec<String>,
    pub study_instance_uid: String,
    pub frame_of_reference_uid: String,
    pub software_version: String,
}

impl BuildManifest {
    /// Reads the manifest, or creates it for a new build.
    pub fn load_or_create(
        dir: &Path,
        make: impl FnOnce() -> BuildManifest,
    ) -> Result<BuildManifest, ManifestError> {
        let path = dir.join(MANIFEST);
        match super::read_record_file(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes)
                .map_err(|source| ManifestError::Parse { path, source }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let manifest = make();
                let json = serde_json::to_vec_pretty(&manifest).map_err(|e| WriteError {
                    path: path.clone(),
                    source: std::io::Error::other(e),
                })?;
                write_atomic(&path, &json, true)?;
                Ok(manifest)
            }
            Err(source) => Err(ManifestError::Read { path, source }),
        }
    }

    /// Reads the manifest of a build (bounded: a regular file of a few KB).
    pub fn read(dir: &Path) -> Result<BuildManifest, ManifestError> {
        let path = dir.join(MANIFEST);
        let bytes = super::read_record_file(&path).map_err(|source| ManifestError::Read {
            path: path.clone(),
            source,
        })?;
        serde_json::from_slice(&bytes).map_err(|source| ManifestError::Parse { path, source })
    }

    /// The DICOM study this build is: one study, one frame of reference, one StudyDate/Time.
    pub fn study(&self) -> Study {
        let manifest = self;
        let start = manifest.created_at;
        // What the configuration refuses (control and bidirectional characters, the value
        // separator) never reaches a DICOM file from an older or hand-edited build.json either.
        let plain = |text: &str| -> String {
            text.chars()
                .map(|c| {
                    if crate::logging::is_hidden_char(c) || c == '\\' {
                        '_'
                    } else {
                        c
                    }
                })
                .collect()
        };
        let (name, id) = (plain(&manifest.name), plain(&manifest.id));
        // StudyID is a short string (SH, 16 chars): the build id, cut to fit.
        let study_id: String = id.chars().take(16).collect();
        Study {
            study_instance_uid: manifest.study_instance_uid.clone(),
            frame_of_reference_uid: manifest.frame_of_reference_uid.clone(),
            date: start.format("%Y%m%d").to_string(),
            time: start.format("%H%M%S").to_string(),
            patient_name: crate::dicom::person_name(&name),
            patient_id: id.chars().take(64).collect(),
            study_id: if study_id.is_empty() {
                "1".into()
            } else {
                study_id
            },
            description: format!("layerwise build {name}"),
        }
    }
}
