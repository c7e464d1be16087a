//! The build lifecycle: which build the daemon records into, started and ended by an operator
//! (`layerwise build start|stop|list`) without editing the configuration or restarting the
//! service. With `[build] builds_dir` set, the daemon records into the build that
//! `<builds_dir>/current-build.toml` names, one folder per build under `builds_dir`; without it,
//! into `build.output_dir` as before.

use super::{status, JOURNAL, MANIFEST};
use crate::fsutil::{write_atomic, WriteError};
use chrono::{DateTime, Utc};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The order file in `builds_dir`: the build the daemon records into.
pub const CURRENT: &str = "current-build.toml";

/// Longest build name, in characters (it becomes the DICOM PatientName, at most 64 characters
/// per component group, and part of a folder name).
pub const MAX_NAME: usize = 64;

#[derive(Debug, thiserror::Error)]
pub enum LifecycleError {
    #[error(transparent)]
    Write(#[from] WriteError),
    #[error("{path}: cannot read the build order (remove it and start the build again with `layerwise build start`)")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: not a build order (remove it and start the build again with `layerwise build start`)")]
    Parse {
        path: PathBuf,
        #[source]
        source: OrderError,
    },
    #[error("build name {name:?}: {message}")]
    Name { name: String, message: String },
    #[error("{0}: already exists; choose another build name or wait a second")]
    Exists(PathBuf),
    #[error("{0}: cannot list the builds")]
    List(PathBuf, #[source] std::io::Error),
    #[error("{path}: cannot write the build order as TOML")]
    Encode {
        path: PathBuf,
        #[source]
        source: toml::ser::Error,
    },
}

/// What is wrong in an order file (the [`LifecycleError::Parse`] it causes names the file).
#[derive(Debug, thiserror::Error)]
pub enum OrderError {
    /// Not TOML of an order's shape: where (line, column, key) and what.
    #[error("{}", .0.message)]
    Toml(crate::fsutil::TomlError),
    #[error(transparent)]
    Name(Box<LifecycleError>),
    #[error(
        "folder \"{0}\" is not a folder inside builds_dir (one plain name: no `/`, no `..`, \
         not hidden, not a link out of it)"
    )]
    Folder(String),
    #[error("layers = {0}: must be 1 to {max}", max = crate::shot::MAX_LAYER)]
    Layers(u32),
}

/// A build an operator started: what the daemon records into until the next order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BuildOrder {
    /// The build's name (DICOM PatientName).
    pub name: String,
    /// Its short id (DICOM PatientID); the name when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub id: Option<String>,
    /// Its folder, relative to `builds_dir`.
    pub folder: String,
    /// Its laser scan vector file, when the operator gave one (else the configuration's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vectors: Option<PathBuf>,
    /// Layers it will have, when known (else the configuration's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layers: Option<u32>,
    pub started_at: DateTime<Utc>,
    /// Set by `layerwise build stop`: the daemon ends the build and waits for the next.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended_at: Option<DateTime<Utc>>,
}

impl BuildOrder {
    /// The build's folder.
    pub fn dir(&self, builds_dir: &Path) -> PathBuf {
        builds_dir.join(&self.folder)
    }

    /// Whether the daemon should be recording into it.
    pub fn is_open(&self) -> bool {
        self.ended_at.is_none()
    }
}

/// Checks a build name: printable, no path separators, at most [`MAX_NAME`] characters.
pub fn check_name(name: &str) -> Result<(), LifecycleError> {
    let fail = |message: &str| {
        Err(LifecycleError::Name {
            name: name.to_string(),
            message: message.to_string(),
        })
    };
    if name.trim().is_empty() {
        return fail("is empty; give the build a name");
    }
    if name.chars().count() > MAX_NAME {
        return fail(&format!("is longer than {MAX_NAME} characters"));
    }
    if name.chars().any(crate::logging::is_hidden_char) {
        return fail(
            "contains a control character or a bidirectional override (newline, NUL, U+202E, \
             ...); use printable text",
        );
    }
    if name.contains(['/', '\\', '^', '=']) {
        return fail(
            "contains '/', '\\', '^' or '='; use letters, digits, spaces, '-', '_' or '.'",
        );
    }
    Ok(())
}

/// The folder name of a build started at `at`: `YYYYMMDD-HHMMSS-name`, the name reduced to
/// letters, digits, '-', '_' and '.'.
pub fn folder_name(name: &str, at: DateTime<Utc>) -> String {
    let slug: String = name
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') {
                c
            } else {
                '-'
            }
        })
        .collect();
    format!("{}-{}", at.format("%Y%m%d-%H%M%S"), slug.trim_matches('.'))
}

/// The current order, if any.
pub fn current(builds_dir: &Path) -> Result<Option<BuildOrder>, LifecycleError> {
    let path = builds_dir.join(CURRENT);
    let text = match crate::fsutil::read_text_bounded(&path, 64 * 1024) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(LifecycleError::Read { path, source }),
    };
    let order: BuildOrder =
        crate::fsutil::parse_toml(&text, &path).map_err(|e| LifecycleError::Parse {
            path: path.clone(),
            source: OrderError::Toml(e),
        })?;
    check_name(&order.name).map_err(|e| LifecycleError::Parse {
        path: path.clone(),
        source: OrderError::Name(Box::new(e)),
    })?;
    if let Some(id) = &order.id {
        check_name(id).map_err(|e| LifecycleError::Parse {
            path: path.clone(),
            source: OrderError::Name(Box::new(e)),
        })?;
    }
    if order
        .layers
        .is_some_and(|n| n == 0 || n > crate::shot::MAX_LAYER)
    {
        return Err(LifecycleError::Parse {
            path,
            source: OrderError::Layers(order.layers.unwrap_or_default()),
        });
    }
    if !inside(builds_dir, &order.folder) {
        return Err(LifecycleError::Parse {
            path,
            source: OrderError::Folder(crate::logging::escape(&order.folder)),
        });
    }
    Ok(Some(order))
}

/// Whether `folder` names one folder inside `builds_dir`: a single plain component (not `/`,
/// `.`, `..`, nothing hidden) and, when it exists, not a link leading out of `builds_dir`.
fn inside(builds_dir: &Path, folder: &str) -> bool {
    let mut components = Path::new(folder).components();
    let plain = matches!(
        (components.next(), components.next()),
        (Some(std::path::Component::Normal(_)), None)
    ) && !folder.contains('/')
        && !folder.starts_with('.')
        && !folder.chars().any(crate::logging::is_hidden_char);
    if !plain {
        return false;
    }
    let dir = builds_dir.join(folder);
    match (
        std::fs::canonicalize(&dir),
        std::fs::canonicalize(builds_dir),
    ) {
        (Ok(dir), Ok(builds)) => dir.parent() == Some(builds.as_path()),
        // Not there yet: the daemon creates it under builds_dir.
        _ => true,
    }
}

fn write(builds_dir: &Path, order: &BuildOrder) -> Result<(), LifecycleError> {
    let text = toml::to_string(order).map_err(|source| LifecycleError::Encode {
        path: builds_dir.join(CURRENT),
        source,
    })?;
    let text = format!(
        "# The build the layerwise daemon records into (`layerwise build start|stop`).\n{text}"
    );
    write_atomic(&builds_dir.join(CURRENT), text.as_bytes(), true)?;
    Ok(())
}

/// What `layerwise build start` asks for.
#[derive(Clone, Debug, Default)]
pub struct StartRequest {
    pub name: String,
    pub id: Option<String>,
    pub vectors: Option<PathBuf>,
    pub layers: Option<u32>,
}

/// Starts a build: creates its folder and makes it the current order (ending the one before).
pub fn start(
    builds_dir: &Path,
    request: StartRequest,
    at: DateTime<Utc>,
) -> Result<BuildOrder, LifecycleError> {
    check_name(&request.name)?;
    if let Some(id) = &request.id {
        check_name(id)?;
    }
    std::fs::create_dir_all(builds_dir).map_err(|source| WriteError {
        path: builds_dir.to_path_buf(),
        source,
    })?;
    let order = BuildOrder {
        folder: folder_name(&request.name, at),
        name: request.name.trim().to_string(),
        id: request.id,
        vectors: request.vectors,
        layers: request.layers,
        started_at: at,
        ended_at: None,
    };
    let dir = order.dir(builds_dir);
    match std::fs::create_dir(&dir) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
            return Err(LifecycleError::Exists(dir))
        }
        Err(source) => return Err(WriteError { path: dir, source }.into()),
    }
    write(builds_dir, &order)?;
    Ok(order)
}

/// Ends the current build (the daemon finishes the frame in hand and waits for the next build).
/// Returns the order it ended, or None when no build was open.
pub fn stop(builds_dir: &Path, at: DateTime<Utc>) -> Result<Option<BuildOrder>, LifecycleError> {
    match current(builds_dir)? {
        Some(mut order) if order.is_open() => {
            order.ended_at = Some(at);
            write(builds_dir, &order)?;
            Ok(Some(order))
        }
        _ => Ok(None),
    }
}

/// One build of `builds_dir`, for `layerwise build list`.
#[derive(Clone, Debug, Serialize)]
pub struct BuildEntry {
    pub folder: String,
    pub name: Option<String>,
    pub created_at: Option<DateTime<Utc>>,
    /// The current order's build, still open.
    pub current: bool,
    pub frames: usize,
    pub frames_missing: usize,
    pub layers_seen: usize,
    /// The daemon's last word on it ("running", "stopped", ...), or why it cannot be read.
    pub state: String,
}

/// Every build folder in `builds_dir` (those with a journal or a manifest), oldest first.
pub fn list(builds_dir: &Path) -> Result<Vec<BuildEntry>, LifecycleError> {
    let order = current(builds_dir)?;
    let entries = match std::fs::read_dir(builds_dir) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(LifecycleError::List(builds_dir.into(), e)),
    };
    let mut builds = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        let folder = entry.file_name().to_string_lossy().into_owned();
        let is_dir = entry.file_type().map(|t| t.is_dir()).unwrap_or(false);
        let is_build = path.join(JOURNAL).exists() || path.join(MANIFEST).exists();
        let is_current = order
            .as_ref()
            .is_some_and(|o| o.folder == folder && o.is_open());
        if !is_dir || !(is_build || is_current) {
            continue;
        }
        let mut build = BuildEntry {
            folder,
            name: None,
            created_at: None,
            current: is_current,
            frames: 0,
            frames_missing: 0,
            layers_seen: 0,
            state: "not started yet".into(),
        };
        if let Ok(m) = super::BuildManifest::read(&path) {
            build.name = Some(m.name);
            build.created_at = Some(m.created_at);
        }
        if path.join(JOURNAL).exists() {
            match status::report(&path, status::ReportSettings::default()) {
                Ok(r) => {
                    build.frames = r.frames;
                    build.frames_missing = r.frames_missing;
                    build.layers_seen = r.layers_seen;
                    build.state = r.state;
                }
                Err(e) => build.state = format!("unreadable: {}", crate::logging::chain(&e)),
            }
        }
        builds.push(build);
    }
    builds.sort_by(|a, b| a.folder.cmp(&b.folder));
    Ok(builds)
}

#[cfg(test)]
mod tests {
    use super::*;
    use chrono::TimeZone;

    fn at(s: u32) -> DateTime<Utc> {
        Utc.with_ymd_and_hms(2026, 12, 2, 1, 2, s).unwrap()
    }

    #[test]
    fn a_start_makes_the_folder_and_the_order_and_a_stop_ends_it() {
        let tmp = tempfile::tempdir().unwrap();
        let builds = tmp.path().join("builds");
        assert_eq!(current(&builds).unwrap(), None);
        let request = StartRequest {
            name: "Bracket 7 / rev b".into(),
            ..StartRequest::default()
        };
        assert!(matches!(
            start(&builds, request, at(3)),
            Err(LifecycleError::Name { .. })
        ));
        let request = StartRequest {
            name: "Bracket 7 rev.b".into(),
            layers: Some(40),
            ..StartRequest::default()
        };
        let order = start(&builds, request.clone(), at(3)).unwrap();
        assert_eq!(order.folder, "20261202-010203-Bracket-7-rev.b");
        assert!(order.dir(&builds).is_dir());
        assert_eq!(current(&builds).unwrap(), Some(order.clone()));
        // The same name in the same second: refused, the order stays.
        assert!(matches!(
            start(&builds, request, at(3)),
            Err(LifecycleError::Exists(_))
        ));
        let ended = stop(&builds, at(9)).unwrap().unwrap();
        assert_eq!(ended.ended_at, Some(at(9)));
        assert!(!current(&builds).unwrap().unwrap().is_open());
        assert_eq!(stop(&builds, at(10)).unwrap(), None);
        // Listed (no journal yet, but it is the folder of the last order).
        let listed = list(&builds).unwrap();
        assert!(listed.is_empty(), "{listed:?}");
    }

    #[test]
    fn names_with_control_characters_or_paths_are_refused_and_a_bad_order_is_an_error() {
        for bad in [
            "",
            "  ",
            "a\nb",
            "a\0b",
            "a\u{202e}b",
            "../x",
            "a^b",
            &"x".repeat(65),
        ] {
            assert!(check_name(bad).is_err(), "{bad:?}");
        }
        let tmp = tempfile::tempdir().unwrap();
        std::fs::write(
            tmp.path().join(CURRENT),
            r#"name = "x"
folder = "../../etc"
started_at = "2026-12-02T01:02:03Z"
"#,
        )
        .unwrap();
        let e = crate::logging::chain(&current(tmp.path()).unwrap_err());
        assert!(e.contains("not a folder inside builds_dir"), "{e}");
        std::fs::write(tmp.path().join(CURRENT), "garbage").unwrap();
        let e = current(tmp.path()).unwrap_err().to_string();
        assert!(e.contains("current-build.toml: not a build order"), "{e}");
    }
}
