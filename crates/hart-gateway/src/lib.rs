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
    audit: Mutex<Vec<AuditRecord>>,
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
}

/// Starts the server with `client` reaching the loop; returns once the sockets are
/// bound. The server runs on local tasks: call it inside a `tokio::task::LocalSet`
/// (the loop's client is not `Send`: serial ports and simulated plants stay on one
/// thread).
pub async fn start(config: Config, loops: Vec<Client<AnyTransport>>) -> std::io::Result<Server> {
    let (bursts, _) = broadcast::channel(64);
    let subs = Arc::new(Mutex::new(vec![]));
    let mut tasks = vec![];
    let mut senders = vec![];
    for (channel, client) in loops.into_iter().enumerate() {
        let (tx, rx) = mpsc::channel::<LoopRequest>(256);
        senders.push(tx);
        tasks.push(tokio::task::spawn_local(backend(
            client,
            channel as u8,
            config.scan_to,
            subs.clone(),
            rx,
            bursts.clone(),
        )));
    }
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
        audit: Mutex::new(vec![]),
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
                let _ = r.reply.send(reply);
            }
            (None, Some(poll)) => {
                if let Ok(mut info) = client.identify(poll).await {
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
                    subs.lock().await.push(SubDevice { channel, info });
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

fn message(ty: MessageType, id: MessageId, st: u8, seq: u16, body: &[u8]) -> Vec<u8> {
    let mut out = vec![0u8; HEADER_LEN + body.len()];
    let _ = encode(1, ty, id, st, seq, body, &mut out);
    out
}

/// A status-only reply to a request, built by the server itself (read-only mode).
fn local_reply(f: &Frame<'_>, rc: u8) -> Vec<u8> {
    let spec = FrameSpec {
        preambles: 0,
        frame_type: FrameType::Ack,
        extended: f.extended,
        status: Some((rc, 0)),
        ..FrameSpec::request(f.address, f.command, &[])
    };
    let mut out = vec![0u8; spec.encoded_len()];
    let n = spec.encode(&mut out).unwrap_or(0);
    out.truncate(n);
    out
}

/// What to do with one received message of a session.
enum Action {
    Reply(Vec<u8>),
    ReplyAndClose(Vec<u8>),
    Close,
}

/// Session state shared by UDP and TCP.
struct Session {
    open: bool,
    timer: Duration,
    last_rx: Instant,
    publish_seq: u16,
    peer: SocketAddr,
    local_port: u16,
    /// Index of this session's audit record.
    audit: Option<usize>,
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
                let mut audit = shared.audit.lock().await;
                s.audit = Some(audit.len());
                // Every HART-IP v1 session is an insecure session (0x0010).
                audit.push(AuditRecord {
                    client: s.peer,
                    server_port: s.local_port,
                    connected: unix_now(),
                    disconnected: 0,
                    status: 0x0010,
                    publishes: 0,
                    requests: 0,
                    responses: 0,
                });
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
                    &local_reply(&f, hart_proto::tables::rc::ACCESS_RESTRICTED),
                ));
            }
            let route = shared.mux.route(&f).await;
            match route {
                Route::Local => {
                    let (code, data) = shared.mux.local(f.command, f.data).await;
                    let data = if hart_proto::tables::response_class(code)
                        == hart_proto::tables::ResponseClass::Error
                    {
                        vec![]
                    } else {
                        data
                    };
                    let spec = FrameSpec {
                        preambles: 0,
                        frame_type: FrameType::Ack,
                        extended: f.extended,
                        status: Some((code, 0)),
                        ..FrameSpec::request(f.address, f.command, &data)
                    };
                    let mut out = vec![0u8; spec.encoded_len()];
                    let n = spec.encode(&mut out).unwrap_or(0);
                    out.truncate(n);
                    Action::Reply(reply(status::SUCCESS, &out))
                }
                Route::Loop(channel) => {
                    shared.stats.lock().await.forwarded += 1;
                    match shared.mux.forward(channel, body.to_vec()).await {
                        Some(pdu) => Action::Reply(reply(status::SUCCESS, &pdu)),
                        // The device did not answer: an empty response, so the client stops waiting.
                        None => Action::Reply(reply(status::DEVICE_SPECIFIC, &[])),
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

async fn serve_udp(sock: Arc<UdpSocket>, shared: Arc<Shared>) {
    let local_port = sock.local_addr().map_or(0, |a| a.port());
    let sessions: Arc<Mutex<HashMap<SocketAddr, Session>>> = Arc::new(Mutex::new(HashMap::new()));
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
                let mut map = sessions.lock().await;
                let mut closed = vec![];
                for (peer, s) in map.iter_mut() {
                    if s.last_rx.elapsed() > s.timer {
                        closed.push(*peer);
                        continue;
                    }
                    if let Some(b) = &burst {
                        s.publish_seq = s.publish_seq.wrapping_add(1);
                        let _ = sock
                            .send_to(
                                &message(
                                    MessageType::Publish,
                                    MessageId::TokenPassingPdu,
                                    0,
                                    s.publish_seq,
                                    b,
                                ),
                                peer,
                            )
                            .await;
                        shared.stats.lock().await.published += 1;
                        if let Some(r) = s.audit {
                            if let Some(rec) = shared.audit.lock().await.get_mut(r) {
                                rec.publishes += 1;
                            }
                        }
                    }
                }
                for p in closed {
                    if let Some(mut s) = map.remove(&p) {
                        close_session(&shared, &mut s, 0x0008).await;
                    }
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
    sessions: Arc<Mutex<HashMap<SocketAddr, Session>>>,
    peer: SocketAddr,
    local_port: u16,
    data: Vec<u8>,
) {
    let mut rest = &data[..];
    while !rest.is_empty() {
        let (h, body, used) = match Message::parse(rest) {
            Ok((m, used)) => (m.header, m.body.to_vec(), used),
            Err(_) => {
                shared.stats.lock().await.malformed += 1;
                return;
            }
        };
        rest = &rest[used..];
        let mut s = sessions
            .lock()
            .await
            .remove(&peer)
            .unwrap_or_else(|| Session::new(peer, local_port));
        let action = handle(&shared, &mut s, h, &body).await;
        let (keep, why) = match action {
            Action::Reply(r) => {
                let _ = sock.send_to(&r, peer).await;
                (s.open, 0)
            }
            Action::ReplyAndClose(r) => {
                let _ = sock.send_to(&r, peer).await;
                (false, 0)
            }
            Action::Close => (false, 0x0004),
        };
        if keep {
            sessions.lock().await.insert(peer, s);
        } else {
            close_session(&shared, &mut s, why).await;
        }
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
