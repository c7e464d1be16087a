//! Originals on disk: `<build_dir>/raw/L{layer:05}_{phase}_{light}.{ext}` and a JSON sidecar,
//! each written to a temporary file, fsynced and renamed, so a crash leaves either the whole file
//! or nothing under the final name.

use crate::camera::Frame;
use crate::view::Shot;
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
#[error("{path}: {source} (is the disk full or read-only?)")]
pub struct StorageError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

/// What the sidecar next to each original says.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sidecar {
    pub layer: u32,
    pub phase: crate::view::Phase,
    pub light: crate::view::Light,
    pub file: String,
    pub bytes: u64,
    pub sha256: String,
    pub event_at: DateTime<Utc>,
    pub captured_at: DateTime<Utc>,
    pub capture_ms: f64,
    pub download_ms: f64,
    pub attempts: u32,
    pub camera: BTreeMap<String, String>,
}

pub struct Storage {
    root: PathBuf,
    raw: PathBuf,
    fsync: bool,
}

pub fn sha256_hex(data: &[u8]) -> String {
    let digest = Sha256::digest(data);
    let mut out = String::with_capacity(64);
    for b in digest {
        out.push_str(&format!("{b:02x}"));
    }
    out
}

impl Storage {
    pub fn open(root: &Path, fsync: bool) -> Result<Storage, StorageError> {
        let raw = root.join("raw");
        std::fs::create_dir_all(&raw).map_err(|source| StorageError {
            path: raw.clone(),
            source,
        })?;
        Ok(Storage {
            root: root.to_path_buf(),
            raw,
            fsync,
        })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    /// Writes `data` under `path` atomically (temp file, fsync, rename, fsync of the directory).
    pub fn write_atomic(&self, path: &Path, data: &[u8]) -> Result<(), StorageError> {
        write_atomic(path, data, self.fsync)
    }

    /// Stores an original and its sidecar; returns the sidecar.
    pub fn store_frame(
        &self,
        shot: &Shot,
        frame: &Frame,
        event_at: DateTime<Utc>,
        attempts: u32,
        camera: &BTreeMap<String, String>,
    ) -> Result<Sidecar, StorageError> {
        let name = format!("{}.{}", shot.stem(), frame.extension);
        let sidecar = Sidecar {
            layer: shot.layer,
            phase: shot.phase,
            light: shot.light,
            file: format!("raw/{name}"),
            bytes: frame.data.len() as u64,
            sha256: sha256_hex(&frame.data),
            event_at,
            captured_at: Utc::now(),
            capture_ms: frame.capture_ms,
            download_ms: frame.download_ms,
            attempts,
            camera: camera.clone(),
        };
        let sidecar_path = self.raw.join(format!("{}.json", shot.stem()));
        let json = serde_json::to_vec_pretty(&sidecar).map_err(|e| StorageError {
            path: sidecar_path.clone(),
            source: std::io::Error::other(e),
        })?;
        // The original is renamed first: a crash between the two renames leaves an original
        // whose sidecar `recover` rebuilds.
        write_atomic_all(
            &[(&self.raw.join(&name), &frame.data), (&sidecar_path, &json)],
            self.fsync,
        )?;
        Ok(sidecar)
    }

    fn write_sidecar(&self, shot: &Shot, sidecar: &Sidecar) -> Result<(), StorageError> {
        let path = self.raw.join(format!("{}.json", shot.stem()));
        let json = serde_json::to_vec_pretty(sidecar).map_err(|e| StorageError {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
        self.write_atomic(&path, &json)
    }

    /// After a crash: removes temporary files and returns the originals on disk whose shots the
    /// journal does not know (`known`), with sidecars (rebuilt from the file if missing).
    pub fn recover(&self, known: impl Fn(&Shot) -> bool) -> Result<Vec<Sidecar>, StorageError> {
        let io = |source| StorageError {
            path: self.raw.clone(),
            source,
        };
        let mut found = Vec::new();
        for entry in std::fs::read_dir(&self.raw).map_err(io)? {
            let entry = entry.map_err(io)?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.starts_with('.') && name.ends_with(".tmp") {
                std::fs::remove_file(entry.path()).map_err(io)?;
                continue;
            }
            let path = entry.path();
            let (Some(stem), Some(ext)) = (path.file_stem(), path.extension()) else {
                continue;
            };
            let ext = ext.to_string_lossy().into_owned();
            let Some(shot) = Shot::from_stem(&stem.to_string_lossy()) else {
                continue;
            };
            if ext == "json" || known(&shot) {
                continue;
            }
            let data = std::fs::read(&path).map_err(|source| StorageError {
                path: path.clone(),
                source,
            })?;
            let sidecar_path = self.raw.join(format!("{}.json", shot.stem()));
            let sha = sha256_hex(&data);
            let existing: Option<Sidecar> = std::fs::read(&sidecar_path)
                .ok()
                .and_then(|b| serde_json::from_slice(&b).ok());
            let sidecar = match existing {
                Some(s) if s.sha256 == sha => s,
                _ => {
                    let modified = entry
                        .metadata()
                        .and_then(|m| m.modified())
                        .map(DateTime::<Utc>::from)
                        .unwrap_or_else(|_| Utc::now());
                    let s = Sidecar {
                        layer: shot.layer,
                        phase: shot.phase,
                        light: shot.light,
                        file: format!("raw/{name}"),
                        bytes: data.len() as u64,
                        sha256: sha,
                        event_at: modified,
                        captured_at: modified,
                        capture_ms: 0.0,
                        download_ms: 0.0,
                        attempts: 0,
                        camera: BTreeMap::from([(
                            "recovered".to_string(),
                            "sidecar rebuilt after a crash".to_string(),
                        )]),
                    };
                    self.write_sidecar(&shot, &s)?;
                    s
                }
            };
            found.push(sidecar);
        }
        found.sort_by_key(|s| (s.layer, s.phase, s.light));
        Ok(found)
    }
}

pub fn write_atomic(path: &Path, data: &[u8], fsync: bool) -> Result<(), StorageError> {
    write_atomic_all(&[(path, data)], fsync)
}

/// The directory a file is in; "." for a bare file name (whose `parent()` is the empty path,
/// which cannot be opened to fsync).
fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    }
}

/// Writes files of one directory atomically, renaming them in the order given, with a single
/// fsync of the directory for all the renames (it is the slowest part of the capture path).
fn write_atomic_all(files: &[(&Path, &[u8])], fsync: bool) -> Result<(), StorageError> {
    let mut renames = Vec::with_capacity(files.len());
    for (path, data) in files {
        let err = |source| StorageError {
            path: path.to_path_buf(),
            source,
        };
        let dir = parent_dir(path);
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dir.join(format!(".{name}.tmp"));
        let mut file = File::create(&tmp).map_err(err)?;
        file.write_all(data).map_err(err)?;
        if fsync {
            file.sync_data().map_err(err)?;
        }
        renames.push((tmp, *path));
    }
    for (tmp, path) in &renames {
        std::fs::rename(tmp, path).map_err(|source| StorageError {
            path: path.to_path_buf(),
            source,
        })?;
    }
    if fsync {
        let mut dirs: Vec<&Path> = renames.iter().map(|(_, p)| parent_dir(p)).collect();
        dirs.dedup();
        for dir in dirs {
            File::open(dir)
                .and_then(|d| d.sync_all())
                .map_err(|source| StorageError {
                    path: dir.to_path_buf(),
                    source,
                })?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::view::{Light, Phase};

    #[test]
    fn recover_adopts_orphans_and_drops_temps() {
        let dir = tempfile::tempdir().unwrap();
        let storage = Storage::open(dir.path(), true).unwrap();
        let shot = Shot {
            layer: 3,
            phase: Phase::Pre,
            light: Light::Side,
        };
        // An original renamed into place just before a crash: no sidecar, no journal record.
        std::fs::write(dir.path().join("raw/L00003_pre_side.jpg"), b"jpegbytes").unwrap();
        std::fs::write(dir.path().join("raw/.L00004_pre_front.jpg.tmp"), b"half").unwrap();
        let found = storage.recover(|_| false).unwrap();
        assert_eq!(found.len(), 1);
        assert_eq!(
            (found[0].layer, found[0].sha256.clone()),
            (shot.layer, sha256_hex(b"jpegbytes"))
        );
        assert!(dir.path().join("raw/L00003_pre_side.json").exists());
        assert!(!dir.path().join("raw/.L00004_pre_front.jpg.tmp").exists());
        assert!(storage.recover(|s| *s == shot).unwrap().is_empty());
    }
}
