//! `[web]`: the operator page the daemon serves (src/web), and `layerwise serve`.

use super::Invalid;
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::PathBuf;

/// Most connections a page server keeps open at once.
pub const MAX_CONNECTIONS: usize = 4096;

/// The least address space the page's process is given (it maps its program, libraries,
/// thread stacks and picture cache).
pub const MIN_MEMORY_MB: u64 = 256;

/// How the operator page is served.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WebConfig {
    /// `host:port` to listen on; `""` serves no page. Loopback (`127.0.0.1:8040`) by default.
    pub listen: String,
    /// A file holding the bearer token every request must carry; required when `listen` is not
    /// a loopback address.
    pub token_file: Option<PathBuf>,
    /// Connections open at once. A new connection beyond it closes one that is waiting for a
    /// request (one that never had a request answered first, then one of the address holding
    /// the most, the one waiting longest); it is refused (503) only when every connection is
    /// being answered.
    pub max_connections: usize,
    /// Connections from one client address at once (at most `max_connections`); beyond it that
    /// address's own waiting connections make room.
    pub max_connections_per_client: usize,
    /// Live-update streams (one per open page) at once; more are refused with 503.
    pub max_event_streams: usize,
    /// Seconds a connection may sit with nothing read or written (an idle keep-alive, a client
    /// that sends half a request and stops) while no request of it is being answered; then it
    /// is closed and its place goes to the next client. Open pages stay: their event stream
    /// sends a keep-alive well within it.
    pub idle_timeout_s: u64,
    /// Seconds a client has to send a request's headers, from its connection's start or the
    /// previous answer's end; then the connection is closed.
    pub header_timeout_s: u64,
    /// Seconds a client has to send a request's body (at most 64 KiB), from its headers; then
    /// it is answered 408 and the connection closed.
    pub body_timeout_s: u64,
    /// The daemon's page runs as a process of its own, restarted if it ends: its address space
    /// in MiB. A request that would need more ends that process, never the capture.
    pub memory_mb: u64,
    /// Longest side of a preview and of a zoomed crop, in pixels.
    pub preview_px: u32,
    /// Memory for encoded previews, in MB.
    pub cache_mb: u64,
    /// The calibration page may save a new points file in the build directory (never
    /// overwriting one) and run the registration.
    pub calibration_page: bool,
    /// Names besides 127.0.0.1, [::1] and localhost the page answers to (as a request's `Host`)
    /// without a token: those a reverse proxy on this machine sends. Any other name is refused
    /// (a site made to resolve to 127.0.0.1: DNS rebinding). With a token, every name is.
    pub allowed_hosts: Vec<String>,
}

impl Default for WebConfig {
    fn default() -> Self {
        WebConfig {
            listen: "127.0.0.1:8040".into(),
            token_file: None,
            max_connections: 512,
            max_connections_per_client: 256,
            max_event_streams: 16,
            idle_timeout_s: 30,
            header_timeout_s: 10,
            body_timeout_s: 10,
            memory_mb: 2048,
            preview_px: 1024,
            cache_mb: 64,
            calibration_page: false,
            allowed_hosts: Vec::new(),
        }
    }
}

impl WebConfig {
    /// The address to listen on, or None when the page is off; refused under `web.listen`.
    pub fn address(&self) -> Result<Option<SocketAddr>, Invalid> {
        let text = self.listen.trim();
        if text.is_empty() {
            return Ok(None);
        }
        // A socket address that does not parse says no more than this (std's AddrParseError of
        // a socket address is always "invalid socket address syntax"): no cause to keep.
        text.parse()
            .map(Some)
            .map_err(|_: std::net::AddrParseError| {
                Invalid::new(
                    "web.listen",
                    format!(
                        "\"{text}\" is not host:port (invalid socket address syntax); e.g. \
                     \"127.0.0.1:8040\", or \"\" for no page"
                    ),
                )
            })
    }

    /// Checks the section: an address (beyond loopback only with a token) and bounds that fit.
    pub fn validate(&self) -> Result<(), Invalid> {
        if let Some(address) = self.address()? {
            if !address.ip().is_loopback() && self.token_file.is_none() {
                return Err(Invalid::new(
                    "web.listen",
                    format!(
                        "{address} is reachable from other machines: set web.token_file to a file \
                         holding a bearer token (or listen on 127.0.0.1 behind a reverse proxy)"
                    ),
                ));
            }
        }
        if !(1..=MAX_CONNECTIONS).contains(&self.max_connections) {
            return Err(Invalid::new(
                "web.max_connections",
                format!("must be 1 to {MAX_CONNECTIONS}"),
            ));
        }
        // Beyond max_connections it is max_connections: a configuration that lowered that
        // alone keeps loading.
        if !(1..=MAX_CONNECTIONS).contains(&self.max_connections_per_client) {
            return Err(Invalid::new(
                "web.max_connections_per_client",
                format!("must be 1 to {MAX_CONNECTIONS}"),
            ));
        }
        if !(1..=self.max_connections).contains(&self.max_event_streams) {
            return Err(Invalid::new(
                "web.max_event_streams",
                "must be 1 to web.max_connections",
            ));
        }
        if !(1..=3600).contains(&self.idle_timeout_s) {
            return Err(Invalid::new(
                "web.idle_timeout_s",
                "must be 1 to 3600 seconds",
            ));
        }
        for (key, value) in [
            ("web.header_timeout_s", self.header_timeout_s),
            ("web.body_timeout_s", self.body_timeout_s),
        ] {
            if !(1..=3600).contains(&value) {
                return Err(Invalid::new(key, "must be 1 to 3600 seconds"));
            }
        }
        if !(MIN_MEMORY_MB..=1 << 20).contains(&self.memory_mb) {
            return Err(Invalid::new(
                "web.memory_mb",
                format!("must be {MIN_MEMORY_MB} to 1048576 MiB"),
            ));
        }
        if !(64..=4096).contains(&self.preview_px) {
            return Err(Invalid::new("web.preview_px", "must be 64 to 4096 pixels"));
        }
        if !(1..=4096).contains(&self.cache_mb) {
            return Err(Invalid::new("web.cache_mb", "must be 1 to 4096 MB"));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_by_default_off_when_empty_token_beyond_loopback() {
        let mut web = WebConfig::default();
        assert_eq!(
            web.address().unwrap().unwrap().to_string(),
            "127.0.0.1:8040"
        );
        assert!(web.validate().is_ok());
        web.listen = "".into();
        assert_eq!(web.address().unwrap(), None);
        web.listen = "0.0.0.0:8040".into();
        assert_eq!(web.validate().unwrap_err().key, "web.listen");
        web.token_file = Some("/etc/layerwise/web.token".into());
        assert!(web.validate().is_ok());
        web.listen = "printer:80".into();
        let refused = web.validate().unwrap_err();
        assert_eq!(refused.key, "web.listen");
        // The words std gives, where they always stood.
        let cause = "printer:80".parse::<SocketAddr>().unwrap_err();
        assert_eq!(
            refused.message,
            format!(
                "\"printer:80\" is not host:port ({cause}); e.g. \"127.0.0.1:8040\", or \"\" for \
                 no page"
            )
        );
        assert_eq!(web.address().unwrap_err().message, refused.message);
        web.listen = "[::1]:8040".into();
        web.max_event_streams = 0;
        assert_eq!(web.validate().unwrap_err().key, "web.max_event_streams");
    }
}
