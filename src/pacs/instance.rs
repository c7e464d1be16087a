//! One DICOM instance read for sending, what an archive says of it, and the [`Sender`] that
//! reaches an archive.

use super::error::PacsError;
use std::path::Path;
use std::time::Duration;

/// The largest instance pushed: a slice of a build is a few MB, a resampled CT slice tens; a
/// larger file (a sparse 3 GB `.dcm`) is refused by its size, never read whole.
pub const MAX_INSTANCE_BYTES: u64 = 512 << 20;

/// One DICOM file read for sending: its identity from the file meta group and its bytes.
pub struct Instance {
    /// Path relative to the pushed folder, as the log names it.
    pub file: String,
    pub sop_class_uid: String,
    pub sop_instance_uid: String,
    pub transfer_syntax: String,
    /// The whole file (Part 10: preamble, meta group, data set).
    pub bytes: Vec<u8>,
    /// Where the data set starts in `bytes`.
    pub dataset_offset: usize,
}

impl Instance {
    /// Reads `root/file`; a file that is not Part 10 DICOM is an error naming it.
    pub fn read(root: &Path, file: &str) -> Result<Instance, PacsError> {
        let path = root.join(file);
        let bytes = crate::fsutil::read_bounded(&path, MAX_INSTANCE_BYTES).map_err(|source| {
            PacsError::Read {
                file: file.to_string(),
                source,
            }
        })?;
        if bytes.len() < 132 || &bytes[128..132] != b"DICM" {
            return Err(PacsError::NotPart10 {
                file: file.to_string(),
            });
        }
        let meta = dicom_object::FileMetaTable::from_reader(&bytes[128..]).map_err(|source| {
            PacsError::Meta {
                file: file.to_string(),
                source: Box::new(source),
            }
        })?;
        let dataset_offset = 132 + 12 + meta.information_group_length as usize;
        if dataset_offset > bytes.len() {
            return Err(PacsError::MetaLength {
                file: file.to_string(),
            });
        }
        Ok(Instance {
            file: file.to_string(),
            sop_class_uid: meta.media_storage_sop_class_uid().to_string(),
            sop_instance_uid: meta.media_storage_sop_instance_uid().to_string(),
            transfer_syntax: meta.transfer_syntax().to_string(),
            bytes,
            dataset_offset,
        })
    }

    pub fn dataset(&self) -> &[u8] {
        &self.bytes[self.dataset_offset..]
    }
}

/// What the archive said about one instance.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Stored,
    /// Refused, with the archive's reason: logged and not sent again unless asked.
    Rejected(String),
}

/// A connection to one archive that stores batches of instances. `Ok` has an outcome per
/// instance of the batch; per-instance refusals are [`Outcome::Rejected`]. An `Err` means the
/// archive was not reached, did not answer for every instance, or not within `deadline` (the
/// whole batch's time, however slowly the bytes come): what it did answer for is in
/// [`Unfinished::answered`], the rest is sent again later.
pub trait Sender: Send {
    fn send(&mut self, batch: &[Instance], deadline: Duration) -> Result<Vec<Outcome>, Unfinished>;
}

/// A batch the archive did not answer for in full: the outcomes it gave (by index in the
/// batch) and what stopped the rest.
#[derive(Debug)]
pub struct Unfinished {
    pub answered: Vec<(usize, Outcome)>,
    pub error: PacsError,
}

impl From<PacsError> for Unfinished {
    fn from(error: PacsError) -> Unfinished {
        Unfinished {
            answered: Vec::new(),
            error,
        }
    }
}

/// Text for a DICOM storage failure status (PS3.4 B.2.3, PS3.7 C.4.2; STOW-RS FailureReason).
pub fn status_text(status: u16) -> &'static str {
    match status {
        0x0110 => "processing failure",
        0x0117 => "invalid SOP instance",
        0x0122 => "SOP class not supported",
        0x0124 => "not authorized",
        0x0210 => "duplicate invocation",
        0x0211 => "unrecognized operation",
        0x0212 => "mistyped argument",
        0xA700..=0xA7FF => "refused: out of resources",
        0xA900..=0xA9FF => "error: data set does not match SOP class",
        0xC122 => "referenced transfer syntax not supported",
        0xC000..=0xCFFF => "error: cannot understand",
        0xB000..=0xBFFF => "warning",
        _ => "failure",
    }
}
