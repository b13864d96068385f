//! The node manager of the gateway's namespace: async-opcua's in-memory address space
//! (the model keeps it in step with the engine's image), variables read from it and
//! never written, and method calls that see the session (its endpoint and user) so
//! each is checked against the [`Rules`] and recorded in the audit.

use std::collections::HashMap;
use std::sync::RwLock;

use async_trait::async_trait;
use hart_poller::{Engine, WriteFailure, WriteOp};
use opcua::server::address_space::AddressSpace;
use opcua::server::diagnostics::NamespaceMetadata;
use opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerImpl};
use opcua::server::node_manager::{MethodCall, RequestContext, ServerContext, WriteNode};
use opcua::sync::RwLock as UaRwLock;
use opcua::types::{NodeId, StatusCode, Variant};

use crate::access::{self, Rules};

/// The gateway's node manager.
pub(crate) type HartNodeManager = InMemoryNodeManager<HartNodes>;

/// Where a method goes: the device, and which method it is.
#[derive(Debug, Clone)]
pub(crate) struct MethodTarget {
    /// The device's position in the engine's image.
    pub position: usize,
    /// `SetDamping`, `SetRange`, `WriteTag`, `LoopTest`.
    pub method: &'static str,
    /// The device's path, `HART/<loop>/<name>` (for the audit).
    pub device: String,
}

/// Who calls, for the audit.
pub(crate) struct Caller<'a> {
    identity: String,
    device: &'a str,
}

impl Caller<'_> {
    /// The origin of a call of `method` for the engine's typed write, which records it
    /// in the audit just before its command goes on the loop.
    pub(crate) fn origin(&self, method: &str) -> hart_access::WriteRecord {
        hart_access::WriteRecord {
            front_end: "opcua",
            session: None,
            // async-opcua does not tell a session's peer address.
            peer: "-".to_string(),
            identity: Some(self.identity.clone()),
            via: format!("method {method} of {}", self.device),
            ..Default::default()
        }
    }
}

/// The implementation behind [`HartNodeManager`].
pub(crate) struct HartNodes {
    namespaces: Vec<NamespaceMetadata>,
    engine: Engine,
    rules: Rules,
    methods: RwLock<HashMap<NodeId, MethodTarget>>,
}

impl HartNodes {
    /// The node manager's builder: registers `namespace` and keeps what calls need.
    pub(crate) fn builder(
        namespace: &str,
        engine: Engine,
        rules: Rules,
    ) -> impl FnOnce(ServerContext, &mut AddressSpace) -> HartNodes {
        let uri = namespace.to_string();
        move |context: ServerContext, space: &mut AddressSpace| {
            let index = context
                .type_tree
                .write()
                .namespaces_mut()
                .add_namespace(&uri);
            space.add_namespace(&uri, index);
            HartNodes {
                namespaces: vec![NamespaceMetadata {
                    namespace_uri: uri,
                    namespace_index: index,
                    ..Default::default()
                }],
                engine,
                rules,
                methods: Default::default(),
            }
        }
    }

    /// Routes calls of the method `id` to `target`.
    pub(crate) fn add_method(&self, id: NodeId, target: MethodTarget) {
        self.methods
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(id, target);
    }
}

#[async_trait]
impl InMemoryNodeManagerImpl for HartNodes {
    async fn init(&self, _address_space: &mut AddressSpace, _context: ServerContext) {}

    fn name(&self) -> &str {
        "hart"
    }

    fn namespaces(&self) -> Vec<NamespaceMetadata> {
        self.namespaces.clone()
    }

    async fn write(
        &self,
        context: &RequestContext,
        address_space: &UaRwLock<AddressSpace>,
        nodes_to_write: &mut [&mut WriteNode],
    ) -> Result<(), StatusCode> {
        // No variable of the gateway is written, whoever asks: devices change through
        // the methods only. The status says why (async-opcua's own check first).
        let mut space = address_space.write();
        let type_tree = context.type_tree.read();
        for w in nodes_to_write {
            let status = match space.validate_node_write(context, w.value(), &*type_tree) {
                Err(e) => e,
                Ok(_) => StatusCode::BadUserAccessDenied,
            };
            w.set_status(status);
        }
        Ok(())
    }

    async fn call(
        &self,
        context: &RequestContext,
        _address_space: &UaRwLock<AddressSpace>,
        methods_to_call: &mut [&mut &mut MethodCall],
    ) -> Result<(), StatusCode> {
        let channel = access::Channel::of_uri(context.session.read().security_policy_uri());
        let token = access::token_kind(&context.token);
        let identity = access::identity(&context.token);
        for m in methods_to_call {
            let target = self
                .methods
                .read()
                .unwrap_or_else(|e| e.into_inner())
                .get(m.method_id())
                .cloned();
            let Some(target) = target else {
                m.set_status(StatusCode::BadMethodInvalid);
                continue;
            };
            if !self.rules.may_call(channel, token) {
                tracing::warn!(
                    "opcua: {} on {} refused: {identity} on the {channel:?} endpoint may not \
                     call methods{}",
                    target.method,
                    target.device,
                    if self.rules.read_only {
                        " (--read-only)"
                    } else {
                        ""
                    }
                );
                m.set_status(StatusCode::BadUserAccessDenied);
                continue;
            }
            let caller = Caller {
                identity: identity.clone(),
                device: &target.device,
            };
            let r = call_device(
                self.engine.clone(),
                target.position,
                target.method,
                m.arguments().to_vec(),
                &caller,
            )
            .await;
            match r {
                Ok(out) => {
                    m.set_outputs(out);
                    m.set_status(StatusCode::Good);
                }
                Err(e) => m.set_status(e),
            }
        }
        Ok(())
    }
}

/// Carries a method call to the device at `position` as one of the engine's typed
/// writes (audited there, with `who`).
async fn call_device(
    engine: Engine,
    position: usize,
    method: &str,
    args: Vec<Variant>,
    who: &Caller<'_>,
) -> Result<Vec<Variant>, StatusCode> {
    let float = |i: usize| match args.get(i) {
        Some(Variant::Float(f)) if f.is_finite() => Ok(*f),
        Some(Variant::Double(f)) if f.is_finite() => Ok(*f as f32),
        _ => Err(StatusCode::BadInvalidArgument),
    };
    let op = match method {
        "SetDamping" => WriteOp::Damping(float(0)?),
        "LoopTest" => WriteOp::FixedCurrent(float(0)?),
        // The range units are kept.
        "SetRange" => WriteOp::Range {
            upper: Some(float(0)?),
            lower: Some(float(1)?),
            units: None,
        },
        "WriteTag" => match args.first() {
            Some(Variant::String(tag)) => WriteOp::Tag(tag.as_ref().to_string()),
            _ => return Err(StatusCode::BadInvalidArgument),
        },
        _ => return Err(StatusCode::BadMethodInvalid),
    };
    match engine.apply(position, &op, &who.origin(method)).await {
        Ok(_) => Ok(vec![]),
        Err(e) => {
            tracing::warn!("opcua: {method} ({}) not done: {e}", op.describe());
            Err(status_of(&e))
        }
    }
}

/// The OPC UA status of a typed write that was not done.
fn status_of(e: &WriteFailure) -> StatusCode {
    use hart_poller::{DeviceRefusal, WriteError};
    match e {
        WriteFailure::NotPermitted(_) => StatusCode::BadUserAccessDenied,
        WriteFailure::Invalid(_) => StatusCode::BadInvalidArgument,
        WriteFailure::NotReadYet(_) => StatusCode::BadWaitingForInitialData,
        WriteFailure::Link(WriteError::UnknownDevice) => StatusCode::BadNodeIdUnknown,
        WriteFailure::Link(WriteError::NoReply) => StatusCode::BadNoCommunication,
        WriteFailure::Link(WriteError::Busy) => StatusCode::BadResourceUnavailable,
        WriteFailure::Link(WriteError::BadReply(_)) => StatusCode::BadCommunicationError,
        WriteFailure::Refused { refusal, .. } => match refusal {
            DeviceRefusal::OutOfRange => StatusCode::BadOutOfRange,
            DeviceRefusal::NotWritable => StatusCode::BadNotWritable,
            DeviceRefusal::Busy => StatusCode::BadResourceUnavailable,
            DeviceRefusal::NotImplemented => StatusCode::BadNotSupported,
            DeviceRefusal::Failed => StatusCode::BadDeviceFailure,
        },
    }
}
