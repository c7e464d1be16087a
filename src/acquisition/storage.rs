//! Originals on disk: `<build_dir>/raw/L{layer:05}_{phase}_{light}.{ext}` and a JSON sidecar,
//! each written to a temporary file, fsynced and renamed, so a crash leaves either the whole file
//! or nothing under the final name.

use crate::build_dir::Sidecar;
use crate::fsutil::{is_temporary, sha256_hex, write_atomic, write_atomic_all, WriteError};
use crate::hardware::camera::Frame;
use crate::shot::Shot;
use chrono::{DateTime, Utc};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

fn take_name(shot: &Shot, take: u32, extension: &str) -> String {
    format!("{}.{extension}", shot.take_stem(take))
}

pub struct Storage {
    root: PathBuf,
    raw: PathBuf,
    fsync: bool,
}

impl Storage {
    pub fn open(root: &Path, fsync: bool) -> Result<Storage, WriteError> {
        let raw = root.join(crate::build_dir::RAW_DIR);
        std::fs::create_dir_all(&raw).map_err(|source| WriteError {
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
    pub fn write_atomic(&self, path: &Path, data: &[u8]) -> Result<(), WriteError> {
        write_atomic(path, data, self.fsync)
    }

    /// Stores an original and its sidecar; returns the sidecar. Take 1 is
    /// `L…_{phase}_{light}.{ext}`, take n > 1 (a retake) `L…_{phase}_{light}.r{n}.{ext}`; an
    /// original already on disk is never replaced (the next free take is used).
    #[allow(clippy::too_many_arguments)]
    pub fn store_frame(
        &self,
        shot: &Shot,
        take: u32,
        frame: &Frame,
        event_at: DateTime<Utc>,
        captured_at: DateTime<Utc>,
        attempts: u32,
        camera: &BTreeMap<String, String>,
    ) -> Result<Sidecar, WriteError> {
        let mut take = take.max(1);
        while take < u32::MAX
            && self
                .raw
                .join(take_name(shot, take, &frame.extension))
                .exists()
        {
            take += 1;
        }
        let stem = shot.take_stem(take);
        let name = format!("{stem}.{}", frame.extension);
        let sidecar = Sidecar {
            layer: shot.layer,
            phase: shot.phase,
            light: shot.light,
            file: format!("raw/{name}"),
            bytes: frame.data.len() as u64,
            sha256: sha256_hex(&frame.data),
            event_at,
            captured_at,
            capture_ms: frame.capture_ms,
            download_ms: frame.download_ms,
            attempts,
            camera: camera.clone(),
        };
        let sidecar_path = self.raw.join(format!("{stem}.json"));
        let json = serde_json::to_vec_pretty(&sidecar).map_err(|e| WriteError {
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

    fn write_sidecar(&self, shot: &Shot, sidecar: &Sidecar) -> Result<(), WriteError> {
        let path = self.raw.join(format!("{}.json", shot.stem()));
        let json = serde_json::to_vec_pretty(sidecar).map_err(|e| WriteError {
            path: path.clone(),
            source: std::io::Error::other(e),
        })?;
        self.write_atomic(&path, &json)
    }

    /// After a crash: removes temporary files and returns the originals on disk whose shots the
    /// journal does not know (`known`), with sidecars (rebuilt from the file if missing).
    pub fn recover(&self, known: impl Fn(&Shot) -> bool) -> Result<Vec<Sidecar>, WriteError> {
        let io = |source| WriteError {
            path: self.raw.clone(),
            source,
        };
        let mut found = Vec::new();
        for entry in std::fs::read_dir(&self.raw).map_err(io)? {
            let entry = entry.map_err(io)?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if is_temporary(&name) {
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
            // Only what the daemon writes is adopted: a link, a FIFO or a device planted under
            // an original's name is left alone (and said).
            if !entry.file_type().is_ok_and(|t| t.is_file()) {
                tracing::warn!(file = %path.display(), "not a regular file: not adopted as an original");
                continue;
            }
            // What the camera left: a regular file of a frame's size at most, never a link.
            let data = crate::fsutil::open_regular_nofollow(&path)
                .and_then(|f| crate::fsutil::read_file_bounded(f, crate::fsutil::MAX_FRAME_BYTES))
                .map_err(|source| WriteError {
                    path: path.clone(),
                    source,
                })?;
            let sidecar_path = self.raw.join(format!("{}.json", shot.stem()));
            let sha = sha256_hex(&data);
            let existing: Option<Sidecar> = crate::build_dir::read_record_file(&sidecar_path)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::{Light, Phase};

    #[test]
    fn an_original_is_never_overwritten() {
        let dir = tempfile::tempdir().unwrap();
        let storage = Storage::open(dir.path(), false).unwrap();
        let shot = Shot {
            layer: 3,
            phase: Phase::Post,
            light: Light::Front,
        };
        let frame = |data: &[u8]| Frame {
            data: data.to_vec(),
            extension: "jpg".into(),
            capture_ms: 1.0,
            download_ms: 1.0,
        };
        let t = chrono::Utc::now();
        let first = storage
            .store_frame(&shot, 1, &frame(b"one"), t, t, 1, &BTreeMap::new())
            .unwrap();
        // Asked for take 1 again (a daemon that lost count): the next free take is used.
        let second = storage
            .store_frame(&shot, 1, &frame(b"two"), t, t, 1, &BTreeMap::new())
            .unwrap();
        assert_eq!(first.file, "raw/L00003_post_front.jpg");
        assert_eq!(second.file, "raw/L00003_post_front.r2.jpg");
        let raw = dir.path().join("raw");
        assert_eq!(
            std::fs::read(raw.join("L00003_post_front.jpg")).unwrap(),
            b"one"
        );
        assert_eq!(
            std::fs::read(raw.join("L00003_post_front.r2.jpg")).unwrap(),
            b"two"
        );
        assert!(raw.join("L00003_post_front.r2.json").exists());
    }

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
