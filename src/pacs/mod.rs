//! Pushing a build's DICOM instances to archives (PACS): DICOMweb STOW-RS ([`stow`]) and DIMSE
//! C-STORE ([`cstore`]). Every instance the archive confirms or rejects is written to the push
//! log (`build_dir::pushlog`), so a push resumes where it stopped; [`live`] runs the push beside
//! the daemon, off the capture and processing paths.

pub mod cstore;
pub mod live;
pub mod stow;

use crate::build_dir::pushlog::{self, PushLog, PushLogError, PushRecord, PushState};
use crate::clock::Clock;
use crate::config::pacs::{PacsAuth, PacsDestination};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tracing::{info, warn};

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
        source: stow::TransportError,
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
        source: stow::Unmentioned,
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
        source: cstore::StoreError,
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

/// How an archive is reached.
#[derive(Clone, Debug, PartialEq)]
pub enum Target {
    /// POST multipart/related to `{url}/studies`, with this Authorization header if any.
    Stow {
        url: String,
        authorization: Option<String>,
    },
    CStore {
        host: String,
        port: u16,
        called_ae: String,
        calling_ae: String,
    },
}

/// An archive, ready to push to.
#[derive(Clone, Debug)]
pub struct Destination {
    pub name: String,
    pub target: Target,
    pub timeout: Duration,
    pub backoff: [Duration; 2],
}

impl Destination {
    /// The destination a `[[pacs]]` section describes, its secret read from its file.
    pub fn from_config(config: &PacsDestination) -> Result<Destination, PacsError> {
        let target = match (&config.url, &config.host) {
            (Some(url), _) => {
                let secret = match &config.secret_file {
                    Some(path) => Some(
                        std::fs::read_to_string(path)
                            .map_err(|source| PacsError::Secret {
                                name: config.name.clone(),
                                path: path.clone(),
                                source,
                            })?
                            .trim_end_matches(['\r', '\n'])
                            .to_string(),
                    ),
                    None => None,
                };
                let authorization = match (config.auth, secret) {
                    (Some(PacsAuth::Basic), Some(password)) => Some(format!(
                        "Basic {}",
                        base64(
                            format!("{}:{password}", config.user.as_deref().unwrap_or(""))
                                .as_bytes()
                        )
                    )),
                    (Some(PacsAuth::Bearer), Some(token)) => Some(format!("Bearer {token}")),
                    _ => None,
                };
                Target::Stow {
                    url: url.trim_end_matches('/').to_string(),
                    authorization,
                }
            }
            (None, host) => Target::CStore {
                host: host.clone().unwrap_or_default(),
                port: config.port.unwrap_or(104),
                called_ae: config.called_ae.clone().unwrap_or_default(),
                calling_ae: config.calling_ae.clone(),
            },
        };
        Ok(Destination {
            name: config.name.clone(),
            target,
            timeout: Duration::from_secs(config.timeout_s),
            backoff: config.retry_backoff_ms.map(Duration::from_millis),
        })
    }

    /// `--to`: a configured name, or a URL (`http(s)://…/dicom-web`, `dicom://AE@host:port`).
    pub fn resolve(to: &str, configured: &[PacsDestination]) -> Result<Destination, PacsError> {
        if let Some(config) = configured.iter().find(|d| d.name == to) {
            return Destination::from_config(config);
        }
        let bad = || PacsError::BadTarget(to.to_string());
        let mut config = PacsDestination {
            name: log_name(to),
            url: None,
            auth: None,
            user: None,
            secret_file: None,
            host: None,
            port: None,
            called_ae: None,
            calling_ae: "LAYERWISE".into(),
            timeout_s: 30,
            retry_backoff_ms: [500, 30_000],
        };
        if to.starts_with("http://") || to.starts_with("https://") {
            config.url = Some(to.to_string());
        } else if let Some(rest) = to.strip_prefix("dicom://") {
            let (ae, address) = rest.split_once('@').ok_or_else(bad)?;
            let (host, port) = address.rsplit_once(':').ok_or_else(bad)?;
            config.called_ae = Some(ae.to_string());
            config.host = Some(host.trim_start_matches('[').trim_end_matches(']').into());
            config.port = Some(port.trim_end_matches('/').parse().map_err(|_| bad())?);
        } else {
            return Err(bad());
        }
        if let Err(invalid) = config.validate() {
            return Err(PacsError::Invalid {
                destination: to.to_string(),
                message: invalid.message,
            });
        }
        Destination::from_config(&config)
    }

    /// A connection to the archive.
    pub fn connect(&self) -> Box<dyn Sender> {
        match &self.target {
            Target::Stow { .. } => Box::new(stow::StowClient::new(self)),
            Target::CStore { .. } => Box::new(cstore::CStoreClient::new(self)),
        }
    }
}

/// A file-system-safe log name for a URL given on the command line.
fn log_name(to: &str) -> String {
    let body = to.split_once("://").map_or(to, |(_, rest)| rest);
    let name: String = body
        .trim_end_matches('/')
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect();
    name.trim_start_matches('.').to_string()
}

/// Standard base64 (RFC 4648) for the Basic authorization header.
fn base64(data: &[u8]) -> String {
    const TABLE: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(data.len().div_ceil(3) * 4);
    for chunk in data.chunks(3) {
        let b = [
            chunk[0],
            *chunk.get(1).unwrap_or(&0),
            *chunk.get(2).unwrap_or(&0),
        ];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        for i in 0..4 {
            if i <= chunk.len() {
                out.push(TABLE[(n >> (18 - 6 * i) & 63) as usize] as char);
            } else {
                out.push('=');
            }
        }
    }
    out
}

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
        let bytes = std::fs::read(&path).map_err(|source| PacsError::Read {
            file: file.to_string(),
            source,
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

/// A connection to one archive that stores batches of instances. An `Err` means the archive
/// was not reached or did not answer for the batch (retry later); per-instance refusals are
/// [`Outcome::Rejected`].
pub trait Sender: Send {
    fn send(&mut self, batch: &[Instance]) -> Result<Vec<Outcome>, PacsError>;
}

/// Batches stay below this many bytes (and [`BATCH_FILES`] files).
const BATCH_BYTES: usize = 32 << 20;
const BATCH_FILES: usize = 64;

/// What one push did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PushCount {
    pub stored: usize,
    pub rejected: Vec<(String, String)>,
    pub bytes: u64,
}

/// One destination's log and state, opened for pushing.
pub struct Queue {
    pub root: PathBuf,
    pub destination: Destination,
    log: PushLog,
    pub state: PushState,
    last_logged_error: Option<String>,
}

impl Queue {
    pub fn open(root: &Path, destination: Destination) -> Result<Queue, PacsError> {
        let (log, state) = PushLog::open(&pushlog::log_path(root, &destination.name))?;
        Ok(Queue {
            root: root.to_path_buf(),
            destination,
            log,
            state,
            last_logged_error: None,
        })
    }

    /// The instances on disk the archive does not have yet.
    pub fn pending(&self, retry_rejected: bool) -> Vec<String> {
        pushlog::instances(&self.root)
            .into_iter()
            .filter(|f| {
                !self.state.is_done(f, retry_rejected) || self.state.replaced(&self.root, f)
            })
            .collect()
    }

    /// Pushes every pending instance through `sender`, logging each outcome as it comes;
    /// stops at the first transport error (logged once per distinct message) and returns it.
    pub fn push_pending(
        &mut self,
        sender: &mut dyn Sender,
        retry_rejected: bool,
        clock: &dyn Clock,
    ) -> Result<PushCount, PacsError> {
        let mut count = PushCount::default();
        let pending = self.pending(retry_rejected);
        let mut next = 0;
        while next < pending.len() {
            let mut batch = Vec::new();
            let mut bytes = 0;
            while next < pending.len() && batch.len() < BATCH_FILES && bytes < BATCH_BYTES {
                let file = &pending[next];
                next += 1;
                match Instance::read(&self.root, file) {
                    Ok(instance) => {
                        bytes += instance.bytes.len();
                        batch.push(instance);
                    }
                    // The file vanished (a series rewritten): nothing to push.
                    Err(_) if !self.root.join(file).exists() => {}
                    Err(e) => {
                        let reason = crate::logging::chain(&e);
                        self.record(&PushRecord::Rejected {
                            file: file.clone(),
                            sop_instance_uid: String::new(),
                            reason: reason.clone(),
                            at: clock.now(),
                        })?;
                        count.rejected.push((file.clone(), reason));
                    }
                }
            }
            if batch.is_empty() {
                continue;
            }
            let outcomes = match sender.send(&batch) {
                Ok(outcomes) => outcomes,
                // Whatever the sender met, the batch's fate is unknown: a transport error, retried.
                Err(source) => {
                    let message = crate::logging::chain(&source);
                    if self.last_logged_error.as_deref() != Some(&message) {
                        warn!(destination = %self.destination.name, error = %message, "pacs: push failed; will retry");
                        self.record(&PushRecord::Error {
                            message: message.clone(),
                            at: clock.now(),
                        })?;
                        self.last_logged_error = Some(message);
                    }
                    return Err(PacsError::Transport {
                        destination: self.destination.name.clone(),
                        source: Box::new(source),
                    });
                }
            };
            self.last_logged_error = None;
            for (instance, outcome) in batch.iter().zip(outcomes) {
                let (record, rejected) = match outcome {
                    Outcome::Stored => {
                        count.stored += 1;
                        count.bytes += instance.bytes.len() as u64;
                        (
                            PushRecord::Stored {
                                file: instance.file.clone(),
                                sop_instance_uid: instance.sop_instance_uid.clone(),
                                at: clock.now(),
                            },
                            None,
                        )
                    }
                    Outcome::Rejected(reason) => {
                        warn!(destination = %self.destination.name, file = %instance.file, %reason, "pacs: instance rejected");
                        (
                            PushRecord::Rejected {
                                file: instance.file.clone(),
                                sop_instance_uid: instance.sop_instance_uid.clone(),
                                reason: reason.clone(),
                                at: clock.now(),
                            },
                            Some(reason),
                        )
                    }
                };
                self.record(&record)?;
                if let Some(reason) = rejected {
                    count.rejected.push((instance.file.clone(), reason));
                }
            }
        }
        if count.stored > 0 {
            info!(destination = %self.destination.name, instances = count.stored, "pacs: pushed");
        }
        Ok(count)
    }

    fn record(&mut self, record: &PushRecord) -> Result<(), PacsError> {
        self.log.append(record)?;
        self.state.apply(record);
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_from_urls_and_names() {
        let web = Destination::resolve("http://127.0.0.1:8042/dicom-web/", &[]).unwrap();
        assert_eq!(web.name, "127.0.0.1_8042_dicom-web");
        assert!(
            matches!(web.target, Target::Stow { ref url, .. } if url == "http://127.0.0.1:8042/dicom-web")
        );
        let dimse = Destination::resolve("dicom://ORTHANC@localhost:4242", &[]).unwrap();
        assert_eq!(
            dimse.target,
            Target::CStore {
                host: "localhost".into(),
                port: 4242,
                called_ae: "ORTHANC".into(),
                calling_ae: "LAYERWISE".into()
            }
        );
        for bad in ["orthanc", "dicom://host:4242", "dicom://AE@host", "ftp://x"] {
            assert!(Destination::resolve(bad, &[]).is_err(), "{bad}");
        }
    }

    #[test]
    fn basic_auth_is_base64_of_user_and_secret_file() {
        assert_eq!(
            base64(b"Aladdin:open sesame"),
            "QWxhZGRpbjpvcGVuIHNlc2FtZQ=="
        );
        assert_eq!(base64(b"ab"), "YWI=");
        let dir = tempfile::tempdir().unwrap();
        let secret = dir.path().join("secret");
        std::fs::write(&secret, "open sesame\n").unwrap();
        let config: PacsDestination = toml::from_str(&format!(
            "name = \"a\"\nurl = \"https://pacs/dicom-web\"\nauth = \"basic\"\nuser = \"Aladdin\"\nsecret_file = {:?}\n",
            secret
        ))
        .unwrap();
        let destination = Destination::from_config(&config).unwrap();
        assert!(matches!(destination.target,
            Target::Stow { authorization: Some(ref a), .. } if a == "Basic QWxhZGRpbjpvcGVuIHNlc2FtZQ=="));
        let missing = PacsDestination {
            secret_file: Some(dir.path().join("none")),
            ..config
        };
        let err = Destination::from_config(&missing).unwrap_err().to_string();
        assert!(err.contains("secret_file") && err.contains("none"), "{err}");
    }
}
