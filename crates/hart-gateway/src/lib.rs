//! # hart-gateway
//!
//! A HART-IP server (UDP and TCP, port 5094) in front of a HART loop: sessions with a
//! limit and an inactivity timer, keep-alive, token-passing PDUs forwarded to the
//! devices on the loop, direct PDUs answered by the server itself, burst frames
//! published to every session, a read-only mode, and a read audit log.
//!
//! Every session is independent: a malformed message closes (TCP) or is refused
//! (UDP) for its own session only. The loop is reached through a
//! `hart_host::Client`, one transaction at a time, by a single backend task.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_host::target::AnyTransport;
use hart_host::Client;
use hart_ip::{encode, status, Body, Header, Message, MessageId, MessageType, HEADER_LEN};
use hart_link::master::RetryPolicy;
use hart_proto::frame::{Frame, FrameSpec, FrameType};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream, UdpSocket};
use tokio::sync::{broadcast, mpsc, Mutex};

pub mod mux;
use mux::LoopRequest;
pub use mux::{GatewayIdentity, Mux, Route, SubDevice};

/// Server settings.
#[derive(Debug, Clone)]
pub struct Config {
    /// Address to listen on (UDP and TCP).
    pub bind: SocketAddr,
    /// Serve UDP.
    pub udp: bool,
    /// Serve TCP.
    pub tcp: bool,
    /// Most sessions at once (UDP and TCP together).
    pub max_sessions: usize,
    /// Refuse every command that changes a device ("access restricted").
    pub read_only: bool,
    /// Scan each loop's polling addresses 0..=N at start (for routing by long address
    /// and command 84); `None` skips the scan.
    pub scan_to: Option<u8>,
    /// The gateway's own identity.
    pub identity: GatewayIdentity,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            bind: "127.0.0.1:5094".parse().unwrap(),
            udp: true,
            tcp: true,
            max_sessions: 64,
            read_only: false,
            scan_to: Some(15),
            identity: GatewayIdentity::default(),
        }
    }
}

/// Shortest inactivity timer the server accepts, ms.
pub const MIN_TIMER_MS: u32 = 1000;

/// Counters for the audit log and tests.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Stats {
    /// Sessions opened.
    pub sessions_opened: u64,
    /// Sessions refused (limit reached, bad initiate).
    pub sessions_refused: u64,
    /// Token-passing requests forwarded.
    pub forwarded: u64,
    /// Publish messages sent.
    pub published: u64,
    /// Malformed messages.
    pub malformed: u64,
}

struct Shared {
    config: Config,
    sessions: Mutex<usize>,
    stats: Mutex<Stats>,
    mux: Mux,
    bursts: broadcast::Sender<Vec<u8>>,
    audit: Mutex<AuditLog>,
    power_up: u64,
}

/// A running server.
pub struct Server {
    /// UDP address actually bound.
    pub udp_addr: Option<SocketAddr>,
    /// TCP address actually bound.
    pub tcp_addr: Option<SocketAddr>,
    shared: Arc<Shared>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

impl Server {
    /// Stops serving: every task ends and the sockets close.
    pub fn stop(self) {
        for t in &self.tasks {
            t.abort();
        }
    }

    /// Counters so far.
    pub async fn stats(&self) -> Stats {
        *self.shared.stats.lock().await
    }

    /// Sessions open now (UDP and TCP).
    pub async fn active_sessions(&self) -> usize {
        *self.shared.sessions.lock().await
    }
}

/// Starts the server with `client` reaching the loop; returns once the sockets are
/// bound. The server runs on local tasks: call it inside a `tokio::task::LocalSet`
/// (the loop's client is not `Send`: serial ports and simulated plants stay on one
/// thread).
pub async fn start(config: Config, loops: Vec<Client<AnyTransport>>) -> std::io::Result<Server> {
    let mut senders = vec![];
    let mut receivers = vec![];
    for _ in 0..loops.len() {
        let (tx, rx) = mpsc::channel::<LoopRequest>(256);
        senders.push(tx);
        receivers.push(rx);
    }
    let scan_to = config.scan_to;
    start_with(config, senders, move |bursts, subs| {
        loops
            .into_iter()
            .zip(receivers)
            .enumerate()
            .map(|(channel, (client, rx))| {
                tokio::task::spawn_local(backend(
                    client,
                    channel as u8,
                    scan_to,
                    subs.clone(),
                    rx,
                    bursts.clone(),
                ))
            })
            .collect()
    })
    .await
}

/// Starts the sockets with loop request queues `senders`, whose consumers `spawn`
/// starts.
async fn start_with(
    config: Config,
    senders: Vec<mpsc::Sender<LoopRequest>>,
    spawn: impl FnOnce(
        broadcast::Sender<Vec<u8>>,
        Arc<Mutex<Vec<SubDevice>>>,
    ) -> Vec<tokio::task::JoinHandle<()>>,
) -> std::io::Result<Server> {
    let (bursts, _) = broadcast::channel(64);
    let subs = Arc::new(Mutex::new(vec![]));
    let mut tasks = spawn(bursts.clone(), subs.clone());
    let mux = Mux {
        identity: config.identity.clone(),
        loops: senders,
        subs,
    };
    let shared = Arc::new(Shared {
        config: config.clone(),
        sessions: Mutex::new(0),
        stats: Mutex::new(Stats::default()),
        mux,
        bursts: bursts.clone(),
        audit: Mutex::new(AuditLog::default()),
        power_up: unix_now(),
    });
    let mut udp_addr = None;
    let mut tcp_addr = None;
    if config.udp {
        let sock = Arc::new(UdpSocket::bind(config.bind).await?);
        udp_addr = Some(sock.local_addr()?);
        tasks.push(tokio::task::spawn_local(serve_udp(sock, shared.clone())));
    }
    if config.tcp {
        let bind = match udp_addr {
            Some(a) if config.bind.port() == 0 => a,
            _ => config.bind,
        };
        let listener = TcpListener::bind(bind).await?;
        tcp_addr = Some(listener.local_addr()?);
        tasks.push(tokio::task::spawn_local(serve_tcp(
            listener,
            shared.clone(),
        )));
    }
    Ok(Server {
        udp_addr,
        tcp_addr,
        shared,
        tasks,
    })
}

/// Starts the server with field devices answered in memory, without a simulated line
/// (for benchmarks and tests of the server itself): requests are answered by the
/// device with that address at once; burst messages are published when due. Call it
/// inside a `tokio::task::LocalSet`.
pub async fn start_in_memory(
    config: Config,
    devices: Vec<hart_device::Device>,
) -> std::io::Result<Server> {
    let (tx, rx) = mpsc::channel::<LoopRequest>(1024);
    let server = start_with(config, vec![tx], |bursts, subs| {
        vec![tokio::task::spawn_local(memory_backend(
            devices, subs, rx, bursts,
        ))]
    })
    .await?;
    Ok(server)
}

async fn memory_backend(
    mut devices: Vec<hart_device::Device>,
    subs: Arc<Mutex<Vec<SubDevice>>>,
    mut requests: mpsc::Receiver<LoopRequest>,
    bursts: broadcast::Sender<Vec<u8>>,
) {
    use hart_link::slave::Handler;
    use hart_proto::frame::Address;
    let start = Instant::now();
    let now = || start.elapsed().as_micros() as u64;
    {
        let mut s = subs.lock().await;
        for d in &devices {
            let c = d.config();
            let identity = d.identity();
            s.push(SubDevice {
                channel: 0,
                info: hart_host::DeviceInfo {
                    polling_address: Some(c.polling_address),
                    identity,
                    tag: Some(c.tag.clone()),
                    descriptor: Some(c.descriptor.clone()),
                    long_tag: Some(c.long_tag.clone()),
                },
            });
        }
    }
    loop {
        let req = tokio::select! {
            r = requests.recv() => match r { Some(r) => Some(r), None => return },
            _ = tokio::time::sleep(Duration::from_millis(20)) => None,
        };
        let t = now();
        if let Some(r) = req {
            let reply = Frame::parse_pdu(&r.pdu).ok().and_then(|f| {
                let d = devices.iter_mut().find(|d| {
                    let c = d.config();
                    match f.address {
                        Address::Short(a) => a.polling_address == c.polling_address,
                        Address::Long(a) => {
                            a.id == d.unique_id()
                                || (a.id.is_broadcast() && matches!(f.command, 11 | 21))
                        }
                    }
                })?;
                let (code, status, data) = d.handle(&f, t)?;
                Some(pdu(&FrameSpec {
                    frame_type: FrameType::Ack,
                    extended: f.extended,
                    status: Some((code, status)),
                    ..FrameSpec::request(f.address.with_burst(d.burst_mode()), f.command, &data)
                }))
            });
            let _ = r.reply.send(reply);
        }
        // Burst messages that are due.
        for d in &mut devices {
            if d.burst_mode() && d.burst_due(t).is_some_and(|due| due <= t) {
                let mut reply = hart_link::slave::Reply::default();
                let command = d.burst(&mut reply, t);
                let id = d.unique_id();
                let _ = bursts.send(pdu(&FrameSpec {
                    frame_type: FrameType::Back,
                    status: Some((reply.response_code, reply.device_status)),
                    extended: command > 255,
                    ..FrameSpec::request(Address::long(id).with_burst(true), command, reply.data())
                }));
            }
        }
    }
}

/// The one task that talks to a loop: requests in turn; between them, one polling
/// address of the scan at a time (so requests never wait long) and listening for
/// burst frames.
async fn backend(
    mut client: Client<AnyTransport>,
    channel: u8,
    scan_to: Option<u8>,
    subs: Arc<Mutex<Vec<SubDevice>>>,
    mut requests: mpsc::Receiver<LoopRequest>,
    bursts: broadcast::Sender<Vec<u8>>,
) {
    let mut next_scan = scan_to.map(|_| 0u8);
    loop {
        let req = match requests.try_recv() {
            Ok(r) => Some(r),
            Err(mpsc::error::TryRecvError::Disconnected) => return,
            Err(mpsc::error::TryRecvError::Empty) if next_scan.is_some() => None,
            Err(mpsc::error::TryRecvError::Empty) => tokio::select! {
                r = requests.recv() => match r { Some(r) => Some(r), None => return },
                _ = tokio::time::sleep(Duration::from_millis(20)) => None,
            },
        };
        match (req, next_scan) {
            (Some(r), _) => {
                let reply = client.forward(&r.pdu).await.ok();
                if let Some(reply) = &reply {
                    learn(&subs, channel, &r.pdu, reply).await;
                }
                let _ = r.reply.send(reply);
            }
            (None, Some(poll)) => {
                // One retry only: an empty address must not hold the line (and the
                // requests queued behind it) for four slave time-outs.
                client.set_policy(RetryPolicy {
                    retries: 1,
                    ..RetryPolicy::default()
                });
                let found = client.identify(poll).await;
                client.set_policy(RetryPolicy::default());
                if let Ok(mut info) = found {
                    if info.revision() >= 6 {
                        if let Ok(r) = client.command(&info, 20, &[]).await {
                            info.long_tag = Some(
                                hart_proto::types::Latin1String::<32>(
                                    r.data
                                        .get(..32)
                                        .and_then(|b| b.try_into().ok())
                                        .unwrap_or([0; 32]),
                                )
                                .to_string(),
                            );
                        }
                    }
                    remember(&subs, SubDevice { channel, info }).await;
                }
                next_scan = (poll < scan_to.unwrap_or(0).min(63)).then_some(poll + 1);
            }
            (None, None) => {
                let _ = client.listen(20_000).await;
            }
        }
        for b in client.take_bursts() {
            let _ = bursts.send(b);
        }
    }
}

/// Adds a sub-device, or updates the one with the same unique ID.
async fn remember(subs: &Mutex<Vec<SubDevice>>, sub: SubDevice) {
    let mut subs = subs.lock().await;
    match subs
        .iter_mut()
        .find(|s| s.info.unique_id() == sub.info.unique_id())
    {
        Some(s) => {
            let old = std::mem::replace(s, sub);
            // Keep what the new sighting did not learn.
            s.info.polling_address = s.info.polling_address.or(old.info.polling_address);
            s.info.tag = s.info.tag.take().or(old.info.tag);
            s.info.descriptor = s.info.descriptor.take().or(old.info.descriptor);
            s.info.long_tag = s.info.long_tag.take().or(old.info.long_tag);
        }
        None => subs.push(sub),
    }
}

/// Learns sub-devices from the identity replies (commands 0, 11 and 21) that clients'
/// requests bring back, so devices connected after the start-up scan are routed too.
async fn learn(subs: &Mutex<Vec<SubDevice>>, channel: u8, request: &[u8], reply: &[u8]) {
    use hart_proto::wire::{Reader, Wire};
    let (Ok(req), Ok(rep)) = (Frame::parse_pdu(request), Frame::parse_pdu(reply)) else {
        return;
    };
    if !matches!(rep.command, 0 | 11 | 21) || rep.response_code.unwrap_or(0xFF) != 0 {
        return;
    }
    let Ok(identity) = hart_proto::command::Identity::decode(&mut Reader::new(rep.data)) else {
        return;
    };
    let polling_address = match req.address {
        hart_proto::frame::Address::Short(a) => Some(a.polling_address),
        hart_proto::frame::Address::Long(_) => None,
    };
    let info = hart_host::DeviceInfo {
        polling_address,
        identity,
        tag: None,
        descriptor: None,
        long_tag: None,
    };
    remember(subs, SubDevice { channel, info }).await;
}

fn message(ty: MessageType, id: MessageId, st: u8, seq: u16, body: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; HEADER_LEN + body.len()];
    let _ = encode(1, ty, id, st, seq, body, &mut out);
    out
}

/// The PDU of `spec` (no preambles, as HART-IP carries it); empty if it cannot be
/// encoded.
fn pdu(spec: &FrameSpec<'_>) -> Vec<u8> {
    hart_proto::frame::FrameBuf::encode(spec).map_or_else(|_| vec![], |b| b.as_slice().to_vec())
}

/// The gateway's own reply to a request frame: response code `code` and `data` (left
/// out for error codes), the field device status 0.
fn local_frame(f: &Frame<'_>, code: u8, data: &[u8]) -> Vec<u8> {
    let data =
        if hart_proto::tables::response_class(code) == hart_proto::tables::ResponseClass::Error {
            &[][..]
        } else {
            data
        };
    pdu(&FrameSpec {
        frame_type: FrameType::Ack,
        extended: f.extended,
        status: Some((code, 0)),
        ..FrameSpec::request(f.address, f.command, data)
    })
}

/// What to do with one received message of a session.
enum Action {
    Reply(Vec<u8>),
    ReplyAndClose(Vec<u8>),
    Close,
    /// Forward a token-passing request to a loop and answer with sequence number `seq`
    /// when the reply comes (over TCP, other requests and publish messages go on
    /// meanwhile).
    Forward {
        channel: usize,
        pdu: Vec<u8>,
        seq: u16,
    },
}

/// Waits for a loop's reply to a forwarded request and builds the response message:
/// the reply PDU with status 0, or an empty response with status 6 when the device did
/// not answer (so the client stops waiting at once).
async fn forwarded(shared: &Shared, channel: usize, pdu: Vec<u8>, seq: u16) -> Vec<u8> {
    let (st, body) = match shared.mux.forward(channel, pdu).await {
        Some(reply) => (status::SUCCESS, reply),
        None => (status::DEVICE_SPECIFIC, vec![]),
    };
    message(
        MessageType::Response,
        MessageId::TokenPassingPdu,
        st,
        seq,
        &body,
    )
}

/// Publish-message subscription flags (command 533).
pub mod subscription {
    /// Process data (burst messages).
    pub const PROCESS_DATA: u16 = 0x0001;
    /// Event notifications.
    pub const EVENT_NOTIFICATION: u16 = 0x0002;
    /// Device status.
    pub const DEVICE_STATUS: u16 = 0x0004;
    /// Device configuration.
    pub const DEVICE_CONFIGURATION: u16 = 0x0008;
}

/// A session's publish subscriptions: `None` until the client writes one with command
/// 533 (every burst message is published to it then, as HART-IP clients that predate
/// subscriptions expect); then the list of (target, flags), where the all-zero unique
/// ID stands for every device and excludes entries for single devices.
type Subscriptions = Option<Vec<([u8; 5], u16)>>;

/// Whether a burst frame goes to a session with `subs`.
fn subscribed(subs: &Subscriptions, pdu: &[u8]) -> bool {
    let Some(list) = subs else {
        return true;
    };
    let Ok(f) = Frame::parse_pdu(pdu) else {
        return false;
    };
    let id = match f.address {
        hart_proto::frame::Address::Long(a) => Some(a.id.to_bytes()),
        hart_proto::frame::Address::Short(_) => None,
    };
    list.iter().any(|(t, _)| *t == [0; 5] || Some(*t) == id)
}

/// Commands 532 (read client subscription summary) and 533 (write client subscription
/// flags), answered by the server for the session: request data is the target unique
/// ID (5 bytes, all zero for every device), for 533 followed by the flags (u16); the
/// reply data is the unique ID and the flags. Response codes: 5 too few data bytes, 9
/// individual subscription not allowed (a subscription to every device is in place),
/// 65 unknown unique ID (no such sub-device, or no subscription to read).
async fn subscription_command(
    shared: &Shared,
    subs: &mut Subscriptions,
    command: u16,
    data: &[u8],
) -> (u8, Vec<u8>) {
    use hart_proto::tables::rc;
    let need = if command == 533 { 7 } else { 5 };
    if data.len() < need {
        return (rc::TOO_FEW_DATA_BYTES, vec![]);
    }
    let mut target = [0u8; 5];
    target.copy_from_slice(&data[..5]);
    // The burst and master bits are not part of the device's identity.
    target[0] &= 0x3F;
    let all = target == [0; 5];
    let same = |t: &[u8; 5]| *t == target;
    let list = subs.get_or_insert_with(|| vec![([0; 5], subscription::PROCESS_DATA)]);
    let broadcast_in_place = list.iter().any(|(t, _)| *t == [0; 5]);
    if command == 532 {
        if broadcast_in_place && !all {
            return (INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED, vec![]);
        }
        return match list.iter().find(|(t, _)| same(t) || *t == [0; 5]) {
            Some((t, flags)) => {
                let mut d = t.to_vec();
                d.extend(flags.to_be_bytes());
                (rc::SUCCESS, d)
            }
            None => (UNKNOWN_UNIQUE_ID, vec![]),
        };
    }
    let flags = u16::from_be_bytes([data[5], data[6]]);
    if all {
        list.clear();
        if flags != 0 {
            list.push(([0; 5], flags));
        }
    } else {
        if broadcast_in_place {
            return (INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED, vec![]);
        }
        let known = shared
            .mux
            .subs
            .lock()
            .await
            .iter()
            .any(|s| same(&s.info.unique_id().to_bytes()));
        if !known && !list.iter().any(|(t, _)| same(t)) {
            return (UNKNOWN_UNIQUE_ID, vec![]);
        }
        list.retain(|(t, _)| !same(t));
        if flags != 0 {
            list.push((target, flags));
        }
    }
    let mut d = target.to_vec();
    d.extend(flags.to_be_bytes());
    (rc::SUCCESS, d)
}

/// Response code of commands 532/533: a subscription to every device is in place.
const INDIVIDUAL_SUBSCRIPTION_NOT_ALLOWED: u8 = 9;
/// Response code of commands 532/533: no such sub-device, or no subscription to read.
const UNKNOWN_UNIQUE_ID: u8 = 65;

/// Session state shared by UDP and TCP.
struct Session {
    open: bool,
    timer: Duration,
    last_rx: Instant,
    publish_seq: u16,
    peer: SocketAddr,
    local_port: u16,
    /// Number of this session's audit record.
    audit: Option<u64>,
    /// Publish subscriptions (commands 532/533).
    subs: Subscriptions,
}

/// Audit records kept: the newest sessions, oldest dropped first. Read Audit Log
/// addresses records with one byte, so a client can reach at most 256 anyway.
pub const AUDIT_RECORDS: usize = 128;

/// The newest [`AUDIT_RECORDS`] session records; record 0 of a read is the oldest kept.
#[derive(Default)]
struct AuditLog {
    records: std::collections::VecDeque<AuditRecord>,
    /// Number of the oldest record kept (records are numbered from 0 at power-up).
    first: u64,
}

impl AuditLog {
    fn push(&mut self, r: AuditRecord) -> u64 {
        if self.records.len() == AUDIT_RECORDS {
            self.records.pop_front();
            self.first += 1;
        }
        self.records.push_back(r);
        self.first + self.records.len() as u64 - 1
    }

    /// The record numbered `n`, while it is still kept.
    fn get_mut(&mut self, n: u64) -> Option<&mut AuditRecord> {
        let i = usize::try_from(n.checked_sub(self.first)?).ok()?;
        self.records.get_mut(i)
    }
}

/// One session in the audit log (58 bytes on the wire).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AuditRecord {
    /// Client address.
    pub client: SocketAddr,
    /// Server port.
    pub server_port: u16,
    /// Connect time, s since 1970.
    pub connected: u64,
    /// Disconnect time, s since 1970 (0 while open).
    pub disconnected: u64,
    /// Session status bits: 0x0001 writes occurred, 0x0002 bad session initialization,
    /// 0x0004 aborted session, 0x0008 session timeout, 0x0010 insecure session.
    pub status: u16,
    /// Publish PDUs sent.
    pub publishes: u32,
    /// Request PDUs received.
    pub requests: u32,
    /// Response PDUs sent.
    pub responses: u32,
}

impl AuditRecord {
    fn bytes(&self) -> [u8; 58] {
        let mut b = [0u8; 58];
        match self.client.ip() {
            std::net::IpAddr::V4(a) => b[0..4].copy_from_slice(&a.octets()),
            std::net::IpAddr::V6(a) => b[4..20].copy_from_slice(&a.octets()),
        }
        b[20..22].copy_from_slice(&self.client.port().to_be_bytes());
        b[22..24].copy_from_slice(&self.server_port.to_be_bytes());
        b[24..32].copy_from_slice(&self.connected.to_be_bytes());
        b[32..40].copy_from_slice(&self.disconnected.to_be_bytes());
        b[40..42].copy_from_slice(&self.status.to_be_bytes());
        // 42..46: configuration change counts at start and end (not tracked: 0).
        b[46..50].copy_from_slice(&self.publishes.to_be_bytes());
        b[50..54].copy_from_slice(&self.requests.to_be_bytes());
        b[54..58].copy_from_slice(&self.responses.to_be_bytes());
        b
    }
}

/// Aborts a task when dropped (children of a server task end with it).
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

fn unix_now() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

impl Session {
    fn new(peer: SocketAddr, local_port: u16) -> Self {
        Session {
            open: false,
            timer: Duration::from_secs(60),
            last_rx: Instant::now(),
            publish_seq: 0,
            peer,
            local_port,
            audit: None,
            subs: None,
        }
    }
}

async fn handle(shared: &Shared, s: &mut Session, h: Header, body: &[u8]) -> Action {
    s.last_rx = Instant::now();
    if h.message_type != MessageType::Request || h.reserved != 0 {
        shared.stats.lock().await.malformed += 1;
        return Action::Close;
    }
    let reply = |st: u8, b: &[u8]| message(MessageType::Response, h.message_id, st, h.sequence, b);
    match h.message_id {
        MessageId::SessionInitiate => {
            if body.len() < 5 {
                shared.stats.lock().await.sessions_refused += 1;
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            }
            let master = body[0];
            if master > 1 {
                shared.stats.lock().await.sessions_refused += 1;
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            let asked = u32::from_be_bytes([body[1], body[2], body[3], body[4]]);
            if !s.open {
                let mut n = shared.sessions.lock().await;
                if *n >= shared.config.max_sessions {
                    shared.stats.lock().await.sessions_refused += 1;
                    return Action::Reply(reply(status::ALL_SESSIONS_IN_USE, &[]));
                }
                *n += 1;
                s.open = true;
                shared.stats.lock().await.sessions_opened += 1;
                // Every HART-IP v1 session is an insecure session (0x0010).
                s.audit = Some(shared.audit.lock().await.push(AuditRecord {
                    client: s.peer,
                    server_port: s.local_port,
                    connected: unix_now(),
                    disconnected: 0,
                    status: 0x0010,
                    publishes: 0,
                    requests: 0,
                    responses: 0,
                }));
            }
            let timer = asked.max(MIN_TIMER_MS);
            s.timer = Duration::from_millis(u64::from(timer));
            let mut st = if timer != asked {
                status::SET_TO_NEAREST
            } else {
                status::SUCCESS
            };
            if h.version != 1 {
                st = status::VERSION_NOT_SUPPORTED;
            }
            Action::Reply(reply(st, &hart_ip::session_initiate_body(master, timer)))
        }
        _ if !s.open => Action::Close,
        MessageId::SessionClose => Action::ReplyAndClose(reply(status::SUCCESS, &[])),
        MessageId::KeepAlive => Action::Reply(reply(status::SUCCESS, &[])),
        MessageId::TokenPassingPdu => {
            if let Some(i) = s.audit {
                if let Some(r) = shared.audit.lock().await.get_mut(i) {
                    r.requests += 1;
                    r.responses += 1;
                    if Frame::parse_pdu(body).is_ok_and(|f| {
                        hart_proto::command::info(f.command).is_some_and(|c| c.writes)
                    }) && !shared.config.read_only
                    {
                        r.status |= 0x0001;
                    }
                }
            }
            let Ok(f) = Frame::parse_pdu(body) else {
                shared.stats.lock().await.malformed += 1;
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            if f.frame_type() != FrameType::Stx {
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            if shared.config.read_only
                && hart_proto::command::info(f.command).is_some_and(|i| i.writes)
            {
                return Action::Reply(reply(
                    status::SUCCESS,
                    &local_frame(&f, hart_proto::tables::rc::ACCESS_RESTRICTED, &[]),
                ));
            }
            if matches!(f.command, 532 | 533) {
                // Subscriptions belong to this session: the server answers them whatever
                // the address.
                let (code, data) =
                    subscription_command(shared, &mut s.subs, f.command, f.data).await;
                return Action::Reply(reply(status::SUCCESS, &local_frame(&f, code, &data)));
            }
            let route = shared.mux.route(&f).await;
            match route {
                Route::Local => {
                    let (code, data) = shared.mux.local(f.command, f.data).await;
                    Action::Reply(reply(status::SUCCESS, &local_frame(&f, code, &data)))
                }
                Route::Loop(channel) => {
                    shared.stats.lock().await.forwarded += 1;
                    Action::Forward {
                        channel,
                        pdu: body.to_vec(),
                        seq: h.sequence,
                    }
                }
                Route::Nowhere => Action::Reply(reply(status::DEVICE_SPECIFIC, &[])),
            }
        }
        MessageId::DirectPdu => {
            let Ok(Body::Direct { entries, .. }) = Body::parse(h.message_id, h.message_type, body)
            else {
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            // Commands to the gateway itself, each answered in turn.
            let mut out = vec![0u8, 0u8];
            for e in hart_ip::DirectEntries(entries).flatten() {
                let (code, data) = shared.mux.local(e.command, e.data).await;
                let data = if hart_proto::tables::response_class(code)
                    == hart_proto::tables::ResponseClass::Error
                {
                    vec![]
                } else {
                    data
                };
                out.extend_from_slice(&e.command.to_be_bytes());
                out.push((1 + data.len()).min(255) as u8);
                out.push(code);
                out.extend_from_slice(&data[..data.len().min(254)]);
            }
            Action::Reply(reply(status::SUCCESS, &out))
        }
        MessageId::ReadAuditLog => {
            let (start, count) = match Body::parse(h.message_id, h.message_type, body) {
                Ok(Body::AuditLogRequest { start, count }) => (start, count),
                _ => return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[])),
            };
            let audit = shared.audit.lock().await;
            let records: Vec<&AuditRecord> = audit
                .records
                .iter()
                .skip(usize::from(start))
                .take(usize::from(count))
                .collect();
            let mut out = vec![start, records.len() as u8];
            out.extend(shared.power_up.to_be_bytes());
            out.extend(0u64.to_be_bytes()); // last security change: never
            out.extend(0u16.to_be_bytes()); // server status: no syslog in use
            out.extend(58u16.to_be_bytes());
            for r in records {
                out.extend(r.bytes());
            }
            Action::Reply(reply(status::SUCCESS, &out))
        }
        MessageId::Other(_) => {
            shared.stats.lock().await.malformed += 1;
            Action::Reply(message(
                MessageType::Nak,
                h.message_id,
                status::INVALID_SELECTION,
                h.sequence,
                &[],
            ))
        }
    }
}

/// Ends a session; `why` goes into its audit record (0 normal, 0x0004 aborted,
/// 0x0008 timed out).
async fn close_session(shared: &Shared, s: &mut Session, why: u16) {
    if s.open {
        s.open = false;
        if let Some(r) = s.audit {
            if let Some(rec) = shared.audit.lock().await.get_mut(r) {
                rec.disconnected = unix_now();
                rec.status |= why;
            }
        }
        let mut n = shared.sessions.lock().await;
        *n = n.saturating_sub(1);
    }
}

/// UDP sessions by client address. Each session has its own lock, so datagrams from
/// one client are handled one after another, in the order they arrived, while other
/// clients' requests go on. Lock order: a session, then the table.
type UdpSessions = Arc<Mutex<HashMap<SocketAddr, Arc<Mutex<Session>>>>>;

/// Drops a closed session from the table unless another task still holds it (that task
/// may reopen it, or the next sweep drops it).
async fn forget_udp_session(sessions: &UdpSessions, peer: SocketAddr, cell: &Arc<Mutex<Session>>) {
    let mut map = sessions.lock().await;
    if map.get(&peer).is_some_and(|c| Arc::ptr_eq(c, cell)) && Arc::strong_count(cell) == 2 {
        map.remove(&peer);
    }
}

async fn serve_udp(sock: Arc<UdpSocket>, shared: Arc<Shared>) {
    let local_port = sock.local_addr().map_or(0, |a| a.port());
    let sessions: UdpSessions = Arc::new(Mutex::new(HashMap::new()));
    // Publish bursts and close idle sessions.
    let _publisher = {
        let (sock, shared, sessions) = (sock.clone(), shared.clone(), sessions.clone());
        AbortOnDrop(tokio::task::spawn_local(async move {
            let mut bursts = shared.bursts.subscribe();
            loop {
                let burst = tokio::select! {
                    b = bursts.recv() => b.ok(),
                    _ = tokio::time::sleep(Duration::from_millis(200)) => None,
                };
                let mut idle = vec![];
                for (peer, cell) in sessions.lock().await.iter() {
                    // A session busy with a request is not idle.
                    if let Ok(s) = cell.try_lock() {
                        if !s.open || s.last_rx.elapsed() > s.timer {
                            idle.push((*peer, cell.clone()));
                            continue;
                        }
                    }
                    if let Some(b) = &burst {
                        // Each session gets its publish message after the reply it is
                        // working on, without holding up the others.
                        let (sock, shared, cell, b) =
                            (sock.clone(), shared.clone(), cell.clone(), b.clone());
                        let peer = *peer;
                        tokio::task::spawn_local(async move {
                            let mut s = cell.lock().await;
                            if !s.open || !subscribed(&s.subs, &b) {
                                return;
                            }
                            s.publish_seq = s.publish_seq.wrapping_add(1);
                            let m = message(
                                MessageType::Publish,
                                MessageId::TokenPassingPdu,
                                0,
                                s.publish_seq,
                                &b,
                            );
                            let _ = sock.send_to(&m, peer).await;
                            shared.stats.lock().await.published += 1;
                            if let Some(r) = s.audit {
                                if let Some(rec) = shared.audit.lock().await.get_mut(r) {
                                    rec.publishes += 1;
                                }
                            }
                        });
                    }
                }
                for (peer, cell) in idle {
                    {
                        let mut s = cell.lock().await;
                        if s.open && s.last_rx.elapsed() <= s.timer {
                            continue; // a request came in meanwhile
                        }
                        close_session(&shared, &mut s, 0x0008).await;
                    }
                    forget_udp_session(&sessions, peer, &cell).await;
                }
            }
        }))
    };
    let mut buf = vec![0u8; 65536];
    loop {
        let Ok((n, peer)) = sock.recv_from(&mut buf).await else {
            continue;
        };
        let data = buf[..n].to_vec();
        let (sock, shared, sessions) = (sock.clone(), shared.clone(), sessions.clone());
        tokio::task::spawn_local(udp_datagram(sock, shared, sessions, peer, local_port, data));
    }
}

async fn udp_datagram(
    sock: Arc<UdpSocket>,
    shared: Arc<Shared>,
    sessions: UdpSessions,
    peer: SocketAddr,
    local_port: u16,
    data: Vec<u8>,
) {
    let cell = sessions
        .lock()
        .await
        .entry(peer)
        .or_insert_with(|| Arc::new(Mutex::new(Session::new(peer, local_port))))
        .clone();
    let mut s = cell.lock().await;
    let mut rest = &data[..];
    while !rest.is_empty() {
        let (h, body, used) = match Message::parse(rest) {
            Ok((m, used)) => (m.header, m.body.to_vec(), used),
            Err(_) => {
                shared.stats.lock().await.malformed += 1;
                break;
            }
        };
        rest = &rest[used..];
        let action = handle(&shared, &mut s, h, &body).await;
        let why = match action {
            Action::Reply(r) => {
                let _ = sock.send_to(&r, peer).await;
                if s.open {
                    continue;
                }
                0x0004
            }
            Action::Forward { channel, pdu, seq } => {
                // In order, per client: the session waits for its loop's reply.
                let r = forwarded(&shared, channel, pdu, seq).await;
                let _ = sock.send_to(&r, peer).await;
                continue;
            }
            Action::ReplyAndClose(r) => {
                let _ = sock.send_to(&r, peer).await;
                0
            }
            Action::Close => 0x0004,
        };
        close_session(&shared, &mut s, why).await;
        break;
    }
    let open = s.open;
    if open {
        // Back in the table if a sweep dropped it while this datagram waited.
        sessions
            .lock()
            .await
            .entry(peer)
            .or_insert_with(|| cell.clone());
    }
    drop(s);
    if !open {
        forget_udp_session(&sessions, peer, &cell).await;
    }
}

async fn serve_tcp(listener: TcpListener, shared: Arc<Shared>) {
    // Sessions end with the server.
    let mut sessions: Vec<AbortOnDrop> = vec![];
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            continue;
        };
        let _ = stream.set_nodelay(true);
        sessions.retain(|s: &AbortOnDrop| !s.0.is_finished());
        sessions.push(AbortOnDrop(tokio::task::spawn_local(tcp_session(
            stream,
            shared.clone(),
        ))));
    }
}

async fn tcp_session(stream: TcpStream, shared: Arc<Shared>) {
    let peer = stream
        .peer_addr()
        .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)));
    let local_port = stream.local_addr().map_or(0, |a| a.port());
    let (mut rd, wr) = stream.into_split();
    let wr = Arc::new(Mutex::new(wr));
    let mut s = Session::new(peer, local_port);
    let mut in_flight: Vec<AbortOnDrop> = vec![];
    let mut buf: Vec<u8> = vec![];
    let mut bursts = shared.bursts.subscribe();
    let mut tmp = [0u8; 4096];
    let publish_seq = Arc::new(Mutex::new(0u16));
    loop {
        // Complete messages first.
        loop {
            match Message::parse(&buf) {
                Ok((m, used)) => {
                    let (h, body) = (m.header, m.body.to_vec());
                    buf.drain(..used);
                    match handle(&shared, &mut s, h, &body).await {
                        Action::Reply(r) => {
                            if wr.lock().await.write_all(&r).await.is_err() {
                                close_session(&shared, &mut s, 0x0004).await;
                                return;
                            }
                        }
                        Action::ReplyAndClose(r) => {
                            let _ = wr.lock().await.write_all(&r).await;
                            close_session(&shared, &mut s, 0).await;
                            return;
                        }
                        Action::Close => {
                            close_session(&shared, &mut s, 0x0004).await;
                            return;
                        }
                        Action::Forward { channel, pdu, seq } => {
                            // Several requests may be in flight on one connection: each
                            // reply goes out when its loop answers, with its sequence
                            // number, while this task reads on and publishes. The
                            // replies' writers end with the session.
                            let (shared, wr) = (shared.clone(), wr.clone());
                            in_flight.retain(|t: &AbortOnDrop| !t.0.is_finished());
                            in_flight.push(AbortOnDrop(tokio::task::spawn_local(async move {
                                let r = forwarded(&shared, channel, pdu, seq).await;
                                let _ = wr.lock().await.write_all(&r).await;
                            })));
                        }
                    }
                }
                Err(hart_ip::Error::ShortHeader { .. }) | Err(hart_ip::Error::Truncated { .. })
                    if buf.len() < 65536 =>
                {
                    break
                }
                Err(_) => {
                    // A stream that cannot be split any more: this session ends.
                    shared.stats.lock().await.malformed += 1;
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            }
        }
        let timer = s.timer;
        tokio::select! {
            r = tokio::time::timeout(timer, rd.read(&mut tmp)) => match r {
                Ok(Ok(n)) if n > 0 => buf.extend_from_slice(&tmp[..n]),
                Err(_) => {
                    close_session(&shared, &mut s, 0x0008).await;
                    return;
                }
                _ => {
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            },
            b = bursts.recv() => if let (Ok(b), true) = (b, s.open) {
                if !subscribed(&s.subs, &b) {
                    continue;
                }
                let mut seq = publish_seq.lock().await;
                *seq = seq.wrapping_add(1);
                let m = message(MessageType::Publish, MessageId::TokenPassingPdu, 0, *seq, &b);
                if wr.lock().await.write_all(&m).await.is_err() {
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
                shared.stats.lock().await.published += 1;
            },
        }
    }
}

/// The address of a frame, for messages.
pub fn describe(pdu: &[u8]) -> String {
    Frame::parse_pdu(pdu)
        .map(|f| f.address.to_string())
        .unwrap_or_else(|e| e.to_string())
}
