//! `[mqtt]`: the build's events published to the shop's MQTT broker (src/plant/mqtt,
//! docs/mqtt.md). Off while `url` is empty. The password is read from a file named here
//! (`password_file`), never written in the configuration.

use super::common::check_backoff;
use super::Invalid;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// The most a queue may hold on disk, in MB.
pub const MAX_QUEUE_MB: u64 = 4096;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MqttConfig {
    /// `mqtt://host:1883` or `mqtts://host:8883` (TLS, with `ca_file`); `""`: no MQTT.
    pub url: String,
    /// mqtts: the certificates (PEM) the broker's certificate must chain to.
    pub ca_file: Option<PathBuf>,
    /// A file holding `user:password` on its first line, readable by the service only.
    pub password_file: Option<PathBuf>,
    /// The client id the broker knows the daemon by; `""`: `layerwise-<host name>`.
    pub client_id: String,
    /// Topics start with this; `""`: `layerwise/<build.name>` (the build's name made a topic
    /// level: `/`, `+`, `#` and control characters replaced by `_`).
    pub topic_prefix: String,
    /// Where messages wait (in order, on disk) while the broker is away.
    pub queue_dir: PathBuf,
    /// The most the queue keeps; beyond it the oldest messages are dropped (and a `gap` message
    /// says which).
    pub max_queue_mb: u64,
    /// Seconds between keep-alive pings; the broker publishes the last will after 1.5 times
    /// this without a word (a host gone without closing its connection).
    pub keep_alive_s: u64,
    /// Wait between connection attempts while the broker is away: first and longest, in ms.
    pub retry_backoff_ms: [u64; 2],
}

impl Default for MqttConfig {
    fn default() -> Self {
        MqttConfig {
            url: String::new(),
            ca_file: None,
            password_file: None,
            client_id: String::new(),
            topic_prefix: String::new(),
            queue_dir: PathBuf::from("/var/lib/layerwise/mqtt"),
            max_queue_mb: 64,
            keep_alive_s: 30,
            retry_backoff_ms: [1_000, 60_000],
        }
    }
}

/// Where the broker is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MqttBroker {
    pub host: String,
    pub port: u16,
    pub tls: bool,
}

impl MqttConfig {
    /// The broker, or None when MQTT is off; refused under `mqtt.url`.
    pub fn broker(&self) -> Result<Option<MqttBroker>, Invalid> {
        let url = self.url.trim();
        if url.is_empty() {
            return Ok(None);
        }
        let refuse = |why: &str| {
            Invalid::new(
                "mqtt.url",
                format!("\"{}\": {why}; e.g. \"mqtt://broker:1883\", \"mqtts://broker:8883\", or \"\" for no MQTT", url.escape_debug()),
            )
        };
        let (tls, rest) = if let Some(rest) = url.strip_prefix("mqtts://") {
            (true, rest)
        } else if let Some(rest) = url.strip_prefix("mqtt://") {
            (false, rest)
        } else {
            return Err(refuse("must start with mqtt:// or mqtts://"));
        };
        let rest = rest.strip_suffix('/').unwrap_or(rest);
        let default_port = if tls { 8883 } else { 1883 };
        // An IPv6 address is written in brackets (`mqtt://[::1]:1883`); rumqttc takes it bare.
        let (host, port) = match rest.strip_prefix('[').and_then(|r| r.split_once(']')) {
            Some((host, "")) => (host, None),
            Some((host, port)) => (host, Some(port.strip_prefix(':').unwrap_or("x"))),
            None => match rest.split_once(':') {
                Some((host, port)) => (host, Some(port)),
                None => (rest, None),
            },
        };
        let port = match port {
            None => default_port,
            Some(port) => port
                .parse()
                .ok()
                .filter(|p: &u16| *p > 0)
                .ok_or_else(|| refuse("the port must be 1 to 65535"))?,
        };
        let valid_host = !host.is_empty()
            && host
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_' | ':'));
        if !valid_host {
            return Err(refuse(
                "expected a host name or address (no user, path or query)",
            ));
        }
        Ok(Some(MqttBroker {
            host: host.to_string(),
            port,
            tls,
        }))
    }

    /// Checks the section: a broker URL, TLS with its CA file, bounds that fit.
    pub fn validate(&self) -> Result<(), Invalid> {
        let Some(broker) = self.broker()? else {
            return Ok(());
        };
        if broker.tls && self.ca_file.is_none() {
            return Err(Invalid::new(
                "mqtt.ca_file",
                "mqtts:// needs the CA certificates (PEM) the broker's certificate chains to",
            ));
        }
        if !broker.tls && self.ca_file.is_some() {
            return Err(Invalid::new(
                "mqtt.ca_file",
                "is for mqtts:// only (mqtt:// is not encrypted)",
            ));
        }
        if self.client_id.len() > 128 || self.client_id.chars().any(char::is_control) {
            return Err(Invalid::new(
                "mqtt.client_id",
                "must be at most 128 characters without control characters",
            ));
        }
        if self.topic_prefix.len() > 128
            || self.topic_prefix.starts_with('/')
            || self.topic_prefix.ends_with('/')
            || self
                .topic_prefix
                .chars()
                .any(|c| matches!(c, '+' | '#') || c.is_control())
        {
            return Err(Invalid::new(
                "mqtt.topic_prefix",
                "must be at most 128 characters, with no `+`, `#` or control characters and no \
                 `/` at either end, e.g. \"plant/hall-2/prox320-07\"",
            ));
        }
        if !(1..=MAX_QUEUE_MB).contains(&self.max_queue_mb) {
            return Err(Invalid::new(
                "mqtt.max_queue_mb",
                format!("must be 1 to {MAX_QUEUE_MB} MB"),
            ));
        }
        if !(5..=3600).contains(&self.keep_alive_s) {
            return Err(Invalid::new(
                "mqtt.keep_alive_s",
                "must be 5 to 3600 seconds",
            ));
        }
        check_backoff("mqtt.retry_backoff_ms", self.retry_backoff_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_url(url: &str) -> MqttConfig {
        MqttConfig {
            url: url.into(),
            ..MqttConfig::default()
        }
    }

    #[test]
    fn broker_urls_parse_with_their_default_ports_and_mistakes_name_their_key() {
        assert_eq!(MqttConfig::default().broker().unwrap(), None);
        let broker = |url: &str| with_url(url).broker().unwrap().unwrap();
        assert_eq!(
            broker("mqtt://broker.plant"),
            MqttBroker {
                host: "broker.plant".into(),
                port: 1883,
                tls: false
            }
        );
        assert_eq!(broker("mqtts://10.0.0.5").port, 8883);
        assert_eq!(broker("mqtt://127.0.0.1:18830/").port, 18830);
        assert_eq!(broker("mqtt://[::1]:1884").host, "::1");
        assert_eq!(broker("mqtt://[fe80::2]").port, 1883);
        for bad in [
            "tcp://x",
            "mqtt://",
            "mqtt://h:0",
            "mqtt://h:99999",
            "mqtt://u:p@h",
            "mqtt://h/path",
        ] {
            assert_eq!(
                with_url(bad).validate().unwrap_err().key,
                "mqtt.url",
                "{bad}"
            );
        }
        assert_eq!(
            with_url("mqtts://h").validate().unwrap_err().key,
            "mqtt.ca_file"
        );
        let mut config = with_url("mqtt://h");
        config.topic_prefix = "plant/#".into();
        assert_eq!(config.validate().unwrap_err().key, "mqtt.topic_prefix");
        config.topic_prefix = "plant/hall-2".into();
        config.retry_backoff_ms = [0, 1];
        assert_eq!(config.validate().unwrap_err().key, "mqtt.retry_backoff_ms");
    }
}
