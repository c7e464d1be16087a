//! Every integration test of layerwise in one binary: one link of a large test binary per build
//! instead of one per file. Each module was a file of its own under tests/; a test's name is
//! `module::test` (`cargo test --test it daemon::` runs one module). Modules that need an
//! optional feature are compiled with it only; `cargo test --workspace --all-features` (the CI
//! command, tests/run.sh) runs them all.
//!
//! No test here needs a process of its own: the ones that change process-wide state do it per
//! thread (each test runs on its own thread: the mount and network namespaces of `disk`, `pacs`
//! and `soak` are the test thread's) or only in the children they start (environment variables,
//! resource limits, the working directory). The in-process daemon (`common::run_daemon`) watches
//! SIGTERM and SIGINT, which no test sends to this process.

mod common;

mod architecture;
mod argument_values;
mod bounded_inputs;
mod calibration_spread;
mod check_config;
mod cli;
mod console;
#[cfg(feature = "testkit")]
mod ct_accuracy;
#[cfg(feature = "testkit")]
mod ct_dicom;
mod daemon;
mod dicom_validation;
mod disk;
mod doc_commands;
mod doc_links;
#[cfg(feature = "testkit")]
mod flaws;
mod fuzz_smoke;
mod health;
mod inspect_frames;
mod inspection;
mod learn;
mod learn_cv;
mod learn_options;
mod lifecycle;
mod pacs;
mod pacs_push;
mod plant_metrics;
mod plant_mqtt;
#[cfg(feature = "opcua")]
mod plant_opcua;
mod raster;
#[cfg(feature = "nef")]
mod raw_frames;
mod register_ct_cli;
mod registration;
mod renderer2;
mod restart;
mod serial_trigger;
mod soak;
mod systemd;
mod trusted_files;
mod tsdf;
mod tutorial;
mod vectors;
#[cfg(feature = "gphoto")]
mod virtual_camera;
mod web;
mod web_files;
mod web_load;
