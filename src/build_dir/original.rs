//! A build's originals as every reader takes them: only from `raw/`, under the shot's own name
//! (`L{layer:05}_{phase}_{light}[.r{take}].{ext}`), a regular file (never a link, a FIFO or a
//! device) of at most [`MAX_FRAME_BYTES`](crate::fsutil::MAX_FRAME_BYTES), and the bytes its
//! sidecar describes (size and SHA-256). A journal record's `file` is a name to check, never a
//! path to follow.

use super::{read_record_file, Sidecar, RAW_DIR};
use crate::shot::Shot;
use std::path::{Path, PathBuf};

pub use super::FRAME_EXTENSIONS;

#[derive(Debug, thiserror::Error)]
pub enum OriginalError {
    /// A journal record names a file that is not the take's own in `raw/`.
    #[error(
        "the journal names `{recorded}` for {shot}, take {take}: originals are read only from \
         raw/ under their own name ({expected}.{{jpg,nef,…}}); the record is not trusted"
    )]
    NotItsName {
        recorded: String,
        shot: Shot,
        take: u32,
        expected: String,
    },
    #[error("{path}: cannot read the original")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: cannot read its sidecar {sidecar} (an original is used only with it)")]
    Sidecar {
        path: PathBuf,
        sidecar: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{sidecar}: not a sidecar")]
    SidecarParse {
        sidecar: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error(
        "{path}: not the frame its sidecar describes ({what}): it was replaced or damaged since \
         it was captured; restore it from a backup"
    )]
    Mismatch { path: PathBuf, what: String },
}

/// The path of take `take` of `shot` that a journal record names (`raw/L00003_post_top.jpg`):
/// refused unless it is exactly the take's own name in `raw/` with an original's extension.
pub fn recorded_path(
    build_dir: &Path,
    shot: &Shot,
    take: u32,
    recorded: &str,
) -> Result<PathBuf, OriginalError> {
    let stem = shot.take_stem(take.max(1));
    let ok = recorded
        .strip_prefix(RAW_DIR)
        .and_then(|rest| rest.strip_prefix('/'))
        .and_then(|name| name.strip_prefix(stem.as_str()))
        .and_then(|rest| rest.strip_prefix('.'))
        .is_some_and(|ext| FRAME_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()));
    if !ok {
        return Err(OriginalError::NotItsName {
            recorded: crate::logging::escape(recorded),
            shot: *shot,
            take,
            expected: format!("{RAW_DIR}/{stem}"),
        });
    }
    Ok(build_dir.join(recorded))
}

/// An original and the sidecar it matches.
pub struct Original {
    pub bytes: Vec<u8>,
    pub sidecar: Sidecar,
}

/// Reads an original of a build directory (`…/raw/NAME.ext`) and checks it against its sidecar
/// (`…/raw/NAME.json`): its name, size and SHA-256.
pub fn read(path: &Path) -> Result<Original, OriginalError> {
    let read_err = |source| OriginalError::Read {
        path: path.to_path_buf(),
        source,
    };
    let sidecar_path = path.with_extension("json");
    let sidecar_bytes =
        read_record_file(&sidecar_path).map_err(|source| OriginalError::Sidecar {
            path: path.to_path_buf(),
            sidecar: sidecar_path.clone(),
            source,
        })?;
    let sidecar: Sidecar =
        serde_json::from_slice(&sidecar_bytes).map_err(|source| OriginalError::SidecarParse {
            sidecar: sidecar_path.clone(),
            source,
        })?;
    let file = crate::fsutil::open_regular_nofollow(path).map_err(read_err)?;
    let bytes =
        crate::fsutil::read_file_bounded(file, crate::fsutil::MAX_FRAME_BYTES).map_err(read_err)?;
    let mismatch = |what: String| OriginalError::Mismatch {
        path: path.to_path_buf(),
        what,
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    if sidecar.file != format!("{RAW_DIR}/{name}") {
        return Err(mismatch(format!(
            "the sidecar is of `{}`",
            crate::logging::escape(&sidecar.file)
        )));
    }
    if sidecar.bytes != bytes.len() as u64 {
        return Err(mismatch(format!(
            "{} bytes, the sidecar says {}",
            bytes.len(),
            sidecar.bytes
        )));
    }
    if crate::fsutil::sha256_hex(&bytes) != sidecar.sha256 {
        return Err(mismatch("its SHA-256 is not the sidecar's".into()));
    }
    Ok(Original { bytes, sidecar })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shot::{Light, Phase};

    #[test]
    fn only_the_takes_own_name_in_raw_is_taken() {
        let dir = Path::new("/b");
        let shot = Shot::new(3, Phase::Post, Light::Top);
        assert_eq!(
            recorded_path(dir, &shot, 1, "raw/L00003_post_top.jpg").unwrap(),
            dir.join("raw/L00003_post_top.jpg")
        );
        assert!(recorded_path(dir, &shot, 2, "raw/L00003_post_top.r2.NEF").is_ok());
        for bad in [
            "/other/build/raw/L00003_post_top.jpg",
            "raw/../../other/raw/L00003_post_top.jpg",
            "raw/L00004_post_top.jpg",
            "raw/L00003_post_top.r2.jpg",
            "raw/L00003_post_top.json",
            "raw/L00003_post_top.jpg/x",
            "L00003_post_top.jpg",
        ] {
            let err = recorded_path(dir, &shot, 1, bad).unwrap_err().to_string();
            assert!(err.contains("raw/L00003_post_top."), "{bad}: {err}");
        }
    }
}
