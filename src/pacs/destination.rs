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
