//! What a push can meet, each error naming the destination, the URL or peer, and the file.

use crate::build_dir::pushlog::PushLogError;
use std::path::PathBuf;

/// What a push can meet: a destination that cannot be used, a log that cannot be written, a file
/// that is not an instance, and what a [`Sender`] meets on the way to the archive (each naming the
/// URL or the peer, and the file).
#[derive(Debug, thiserror::Error)]
pub enum PacsError {
    #[error("pacs destination {name}: cannot read secret_file {path}")]
    Secret {
        name: String,
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "`{0}` is neither a configured [[pacs]] name nor a URL (http(s)://host:port/dicom-web \
         for STOW-RS, dicom://CALLED_AE@host:port for C-STORE)"
    )]
    BadTarget(String),
    /// A destination given on the command line that its `[[pacs]]` checks refuse.
    #[error("{destination}: {message}")]
    Invalid {
        destination: String,
        message: String,
    },
    #[error(transparent)]
    Log(#[from] PushLogError),
    /// The batch did not reach the archive, or its fate is unknown: the push stops here and is
    /// retried (with back-off in the daemon). The source is what the [`Sender`] met.
    #[error("cannot push to {destination}")]
    Transport {
        destination: String,
        #[source]
        source: Box<PacsError>,
    },
    /// The archive took longer than the deadline (`deadline_s` per instance of the batch, or
    /// what was left of the push's own): the batch is sent again later.
    #[error(
        "{peer}: no complete answer within the deadline of {seconds:.0} s (deadline_s per \
         instance); the archive is too slow, the rest is sent again later"
    )]
    Deadline { peer: String, seconds: f64 },
    /// The push's own deadline passed with instances still to push.
    #[error(
        "{destination}: the push's deadline of {seconds:.0} s passed with {pending} instances \
         still to push (they stay pending: push again to complete it)"
    )]
    RunDeadline {
        destination: String,
        seconds: f64,
        pending: usize,
    },
    #[error("{destination}: cannot start the push thread")]
    Thread {
        destination: String,
        #[source]
        source: std::io::Error,
    },
    /// An instance file ([`Instance::read`]): unreadable, or not Part 10 DICOM.
    #[error("cannot read {file}")]
    Read {
        file: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{file} is not a DICOM Part 10 file (no DICM prefix)")]
    NotPart10 { file: String },
    #[error("{file}: unreadable DICOM file meta group")]
    Meta {
        file: String,
        #[source]
        source: Box<dicom_object::meta::Error>,
    },
    #[error("{file}: file meta group longer than the file")]
    MetaLength { file: String },
    /// STOW-RS: the archive refused the credentials.
    #[error(
        "POST {url}: HTTP {status} {} (check auth, user and secret_file of this destination)",
        status_word(.status)
    )]
    Unauthorized { url: String, status: u16 },
    /// STOW-RS: an HTTP status without a per-instance answer, with the first line of the body.
    #[error("POST {url}: HTTP {status}{}", body_line(.body))]
    Http {
        url: String,
        status: u16,
        body: Option<String>,
    },
    /// STOW-RS: the archive was not reached (connection, DNS, TLS, timeout).
    #[error("POST {url}")]
    Connect {
        url: String,
        #[source]
        source: TransportError,
    },
    /// STOW-RS: an answer that is not the DICOM JSON of a STOW-RS response.
    #[error(
        "POST {url}: HTTP {status} without a STOW-RS answer (is the URL the DICOMweb root, e.g. \
         http://pacs:8042/dicom-web?){}",
        body_line(.body)
    )]
    NotStow {
        url: String,
        status: u16,
        body: Option<String>,
        #[source]
        source: Option<serde_json::Error>,
    },
    /// STOW-RS: an answer that leaves an instance of the batch out.
    #[error("POST {url}: incomplete STOW-RS answer")]
    Answer {
        url: String,
        #[source]
        source: Unmentioned,
    },
    /// C-STORE: no association (refused, rejected, unreachable).
    #[error(
        "C-STORE association with {peer}{}",
        association_hint(.source)
    )]
    Association {
        peer: String,
        #[source]
        source: Box<dicom_ul::association::Error>,
    },
    /// C-STORE: one instance's exchange on an open association failed.
    #[error("C-STORE to {peer} of {file}")]
    Store {
        peer: String,
        file: String,
        #[source]
        source: StoreError,
    },
    #[error("C-STORE release of the association with {peer}")]
    Release {
        peer: String,
        #[source]
        source: Box<dicom_ul::association::Error>,
    },
}

/// The reason phrase of 401 and 403.
fn status_word(status: &u16) -> &'static str {
    if *status == 401 {
        "Unauthorized"
    } else {
        "Forbidden"
    }
}

/// What to check when the archive rejects the association.
fn association_hint(error: &dicom_ul::association::Error) -> &'static str {
    if matches!(error, dicom_ul::association::Error::Rejected { .. }) {
        " (check called_ae and calling_ae: the archive must know this printer's AE title)"
    } else {
        ""
    }
}

/// `: the line` of an answer's body, or nothing.
fn body_line(body: &Option<String>) -> String {
    body.as_ref().map(|t| format!(": {t}")).unwrap_or_default()
}

/// A ureq transport error said once: its own `Display` repeats its source (and the URL, which
/// [`PacsError::Connect`] names); this one leaves the source to the chain.
#[derive(Debug)]
pub struct TransportError(pub Box<ureq::Transport>);

impl std::fmt::Display for TransportError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0.kind())?;
        if let Some(message) = self.0.message() {
            write!(f, ": {message}")?;
        }
        Ok(())
    }
}

impl std::error::Error for TransportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        std::error::Error::source(self.0.as_ref())
    }
}

/// Instances the STOW-RS answer does not mention: their fate is unknown (they are sent again
/// later; the ones it mentions are logged).
#[derive(Debug, thiserror::Error)]
#[error("the answer does not mention {missing} of the {total} instances, the first {uid} ({file})")]
pub struct Unmentioned {
    pub uid: String,
    pub file: String,
    pub missing: usize,
    pub total: usize,
}

/// What went wrong sending one instance on an open association ([`PacsError::Store`] names the
/// peer and the file).
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("cannot inflate the data set")]
    Inflate(#[source] std::io::Error),
    #[error("cannot encode the command")]
    Encode(#[source] Box<dicom_object::WriteError>),
    #[error("cannot send the command")]
    Command(#[source] Box<dicom_ul::association::Error>),
    #[error("cannot send the data set")]
    Data(#[source] std::io::Error),
    #[error("no answer")]
    Receive(#[source] Box<dicom_ul::association::Error>),
    /// The archive aborted the association (the abort's source as the PDU gives it).
    #[error("the archive aborted ({0})")]
    Aborted(String),
    #[error("unexpected answer {0}")]
    Unexpected(String),
    #[error("unreadable C-STORE-RSP")]
    Response(#[source] Box<dicom_object::ReadError>),
    #[error("C-STORE-RSP without a Status")]
    NoStatus,
}
