//! layerwise: layer-wise imaging of laser powder bed fusion builds, registered to the laser scan
//! vectors and to post-build CT in one frame of reference (docs/frames.md).

pub mod acquisition;
pub mod camera;
pub mod config;
pub mod dicom;
pub mod export;
pub mod lights;
pub mod logging;
pub mod optics;
pub mod raster;
pub mod rectify;
pub mod registration;
pub mod trigger;
pub mod tsdf;
pub mod vectors;
pub mod view;
