//! A load generator for HART-IP servers (`hartkit hart-ip bench`): many sessions, each
//! sending token-passing requests one after another for a while, from a separate
//! process, so what it measures is the server.
//!
//! [`run`] first finds the target device with command 0 at a polling address (through
//! the data-link client, [`crate::hartip::HartIpTransport`]), then opens
//! [`LoadOptions::sessions`] sessions at once, and then every session sends the
//! request (a long frame to that device) and waits for its response before it sends
//! the next, until [`LoadOptions::duration`] is over. Every request has a time-out
//! ([`LoadOptions::timeout`]): a response that does not come in time is counted as an
//! error and the session goes on with the next request, so no concurrency can
//! deadlock. The [`LoadReport`] gives transactions per second, latency quantiles and
//! the errors by kind.
//!
//! The sessions run as tasks of a multi-threaded runtime ([`run_blocking`] builds one
//! with a worker per core), over raw sockets with the `hart-ip` codec, one socket per
//! session, and share a latency histogram of atomic counters, so the generator's own
//! cost per transaction stays small next to the server's.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_ip::{encode, status, Header, Message, MessageId, MessageType, HEADER_LEN};
use hart_proto::frame::{Address, Frame, FrameBuf, FrameSpec, FrameType, UniqueId};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpStream, UdpSocket};

/// What to run.
#[derive(Debug, Clone)]
pub struct LoadOptions {
    /// The server, `HOST:PORT`.
    pub address: String,
    /// TCP instead of UDP.
    pub tcp: bool,
    /// Sessions at once (each one request in flight at a time).
    pub sessions: usize,
    /// How long the sessions send requests.
    pub duration: Duration,
    /// The command each request carries (to the device found at
    /// [`LoadOptions::poll`], in a long frame).
    pub command: u16,
    /// The request's data bytes.
    pub data: Vec<u8>,
    /// The polling address where command 0 finds the target device.
    pub poll: u8,
    /// How long a request waits for its response before it counts as a time-out.
    pub timeout: Duration,
    /// Worker threads of the runtime [`run_blocking`] builds (0: one per core).
    pub threads: usize,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            address: format!("127.0.0.1:{}", hart_ip::PORT),
            tcp: false,
            sessions: 1,
            duration: Duration::from_secs(10),
            command: 1,
            data: vec![],
            poll: 1,
            timeout: Duration::from_secs(2),
            threads: 0,
        }
    }
}

/// Errors by kind. Each counts one request or one session.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LoadErrors {
    /// Requests (and session initiates) without a response within the time-out.
    pub timeouts: u64,
    /// Sessions the server refused: an error status to the session initiate (all
    /// sessions in use, ...), or a TCP connection refused.
    pub refused: u64,
    /// Sessions that ended early: the connection closed or a socket error.
    pub closed: u64,
    /// Responses that are not a good reply: a HART-IP status other than success, a
    /// body that is not an ACK frame of the command, or an error response code (35:
    /// the server reports the device silent).
    pub bad_replies: u64,
}

impl LoadErrors {
    /// All errors.
    pub fn total(&self) -> u64 {
        self.timeouts + self.refused + self.closed + self.bad_replies
    }

    fn add(&mut self, o: &LoadErrors) {
        self.timeouts += o.timeouts;
        self.refused += o.refused;
        self.closed += o.closed;
        self.bad_replies += o.bad_replies;
    }
}

/// Latency of the transactions that succeeded, µs.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Latency {
    /// Median.
    pub p50_us: f64,
    /// 99th percentile.
    pub p99_us: f64,
    /// Longest.
    pub max_us: f64,
    /// Mean.
    pub mean_us: f64,
}

/// What a run measured.
#[derive(Debug, Clone)]
pub struct LoadReport {
    /// The server's address as connected.
    pub server: SocketAddr,
    /// TCP instead of UDP.
    pub tcp: bool,
    /// Sessions asked for.
    pub sessions: usize,
    /// Sessions the server opened.
    pub sessions_open: usize,
    /// The device the requests went to.
    pub device: UniqueId,
    /// Its polling address.
    pub poll: u8,
    /// The command sent.
    pub command: u16,
    /// Wall time from the first request to the last response, s.
    pub seconds: f64,
    /// Transactions that got a good reply.
    pub transactions: u64,
    /// Latency of those.
    pub latency: Latency,
    /// Errors.
    pub errors: LoadErrors,
    /// Publish messages the sessions received (burst frames of devices behind the
    /// server; not counted as transactions).
    pub publish_messages: u64,
}

impl LoadReport {
    /// Good transactions per second of wall time.
    pub fn transactions_per_second(&self) -> f64 {
        if self.seconds > 0.0 {
            self.transactions as f64 / self.seconds
        } else {
            0.0
        }
    }
}

/// Why a run could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LoadError {
    /// The options cannot work (the message says which and why).
    Usage(String),
    /// The server or the device behind it did not answer the set-up (session initiate,
    /// command 0).
    NoAnswer(String),
    /// The operating system refused something (runtime, open files).
    System(String),
}

impl LoadError {
    /// The exit status `hartkit` uses for it: 2 usage, 3 no answer, 5 system.
    pub fn exit_code(&self) -> u8 {
        match self {
            LoadError::Usage(_) => 2,
            LoadError::NoAnswer(_) => 3,
            LoadError::System(_) => 5,
        }
    }
}

impl std::fmt::Display for LoadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LoadError::Usage(m) | LoadError::NoAnswer(m) | LoadError::System(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for LoadError {}

/// Raises this process's soft limit of open files (`RLIMIT_NOFILE`) to at least
/// `wanted` if the hard limit allows; returns the soft limit now in force (0 when it
/// cannot be read). A TCP server or load generator needs a descriptor per session.
// `rlim_t` is u64 on some targets only.
#[allow(clippy::unnecessary_cast)]
pub fn raise_open_file_limit(wanted: u64) -> u64 {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit with a valid rlimit struct.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) != 0 {
            return 0;
        }
        let cur = lim.rlim_cur as u64;
        if cur >= wanted {
            return cur;
        }
        let max = lim.rlim_max as u64;
        lim.rlim_cur = wanted.min(max) as libc::rlim_t;
        if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) != 0 {
            return cur;
        }
        lim.rlim_cur as u64
    }
}

/// Runs the load on a new multi-threaded runtime with [`LoadOptions::threads`] workers
/// (one per core by default).
pub fn run_blocking(opts: &LoadOptions) -> Result<LoadReport, LoadError> {
    let workers = match opts.threads {
        0 => std::thread::available_parallelism().map_or(2, |n| n.get()),
        n => n,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(workers)
        .enable_all()
        .build()
        .map_err(|e| LoadError::System(format!("cannot start the runtime: {e}")))?;
    rt.block_on(run(opts))
}

/// Runs the load. Call it on a multi-threaded runtime (the sessions are spawned
/// tasks); [`run_blocking`] makes one.
pub async fn run(opts: &LoadOptions) -> Result<LoadReport, LoadError> {
    if opts.sessions == 0 {
        return Err(LoadError::Usage(
            "--sessions 0: give at least one session".into(),
        ));
    }
    if opts.duration.is_zero() || opts.timeout.is_zero() {
        return Err(LoadError::Usage(
            "the duration and the request time-out must be more than 0".into(),
        ));
    }
    let fds = raise_open_file_limit(opts.sessions as u64 + 64);
    if fds > 0 && fds < opts.sessions as u64 + 16 {
        return Err(LoadError::System(format!(
            "{} sessions need as many sockets, but this process may open only {fds} files; \
             raise the limit (ulimit -n {}) or use fewer sessions",
            opts.sessions,
            opts.sessions + 64
        )));
    }
    let what = format!(
        "HART-IP server {} ({})",
        opts.address,
        if opts.tcp { "TCP" } else { "UDP" }
    );
    let (device, request) = find_device(opts, &what).await?;
    let peer = tokio::net::lookup_host(&opts.address)
        .await
        .ok()
        .and_then(|mut a| a.next())
        .ok_or_else(|| LoadError::Usage(format!("{}: not an address", opts.address)))?;

    // All sessions first, then the load on all of them at once.
    let mut opening = tokio::task::JoinSet::new();
    for _ in 0..opts.sessions {
        let tcp = opts.tcp;
        opening.spawn(async move { Conn::open(peer, tcp).await });
    }
    let stats = Arc::new(Histogram::new());
    let mut errors = LoadErrors::default();
    let mut conns = vec![];
    while let Some(r) = opening.join_next().await {
        match r {
            Ok(Ok(c)) => conns.push(c),
            Ok(Err(e)) => errors.add(&e),
            Err(e) => {
                return Err(LoadError::System(format!("a session task failed: {e}")));
            }
        }
    }
    let sessions_open = conns.len();
    let started = Instant::now();
    let deadline = started + opts.duration;
    let request = Arc::new(request);
    let mut running = tokio::task::JoinSet::new();
    for c in conns {
        let (stats, request) = (stats.clone(), request.clone());
        let (timeout, command) = (opts.timeout, opts.command);
        running.spawn(async move { c.load(&request, command, deadline, timeout, &stats).await });
    }
    let mut publish_messages = 0;
    let mut finished = vec![];
    while let Some(r) = running.join_next().await {
        match r {
            Ok((c, e, p)) => {
                errors.add(&e);
                publish_messages += p;
                finished.extend(c);
            }
            Err(e) => return Err(LoadError::System(format!("a session task failed: {e}"))),
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    // Close the sessions, so the server's count of sessions goes down at once.
    let mut closing = tokio::task::JoinSet::new();
    for c in finished {
        closing.spawn(c.close());
    }
    while closing.join_next().await.is_some() {}
    Ok(LoadReport {
        server: peer,
        tcp: opts.tcp,
        sessions: opts.sessions,
        sessions_open,
        device,
        poll: opts.poll,
        command: opts.command,
        seconds,
        transactions: stats.count(),
        latency: stats.latency(),
        errors,
        publish_messages,
    })
}

/// Command 0 at the polling address through the data-link client: the device's unique
/// ID, and the request PDU every session sends.
async fn find_device(opts: &LoadOptions, what: &str) -> Result<(UniqueId, Vec<u8>), LoadError> {
    let t = crate::hartip::HartIpTransport::connect(&opts.address, opts.tcp, 60_000)
        .await
        .map_err(|e| {
            LoadError::NoAnswer(format!(
                "{what}: {e}; check that a server runs there (hartkit serve --hart-ip ADDR) and \
                 serves this transport"
            ))
        })?;
    let mut client = crate::Client::new(crate::target::AnyTransport::HartIp(Box::new(t)));
    let info = client.identify(opts.poll).await.map_err(|e| {
        LoadError::NoAnswer(format!(
            "no device found at polling address {} behind {what}: {e}; give the polling \
             address of a field device with --poll (hartkit scan -p {}://{} lists them)",
            opts.poll,
            if opts.tcp { "tcp" } else { "udp" },
            opts.address
        ))
    })?;
    let id = info.unique_id();
    let frame = FrameBuf::encode(&FrameSpec::request(
        Address::long(id),
        opts.command,
        &opts.data,
    ))
    .map_err(|e| LoadError::Usage(format!("command {}: {e}", opts.command)))?;
    Ok((id, frame.as_slice().to_vec()))
}

/// Latency histogram shared by the sessions: exact below 512 µs, then 256 buckets per
/// power of two (within 0.4 %).
struct Histogram {
    buckets: Vec<AtomicU64>,
    count: AtomicU64,
    sum: AtomicU64,
    max: AtomicU64,
}

const SUB: u32 = 256;

impl Histogram {
    fn new() -> Self {
        Histogram {
            buckets: (0..Self::index(u64::MAX) + 1)
                .map(|_| AtomicU64::new(0))
                .collect(),
            count: AtomicU64::new(0),
            sum: AtomicU64::new(0),
            max: AtomicU64::new(0),
        }
    }

    fn index(us: u64) -> usize {
        if us < u64::from(2 * SUB) {
            return us as usize;
        }
        // us in [2^k, 2^(k+1)), k >= 9: 256 buckets of 2^(k-8).
        let k = 63 - us.leading_zeros();
        let shift = k - 8;
        let sub = (us >> shift) as u32 - SUB;
        (2 * SUB + (k - 9) * SUB + sub) as usize
    }

    /// The smallest value of bucket `i`.
    fn value(i: usize) -> u64 {
        let i = i as u64;
        let s = u64::from(SUB);
        if i < 2 * s {
            return i;
        }
        let k = (i - 2 * s) / s + 9;
        let sub = (i - 2 * s) % s + s;
        sub << (k - 8)
    }

    fn record(&self, us: u64) {
        self.buckets[Self::index(us)].fetch_add(1, Ordering::Relaxed);
        self.count.fetch_add(1, Ordering::Relaxed);
        self.sum.fetch_add(us, Ordering::Relaxed);
        self.max.fetch_max(us, Ordering::Relaxed);
    }

    fn count(&self) -> u64 {
        self.count.load(Ordering::Relaxed)
    }

    fn quantile(&self, q: f64) -> f64 {
        let n = self.count();
        if n == 0 {
            return 0.0;
        }
        let rank = ((q * n as f64).ceil() as u64).clamp(1, n);
        let mut seen = 0;
        for (i, b) in self.buckets.iter().enumerate() {
            seen += b.load(Ordering::Relaxed);
            if seen >= rank {
                return Self::value(i) as f64;
            }
        }
        self.max.load(Ordering::Relaxed) as f64
    }

    fn latency(&self) -> Latency {
        let n = self.count();
        Latency {
            p50_us: self.quantile(0.50),
            p99_us: self.quantile(0.99),
            max_us: self.max.load(Ordering::Relaxed) as f64,
            mean_us: if n == 0 {
                0.0
            } else {
                self.sum.load(Ordering::Relaxed) as f64 / n as f64
            },
        }
    }
}

enum Socket {
    /// Connected to the server's address once it answered the session initiate (a UDP
    /// server may answer from another port; the session follows it there).
    Udp(UdpSocket, SocketAddr, bool),
    Tcp(TcpStream, Vec<u8>),
}

/// One session of the load.
struct Conn {
    socket: Socket,
    sequence: u16,
    out: Vec<u8>,
    publishes: u64,
}

/// How an exchange ended.
enum Outcome {
    /// The response: HART-IP status and whether the body is a good reply.
    Answer(u8, bool),
    TimedOut,
    Closed,
}

impl Conn {
    /// Connects and initiates a session; over UDP the initiate is sent up to three
    /// times (a burst of initiates may overflow the server's receive buffer).
    async fn open(peer: SocketAddr, tcp: bool) -> Result<Conn, LoadErrors> {
        let refused = LoadErrors {
            refused: 1,
            ..LoadErrors::default()
        };
        let closed = LoadErrors {
            closed: 1,
            ..LoadErrors::default()
        };
        let socket = if tcp {
            match tokio::time::timeout(Duration::from_secs(5), TcpStream::connect(peer)).await {
                Ok(Ok(s)) => {
                    let _ = s.set_nodelay(true);
                    Socket::Tcp(s, Vec::with_capacity(4096))
                }
                Ok(Err(e)) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                    return Err(refused)
                }
                Ok(Err(_)) => return Err(closed),
                Err(_) => {
                    return Err(LoadErrors {
                        timeouts: 1,
                        ..LoadErrors::default()
                    })
                }
            }
        } else {
            let local: SocketAddr = if peer.is_ipv4() {
                "0.0.0.0:0".parse().unwrap()
            } else {
                "[::]:0".parse().unwrap()
            };
            match UdpSocket::bind(local).await {
                Ok(s) => Socket::Udp(s, peer, false),
                _ => return Err(closed),
            }
        };
        let mut c = Conn {
            socket,
            sequence: 0,
            out: Vec::with_capacity(HEADER_LEN + 64),
            publishes: 0,
        };
        let body = hart_ip::session_initiate_body(1, 60_000);
        let tries = if tcp { 1 } else { 3 };
        for _ in 0..tries {
            match c
                .exchange(
                    MessageId::SessionInitiate,
                    &body,
                    Duration::from_secs(2),
                    |_| true,
                )
                .await
            {
                Outcome::Answer(st, _) => {
                    if let Socket::Udp(s, peer, connected) = &mut c.socket {
                        if s.connect(*peer).await.is_err() {
                            return Err(closed);
                        }
                        *connected = true;
                    }
                    return match st {
                        status::SUCCESS | status::SET_TO_NEAREST => Ok(c),
                        _ => Err(refused),
                    };
                }
                Outcome::Closed => return Err(closed),
                Outcome::TimedOut => {}
            }
        }
        Err(LoadErrors {
            timeouts: 1,
            ..LoadErrors::default()
        })
    }

    /// Requests one after another until `deadline`; returns the session (unless it
    /// ended), its errors and the publish messages it received.
    async fn load(
        mut self,
        request: &[u8],
        command: u16,
        deadline: Instant,
        timeout: Duration,
        stats: &Histogram,
    ) -> (Option<Conn>, LoadErrors, u64) {
        let mut errors = LoadErrors::default();
        let good = |body: &[u8]| {
            Frame::parse_pdu(body).is_ok_and(|f| {
                f.frame_type() == FrameType::Ack
                    && f.command == command
                    && f.response_code.is_some_and(|rc| {
                        hart_proto::tables::response_class(rc)
                            != hart_proto::tables::ResponseClass::Error
                    })
            })
        };
        loop {
            let t0 = Instant::now();
            if t0 >= deadline {
                break;
            }
            match self
                .exchange(MessageId::TokenPassingPdu, request, timeout, good)
                .await
            {
                Outcome::Answer(status::SUCCESS, true) => {
                    stats.record(t0.elapsed().as_micros() as u64)
                }
                Outcome::Answer(..) => errors.bad_replies += 1,
                Outcome::TimedOut => errors.timeouts += 1,
                Outcome::Closed => {
                    errors.closed += 1;
                    let p = self.publishes;
                    return (None, errors, p);
                }
            }
        }
        let p = self.publishes;
        (Some(self), errors, p)
    }

    /// Session close; waits up to half a second for the server to confirm.
    async fn close(mut self) {
        let _ = self
            .exchange(
                MessageId::SessionClose,
                &[],
                Duration::from_millis(500),
                |_| true,
            )
            .await;
    }

    /// Sends a request and waits for the response with its sequence number (stale
    /// responses to timed-out requests and publish messages are passed over); `check`
    /// judges the body.
    async fn exchange(
        &mut self,
        id: MessageId,
        body: &[u8],
        timeout: Duration,
        check: impl Fn(&[u8]) -> bool,
    ) -> Outcome {
        self.sequence = self.sequence.wrapping_add(1);
        let seq = self.sequence;
        self.out.resize(HEADER_LEN + body.len(), 0);
        if encode(1, MessageType::Request, id, 0, seq, body, &mut self.out).is_err() {
            return Outcome::Closed;
        }
        let sent = match &mut self.socket {
            Socket::Udp(s, _, true) => s.send(&self.out).await.map(|_| ()),
            Socket::Udp(s, peer, false) => s.send_to(&self.out, *peer).await.map(|_| ()),
            Socket::Tcp(s, _) => s.write_all(&self.out).await,
        };
        if sent.is_err() {
            return Outcome::Closed;
        }
        let deadline = tokio::time::Instant::now() + timeout;
        let mut tmp = [0u8; 2048];
        loop {
            // A response that fits the request in progress?
            let matched = |h: &Header| {
                matches!(h.message_type, MessageType::Response | MessageType::Nak)
                    && h.message_id == id
                    && h.sequence == seq
            };
            match &mut self.socket {
                Socket::Udp(s, peer, connected) => {
                    let got = if *connected {
                        tokio::time::timeout_at(deadline, s.recv(&mut tmp))
                            .await
                            .map(|r| r.map(|n| (n, *peer)))
                    } else {
                        tokio::time::timeout_at(deadline, s.recv_from(&mut tmp)).await
                    };
                    let n = match got {
                        Ok(Ok((n, from))) if from.ip() == peer.ip() => {
                            *peer = from;
                            n
                        }
                        Ok(Ok(_)) => continue,
                        // An ICMP "port unreachable" from a server that went away.
                        Ok(Err(_)) => return Outcome::Closed,
                        Err(_) => return Outcome::TimedOut,
                    };
                    let mut rest = &tmp[..n];
                    while let Ok((m, used)) = Message::parse(rest) {
                        rest = &rest[used..];
                        if matched(&m.header) {
                            return Outcome::Answer(m.header.status, check(m.body));
                        }
                        if m.header.message_type == MessageType::Publish {
                            self.publishes += 1;
                        }
                    }
                }
                Socket::Tcp(s, buf) => {
                    let mut used_total = 0;
                    let mut answer = None;
                    while let Ok((m, used)) = Message::parse(&buf[used_total..]) {
                        used_total += used;
                        if matched(&m.header) {
                            answer = Some(Outcome::Answer(m.header.status, check(m.body)));
                            break;
                        }
                        if m.header.message_type == MessageType::Publish {
                            self.publishes += 1;
                        }
                    }
                    buf.drain(..used_total);
                    if let Some(a) = answer {
                        return a;
                    }
                    if buf.len() > 65_536 {
                        // A stream that cannot be split into messages any more.
                        return Outcome::Closed;
                    }
                    match tokio::time::timeout_at(deadline, s.read(&mut tmp)).await {
                        Ok(Ok(n)) if n > 0 => buf.extend_from_slice(&tmp[..n]),
                        Ok(_) => return Outcome::Closed,
                        Err(_) => return Outcome::TimedOut,
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_round_trip_within_half_a_percent() {
        for us in [
            0u64,
            1,
            511,
            512,
            513,
            1000,
            4095,
            65_537,
            1_000_000,
            u32::MAX as u64,
        ] {
            let i = Histogram::index(us);
            let v = Histogram::value(i);
            assert!(v <= us, "{us}: bucket starts at {v}");
            assert!(us - v <= us / 256, "{us}: bucket starts at {v}");
            assert!(i < Histogram::index(u64::MAX) + 1);
        }
        assert_eq!(Histogram::index(u64::MAX), Histogram::index(u64::MAX - 1));
    }

    #[test]
    fn quantiles_of_a_known_spread() {
        let h = Histogram::new();
        for us in 1..=100 {
            h.record(us);
        }
        let l = h.latency();
        assert_eq!(l.p50_us, 50.0);
        assert_eq!(l.p99_us, 99.0);
        assert_eq!(l.max_us, 100.0);
        assert_eq!(l.mean_us, 50.5);
    }
}
