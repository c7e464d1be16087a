//! layerwise: layer-wise imaging of laser powder bed fusion builds, registered to the laser scan
//! vectors and to post-build CT in one frame of reference (docs/frames.md).
//!
//! The modules form layers (docs/architecture.md; `tests/it/architecture/` enforces it): each uses
//! only modules of lower layers.
//!
//! | layer | modules | what |
//! | --- | --- | --- |
//! | 0 foundation | [`fsutil`], [`clock`], [`shutdown`], [`geometry`], [`logging`] | atomic files, time, the one way to stop, frame-named transforms and grids, logs and error chains |
//! | 1 formats | [`shot`], [`vectors`], [`dicom`], [`optics`] | what a frame is, CLI vector files, DICOM writing and reading, the optics planner |
//! | 2 records | [`build_dir`], [`config`], [`raster`] | the build directory, the configuration, vectors on a grid |
//! | 3 images | [`rectify`], [`tsdf`] | frame → top-down view and its calibration file; distance fields of the vectors |
//! | 4 registration | [`calibrate`], [`ct`], [`series`] | image ↔ vectors, CT ↔ vectors, the live DICOM series of a view |
//! | 5 products | [`export`], [`flaws`], [`learn`], [`locate`], [`hardware`], [`inspect`], [`pacs`], [`plant`] | one study per build, CT flaws, the trained defect model, a point in every view, camera/lights/trigger, per-layer inspection, the push to archives, the plant interfaces (Prometheus, MQTT) |
//! | 6 daemon | [`acquisition`], [`web`] | the acquisition daemon; the operator page |
//! | 7 simulation | [`sim`] | the simulated machine; only the binary and tests name it |
//!
//! Features that span layers, and where each part lives:
//!
//! | feature | modules |
//! | --- | --- |
//! | the daemon (`layerwise run`) | [`acquisition`] (capture loop, [`acquisition::processing`]), [`hardware`] (trigger, lights, camera), [`build_dir`] (journal, sidecars, status.json), [`series`] (the live DICOM series), [`shutdown`] (how every thread stops) |
//! | inspection | [`inspect`] (cells, detectors, drift, `layerwise inspect`), [`acquisition::inspection`] (live, in the processing worker), [`build_dir::inspection`] (inspection.jsonl), [`config::inspection`] |
//! | the alarm | [`acquisition::alarm`] (stack light, printer message, its thread), [`build_dir::alarm`] (alarm.jsonl, `layerwise alarm ack`), [`hardware::message`] |
//! | the operator page | [`web`] (server, routes, previews, timeline, calibration page), [`build_dir::status`] (what it shows of health) |
//! | plant interfaces | [`plant`] (the sink the daemon feeds, [`plant::metrics`] for `/metrics`, [`plant::mqtt`]), [`config::metrics`], [`config::mqtt`] |
//! | PACS push | [`pacs`] (STOW-RS, C-STORE, [`pacs::live`] beside the daemon), [`build_dir::pushlog`] (what each archive confirmed), [`config::pacs`] |
//! | calibration | [`calibrate`] (`register images`), [`rectify`] (calibration.toml, the rectifier), [`geometry`] (the camera model) |
//! | CT | [`ct`] (readers, segmentation, registration, `register ct`), [`flaws`] (pores → labelled patches), [`tsdf`] |
//! | export and locate | [`export`], [`locate`], [`dicom`] |
//! | the defect model | [`learn`] (training, the model file, `learn predict/eval`, [`learn::live`]: per-tile flags and heat maps), [`config::model`] (`[inspection.model]`), [`acquisition::inspection`] (after the classical checks), [`web`] (verdicts, heat maps) |

pub mod acquisition;
pub mod alloc;
pub mod build_dir;
pub mod calibrate;
pub mod clock;
pub mod config;
pub mod ct;
pub mod dicom;
pub mod export;
pub mod flaws;
pub mod fsutil;
pub mod geometry;
pub mod hardware;
pub mod inspect;
pub mod learn;
pub mod locate;
pub mod logging;
pub mod optics;
pub mod pacs;
pub mod plant;
pub mod raster;
pub mod rectify;
pub mod series;
pub mod shot;
pub mod shutdown;
pub mod sim;
pub mod tsdf;
pub mod vectors;
pub mod web;
