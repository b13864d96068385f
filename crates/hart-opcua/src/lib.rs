//! # hart-opcua
//!
//! The OPC UA front end of hartkit's gateway (on the `async-opcua` crate): every HART
//! device the polling engine knows is an object `Objects/HART/<loop>/<name>` (the long
//! tag, or the tag when the device has none, made unique in its loop) with variables
//! PV, SV, TV, QV, LoopCurrent and PercentRange (each with its EngineeringUnits, a
//! status code from the device's quality, and the source time stamp of the poll),
//! UpperRangeValue, LowerRangeValue, Damping (command 15), DeviceStatus, Quality, Tag,
//! LongTag, Manufacturer, DeviceType, DeviceId and PollingAddress, and methods WriteTag, SetRange, SetDamping and LoopTest that send
//! HART commands 18, 35, 34 and 40 ahead of the engine's polls. Subscriptions see each
//! change as the engine sees it.
//!
//! The server runs on a runtime of its own (a thread with two workers), so the gateway's
//! loops and its other front ends keep their thread.
//!
//! Access: who may connect and who may call methods follows [`access::Rules`] (users
//! and anonymous sessions by endpoint; variables are never written); client
//! certificates are trusted only from the trust list ([`trust`]); every method call let
//! through is recorded in the [`hart_access::Audit`].

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Instant, SystemTime};

use hart_poller::{DeviceImage, Engine, Quality};
use opcua::server::address_space::{MethodBuilder, ObjectBuilder, VariableBuilder};
use opcua::server::node_manager::memory::InMemoryNodeManagerBuilder;
use opcua::server::{ServerBuilder, ServerEndpoint, ServerHandle, SubscriptionCache};
use opcua::types::{
    DataTypeId, DataValue, DateTime, ExtensionObject, NodeId, ObjectId, ObjectTypeId,
    QualifiedName, StatusCode, VariableTypeId, Variant,
};

pub mod access;
pub mod connections;
mod front;
mod nodes;
pub mod sessions;
pub mod trust;
pub mod units;

pub use access::Security;
use access::{Channel, Rules};
use nodes::{HartNodeManager, HartNodes, MethodTarget};

/// The namespace of the gateway's nodes.
pub const NAMESPACE: &str = "urn:hartkit:gateway:hart";

/// Most monitored items in one subscription.
pub const MAX_MONITORED_ITEMS: usize = 50_000;

/// Settings of the OPC UA front end.
#[derive(Clone)]
pub struct Config {
    /// Address to listen on (port 4840 is OPC UA's).
    pub bind: SocketAddr,
    /// Endpoints offered.
    pub security: Security,
    /// Users (name, password) of the secure endpoint. With any, anonymous sessions
    /// only read; they need [`Security::Basic256Sha256`] or [`Security::Both`].
    pub users: Vec<(String, String)>,
    /// Where the certificate and private key are kept (made at the first start), and
    /// the trust list of client certificates (`trusted`, `rejected`; see [`trust`]).
    pub pki_dir: PathBuf,
    /// Refuse every method call (BadUserAccessDenied). An engine whose write policy
    /// is read-only makes the server read-only too; the policy's allow-list and audit
    /// apply to every call (they are the engine's, [`hart_poller::WritePolicy`]).
    pub read_only: bool,
    /// Connections, sessions and message sizes ([`connections`]).
    pub limits: connections::Limits,
}

impl std::fmt::Debug for Config {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the passwords.
        f.debug_struct("Config")
            .field("bind", &self.bind)
            .field("security", &self.security)
            .field(
                "users",
                &self
                    .users
                    .iter()
                    .map(|(u, _)| u.as_str())
                    .collect::<Vec<_>>(),
            )
            .field("pki_dir", &self.pki_dir)
            .field("read_only", &self.read_only)
            .field("limits", &self.limits)
            .finish()
    }
}

impl Config {
    /// The access rules of this configuration.
    pub fn rules(&self) -> Rules {
        Rules {
            security: self.security,
            users: !self.users.is_empty(),
            read_only: self.read_only,
        }
    }

    /// Refuses a configuration that would ignore or expose what it was given: users
    /// with security none (their passwords would travel in clear), an empty or
    /// repeated user name, an empty password, limits that would refuse every client
    /// ([`connections::Limits::check`]).
    pub fn check(&self) -> Result<(), String> {
        self.limits.check()?;
        if !self.users.is_empty() && self.security == Security::None {
            return Err(
                "users are configured but the only endpoint would be SecurityPolicy None, \
                 where a password travels in clear: choose the security basic256sha256 \
                 (users only, signed and encrypted) or both (anonymous read-only on None, \
                 users on Basic256Sha256)"
                    .into(),
            );
        }
        for (i, (u, p)) in self.users.iter().enumerate() {
            if u.is_empty() || p.is_empty() {
                return Err(format!("user {:?}: give a name and a password", u));
            }
            if self.users[..i].iter().any(|(v, _)| v == u) {
                return Err(format!("user {u:?} is given twice"));
            }
        }
        Ok(())
    }

    /// One line on what the endpoints let in, for the start-up message and the log.
    pub fn describe(&self) -> String {
        let users = match self.users.len() {
            0 => "anonymous".to_string(),
            1 => "1 user".to_string(),
            n => format!("{n} users"),
        };
        let mut s = match self.security {
            Security::None => "none, anonymous".to_string(),
            Security::Basic256Sha256 => format!("basic256sha256, {users}, trusted clients"),
            Security::Both => {
                format!("both: none anonymous read-only, basic256sha256 {users}, trusted clients")
            }
        };
        if self.read_only {
            s.push_str(", read only");
        }
        s
    }
}

/// A running OPC UA server.
pub struct OpcUaServer {
    /// The address bound.
    pub addr: SocketAddr,
    /// The endpoint URL clients use.
    pub url: String,
    handle: ServerHandle,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl OpcUaServer {
    /// Stops the server (clients are told) and waits for its thread.
    pub fn stop(mut self) {
        self.handle.cancel();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The node ids of one device's nodes.
struct DeviceNodes {
    object: NodeId,
    name: String,
}

fn var_id(ns: u16, object: &str, var: &str) -> NodeId {
    NodeId::new(ns, format!("{object}/{var}"))
}

/// The analog variables: browse name, and how to read it from the image.
type Analog = (&'static str, fn(&DeviceImage) -> (Option<f32>, Option<u8>));

const ANALOG: &[Analog] = &[
    ("PV", |d| var(d, 0)),
    ("SV", |d| var(d, 1)),
    ("TV", |d| var(d, 2)),
    ("QV", |d| var(d, 3)),
    ("LoopCurrent", |d| (d.loop_current, Some(39))),
    ("PercentRange", |d| (d.percent_range, Some(57))),
];

fn var(d: &DeviceImage, i: usize) -> (Option<f32>, Option<u8>) {
    match d.variables[i] {
        Some(v) => (Some(v.value), Some(v.units)),
        None => (None, None),
    }
}

/// The OPC UA status of a value of quality `q` (`present`: the device reported one;
/// `pending`: not polled yet).
fn status(q: Quality, present: bool, pending: bool) -> StatusCode {
    if pending {
        return StatusCode::BadWaitingForInitialData;
    }
    if !present {
        return match q {
            Quality::NoReply => StatusCode::BadNoCommunication,
            _ => StatusCode::BadWaitingForInitialData,
        };
    }
    match q {
        Quality::Good | Quality::ConfigurationChanged => StatusCode::Good,
        Quality::Stale => StatusCode::UncertainLastUsableValue,
        Quality::NoReply => StatusCode::BadNoCommunication,
        Quality::DeviceMalfunction => StatusCode::BadDeviceFailure,
        Quality::WaitingForData => StatusCode::BadWaitingForInitialData,
        Quality::LoopDisturbed => StatusCode::BadCommunicationError,
    }
}

fn source_time(d: &DeviceImage) -> DateTime {
    d.updated
        .map_or_else(DateTime::now, |t| DateTime::from(chrono_of(t)))
}

fn chrono_of(t: SystemTime) -> opcua::types::date_time::DateTimeUtc {
    opcua::types::date_time::DateTimeUtc::from(t)
}

/// Starts the server on a thread of its own; returns once it listens. Refuses a
/// configuration [`Config::check`] refuses.
pub fn start(engine: Engine, config: Config) -> Result<OpcUaServer, String> {
    config.check()?;
    let rules = Rules {
        read_only: config.read_only || !engine.write_policy().writes_possible(),
        ..config.rules()
    };
    let limits = Arc::new(config.limits.clone());
    // The public address is the front's (which bounds connections); the library
    // listens on a loopback port of its own, fed by the front ([`front`]).
    let std_listener =
        std::net::TcpListener::bind(config.bind).map_err(|e| format!("{}: {e}", config.bind))?;
    let addr = std_listener.local_addr().map_err(|e| e.to_string())?;
    let std_backend = std::net::TcpListener::bind((std::net::Ipv4Addr::LOCALHOST, 0))
        .map_err(|e| format!("a loopback port for the OPC UA server: {e}"))?;
    let backend = std_backend.local_addr().map_err(|e| e.to_string())?;
    for l in [&std_listener, &std_backend] {
        l.set_nonblocking(true).map_err(|e| e.to_string())?;
    }
    let host = addr.ip().to_string();
    let url = format!("opc.tcp://{host}:{}/", addr.port());
    let mut builder = ServerBuilder::new()
        .application_name("hartkit HART gateway")
        .application_uri("urn:hartkit:gateway")
        .product_uri("urn:hartkit")
        .host(host.clone())
        .port(addr.port())
        .pki_dir(config.pki_dir.clone())
        .certificate_path("own/cert.der")
        .private_key_path("private/private.pem")
        .create_sample_keypair(true)
        // Client certificates only from the trust list: an unknown one is refused and
        // lands in <pki>/rejected for an operator to trust (`hartkit opcua trust`).
        .trust_client_certs(false)
        // The library's own limits (connections are the front's).
        .hello_timeout(limits.handshake.as_secs_f64().ceil().max(1.0) as u32)
        .max_sessions(limits.max_sessions)
        .max_session_timeout_ms(limits.session_timeout.as_millis() as u64)
        .max_message_size(limits.max_message_size)
        .max_chunk_count(limits.max_chunk_count)
        .discovery_urls(vec![url.clone()])
        .with_authenticator(Arc::new(access::GatewayAuth::new(
            rules,
            config.users.clone(),
        )))
        .with_node_manager(InMemoryNodeManagerBuilder::new(HartNodes::builder(
            NAMESPACE,
            engine.clone(),
            rules,
        )));
    // A SCADA watching every variable of a large plant: room for 50 000 monitored items
    // in one subscription (the library's default is 1 000).
    builder
        .limits_mut()
        .subscriptions
        .max_monitored_items_per_sub = MAX_MONITORED_ITEMS;
    // The configuration's user tokens (async-opcua checks the endpoints name only
    // known ones); the passwords are checked by access::GatewayAuth.
    for (id, token) in access::user_tokens(&config.users) {
        builder = builder.add_user_token(id, token);
    }
    let mut default = None;
    if rules.offers(Channel::None) {
        let tokens = access::endpoint_token_ids(&rules, &config.users, Channel::None);
        builder = builder.add_endpoint("none", ServerEndpoint::new_none("/", &tokens));
        default = Some("none");
    }
    if rules.offers(Channel::Secure) {
        let tokens = access::endpoint_token_ids(&rules, &config.users, Channel::Secure);
        builder = builder.add_endpoint(
            "basic256sha256",
            ServerEndpoint::new_basic256sha256_sign_encrypt("/", &tokens),
        );
        default = default.or(Some("basic256sha256"));
    }
    if let Some(d) = default {
        builder = builder.default_endpoint(d);
    }
    let (server, handle) = builder.build()?;
    let manager = handle
        .node_managers()
        .get_of_type::<HartNodeManager>()
        .ok_or("the OPC UA node manager is missing")?;
    let ns = handle
        .get_namespace_index(NAMESPACE)
        .ok_or("the OPC UA namespace is missing")?;
    let subscriptions = handle.subscriptions().clone();
    let info = handle.info().clone();
    tracing::info!(
        "opcua: {url} ({}); client certificates trusted from {}; at most {} connections ({} from one address{}), {} sessions",
        config.describe(),
        trust::trusted_dir(&config.pki_dir).display(),
        limits.max_connections,
        limits.max_per_address,
        if limits.priority.is_empty() { "" } else { ", priority hosts aside" },
        limits.max_sessions,
    );
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
    let thread = std::thread::Builder::new()
        .name("opcua".into())
        .spawn(move || {
            let rt = match tokio::runtime::Builder::new_multi_thread()
                .worker_threads(2)
                .enable_all()
                .build()
            {
                Ok(rt) => rt,
                Err(e) => {
                    let _ = ready_tx.send(Err(e.to_string()));
                    return;
                }
            };
            rt.block_on(async move {
                let (listener, backend_listener) = match (
                    tokio::net::TcpListener::from_std(std_listener),
                    tokio::net::TcpListener::from_std(std_backend),
                ) {
                    (Ok(l), Ok(b)) => (l, b),
                    (Err(e), _) | (_, Err(e)) => {
                        let _ = ready_tx.send(Err(e.to_string()));
                        return;
                    }
                };
                let model = Model {
                    engine,
                    manager,
                    subscriptions,
                    ns,
                    devices: Default::default(),
                    folders: Default::default(),
                };
                model.folder_root();
                tokio::spawn(model.run());
                let public_port = addr.port();
                let server = tokio::spawn(server.run_with(backend_listener));
                // run_with takes the port of the listener it is given for the endpoint
                // URLs it gives clients: once it has, the public port again (before the
                // front admits anyone).
                let waited = Instant::now();
                while info.port.load(std::sync::atomic::Ordering::Relaxed) != backend.port()
                    && waited.elapsed() < std::time::Duration::from_secs(10)
                    && !server.is_finished()
                {
                    tokio::time::sleep(std::time::Duration::from_millis(2)).await;
                }
                info.port
                    .store(public_port, std::sync::atomic::Ordering::Relaxed);
                tokio::spawn(front::run(
                    listener,
                    backend,
                    limits,
                    Arc::new(front::Shared::default()),
                ));
                let _ = ready_tx.send(Ok(()));
                match server.await {
                    Ok(Err(e)) => tracing::error!("opcua: the server stopped: {e}"),
                    Err(e) => tracing::error!("opcua: the server stopped: {e}"),
                    Ok(Ok(())) => {}
                }
            });
        })
        .map_err(|e| e.to_string())?;
    ready_rx
        .recv()
        .map_err(|_| "the OPC UA thread ended at start".to_string())??;
    Ok(OpcUaServer {
        addr,
        url,
        handle,
        thread: Some(thread),
    })
}

/// The address space kept in step with the engine's image.
struct Model {
    engine: Engine,
    manager: Arc<HartNodeManager>,
    subscriptions: Arc<SubscriptionCache>,
    ns: u16,
    devices: HashMap<usize, DeviceNodes>,
    folders: HashMap<String, NodeId>,
}

impl Model {
    fn folder_root(&self) {
        let space = self.manager.address_space();
        let mut space = space.write();
        ObjectBuilder::new(
            &NodeId::new(self.ns, "HART"),
            QualifiedName::new(self.ns, "HART"),
            "HART",
        )
        .organized_by(ObjectId::ObjectsFolder)
        .has_type_definition(ObjectTypeId::FolderType)
        .insert(&mut *space);
    }

    /// Adds new devices and pushes every device's values: at once, on each change the
    /// engine announces, and every second (qualities age into "stale").
    async fn run(mut self) {
        let mut changes = self.engine.image().subscribe();
        let mut tick = tokio::time::interval(std::time::Duration::from_secs(1));
        loop {
            let changed: Vec<usize> = tokio::select! {
                _ = tick.tick() => (0..self.engine.image().len()).collect(),
                r = changes.recv() => match r {
                    Ok(p) => {
                        let mut v = vec![p];
                        while let Ok(p) = changes.try_recv() {
                            if !v.contains(&p) { v.push(p); }
                        }
                        v
                    }
                    Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {
                        (0..self.engine.image().len()).collect()
                    }
                    Err(_) => return,
                },
            };
            for p in changed {
                let Some(d) = self.engine.image().with(p, |d| d.clone()) else {
                    continue;
                };
                if !self.devices.contains_key(&p) {
                    // Named by its tag once identified (or by the name configured).
                    if d.info.is_none() && d.name.is_none() {
                        continue;
                    }
                    self.add_device(&d);
                }
                self.push(&d);
            }
        }
    }

    fn loop_folder(&mut self, name: &str) -> NodeId {
        if let Some(id) = self.folders.get(name) {
            return id.clone();
        }
        let id = NodeId::new(self.ns, format!("HART/{name}"));
        let space = self.manager.address_space();
        let mut space = space.write();
        ObjectBuilder::new(&id, QualifiedName::new(self.ns, name), name)
            .organized_by(NodeId::new(self.ns, "HART"))
            .has_type_definition(ObjectTypeId::FolderType)
            .insert(&mut *space);
        self.folders.insert(name.to_string(), id.clone());
        id
    }

    /// A name unique in the device's loop.
    fn unique_name(&self, d: &DeviceImage) -> String {
        let base = d.display_name().replace('/', "_");
        let taken = |n: &str| {
            self.devices.iter().any(|(p, x)| {
                x.name == n
                    && self
                        .engine
                        .image()
                        .with(*p, |o| o.loop_name == d.loop_name)
                        .unwrap_or(false)
            })
        };
        if !taken(&base) {
            return base;
        }
        (2..)
            .map(|k| format!("{base}_{k}"))
            .find(|n| !taken(n))
            .unwrap_or(base)
    }

    fn add_device(&mut self, d: &DeviceImage) {
        let folder = self.loop_folder(&d.loop_name);
        let name = self.unique_name(d);
        let path = format!("HART/{}/{}", d.loop_name, name);
        let object = NodeId::new(self.ns, path.clone());
        let ns = self.ns;
        {
            let space = self.manager.address_space();
            let mut space = space.write();
            ObjectBuilder::new(
                &object,
                QualifiedName::new(ns, name.as_str()),
                name.as_str(),
            )
            .organized_by(folder)
            .has_type_definition(ObjectTypeId::BaseObjectType)
            .insert(&mut *space);
            for (var, read) in ANALOG {
                let id = var_id(ns, &path, var);
                let (_, units) = read(d);
                VariableBuilder::new(&id, QualifiedName::new(ns, *var), *var)
                    .data_type(DataTypeId::Float)
                    .value(f32::NAN)
                    .has_type_definition(VariableTypeId::AnalogItemType)
                    .component_of(object.clone())
                    .insert(&mut *space);
                let eu = var_id(ns, &path, &format!("{var}/EngineeringUnits"));
                VariableBuilder::new(
                    &eu,
                    QualifiedName::new(0, "EngineeringUnits"),
                    "EngineeringUnits",
                )
                .data_type(DataTypeId::EUInformation)
                .value(ExtensionObject::from_message(units::eu_information(
                    units.unwrap_or(250),
                )))
                .has_type_definition(VariableTypeId::PropertyType)
                .property_of(id.clone())
                .insert(&mut *space);
            }
            let scalars: [(&str, DataTypeId); 11] = [
                ("UpperRangeValue", DataTypeId::Float),
                ("LowerRangeValue", DataTypeId::Float),
                ("Damping", DataTypeId::Float),
                ("DeviceStatus", DataTypeId::Byte),
                ("Quality", DataTypeId::String),
                ("Tag", DataTypeId::String),
                ("LongTag", DataTypeId::String),
                ("Manufacturer", DataTypeId::UInt16),
                ("DeviceType", DataTypeId::UInt16),
                ("DeviceId", DataTypeId::UInt32),
                ("PollingAddress", DataTypeId::Byte),
            ];
            for (var, ty) in scalars {
                VariableBuilder::new(&var_id(ns, &path, var), QualifiedName::new(ns, var), var)
                    .data_type(ty)
                    .has_type_definition(VariableTypeId::BaseDataVariableType)
                    .component_of(object.clone())
                    .insert(&mut *space);
            }
            let methods: [(&str, &[(&str, DataTypeId)]); 4] = [
                ("WriteTag", &[("Tag", DataTypeId::String)]),
                (
                    "SetRange",
                    &[("Upper", DataTypeId::Float), ("Lower", DataTypeId::Float)],
                ),
                ("SetDamping", &[("Seconds", DataTypeId::Float)]),
                ("LoopTest", &[("Milliamps", DataTypeId::Float)]),
            ];
            for (method, args) in methods {
                let id = var_id(ns, &path, method);
                let args: Vec<opcua::types::Argument> =
                    args.iter().map(|(n, t)| (*n, *t).into()).collect();
                MethodBuilder::new(&id, QualifiedName::new(ns, method), method)
                    .component_of(object.clone())
                    .input_args(
                        &mut *space,
                        &var_id(ns, &path, &format!("{method}/InputArguments")),
                        &args,
                    )
                    .insert(&mut *space);
            }
        }
        // Calls are checked (the session's endpoint and user) and audited by the node
        // manager, then carried out by `call`.
        for method in ["WriteTag", "SetRange", "SetDamping", "LoopTest"] {
            self.manager.inner().add_method(
                var_id(ns, &path, method),
                MethodTarget {
                    position: d.position,
                    method,
                    device: path.clone(),
                },
            );
        }
        tracing::info!("opcua: {path} added");
        self.devices
            .insert(d.position, DeviceNodes { object, name });
    }

    fn push(&self, d: &DeviceImage) {
        let Some(nodes) = self.devices.get(&d.position) else {
            return;
        };
        let path = nodes
            .object
            .identifier
            .to_string()
            .trim_start_matches("s=")
            .to_string();
        let q = d.quality(Instant::now());
        let time = source_time(d);
        let mut values: Vec<(NodeId, DataValue)> = vec![];
        let dv = |v: Variant, s: StatusCode| DataValue {
            value: Some(v),
            status: Some(s),
            source_timestamp: Some(time),
            server_timestamp: Some(DateTime::now()),
            ..Default::default()
        };
        for (var, read) in ANALOG {
            let (value, units) = read(d);
            values.push((
                var_id(self.ns, &path, var),
                dv(
                    Variant::Float(value.unwrap_or(f32::NAN)),
                    status(
                        q,
                        value.is_some_and(|v| !v.is_nan()),
                        d.last_poll == hart_poller::LastPoll::Pending,
                    ),
                ),
            ));
            if let Some(u) = units {
                values.push((
                    var_id(self.ns, &path, &format!("{var}/EngineeringUnits")),
                    dv(
                        Variant::from(ExtensionObject::from_message(units::eu_information(u))),
                        StatusCode::Good,
                    ),
                ));
            }
        }
        let info = d.info.as_ref();
        let s = |x: Option<&String>| Variant::from(x.cloned().unwrap_or_default());
        values.push((
            var_id(self.ns, &path, "DeviceStatus"),
            dv(Variant::Byte(d.device_status), StatusCode::Good),
        ));
        values.push((
            var_id(self.ns, &path, "Quality"),
            dv(Variant::from(q.name()), StatusCode::Good),
        ));
        values.push((
            var_id(self.ns, &path, "Tag"),
            dv(s(info.and_then(|i| i.tag.as_ref())), StatusCode::Good),
        ));
        values.push((
            var_id(self.ns, &path, "LongTag"),
            dv(s(info.and_then(|i| i.long_tag.as_ref())), StatusCode::Good),
        ));
        if let Some(i) = info {
            values.push((
                var_id(self.ns, &path, "Manufacturer"),
                dv(Variant::UInt16(i.manufacturer_id()), StatusCode::Good),
            ));
            values.push((
                var_id(self.ns, &path, "DeviceType"),
                dv(
                    Variant::UInt16(i.identity.expanded_device_type),
                    StatusCode::Good,
                ),
            ));
            values.push((
                var_id(self.ns, &path, "DeviceId"),
                dv(
                    Variant::UInt32(i.identity.device_id.get()),
                    StatusCode::Good,
                ),
            ));
        }
        if let Some(r) = d.range {
            values.push((
                var_id(self.ns, &path, "UpperRangeValue"),
                dv(Variant::Float(r.upper), StatusCode::Good),
            ));
            values.push((
                var_id(self.ns, &path, "LowerRangeValue"),
                dv(Variant::Float(r.lower), StatusCode::Good),
            ));
            values.push((
                var_id(self.ns, &path, "Damping"),
                dv(Variant::Float(r.damping), StatusCode::Good),
            ));
        }
        if let Some(p) = d.polling_address {
            values.push((
                var_id(self.ns, &path, "PollingAddress"),
                dv(Variant::Byte(p), StatusCode::Good),
            ));
        }
        let r = self.manager.set_values(
            &self.subscriptions,
            values.iter().map(|(id, v)| (id, None, v.clone())),
        );
        if let Err(e) = r {
            tracing::warn!("opcua: updating {path}: {e}");
        }
    }
}
