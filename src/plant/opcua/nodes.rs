//! The node manager of the monitor's namespace: its nodes kept in memory ([`super::space`]
//! builds them), and the one method, the inspection alarm's `Acknowledge`, which records the
//! same acknowledgement as `layerwise alarm ack`.

use super::space;
use crate::build_dir::alarm::{acknowledge, AckError};
use async_trait::async_trait;
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerImpl};
use opcua::server::node_manager::{MethodCall, RequestContext, ServerContext};
use opcua::sync::RwLock;
use opcua::types::{ByteString, StatusCode, Variant};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use tokio::sync::mpsc;
use tracing::{info, warn};

/// The node manager of the monitor's namespace.
pub type Manager = InMemoryNodeManager<MonitorNodes>;

/// The prefix of a configured user's token id (the rest is the user's name).
pub const USER_TOKEN: &str = "user:";

/// The alarm as the server knows it, shared by the model and the Acknowledge method.
#[derive(Debug, Default)]
pub struct AlarmShared {
    /// The build whose alarm.jsonl an acknowledgement goes to.
    pub build_dir: Option<PathBuf>,
    /// The event id of the raise waiting for an acknowledgement.
    pub pending: Option<ByteString>,
    /// That raise as alarm.jsonl has it: an acknowledgement of it is refused once the alarm
    /// was raised again (the check and the append are one step in the log).
    pub raise: Option<crate::build_dir::alarm::SeenRaise>,
}

/// An acknowledgement a client recorded: who, and the note.
pub type Acknowledged = (String, Option<String>);

/// The monitor's nodes: kept in memory, with the alarm's Acknowledge method.
pub struct MonitorNodes {
    pub ns: u16,
    pub alarm: Arc<Mutex<AlarmShared>>,
    /// Acknowledgements recorded by a client, for the address space at once.
    pub acks: mpsc::Sender<Acknowledged>,
    /// No users file: a client without a name may acknowledge (loopback only).
    pub anonymous_acknowledges: bool,
}

impl MonitorNodes {
    /// The Acknowledge method: `EventId` of the raise, `Comment` the note. Recorded in the
    /// build's alarm.jsonl as `layerwise alarm ack` records it, by the client's user
    /// (`opcua:<user>`, or `opcua:anonymous`).
    async fn acknowledge(&self, user: &str, args: &[Variant]) -> Result<(), StatusCode> {
        let by = match user.strip_prefix(USER_TOKEN) {
            Some(name) => format!("opcua:{name}"),
            None if self.anonymous_acknowledges => "opcua:anonymous".to_string(),
            None => return Err(StatusCode::BadUserAccessDenied),
        };
        let event_id = match args.first() {
            Some(Variant::ByteString(id)) => id.clone(),
            Some(_) => return Err(StatusCode::BadTypeMismatch),
            None => return Err(StatusCode::BadArgumentsMissing),
        };
        let note = match args.get(1) {
            Some(Variant::LocalizedText(text)) => Some(text.text.as_ref().to_string()),
            Some(Variant::Empty) | None => None,
            Some(_) => return Err(StatusCode::BadTypeMismatch),
        }
        .filter(|n| !n.trim().is_empty());
        let (dir, raise) = {
            let alarm = self.alarm.lock().unwrap_or_else(|e| e.into_inner());
            match &alarm.pending {
                None => return Err(StatusCode::BadConditionBranchAlreadyAcked),
                Some(pending) if *pending != event_id => return Err(StatusCode::BadEventIdUnknown),
                Some(_) => {}
            }
            let dir = alarm.build_dir.clone().ok_or(StatusCode::BadInvalidState)?;
            (dir, alarm.raise)
        };
        // On a blocking thread: the log's lock may be waited for (up to 2 s), and the server's
        // runtime has one thread for every session.
        let recorded = {
            let (by, note) = (by.clone(), note.clone());
            tokio::task::spawn_blocking(move || {
                acknowledge(&dir, &by, note.as_deref(), chrono::Utc::now(), raise)
            })
            .await
            .map_err(|_| StatusCode::BadInternalError)?
        };
        match recorded {
            Ok(_) => {
                info!(by = %by, "inspection alarm acknowledged over OPC UA");
                let _ = self.acks.try_send((by, note));
                Ok(())
            }
            Err(AckError::NotRaised { .. }) => Err(StatusCode::BadConditionBranchAlreadyAcked),
            Err(AckError::Invalid { .. }) => Err(StatusCode::BadInvalidArgument),
            // Raised again since the event the client acknowledges.
            Err(AckError::Another { .. }) => Err(StatusCode::BadEventIdUnknown),
            Err(e) => {
                warn!(error = %crate::logging::Chain(&e), "OPC UA acknowledgement not recorded");
                Err(StatusCode::BadInternalError)
            }
        }
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for MonitorNodes {
    async fn init(&self, _space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &str {
        "layerwise"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        vec![NamespaceMetadata {
            namespace_uri: space::NAMESPACE.to_string(),
            namespace_index: self.ns,
            ..Default::default()
        }]
    }

    async fn call(
        &self,
        context: &RequestContext,
        _space: &RwLock<AddressSpace>,
        methods: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        let acknowledge = space::id(self.ns, space::ACKNOWLEDGE);
        for method in methods {
            if *method.method_id() != acknowledge {
                method.set_status(StatusCode::BadMethodInvalid);
                continue;
            }
            match self.acknowledge(&context.token.0, method.arguments()).await {
                Ok(()) => {
                    method.set_outputs(Vec::new());
                    method.set_status(StatusCode::Good);
                }
                Err(status) => method.set_status(status),
            }
        }
        Ok(())
    }
}
