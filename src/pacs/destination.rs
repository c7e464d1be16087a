//! Where a push goes: a configured `[[pacs]]` destination or a URL given on the command line.

use super::error::PacsError;
use crate::config::pacs::{PacsAuth, PacsDestination};
use std::time::Duration;

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
    /// Longest wait for a connection or the next bytes.
    pub timeout: Duration,
    /// Longest one instance may take, however slowly the bytes come (`deadline_s`).
    pub deadline: Duration,
    pub backoff: [Duration; 2],
}

impl Destination {
    /// The destination a `[[pacs]]` section describes, its secret read from its file.
    pub fn from_config(config: &PacsDestination) -> Result<Destination, PacsError> {
        let target = match (&config.url, &config.host) {
            (Some(url), _) => {
                let secret = match &config.secret_file {
                    Some(path) => Some(read_secret(&config.name, path)?),
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
            deadline: Duration::from_secs(config.deadline_s),
            backoff: config.retry_backoff_ms.map(Duration::from_millis),
        })
    }

    /// `--to`: a configured name, or a URL (`http(s)://…/dicom-web`, `dicom://AE@host:port`).
    pub fn resolve(to: &str, configured: &[PacsDestination]) -> Result<Destination, PacsError> {
        if let Some(config) = configured.iter().find(|d| d.name == to) {
            return Destination::from_config(config);
        }
        // What the command line gave is shown (and logged) only without its credentials.
        let shown = without_credentials(to);
        let bad = || PacsError::BadTarget(crate::logging::escape(&shown));
        let mut config = PacsDestination {
            name: log_name(&shown),
            url: None,
            auth: None,
            user: None,
            secret_file: None,
            host: None,
            port: None,
            called_ae: None,
            calling_ae: "LAYERWISE".into(),
            timeout_s: 30,
            deadline_s: 60,
            retry_backoff_ms: [500, 30_000],
        };
        let mut basic = None;
        if to.starts_with("http://") || to.starts_with("https://") {
            // `http://user:secret@host/…`: Basic authorization from the URL, kept in memory
            // only (the log's name, the messages and the log hold the URL without it).
            if let Ok(mut url) = url::Url::parse(to) {
                if !url.username().is_empty() || url.password().is_some() {
                    let decode = |s: &str| {
                        url::form_urlencoded::parse(format!("x={s}").as_bytes())
                            .next()
                            .map(|(_, v)| v.into_owned())
                            .unwrap_or_default()
                    };
                    let user = decode(url.username());
                    let password = decode(url.password().unwrap_or(""));
                    basic = Some(format!(
                        "Basic {}",
                        base64(format!("{user}:{password}").as_bytes())
                    ));
                    let _ = url.set_username("");
                    let _ = url.set_password(None);
                }
                config.url = Some(url.as_str().to_string());
            } else {
                config.url = Some(to.to_string());
            }
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
                destination: crate::logging::escape(&shown),
                message: invalid.message,
            });
        }
        let mut destination = Destination::from_config(&config)?;
        if let (Some(basic), Target::Stow { authorization, .. }) = (basic, &mut destination.target)
        {
            *authorization = Some(basic);
        }
        Ok(destination)
    }
}

/// The largest secret file: a password or a token (a JWT is a few KB).
const MAX_SECRET_BYTES: u64 = 64 << 10;

/// A destination's password or token from its `secret_file`: a regular file (a FIFO or a
/// device is refused, never waited on or read without end) of at most [`MAX_SECRET_BYTES`], one
/// line of printable text (the trailing newline ignored): it goes into an HTTP header.
fn read_secret(name: &str, path: &std::path::Path) -> Result<String, PacsError> {
    let err = |source| PacsError::Secret {
        name: name.to_string(),
        path: path.to_path_buf(),
        source,
    };
    let text = crate::fsutil::read_text_bounded(path, MAX_SECRET_BYTES).map_err(err)?;
    let secret = text.trim_end_matches(['\r', '\n']);
    if secret.chars().any(|c| c.is_control()) {
        return Err(err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            "holds a control character or more than one line: the secret alone on one line",
        )));
    }
    Ok(secret.to_string())
}

/// A URL given on the command line without the `user:password@` of its authority.
fn without_credentials(to: &str) -> String {
    match to.split_once("://") {
        Some((scheme, rest)) if scheme.starts_with("http") => {
            let end = rest.find(['/', '?', '#']).unwrap_or(rest.len());
            match rest[..end].rfind('@') {
                Some(at) => format!("{scheme}://{}", &rest[at + 1..]),
                None => to.to_string(),
            }
        }
        _ => to.to_string(),
    }
}

/// A file-system-safe log name for a URL given on the command line.
pub(super) fn log_name(to: &str) -> String {
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
pub(super) fn base64(data: &[u8]) -> String {
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
