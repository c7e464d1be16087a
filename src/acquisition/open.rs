//! A run's build directory opened: originals, manifest, journal replayed into [`Progress`], the
//! originals a crash left unjournaled adopted, the configuration and calibration snapshots, the
//! layer a restart interrupted.

use super::sequencer::OpenEvent;
use super::storage::Storage;
use super::AcquisitionError;
use crate::build_dir::{self, BuildManifest, Journal, Progress, Record};
use crate::clock::SharedClock;
use crate::config::Config;
use crate::fsutil::WriteError;
use crate::logging::Chain;
use crate::shot::{Light, Shot};
use std::collections::BTreeSet;
use tracing::{info, warn};

/// The build directory opened for a run: originals, manifest, journal and what it replayed.
pub(super) struct OpenedBuild {
    pub(super) storage: Storage,
    pub(super) manifest: BuildManifest,
    pub(super) journal: Journal,
    pub(super) progress: Progress,
}

/// Opens (or starts) the build directory, adopts originals a crash left unjournaled, and
/// journals the start.
pub(super) fn open_build(
    config: &Config,
    clock: &SharedClock,
) -> Result<OpenedBuild, AcquisitionError> {
    let dir = config.build.output_dir.clone();
    let storage = Storage::open(&dir, config.storage.fsync)?;
    let views: Vec<String> = config.views.all().iter().map(|v| v.to_string()).collect();
    let manifest = BuildManifest::load_or_create(&dir, || BuildManifest {
        name: config.build.name.clone(),
        id: config.build_id().to_string(),
        created_at: clock.now(),
        layers_expected: config.build.layers,
        views,
        study_instance_uid: crate::dicom::new_uid(),
        frame_of_reference_uid: crate::dicom::new_uid(),
        software_version: env!("CARGO_PKG_VERSION").to_string(),
    })?;
    match snapshot_configuration(config, &storage) {
        // A restart on a full disk still captures when space returns: the snapshot of the last
        // start stays.
        Err(AcquisitionError::Storage(e)) if crate::fsutil::is_disk_full(&e.source) => {
            warn!(error = %Chain(&e), "disk full: the configuration snapshot is not updated")
        }
        result => result?,
    }
    // The journal folded into compact per-shot flags as it is read: the daemon's memory does not
    // grow with the records of a long build.
    let mut progress = Progress::default();
    let mut journal =
        Journal::open_with(&dir.join(build_dir::JOURNAL), config.storage.fsync, |r| {
            progress.apply(&r)
        })?;
    // Originals that reached the disk but not the journal (a crash in between) are adopted.
    for adopted in storage.recover(|shot| progress.is_stored(shot))? {
        warn!(file = %adopted.file, "recovered a frame stored just before a crash");
        let record = Record::Frame {
            layer: adopted.layer,
            phase: adopted.phase,
            light: adopted.light,
            file: adopted.file.clone(),
            bytes: adopted.bytes,
            sha256: adopted.sha256.clone(),
            at: adopted.captured_at,
        };
        journal.append(&record)?;
        progress.apply(&record);
    }
    remove_stale_temporaries(&dir)?;
    journal.append(&Record::Start {
        at: clock.now(),
        pid: std::process::id(),
        version: env!("CARGO_PKG_VERSION").into(),
    })?;
    let last_event = progress
        .last_event
        .map(|(layer, phase)| format!("layer {layer} {phase}"))
        .unwrap_or_else(|| "none".into());
    info!(
        build = %manifest.name,
        dir = %dir.display(),
        frames = progress.frames(),
        missing = progress.missing(),
        restarts = progress.starts,
        last_event = %last_event,
        "build opened"
    );
    Ok(OpenedBuild {
        storage,
        manifest,
        journal,
        progress,
    })
}

/// The event a restart interrupted, with the lights it had already done.
pub(super) fn interrupted_event(
    config: &Config,
    progress: &Progress,
    clock: &SharedClock,
) -> Option<OpenEvent> {
    let (layer, phase) = progress.last_event?;
    let lights = &config.views.lights;
    let done: BTreeSet<Light> = lights
        .iter()
        .copied()
        .filter(|&light| {
            progress.is_done(&Shot {
                layer,
                phase,
                light,
            })
        })
        .collect();
    (done.len() < lights.len()).then(|| OpenEvent {
        layer,
        phase,
        at: clock.now(),
        done,
    })
}

/// Leaves the configuration in force (`config.toml`) and a copy of the calibration
/// (`calibration.toml`) in the build directory, so export and locate know how the build was made.
fn snapshot_configuration(config: &Config, storage: &Storage) -> Result<(), AcquisitionError> {
    let dir = storage.root();
    let text = toml::to_string(config)?;
    storage.write_atomic(&dir.join(build_dir::CONFIG_SNAPSHOT), text.as_bytes())?;
    if let Some(calibration) = &config.calibration.file {
        let target = dir.join(build_dir::CALIBRATION_COPY);
        let same = std::fs::canonicalize(calibration).ok() == std::fs::canonicalize(&target).ok();
        if !same {
            // The calibration as `run` checked it: a regular file of a calibration's size
            // (rectify::Calibration::load takes at most 1 MiB).
            let bytes =
                crate::fsutil::read_bounded(calibration, 1 << 20).map_err(|source| WriteError {
                    path: calibration.clone(),
                    source,
                })?;
            storage.write_atomic(&target, &bytes)?;
        }
    }
    Ok(())
}

/// Removes the temporary files a killed run left in the build directory and in each series
/// folder of `dicom/` (slices half written when the kill came), said at WARN. `raw/`'s are
/// removed by [`Storage::recover`].
fn remove_stale_temporaries(dir: &std::path::Path) -> Result<(), AcquisitionError> {
    let io = |path: &std::path::Path| {
        let path = path.to_path_buf();
        move |source| AcquisitionError::Storage(WriteError { path, source })
    };
    let dicom = dir.join(build_dir::DICOM_DIR);
    let mut folders = vec![dir.to_path_buf()];
    if let Ok(entries) = std::fs::read_dir(&dicom) {
        for entry in entries {
            let entry = entry.map_err(io(&dicom))?;
            // Folders only, never through a link.
            if entry.file_type().is_ok_and(|t| t.is_dir()) {
                folders.push(entry.path());
            }
        }
    }
    for folder in folders {
        let removed = crate::fsutil::remove_stale_temporaries(&folder).map_err(io(&folder))?;
        if !removed.is_empty() {
            warn!(
                folder = %folder.display(),
                files = removed.len(),
                "removed {} temporary files a stopped run left: {}",
                removed.len(),
                removed.join(", ")
            );
        }
    }
    Ok(())
}

/// A start that fails once the build is opened (the camera cannot be opened, the calibration or
/// the model is refused): the stop is journaled and status.json says "failed", so that `status`
/// and the page show this start's failure, not the run before it. Returns the error.
pub(super) fn failed_start(
    dir: &std::path::Path,
    journal: &mut crate::build_dir::Journal,
    clock: &crate::clock::SharedClock,
    error: super::AcquisitionError,
) -> super::AcquisitionError {
    let reason = crate::shutdown::StopReason::failure_of(&error).to_string();
    let stop = crate::build_dir::journal::Record::Stop {
        reason,
        at: clock.now(),
    };
    if let Err(e) = journal.append(&stop) {
        tracing::error!(error = %crate::logging::Chain(&e), "cannot journal the failed start");
    }
    // What the run before left (its last frames, its parts' health), marked as this start's.
    let path = dir.join(crate::build_dir::STATUS);
    let mut live: crate::build_dir::status::LiveStatus = crate::build_dir::read_record_file(&path)
        .ok()
        .and_then(|bytes| serde_json::from_slice(&bytes).ok())
        .unwrap_or_default();
    live.pid = std::process::id();
    live.state = "failed".into();
    live.updated_at = Some(clock.now());
    live.queue_depth = 0;
    if let Err(e) = live.write(dir) {
        tracing::warn!(error = %crate::logging::Chain(&e), "status: cannot write status.json");
    }
    error
}
