//! Why the MQTT publisher cannot start.

use super::outbox::OutboxError;
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum MqttError {
    #[error("mqtt.password_file {} (write `user:password` on its first line)", path.display())]
    PasswordRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("mqtt.password_file {}: its first line must be `user:password`", path.display())]
    PasswordInvalid { path: PathBuf },
    #[error("mqtt.ca_file {} (PEM certificates of the broker's certificate authority)", path.display())]
    CaRead {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("mqtt.ca_file {}: no usable certificate in it (PEM, `-----BEGIN CERTIFICATE-----`)", path.display())]
    CaInvalid {
        path: PathBuf,
        #[source]
        source: Option<Box<dyn std::error::Error + Send + Sync>>,
    },
    #[error("MQTT over TLS")]
    Tls(#[source] rustls::Error),
    #[error(transparent)]
    Queue(#[from] OutboxError),
    #[error("cannot start the MQTT thread")]
    Thread(#[source] std::io::Error),
}
