//! Every check `run` makes before it touches the hardware, and `check-config` with it: the
//! backends this binary has, and every file the configuration names read as `run` reads it
//! (bounded: a regular file of its kind's size, never a FIFO waited on or a device read without
//! end): the calibration, the vector file, the PACS secrets, the page's token, the mock
//! trigger's script. What check-config calls valid, `run` starts with.

use crate::config::{Config, ConfigError, TriggerConfig};
use std::path::{Path, PathBuf};

/// A configuration `run` would refuse (or fail every frame with).
#[derive(Debug, thiserror::Error)]
pub enum PreflightError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{file}: key `calibration.file`")]
    Calibration {
        file: PathBuf,
        #[source]
        source: crate::rectify::CalibrationError,
    },
    #[error("{file}: key `build.vectors` (or calibration.crop_part)")]
    Vectors {
        file: PathBuf,
        #[source]
        source: crate::series::SeriesError,
    },
    #[error("{file}: key `pacs[{index}]`")]
    Pacs {
        file: PathBuf,
        index: usize,
        #[source]
        source: crate::pacs::PacsError,
    },
    #[error("{file}: key `{key}`: cannot read {path}")]
    Named {
        file: PathBuf,
        key: &'static str,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// The page's token file and the mock trigger's script: a few KB, at most these.
const MAX_TOKEN_BYTES: u64 = 64 << 10;
const MAX_SCRIPT_BYTES: u64 = 16 << 20;

/// Runs every check `run` runs before touching the hardware on `config`, loaded from `file`.
pub fn preflight(config: &Config, file: &Path) -> Result<(), PreflightError> {
    config.check_backends(file)?;
    if let Some(path) = &config.calibration.file {
        crate::rectify::Calibration::load(path).map_err(|source| PreflightError::Calibration {
            file: file.to_path_buf(),
            source,
        })?;
    }
    crate::series::SeriesSettings::from_config(config).map_err(|source| {
        PreflightError::Vectors {
            file: file.to_path_buf(),
            source,
        }
    })?;
    for (index, destination) in config.pacs.iter().enumerate() {
        crate::pacs::Destination::from_config(destination).map_err(|source| {
            PreflightError::Pacs {
                file: file.to_path_buf(),
                index,
                source,
            }
        })?;
    }
    let named = |key: &'static str, path: &Path, max: u64| {
        crate::fsutil::read_bounded(path, max)
            .map(drop)
            .map_err(|source| PreflightError::Named {
                file: file.to_path_buf(),
                key,
                path: path.to_path_buf(),
                source,
            })
    };
    if let Some(token) = &config.web.token_file {
        named("web.token_file", token, MAX_TOKEN_BYTES)?;
    }
    if let TriggerConfig::Mock(mock) = &config.trigger {
        if let Some(script) = &mock.script {
            named("trigger.script", script, MAX_SCRIPT_BYTES)?;
        }
    }
    Ok(())
}
