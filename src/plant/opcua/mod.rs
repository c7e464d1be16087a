//! The OPC UA server (docs/opcua.md): the printer and its build as an OPC 40540 machine
//! ([`space`]), kept current from the plant feed ([`model`]) on a thread of its own
//! (`plant-opcua`, below capture in priority). Its one method, the inspection alarm's
//! `Acknowledge` ([`nodes`]), records the same acknowledgement as `layerwise alarm ack`.

mod error;
mod model;
mod nodes;
pub mod space;

use crate::config::opcua::{OpcuaConfig, OpcuaEndpoint};
use crate::plant::sink::PlantFeed;
use crate::plant::task;
use crate::shutdown::Shutdown;
pub use error::OpcuaError;
use model::Model;
use nodes::{AlarmShared, Manager, MonitorNodes, USER_TOKEN};
use opcua::crypto::SecurityPolicy;
use opcua::server::address_space::AddressSpace;
use opcua::server::node_manager::memory::InMemoryNodeManagerBuilder;
use opcua::server::node_manager::ServerContext;
use opcua::server::{ServerBuilder, ServerUserToken, ANONYMOUS_USER_TOKEN_ID};
use opcua::types::{BuildInfo, MessageSecurityMode};
use std::path::Path;
use std::sync::{Arc, Mutex};
use tracing::{info, warn};

/// Longest users file read.
const MAX_USERS_BYTES: u64 = 1 << 20;

/// The server, ready to start: its users read.
pub struct Prepared {
    config: OpcuaConfig,
    endpoint: OpcuaEndpoint,
    users: Vec<(String, String)>,
}

/// Reads what the server needs (its users). None when `[opcua] listen` is empty.
pub fn prepare(config: &OpcuaConfig) -> Result<Option<Prepared>, OpcuaError> {
    let Ok(Some(endpoint)) = config.endpoint() else {
        return Ok(None);
    };
    let users = match &config.users_file {
        Some(path) => read_users(path)?,
        None => Vec::new(),
    };
    Ok(Some(Prepared {
        config: config.clone(),
        endpoint,
        users,
    }))
}

/// `user:password` lines; blank lines and `#` comments skipped.
fn read_users(path: &Path) -> Result<Vec<(String, String)>, OpcuaError> {
    let text = crate::fsutil::read_text_bounded(path, MAX_USERS_BYTES).map_err(|source| {
        OpcuaError::UsersRead {
            path: path.to_path_buf(),
            source,
        }
    })?;
    let mut users = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim_end_matches('\r');
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        let valid_name = |u: &str| {
            (1..=64).contains(&u.len())
                && u.chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '-' | '_'))
        };
        match line.split_once(':') {
            Some((user, password)) if valid_name(user) && password.chars().count() >= 8 => {
                users.push((user.to_string(), password.to_string()))
            }
            _ => {
                return Err(OpcuaError::UsersInvalid {
                    path: path.to_path_buf(),
                    line: n + 1,
                })
            }
        }
    }
    if users.is_empty() {
        return Err(OpcuaError::NoUsers {
            path: path.to_path_buf(),
        });
    }
    Ok(users)
}

impl Prepared {
    /// Starts the server on its thread (`plant-opcua`); it stops when `shutdown` is requested.
    /// A server that cannot listen (the port taken) is logged; capture goes on.
    pub fn start(
        self,
        feed: PlantFeed,
        shutdown: Shutdown,
    ) -> Result<std::thread::JoinHandle<()>, OpcuaError> {
        let runtime = task::runtime("plant-opcua").map_err(OpcuaError::Thread)?;
        let alarm = Arc::new(Mutex::new(AlarmShared::default()));
        let (acks, ack_inbox) = tokio::sync::mpsc::channel(16);
        let anonymous_acknowledges = self.users.is_empty();
        let (server, handle) = {
            let _entered = runtime.enter();
            let config = self.config.clone();
            let shared = alarm.clone();
            let nodes = InMemoryNodeManagerBuilder::new(
                move |context: ServerContext, space: &mut AddressSpace| {
                    let ns = context
                        .type_tree
                        .write()
                        .namespaces_mut()
                        .add_namespace(space::NAMESPACE);
                    space.add_namespace(space::NAMESPACE, ns);
                    space::build(space, ns, &config);
                    MonitorNodes {
                        ns,
                        alarm: shared,
                        acks,
                        anonymous_acknowledges,
                    }
                },
            );
            self.builder()
                .with_node_manager(nodes)
                .build()
                .map_err(OpcuaError::Setup)?
        };
        let manager = handle
            .node_managers()
            .get_of_type::<Manager>()
            .ok_or_else(|| OpcuaError::Setup("the monitor's node manager is missing".into()))?;
        let ns = handle
            .get_namespace_index(space::NAMESPACE)
            .ok_or_else(|| OpcuaError::Setup("the monitor's namespace is missing".into()))?;
        let model = Model::new(manager, handle.subscriptions().clone(), ns, alarm);
        let listen = self.config.listen.clone();
        let future = async move {
            let stop = handle.clone();
            let watch = shutdown.clone();
            tokio::spawn(async move {
                watch.requested().await;
                stop.cancel();
            });
            tokio::spawn(follow(model, feed, ack_inbox, shutdown));
            info!(listen = %listen, "OPC UA server listening");
            if let Err(e) = server.run().await {
                warn!(error = %e, listen = %listen, "no OPC UA server; capture goes on");
            }
        };
        task::spawn_on(runtime, "plant-opcua", future).map_err(OpcuaError::Thread)
    }

    fn builder(&self) -> ServerBuilder {
        let host = &self.endpoint.host;
        let mut builder = ServerBuilder::new()
            .application_name("layerwise")
            .application_uri(format!("urn:layerwise:{}", task::host_name()))
            .product_uri("urn:layerwise")
            .build_info(BuildInfo {
                product_uri: "urn:layerwise".into(),
                manufacturer_name: "layerwise".into(),
                product_name: "layerwise".into(),
                software_version: env!("CARGO_PKG_VERSION").into(),
                build_number: env!("CARGO_PKG_VERSION").into(),
                build_date: opcua::types::DateTime::now(),
            })
            .host(host.clone())
            .port(self.endpoint.port)
            .discovery_urls(vec![format!("opc.tcp://{host}:{}/", self.endpoint.port)])
            .pki_dir(&self.config.pki_dir)
            .create_sample_keypair(true)
            .certificate_path("own/cert.der")
            .private_key_path("private/private.pem")
            .trust_client_certs(false)
            .max_sessions(self.config.max_sessions)
            .hello_timeout(5)
            .max_message_size(1 << 20)
            .max_chunk_count(64)
            .max_array_length(10_000)
            .max_string_length(64 * 1024)
            .max_byte_string_length(64 * 1024)
            .diagnostics_enabled(false);
        {
            let limits = builder.limits_mut();
            limits.subscriptions.max_subscriptions_per_session = self.config.max_subscriptions;
            limits.subscriptions.max_monitored_items_per_sub = self.config.max_monitored_items;
            limits.subscriptions.max_queued_notifications = 10_000;
        }
        let mut tokens: Vec<String> = Vec::new();
        for (user, password) in &self.users {
            let key = format!("{USER_TOKEN}{user}");
            builder = builder.add_user_token(
                key.clone(),
                ServerUserToken::user_pass(user.clone(), password.clone()),
            );
            tokens.push(key);
        }
        let mut secure = tokens.clone();
        if self.endpoint.loopback {
            secure.push(ANONYMOUS_USER_TOKEN_ID.to_string());
            let open: Vec<&str> = secure.iter().map(String::as_str).collect();
            builder = builder
                .add_endpoint(
                    "none",
                    (
                        "/",
                        SecurityPolicy::None,
                        MessageSecurityMode::None,
                        &open[..],
                    ),
                )
                .default_endpoint("none");
        }
        let ids: Vec<&str> = secure.iter().map(String::as_str).collect();
        builder = builder.add_endpoint(
            "basic256sha256_sign_encrypt",
            (
                "/",
                SecurityPolicy::Basic256Sha256,
                MessageSecurityMode::SignAndEncrypt,
                &ids[..],
            ),
        );
        if !self.endpoint.loopback {
            builder = builder.default_endpoint("basic256sha256_sign_encrypt");
        }
        builder
    }
}

/// Applies the feed's events, the latest status and the server's own acknowledgements to the
/// address space until `shutdown`.
async fn follow(
    mut model: Model,
    mut feed: PlantFeed,
    mut acks: tokio::sync::mpsc::Receiver<nodes::Acknowledged>,
    shutdown: Shutdown,
) {
    let status = feed.status.borrow_and_update().clone();
    model.status(&status);
    loop {
        tokio::select! {
            event = feed.events.recv() => match event {
                Some(event) => model.apply(&event),
                None => break,
            },
            changed = feed.status.changed() => {
                if changed.is_err() {
                    break;
                }
                let status = feed.status.borrow_and_update().clone();
                model.status(&status);
            }
            Some((by, note)) = acks.recv() => {
                model.acknowledged(&by, note.as_deref(), chrono::Utc::now());
            }
            _ = shutdown.requested() => break,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_users_file_is_read_and_a_bad_line_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("users");
        std::fs::write(
            &path,
            "# plant\nana:layer-by-layer\n\nscada-1:0123456789\r\n",
        )
        .unwrap();
        assert_eq!(
            read_users(&path).unwrap(),
            [
                ("ana".to_string(), "layer-by-layer".to_string()),
                ("scada-1".to_string(), "0123456789".to_string())
            ]
        );
        for (text, line) in [
            ("ana:short\n", 1),
            ("ana:layer-by-layer\nbob\n", 2),
            ("a b:layer-by-layer\n", 1),
            (":layer-by-layer\n", 1),
        ] {
            std::fs::write(&path, text).unwrap();
            match read_users(&path) {
                Err(OpcuaError::UsersInvalid { line: l, .. }) => assert_eq!(l, line, "{text:?}"),
                other => panic!("{text:?}: {other:?}"),
            }
        }
        std::fs::write(&path, "# nobody yet\n").unwrap();
        assert!(matches!(read_users(&path), Err(OpcuaError::NoUsers { .. })));
        let missing = read_users(&dir.path().join("absent")).unwrap_err();
        assert!(missing.to_string().contains("absent"), "{missing}");
    }
}
