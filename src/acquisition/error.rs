//! Why a run stopped with an error.

use crate::build_dir::JournalError;
use crate::fsutil::WriteError;
use crate::hardware::camera::CameraError;
use crate::hardware::lights::LightsError;
use crate::hardware::trigger::TriggerError;

#[derive(Debug, thiserror::Error)]
pub enum AcquisitionError {
    #[error(transparent)]
    Storage(#[from] WriteError),
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error(transparent)]
    Manifest(#[from] crate::build_dir::manifest::ManifestError),
    #[error("cannot open the camera")]
    CameraOpen(#[source] CameraError),
    #[error("camera hung; exiting so that systemd restarts the service")]
    CameraHung(#[source] CameraError),
    #[error("camera lost; exiting so that systemd restarts the service")]
    CameraLost(#[source] CameraError),
    #[error(transparent)]
    Trigger(#[from] TriggerError),
    #[error(transparent)]
    Lights(#[from] LightsError),
    #[error(transparent)]
    Hardware(#[from] crate::hardware::HardwareError),
    #[error(transparent)]
    Calibration(#[from] crate::rectify::CalibrationError),
    #[error(transparent)]
    Series(#[from] crate::series::SeriesError),
    #[error("cannot record the configuration")]
    Snapshot(#[from] toml::ser::Error),
    #[error("cannot use the inspection model ([inspection.model] file)")]
    Model(#[source] crate::learn::ModelError),
    #[error("the journal's lock was poisoned by a panic on another thread")]
    Poisoned,
}
