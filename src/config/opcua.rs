//! `[opcua]`: the OPC UA server for the shop's SCADA and MES (src/plant/opcua, docs/opcua.md).
//! Off while `listen` is empty. On loopback anyone may browse, read and subscribe without a
//! name; anywhere else the server asks for a user of `users_file` over Basic256Sha256.

use super::Invalid;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Who made a machine: its nameplate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Nameplate {
    pub manufacturer: String,
    pub model: String,
    /// `""`: not configured (shown empty).
    pub serial_number: String,
}

impl Nameplate {
    fn new(manufacturer: &str, model: &str) -> Nameplate {
        Nameplate {
            manufacturer: manufacturer.into(),
            model: model.into(),
            serial_number: String::new(),
        }
    }
}

impl Default for Nameplate {
    fn default() -> Self {
        Nameplate::new("", "")
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OpcuaConfig {
    /// `opc.tcp://host:port`; `""`: no OPC UA server.
    pub listen: String,
    /// `user:password` per line, readable by the service only. Needed when `listen` is not a
    /// loopback address; when set, acknowledging the alarm needs one of these users.
    pub users_file: Option<PathBuf>,
    /// The server's certificate and key (made on first start, self-signed), and the client
    /// certificates it trusts (`trusted/`; a client it does not know lands in `rejected/`).
    pub pki_dir: PathBuf,
    /// Sessions at once; one more is refused.
    pub max_sessions: usize,
    /// Subscriptions per session, and monitored items per subscription.
    pub max_subscriptions: usize,
    pub max_monitored_items: usize,
    /// The printer the camera watches, and the camera, as the plant knows them.
    pub printer: Nameplate,
    pub camera: Nameplate,
}

impl Default for OpcuaConfig {
    fn default() -> Self {
        OpcuaConfig {
            listen: String::new(),
            users_file: None,
            pki_dir: PathBuf::from("/var/lib/layerwise/opcua-pki"),
            max_sessions: 10,
            max_subscriptions: 10,
            max_monitored_items: 1000,
            printer: Nameplate::new("3D Systems", "ProX320"),
            camera: Nameplate::new("Nikon", "D810"),
        }
    }
}

/// Where the server listens.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OpcuaEndpoint {
    pub host: String,
    pub port: u16,
    /// A loopback address (`127.0.0.0/8`, `::1`, `localhost`): anonymous clients, no security.
    pub loopback: bool,
}

impl OpcuaConfig {
    /// The endpoint, or None when the server is off; refused under `opcua.listen`.
    pub fn endpoint(&self) -> Result<Option<OpcuaEndpoint>, Invalid> {
        let url = self.listen.trim();
        if url.is_empty() {
            return Ok(None);
        }
        let refuse = |why: &str| {
            Invalid::new(
                "opcua.listen",
                format!(
                    "\"{}\": {why}; e.g. \"opc.tcp://127.0.0.1:4840\", or \"\" for no OPC UA server",
                    url.escape_debug()
                ),
            )
        };
        let Some(rest) = url.strip_prefix("opc.tcp://") else {
            return Err(refuse("must start with opc.tcp://"));
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        let (host, port) = match rest.strip_prefix('[').and_then(|r| r.split_once("]:")) {
            Some((host, port)) => (host, port),
            None => rest
                .rsplit_once(':')
                .ok_or_else(|| refuse("needs a port"))?,
        };
        let port = port
            .parse()
            .ok()
            .filter(|p: &u16| *p > 0)
            .ok_or_else(|| refuse("the port must be 1 to 65535"))?;
        let valid_host = !host.is_empty()
            && host
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | ':'));
        if !valid_host {
            return Err(refuse(
                "expected a host name or address (no user, path or query)",
            ));
        }
        let loopback = host == "localhost"
            || host
                .parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback());
        Ok(Some(OpcuaEndpoint {
            host: host.to_string(),
            port,
            loopback,
        }))
    }

    /// Whether this binary has the OPC UA server a `listen` address asks for.
    pub fn check_backend(&self) -> Result<(), Invalid> {
        if !self.listen.is_empty() && cfg!(not(feature = "opcua")) {
            return Err(Invalid::new(
                "opcua.listen",
                "needs a layerwise built with the `opcua` feature (a default one: cargo build \
                 --release); this one was built without it: build it with the feature or leave \
                 `listen` empty",
            ));
        }
        Ok(())
    }

    /// Checks the section: an endpoint, users where the server is reachable from elsewhere,
    /// bounds that fit, nameplates of plain text.
    pub fn validate(&self) -> Result<(), Invalid> {
        let Some(endpoint) = self.endpoint()? else {
            return Ok(());
        };
        if !endpoint.loopback && self.users_file.is_none() {
            return Err(Invalid::new(
                "opcua.users_file",
                format!(
                    "is needed when the server listens on {} (not loopback): a file of \
                     `user:password` lines, readable by the service only; clients then sign in \
                     over Basic256Sha256 (or listen on 127.0.0.1 for anonymous reading)",
                    endpoint.host
                ),
            ));
        }
        for (key, value, range) in [
            ("opcua.max_sessions", self.max_sessions, 1..=100),
            ("opcua.max_subscriptions", self.max_subscriptions, 1..=100),
            (
                "opcua.max_monitored_items",
                self.max_monitored_items,
                1..=100_000,
            ),
        ] {
            if !range.contains(&value) {
                return Err(Invalid::new(
                    key,
                    format!("must be {} to {}", range.start(), range.end()),
                ));
            }
        }
        for (section, plate) in [("printer", &self.printer), ("camera", &self.camera)] {
            for (field, value) in [
                ("manufacturer", &plate.manufacturer),
                ("model", &plate.model),
                ("serial_number", &plate.serial_number),
            ] {
                if value.chars().count() > 128 || value.chars().any(char::is_control) {
                    return Err(Invalid::new(
                        format!("opcua.{section}.{field}"),
                        "must be at most 128 characters without control characters",
                    ));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_listen(listen: &str) -> OpcuaConfig {
        OpcuaConfig {
            listen: listen.into(),
            ..OpcuaConfig::default()
        }
    }

    #[test]
    fn endpoints_parse_and_mistakes_name_their_key() {
        assert_eq!(OpcuaConfig::default().endpoint().unwrap(), None);
        let endpoint = |url: &str| with_listen(url).endpoint().unwrap().unwrap();
        assert_eq!(
            endpoint("opc.tcp://127.0.0.1:4840"),
            OpcuaEndpoint {
                host: "127.0.0.1".into(),
                port: 4840,
                loopback: true
            }
        );
        assert!(endpoint("opc.tcp://localhost:4841/").loopback);
        assert!(endpoint("opc.tcp://[::1]:4840").loopback);
        assert!(!endpoint("opc.tcp://10.0.0.5:4840").loopback);
        for bad in [
            "http://x:4840",
            "opc.tcp://",
            "opc.tcp://host",
            "opc.tcp://host:0",
            "opc.tcp://host:99999",
            "opc.tcp://u@host:4840",
            "opc.tcp://host:4840/path",
        ] {
            let e = with_listen(bad).endpoint().unwrap_err();
            assert_eq!(e.key, "opcua.listen", "{bad}");
            assert!(e.message.contains("opc.tcp://127.0.0.1:4840"), "{bad}: {e}");
        }
    }

    #[test]
    fn a_server_beyond_loopback_needs_its_users_and_bounds_hold() {
        with_listen("opc.tcp://127.0.0.1:4840").validate().unwrap();
        let e = with_listen("opc.tcp://0.0.0.0:4840")
            .validate()
            .unwrap_err();
        assert_eq!(e.key, "opcua.users_file");
        assert!(e.message.contains("Basic256Sha256"), "{e}");
        let mut config = with_listen("opc.tcp://10.0.0.5:4840");
        config.users_file = Some("/etc/layerwise/opcua-users".into());
        config.validate().unwrap();
        config.max_sessions = 0;
        assert_eq!(config.validate().unwrap_err().key, "opcua.max_sessions");
        config.max_sessions = 10;
        config.camera.serial_number = "6\u{1b}[31m".into();
        assert_eq!(
            config.validate().unwrap_err().key,
            "opcua.camera.serial_number"
        );
    }
}
