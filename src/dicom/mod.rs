//! DICOM series of a build, written with dicom-rs: every modality as the CT Image IOD (the paper's
//! choice: it carries the Image Plane module), in the build frame of docs/frames.md. One study and
//! one frame of reference per build; one series per view; one file per layer.
//!
//! `iod`: the attributes and pixels of a slice; `encode`: transfer syntaxes and writing;
//! `info`: reading written files back (`layerwise dicom info`); `lengths`: element lengths
//! checked before a parser trusts them; `uid`: UIDs.

mod deflate;
mod encode;
mod error;
mod info;
mod iod;
// Element lengths checked against the file before a parser trusts them.
mod lengths;
pub mod uid;

pub use deflate::Samples;
pub use encode::{
    encode_slice, encode_slice_from, write_slice, write_slice_pending, Compression, WriteTimes,
};
pub use error::{DicomError, EncodeError};
pub use info::{file_instance_uid, series_info, slice_take, SeriesSummary};
pub use iod::{
    instance_uid, instance_uid_of_take, person_name, Plane, Series, Slice, SliceSource, Study,
};
pub use lengths::{check_lengths, check_lengths_until};
pub use uid::{derived_uid, new_uid};

/// CT Image Storage.
pub const CT_IMAGE_STORAGE: &str = "1.2.840.10008.5.1.4.1.1.2";
/// Our implementation class UID (2.25 root, fixed for layerwise).
pub const IMPLEMENTATION_CLASS_UID: &str = "2.25.302378146212377404151786716384913425853";

/// The finest PixelSpacing a series may state: a nanometre. Finer (a subnormal 1e-320, say)
/// makes a voxel's size round to zero (found by mutation fuzzing).
pub const MIN_PIXEL_SPACING_MM: f64 = 1e-6;
