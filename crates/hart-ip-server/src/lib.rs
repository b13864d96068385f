//! # hart-ip-server
//!
//! A HART-IP server (UDP and TCP, port 5094) in front of a HART loop: sessions with a
//! limit and an inactivity timer, keep-alive, token-passing PDUs forwarded to the
//! devices on the loop, direct PDUs answered by the server itself, burst frames
//! published to every session, a read-only mode, and a read audit log.
//!
//! Every session is independent: a malformed message closes (TCP) or is refused
//! (UDP) for its own session only. The loop is reached through a
//! `hart_host::Client`, one transaction at a time, by a single backend task.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use hart_host::target::AnyTransport;
use hart_host::Client;
use hart_ip::{encode, MessageId, MessageType, HEADER_LEN};
use hart_proto::frame::{Frame, FrameSpec, FrameType};
use tokio::net::{TcpListener, UdpSocket};
use tokio::sync::{broadcast, mpsc};

pub mod access;
mod audit;
mod dtls;
pub mod io_system;
mod limits;
mod session;
pub use session::MAX_DIRECT_ENTRIES;
mod stream;
mod subscriptions;
mod udp;

use audit::AuditLog;
pub use audit::{AuditRecord, AUDIT_RECORDS};
pub use io_system::{GatewayIdentity, IoSystem, Route, SubDevice};
use stream::serve_tcp;
pub use subscriptions::subscription;
use udp::serve_udp;

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
    /// Most sessions at once from one client address (IP), so one host cannot take
    /// every session.
    pub max_sessions_per_host: usize,
    /// Every session may only read, whatever its identity or listener: commands not
    /// known to read are answered "access restricted".
    pub read_only: bool,
    /// What plain (version 1, unauthenticated) sessions may do: those on `bind`
    /// without `psk`, and those on `plain`. `hartkit serve` makes it read-only when a
    /// PSK file is given, unless told otherwise (`--plain-rights`).
    pub plain_rights: access::Rights,
    /// Scan each loop's polling addresses 0..=N at start and keep the list current
    /// (for routing by long address and command 84); `None` skips the scan.
    pub scan_to: Option<u8>,
    /// The I/O system's own identity.
    pub identity: GatewayIdentity,
    /// A loop device at polling address 0 answers there instead of the I/O system
    /// (servers with one loop only).
    pub transparent: bool,
    /// HART-IP version 2 security: with keys, `bind` serves TLS (TCP) and DTLS (UDP)
    /// with these pre-shared keys only.
    pub psk: Option<Arc<hart_ip_tls::PskTable>>,
    /// Also serve plain HART-IP here (with `psk`; without, `bind` is plain anyway).
    pub plain: Option<SocketAddr>,
    /// Only these commands may be sent (others are answered "access restricted");
    /// `None`: every command.
    pub allow_commands: Option<access::CommandAllowList>,
    /// Device-specific commands the plant declares reads (`--device-commands`).
    pub device_commands: access::DeviceCommands,
    /// Append a JSON line for every accepted write to this file (besides the log).
    pub audit_file: Option<std::path::PathBuf>,
    /// Longest inactivity timer a session initiate is granted, ms: a client asking for
    /// more is given this (status 8, "set to nearest possible value"), so a session left
    /// silent is closed within it whatever the client asked. Default
    /// [`DEFAULT_MAX_TIMER_MS`] (5 minutes); never below [`MIN_TIMER_MS`].
    pub max_timer_ms: u32,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            bind: "127.0.0.1:5094".parse().unwrap(),
            udp: true,
            tcp: true,
            max_sessions: 64,
            max_sessions_per_host: 16,
            read_only: false,
            plain_rights: access::Rights::ReadWrite,
            scan_to: Some(63),
            identity: GatewayIdentity::default(),
            transparent: false,
            psk: None,
            plain: None,
            allow_commands: None,
            device_commands: access::DeviceCommands::default(),
            audit_file: None,
            max_timer_ms: DEFAULT_MAX_TIMER_MS,
        }
    }
}

impl Config {
    /// The rule of an engine this server starts itself ([`start`], [`start_in_memory`]):
    /// its read-only, allow-list, declared reads and audit file, so the engine's gate
    /// judges every frame as the server does.
    pub fn write_policy(&self) -> hart_poller::WritePolicy {
        hart_poller::WritePolicy {
            read_only: self.read_only,
            allow: self.allow_commands.clone(),
            device_commands: self.device_commands.clone(),
            audit: hart_access::Audit::new(self.audit_file.clone()),
        }
    }
}

/// A session whose client sent nothing after its session initiate is closed after this
/// long (or its own inactivity timer, if shorter): initiates alone cannot hold the
/// sessions for the full timer.
pub const INITIATE_GRACE: std::time::Duration = std::time::Duration::from_secs(10);

/// Shortest inactivity timer the server accepts, ms.
pub const MIN_TIMER_MS: u32 = 1000;

/// Longest inactivity timer the server grants by default, ms (5 minutes):
/// [`Config::max_timer_ms`]. Long enough for a host that polls once a minute and sends
/// keep-alives between; short enough that sessions a client abandons free themselves
/// in minutes, not the 49.7 days a timer of 0xFFFFFFFF ms would ask for.
pub const DEFAULT_MAX_TIMER_MS: u32 = 300_000;

/// The inactivity timer granted for one a client `asked` for, ms, with the server's
/// longest `max` (itself raised to [`MIN_TIMER_MS`] if below): within
/// [`MIN_TIMER_MS`]..=`max`, and whether it differs from what was asked (the
/// initiate's status is then 8, "set to nearest possible value", and its body carries
/// the timer granted).
pub fn granted_timer(asked: u32, max: u32) -> (u32, bool) {
    let granted = asked.clamp(MIN_TIMER_MS, max.max(MIN_TIMER_MS));
    (granted, granted != asked)
}

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
    /// Requests answered "busy" (response code 32) because a queue was full.
    pub busy: u64,
    /// Datagrams dropped (a session's queue full, or too long to be HART-IP).
    pub dropped: u64,
}

/// The OpenSSL contexts of a secure server, built once.
pub(crate) struct Security {
    pub(crate) keys: Arc<hart_ip_tls::PskTable>,
    pub(crate) tls: openssl::ssl::SslContext,
    pub(crate) dtls: openssl::ssl::SslContext,
}

/// The [`Stats`] counters, each counted where it happens without a lock.
#[derive(Default)]
pub(crate) struct Counters {
    pub(crate) sessions_opened: AtomicU64,
    pub(crate) sessions_refused: AtomicU64,
    pub(crate) forwarded: AtomicU64,
    pub(crate) published: AtomicU64,
    pub(crate) malformed: AtomicU64,
    pub(crate) busy: AtomicU64,
    pub(crate) dropped: AtomicU64,
}

impl Counters {
    /// Adds one to `counter`.
    pub(crate) fn count(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }

    fn snapshot(&self) -> Stats {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        Stats {
            sessions_opened: get(&self.sessions_opened),
            sessions_refused: get(&self.sessions_refused),
            forwarded: get(&self.forwarded),
            published: get(&self.published),
            malformed: get(&self.malformed),
            busy: get(&self.busy),
            dropped: get(&self.dropped),
        }
    }
}

/// What every session task shares. The locks here are never held across an `.await`
/// (they guard a few field updates), so they are plain `std` mutexes.
pub(crate) struct Shared {
    pub(crate) config: Config,
    /// The access rules (allow-list, declared device-specific reads).
    pub(crate) policy: hart_access::Policy,
    /// Where writes let through are recorded.
    pub(crate) write_audit: hart_access::Audit,
    /// Sessions open now, within `max_sessions` and `max_sessions_per_host`.
    pub(crate) sessions: limits::SessionPool,
    pub(crate) stats: Counters,
    pub(crate) io: IoSystem,
    pub(crate) bursts: broadcast::Sender<Vec<u8>>,
    pub(crate) audit: std::sync::Mutex<AuditLog>,
    pub(crate) power_up: u64,
}

/// Locks a `std` mutex of the server; a panic that poisoned it left consistent data
/// (every critical section is a few assignments), so the lock is taken anyway.
pub(crate) fn lock<T>(m: &std::sync::Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// A running server.
pub struct Server {
    /// UDP address actually bound.
    pub udp_addr: Option<SocketAddr>,
    /// TCP address actually bound.
    pub tcp_addr: Option<SocketAddr>,
    /// Whether `udp_addr` and `tcp_addr` serve DTLS and TLS (pre-shared keys).
    pub secure: bool,
    /// Plain UDP address bound besides the secure ones (`Config::plain`).
    pub plain_udp_addr: Option<SocketAddr>,
    /// Plain TCP address bound besides the secure ones.
    pub plain_tcp_addr: Option<SocketAddr>,
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
        self.shared.stats.snapshot()
    }

    /// Sessions open now (UDP and TCP).
    pub async fn active_sessions(&self) -> usize {
        self.shared.sessions.len()
    }

    /// Waits until every loop has been scanned once (`Config::scan_to`), so that
    /// routing by polling address, long address and tag knows the devices; without a
    /// scan it waits for the first try of each loop.
    pub async fn ready(&self) {
        self.shared.io.engine.ready().await
    }
}

/// The engine's loop settings for a server's `scan_to` (`None`: no scan).
fn loop_settings(scan_to: Option<u8>) -> hart_poller::LoopSettings {
    hart_poller::LoopSettings {
        scan: scan_to.is_some(),
        scan_to: scan_to.unwrap_or(0).min(63),
        ..Default::default()
    }
}

/// Starts the server with `loops` behind it (each a channel), on an engine of its own
/// that scans them and carries requests without polling; returns once the sockets are
/// bound. The server runs on local tasks: call it inside a `tokio::task::LocalSet`
/// (the loop's client is not `Send`: serial ports and simulated plants stay on one
/// thread).
pub async fn start(config: Config, loops: Vec<Client<AnyTransport>>) -> std::io::Result<Server> {
    let specs = loops
        .into_iter()
        .map(|c| hart_poller::LoopSpec {
            settings: loop_settings(config.scan_to),
            line: hart_poller::Line::client(c),
        })
        .collect();
    let (engine, tasks) = hart_poller::Engine::start_with(
        hart_poller::EngineConfig::default(),
        specs,
        hart_poller::StartOptions {
            write_policy: config.write_policy(),
            ..hart_poller::StartOptions::default()
        },
    );
    start_with_engine(config, engine, tasks).await
}

/// Starts the server in front of a running `engine` (shared with other front ends);
/// `tasks` (the engine's) end when the server is stopped. `config.scan_to` is the
/// engine's business here. Call it inside a `tokio::task::LocalSet`.
pub async fn start_with_engine(
    config: Config,
    engine: hart_poller::Engine,
    mut tasks: Vec<tokio::task::JoinHandle<()>>,
) -> std::io::Result<Server> {
    let bursts = engine.bursts().clone();
    // The engine's rule is the gateway's: its read-only and allow-list hold here too,
    // and one audit (one numbering of records) serves every front end.
    let gateway = engine.write_policy().clone();
    let mut config = config;
    config.read_only |= gateway.read_only;
    let allow = config.allow_commands.clone().or(gateway.allow.clone());
    let write_audit = match &config.audit_file {
        Some(f) if gateway.audit.file() != Some(f) => hart_access::Audit::new(Some(f.clone())),
        _ => gateway.audit.clone(),
    };
    let io = IoSystem::new(config.identity.clone(), engine, config.transparent);
    let shared = Arc::new(Shared {
        config: config.clone(),
        policy: hart_access::Policy {
            allow,
            device_commands: config.device_commands.clone(),
        },
        write_audit,
        sessions: limits::SessionPool::new(config.max_sessions, config.max_sessions_per_host),
        stats: Counters::default(),
        io,
        bursts,
        audit: std::sync::Mutex::new(AuditLog::default()),
        power_up: unix_now(),
    });
    // The I/O system's own burst messages (commands 102-109).
    let publisher = shared.clone();
    tasks.push(tokio::task::spawn_local(async move {
        publisher.io.publish_bursts(&publisher.bursts).await
    }));
    let security = match &config.psk {
        Some(keys) => {
            let err = |e: String| std::io::Error::other(e);
            Some(Arc::new(Security {
                keys: keys.clone(),
                tls: hart_ip_tls::server_context(keys.clone(), false).map_err(err)?,
                dtls: hart_ip_tls::server_context(keys.clone(), true).map_err(err)?,
            }))
        }
        None => None,
    };
    let (udp_addr, tcp_addr) =
        bind_pair(&config, config.bind, &shared, security.clone(), &mut tasks).await?;
    let (mut plain_udp_addr, mut plain_tcp_addr) = (None, None);
    if let (Some(plain), Some(_)) = (config.plain, &security) {
        (plain_udp_addr, plain_tcp_addr) =
            bind_pair(&config, plain, &shared, None, &mut tasks).await?;
    }
    Ok(Server {
        udp_addr,
        tcp_addr,
        secure: security.is_some(),
        plain_udp_addr,
        plain_tcp_addr,
        shared,
        tasks,
    })
}

/// Binds UDP and TCP (as `config` asks) at `bind`: plain, or DTLS and TLS with
/// `security`. With port 0, TCP takes the port UDP got.
async fn bind_pair(
    config: &Config,
    bind: SocketAddr,
    shared: &Arc<Shared>,
    security: Option<Arc<Security>>,
    tasks: &mut Vec<tokio::task::JoinHandle<()>>,
) -> std::io::Result<(Option<SocketAddr>, Option<SocketAddr>)> {
    // With port 0 the UDP port the kernel picks may be taken for TCP: pick again.
    let mut attempts = 0;
    let (udp, tcp) = loop {
        attempts += 1;
        let udp = match config.udp {
            true => Some(UdpSocket::bind(bind).await?),
            false => None,
        };
        let tcp_bind = match &udp {
            Some(u) if bind.port() == 0 => u.local_addr()?,
            _ => bind,
        };
        let tcp = match config.tcp {
            true => match TcpListener::bind(tcp_bind).await {
                Ok(l) => Some(l),
                Err(e)
                    if e.kind() == std::io::ErrorKind::AddrInUse
                        && bind.port() == 0
                        && attempts < 20 =>
                {
                    continue
                }
                Err(e) => return Err(e),
            },
            false => None,
        };
        break (udp, tcp);
    };
    let mut udp_addr = None;
    let mut tcp_addr = None;
    if let Some(sock) = udp {
        let sock = Arc::new(sock);
        udp_addr = Some(sock.local_addr()?);
        tasks.push(match security.clone() {
            None => tokio::task::spawn_local(serve_udp(sock, shared.clone())),
            Some(sec) => tokio::task::spawn_local(dtls::serve_dtls(sock, shared.clone(), sec)),
        });
    }
    if let Some(listener) = tcp {
        tcp_addr = Some(listener.local_addr()?);
        tasks.push(tokio::task::spawn_local(serve_tcp(
            listener,
            shared.clone(),
            security,
        )));
    }
    Ok((udp_addr, tcp_addr))
}

/// Starts the server with field devices answered in memory, without a simulated line
/// (`hartkit serve --sim --instant`, benchmarks and tests of the server itself): one
/// loop whose requests are answered by the device with that address at once; burst
/// messages are published when due. The whole `config` applies as with [`start`]
/// (read-only, transparent, session limit; `scan_to`: the devices at polling addresses
/// up to it are listed as sub-devices from the start, the others once a client's
/// command 0, 11 or 21 finds them). Call it inside a `tokio::task::LocalSet`.
pub async fn start_in_memory(
    config: Config,
    devices: Vec<hart_device::Device>,
) -> std::io::Result<Server> {
    let spec = hart_poller::LoopSpec {
        settings: loop_settings(config.scan_to),
        line: hart_poller::Line::Memory(hart_poller::MemoryLoop::new(devices)),
    };
    let (engine, tasks) = hart_poller::Engine::start_with(
        hart_poller::EngineConfig::default(),
        vec![spec],
        hart_poller::StartOptions {
            queue: 1024,
            write_policy: config.write_policy(),
            ..hart_poller::StartOptions::default()
        },
    );
    start_with_engine(config, engine, tasks).await
}

/// A HART-IP message of protocol `version` (1 plain, 2 secure sessions).
pub(crate) fn message(
    version: u8,
    ty: MessageType,
    id: MessageId,
    st: u8,
    seq: u16,
    body: &[u8],
) -> Vec<u8> {
    let mut out = vec![0u8; HEADER_LEN + body.len()];
    match encode(version, ty, id, st, seq, body, &mut out) {
        Ok(n) => {
            out.truncate(n);
            out
        }
        Err(e) => {
            // Longer than a HART-IP message can be (the server caps what it builds, so
            // this is a fault): answer "device-specific error" without a body rather
            // than send a broken header.
            tracing::error!(
                "hart-ip: a reply of {} bytes could not be encoded: {e}",
                body.len()
            );
            let mut out = vec![0u8; HEADER_LEN];
            let _ = encode(
                version,
                ty,
                id,
                hart_ip::status::DEVICE_SPECIFIC,
                seq,
                &[],
                &mut out,
            );
            out
        }
    }
}

/// The PDU of `spec` (no preambles, as HART-IP carries it); empty if it cannot be
/// encoded.
pub(crate) fn pdu(spec: &FrameSpec<'_>) -> Vec<u8> {
    hart_proto::frame::FrameBuf::encode(spec).map_or_else(|_| vec![], |b| b.as_slice().to_vec())
}

/// The server's own reply to a request frame: response code `code`, field device
/// status `status` and `data` (left out for error codes).
pub(crate) fn local_frame(f: &Frame<'_>, code: u8, status: u8, data: &[u8]) -> Vec<u8> {
    let data =
        if hart_proto::tables::response_class(code) == hart_proto::tables::ResponseClass::Error {
            &[][..]
        } else {
            data
        };
    pdu(&FrameSpec {
        frame_type: FrameType::Ack,
        extended: f.extended,
        status: Some((code, status)),
        ..FrameSpec::request(f.address, f.command, data)
    })
}

/// Per-peer tasks of a datagram socket (UDP sessions, DTLS associations) by client
/// address: the queue that feeds each, and the task. The tasks hold the table weakly.
pub(crate) type PeerTable =
    std::collections::HashMap<SocketAddr, (mpsc::Sender<Vec<u8>>, AbortOnDrop)>;

/// The table, shared by a socket's receive loop.
pub(crate) type Peers = std::rc::Rc<std::cell::RefCell<PeerTable>>;

/// Aborts a task when dropped (children of a server task end with it).
pub(crate) struct AbortOnDrop(pub(crate) tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

pub(crate) fn unix_now() -> u64 {
    hart_clock::epoch::seconds(std::time::SystemTime::now())
}

/// The address of a frame, for messages.
pub fn describe(pdu: &[u8]) -> String {
    Frame::parse_pdu(pdu)
        .map(|f| f.address.to_string())
        .unwrap_or_else(|e| e.to_string())
}
