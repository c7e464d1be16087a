//! `[[pacs]]`: the archives every DICOM instance of a build is pushed to, by DICOMweb STOW-RS
//! (`url`) or DIMSE C-STORE (`host`, `port`, `called_ae`). Secrets are read from a file named
//! here (`secret_file`), never written in the configuration.

use super::Invalid;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One archive.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PacsDestination {
    /// A short name: the push log is `pacs/<name>.jsonl` in the build directory, and
    /// `layerwise push --to NAME` picks it.
    pub name: String,
    /// STOW-RS: the DICOMweb root, e.g. `http://pacs:8042/dicom-web` (instances are POSTed to
    /// `{url}/studies`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub url: Option<String>,
    /// STOW-RS authentication: `basic` (with `user`) or `bearer`, the password or token read
    /// from `secret_file`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub auth: Option<PacsAuth>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
    /// A file holding the password or token alone (trailing newline ignored), readable by the
    /// service only (chmod 600).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub secret_file: Option<PathBuf>,
    /// C-STORE: the archive's host name or address.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub host: Option<String>,
    /// C-STORE: its DICOM port (Orthanc's DicomPort, 4242 by default; 104 is the standard one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub port: Option<u16>,
    /// C-STORE: the archive's AE title (Orthanc's DicomAet).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub called_ae: Option<String>,
    /// C-STORE: this printer's AE title, as registered on the archive (DicomModalities).
    #[serde(default = "default_calling_ae")]
    pub calling_ae: String,
    /// Longest wait for a connection or for the next bytes of an answer.
    #[serde(default = "default_timeout_s")]
    pub timeout_s: u64,
    /// Longest one instance may take, from connecting to the archive's answer, however the
    /// bytes trickle: a STOW-RS batch of n instances gets n times this, a C-STORE exchange this
    /// (and the association its own). A push over it stops, naming the destination, and
    /// resumes later.
    #[serde(default = "default_deadline_s")]
    pub deadline_s: u64,
    /// Wait between attempts while the archive is unreachable: first and longest.
    #[serde(default = "default_retry_ms")]
    pub retry_backoff_ms: [u64; 2],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PacsAuth {
    Basic,
    Bearer,
}

fn default_calling_ae() -> String {
    "LAYERWISE".into()
}

fn default_timeout_s() -> u64 {
    30
}

fn default_deadline_s() -> u64 {
    60
}

/// Most archives one build is pushed to: each has a thread, a log and a connection.
pub const MAX_DESTINATIONS: usize = 16;

/// Longest destination name (it names the push log).
pub const MAX_NAME: usize = 64;

/// Longest `timeout_s` and `deadline_s`, and the longest back-off.
pub const MAX_TIMEOUT_S: u64 = 3600;
pub const MAX_BACKOFF_MS: u64 = 3_600_000;

/// Checks a STOW-RS URL: printable (no space, CR, LF or other control character: it goes into
/// the request line), a URL of http or https with a host, no credentials (a password in a URL
/// ends up in logs: give it in `secret_file`), no fragment.
pub fn check_stow_url(url: &str) -> Result<url::Url, Invalid> {
    if let Some(c) = url.chars().find(|c| c.is_whitespace() || c.is_control()) {
        return Err(Invalid::new(
            "url",
            format!(
                "holds {} (a space, CR, LF or control character): a URL has none",
                c.escape_unicode()
            ),
        ));
    }
    let parsed =
        url::Url::parse(url).map_err(|e| Invalid::new("url", format!("is not a URL ({e})")))?;
    if !matches!(parsed.scheme(), "http" | "https") {
        return Err(Invalid::new(
            "url",
            "must start with http:// or https:// (the DICOMweb root, e.g. \
             http://pacs:8042/dicom-web)",
        ));
    }
    if parsed.host_str().is_none_or(str::is_empty) {
        return Err(Invalid::new(
            "url",
            "has no host (e.g. http://pacs:8042/dicom-web)",
        ));
    }
    if !parsed.username().is_empty() || parsed.password().is_some() {
        return Err(Invalid::new(
            "url",
            "holds credentials: give `auth`, `user` and `secret_file` instead (a URL is \
             logged and shown)",
        ));
    }
    if parsed.fragment().is_some() {
        return Err(Invalid::new(
            "url",
            "has a #fragment, which HTTP never sends",
        ));
    }
    Ok(parsed)
}

fn default_retry_ms() -> [u64; 2] {
    [500, 30_000]
}

/// Whether an AE title is valid: 1 to 16 characters of printable ASCII, no backslash.
pub fn valid_ae_title(ae: &str) -> bool {
    let trimmed = ae.trim();
    !trimmed.is_empty()
        && ae.len() <= 16
        && ae.bytes().all(|b| (0x20..0x7f).contains(&b) && b != b'\\')
}

impl PacsDestination {
    /// Checks one destination; the key is the destination's own (`url`), [`validate`] puts it
    /// under `pacs[i]`.
    pub fn validate(&self) -> Result<(), Invalid> {
        if self.name.is_empty()
            || self.name.len() > MAX_NAME
            || !self
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.')
            || self.name.starts_with('.')
        {
            return Err(Invalid::new(
                "name",
                format!(
                    "must be a short name (1 to {MAX_NAME}) of letters, digits, `-`, `_` or `.` \
                     (it names the push log)"
                ),
            ));
        }
        match (&self.url, &self.host) {
            (Some(_), Some(_)) | (None, None) => {
                return Err(Invalid::new(
                    "url",
                    "give either `url` (DICOMweb STOW-RS) or `host`, `port` and `called_ae` \
                     (DIMSE C-STORE)",
                ))
            }
            (Some(url), None) => {
                check_stow_url(url)?;
                if let Some(user) = &self.user {
                    if user.is_empty() || user.contains(':') || user.chars().any(char::is_control) {
                        return Err(Invalid::new(
                            "user",
                            "must be a user name without `:` or control characters",
                        ));
                    }
                }
                match (self.auth, &self.user, &self.secret_file) {
                    (Some(PacsAuth::Basic), None, _) => {
                        return Err(Invalid::new("user", "auth = \"basic\" needs `user`"))
                    }
                    (Some(_), _, None) => {
                        return Err(Invalid::new(
                            "secret_file",
                            "auth needs `secret_file`: a file holding the password or token",
                        ))
                    }
                    _ => {}
                }
            }
            (None, Some(host)) => {
                let plain = host.trim_start_matches('[').trim_end_matches(']');
                if host.len() > 253
                    || host.chars().any(|c| c.is_whitespace() || c.is_control())
                    || url::Host::parse(plain)
                        .or_else(|_| plain.parse::<std::net::Ipv6Addr>().map(url::Host::Ipv6))
                        .is_err()
                {
                    return Err(Invalid::new(
                        "host",
                        "must be a host name or an IP address (no space, CR, LF or control \
                         character)",
                    ));
                }
                if self.port.is_none_or(|p| p == 0) {
                    return Err(Invalid::new(
                        "port",
                        "C-STORE needs the archive's DICOM port",
                    ));
                }
                if !self.called_ae.as_deref().is_some_and(valid_ae_title) {
                    return Err(Invalid::new(
                        "called_ae",
                        "C-STORE needs the archive's AE title: 1 to 16 printable ASCII characters",
                    ));
                }
                if self.auth.is_some() {
                    return Err(Invalid::new("auth", "only STOW-RS (`url`) takes auth"));
                }
            }
        }
        if !valid_ae_title(&self.calling_ae) {
            return Err(Invalid::new(
                "calling_ae",
                "must be 1 to 16 printable ASCII characters",
            ));
        }
        if !(1..=MAX_TIMEOUT_S).contains(&self.timeout_s) {
            return Err(Invalid::new(
                "timeout_s",
                format!("must be 1 to {MAX_TIMEOUT_S} seconds"),
            ));
        }
        if !(1..=MAX_TIMEOUT_S).contains(&self.deadline_s) {
            return Err(Invalid::new(
                "deadline_s",
                format!("must be 1 to {MAX_TIMEOUT_S} seconds"),
            ));
        }
        let [first, max] = self.retry_backoff_ms;
        if first == 0 || max < first || max > MAX_BACKOFF_MS {
            return Err(Invalid::new(
                "retry_backoff_ms",
                format!("must be [first, longest] with 0 < first <= longest <= {MAX_BACKOFF_MS}"),
            ));
        }
        Ok(())
    }
}

/// Checks every destination and that names are unique.
pub fn validate(destinations: &[PacsDestination]) -> Result<(), Invalid> {
    if destinations.len() > MAX_DESTINATIONS {
        return Err(Invalid::new(
            "pacs",
            format!(
                "{} destinations; at most {MAX_DESTINATIONS} (each has its own thread, log and \
                 connection)",
                destinations.len()
            ),
        ));
    }
    for (i, destination) in destinations.iter().enumerate() {
        let under = |invalid: Invalid| Invalid {
            key: format!("pacs[{i}].{}", invalid.key),
            ..invalid
        };
        destination.validate().map_err(under)?;
        if destinations[..i].iter().any(|d| d.name == destination.name) {
            return Err(under(Invalid::new(
                "name",
                format!("\"{}\" is used twice", destination.name),
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Why a `[[pacs]]` text is refused: not of the shape, or a value that fails its check.
    #[derive(Debug, thiserror::Error)]
    enum Refused {
        #[error(transparent)]
        Toml(#[from] toml::de::Error),
        #[error(transparent)]
        Invalid(#[from] Invalid),
    }

    fn parse(text: &str) -> Result<Vec<PacsDestination>, Refused> {
        #[derive(Deserialize)]
        struct Doc {
            pacs: Vec<PacsDestination>,
        }
        let doc: Doc = toml::from_str(text)?;
        validate(&doc.pacs)?;
        Ok(doc.pacs)
    }

    #[test]
    fn both_protocols_parse_and_mistakes_name_their_key() {
        let ok = parse(
            "[[pacs]]\nname = \"web\"\nurl = \"http://h:8042/dicom-web\"\nauth = \"basic\"\n\
             user = \"u\"\nsecret_file = \"/etc/s\"\n\
             [[pacs]]\nname = \"dimse\"\nhost = \"h\"\nport = 4242\ncalled_ae = \"ORTHANC\"\n",
        )
        .unwrap();
        assert_eq!(ok.len(), 2);
        assert_eq!(ok[1].calling_ae, "LAYERWISE");
        for (text, key) in [
            ("name = \"a\"\n", "pacs[0].url"),
            ("name = \"a\"\nurl = \"ftp://x\"\n", "pacs[0].url"),
            (
                "name = \"a\"\nhost = \"h\"\ncalled_ae = \"X\"\n",
                "pacs[0].port",
            ),
            (
                "name = \"a\"\nhost = \"h\"\nport = 1\n",
                "pacs[0].called_ae",
            ),
            (
                "name = \"a\"\nhost = \"h\"\nport = 1\ncalled_ae = \"WAY_TOO_LONG_AE_TITLE\"\n",
                "pacs[0].called_ae",
            ),
            ("name = \"a/b\"\nurl = \"http://x\"\n", "pacs[0].name"),
            (
                "name = \"a\"\nurl = \"http://x\"\nauth = \"bearer\"\n",
                "pacs[0].secret_file",
            ),
        ] {
            match parse(&format!("[[pacs]]\n{text}")).unwrap_err() {
                Refused::Invalid(invalid) => assert_eq!(invalid.key, key, "{text}: {invalid}"),
                other => panic!("{text}: {other}"),
            }
        }
        let twice = parse(
            "[[pacs]]\nname = \"a\"\nurl = \"http://x\"\n[[pacs]]\nname = \"a\"\nurl = \"http://y\"\n",
        )
        .unwrap_err();
        match twice {
            Refused::Invalid(invalid) => {
                assert_eq!(invalid.key, "pacs[1].name");
                assert_eq!(invalid.message, "\"a\" is used twice");
            }
            other => panic!("{other}"),
        }
        let inline = parse("[[pacs]]\nname = \"a\"\nurl = \"http://x\"\npassword = \"p\"\n");
        match inline.unwrap_err() {
            Refused::Toml(e) => assert!(e.to_string().contains("password"), "{e}"),
            other => panic!("{other}"),
        }
    }
}
