//! MQTT (docs/mqtt.md): the build's events published to the shop's broker from a thread of
//! its own. Messages wait on disk, in order, while the broker is away ([`outbox`]); the
//! connection ([`session`]) sends them one at a time and drops each once acknowledged.

mod error;
pub mod message;
pub mod outbox;
mod session;

use crate::config::mqtt::MqttConfig;
use crate::plant::metrics::LiveMetrics;
use crate::plant::sink::PlantFeed;
use crate::plant::task;
use crate::shutdown::Shutdown;
pub use error::MqttError;
use std::path::Path;
use std::sync::Arc;

/// Longest password or CA file read.
const MAX_SECRET_BYTES: u64 = 1 << 20;

/// The publisher, ready to start: its secrets read, its queue open.
pub struct Prepared {
    config: MqttConfig,
    identity: session::Identity,
    outbox: outbox::Outbox,
}

/// Reads what the publisher needs (password, CA certificates) and opens its queue. None when
/// `[mqtt] url` is empty.
pub fn prepare(config: &MqttConfig) -> Result<Option<Prepared>, MqttError> {
    let Ok(Some(broker)) = config.broker() else {
        return Ok(None);
    };
    let credentials = match &config.password_file {
        Some(path) => Some(read_credentials(path)?),
        None => None,
    };
    let tls = match &config.ca_file {
        Some(path) if broker.tls => Some(Arc::new(tls_config(path)?)),
        _ => None,
    };
    let client_id = match config.client_id.trim() {
        "" => format!("layerwise-{}", task::host_name()),
        id => id.to_string(),
    };
    let outbox = outbox::Outbox::open(&config.queue_dir, config.max_queue_mb << 20)?;
    Ok(Some(Prepared {
        config: config.clone(),
        identity: session::Identity {
            broker,
            client_id,
            credentials,
            tls,
        },
        outbox,
    }))
}

impl Prepared {
    /// Starts the publisher on its thread (`plant-mqtt`); it stops when `shutdown` is
    /// requested, after publishing the status offline and sending what it can of the queue
    /// for [`session::STOP_GRACE`].
    pub fn start(
        self,
        feed: PlantFeed,
        live: Option<Arc<LiveMetrics>>,
        shutdown: Shutdown,
    ) -> Result<std::thread::JoinHandle<()>, MqttError> {
        let session = session::Session {
            messages: message::Messages::new(&self.config.topic_prefix),
            config: self.config,
            identity: self.identity,
            outbox: self.outbox,
            feed,
            live,
            shutdown,
        };
        task::spawn("plant-mqtt", session.run()).map_err(MqttError::Thread)
    }
}

fn read_credentials(path: &Path) -> Result<(String, String), MqttError> {
    let text = crate::fsutil::read_text_bounded(path, MAX_SECRET_BYTES).map_err(|source| {
        MqttError::PasswordRead {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let line = text.lines().next().unwrap_or_default();
    match line.split_once(':') {
        Some((user, password)) if !user.is_empty() => Ok((user.to_string(), password.to_string())),
        _ => Err(MqttError::PasswordInvalid {
            path: path.to_path_buf(),
        }),
    }
}

/// TLS on ring (the provider the rest of the program uses), trusting the certificates of
/// `ca_file` only.
fn tls_config(ca_file: &Path) -> Result<rustls::ClientConfig, MqttError> {
    use rustls::pki_types::{pem::PemObject, CertificateDer};
    let invalid = |source: Option<Box<dyn std::error::Error + Send + Sync>>| MqttError::CaInvalid {
        path: ca_file.to_path_buf(),
        source,
    };
    let text = crate::fsutil::read_text_bounded(ca_file, MAX_SECRET_BYTES).map_err(|source| {
        MqttError::CaRead {
            path: ca_file.to_path_buf(),
            source,
        }
    })?;
    let mut roots = rustls::RootCertStore::empty();
    for cert in CertificateDer::pem_slice_iter(text.as_bytes()) {
        let cert = cert.map_err(|e| invalid(Some(Box::new(e))))?;
        roots.add(cert).map_err(|e| invalid(Some(Box::new(e))))?;
    }
    if roots.is_empty() {
        return Err(invalid(None));
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    Ok(rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(MqttError::Tls)?
        .with_root_certificates(roots)
        .with_no_client_auth())
}
