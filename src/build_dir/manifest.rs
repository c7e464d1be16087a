//! The build manifest `build.json`: written once when the build starts; its UIDs survive restarts.

use super::MANIFEST;
use crate::dicom::Study;
use crate::fsutil::{write_atomic, WriteError};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// A `build.json` that does not parse: the cause of [`BuildManifest::load_or_create`]'s error.
#[derive(Debug, thiserror::Error)]
#[error("not a build manifest")]
pub struct NotAManifest(#[source] pub serde_json::Error);

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
    ) -> Result<BuildManifest, WriteError> {
        let path = dir.join(MANIFEST);
        match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice(&bytes).map_err(|e| WriteError {
                path: path.clone(),
                source: std::io::Error::new(std::io::ErrorKind::InvalidData, NotAManifest(e)),
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let manifest = make();
                let json = serde_json::to_vec_pretty(&manifest).map_err(|e| WriteError {
                    path: path.clone(),
                    source: std::io::Error::other(e),
                })?;
                write_atomic(&path, &json, true)?;
                Ok(manifest)
            }
            Err(source) => Err(WriteError { path, source }),
        }
    }

    /// The DICOM study this build is: one study, one frame of reference, one StudyDate/Time.
    pub fn study(&self) -> Study {
        let manifest = self;
        let start = manifest.created_at;
        // StudyID is a short string (SH, 16 chars): the build id, cut to fit.
        let study_id: String = manifest.id.chars().take(16).collect();
        Study {
            study_instance_uid: manifest.study_instance_uid.clone(),
            frame_of_reference_uid: manifest.frame_of_reference_uid.clone(),
            date: start.format("%Y%m%d").to_string(),
            time: start.format("%H%M%S").to_string(),
            patient_name: crate::dicom::person_name(&manifest.name),
            patient_id: manifest.id.chars().take(64).collect(),
            study_id: if study_id.is_empty() {
                "1".into()
            } else {
                study_id
            },
            description: format!("layerwise build {}", manifest.name),
        }
    }
}
