//! HART-IP client transport (`udp://HOST:PORT`, `tcp://HOST:PORT`): a session with a
//! server, token-passing PDUs for requests and replies, keep-alives well before the
//! inactivity timer runs out, publish messages delivered as burst frames.

use std::io;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hart_ip::{encode, status, Body, Message, MessageId, MessageType, HEADER_LEN};
use hart_link::{Micros, TimingProfile};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpStream, UdpSocket};

use crate::transport::Transport;

/// A byte stream a secure session runs over: TCP for TLS, a datagram stream for DTLS.
trait Stream: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send {}
impl<T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send> Stream for T {}

/// A TLS or DTLS connection.
type Secure = hart_ip_tls::SslStream<Box<dyn Stream>>;

enum Socket {
    Udp(UdpSocket),
    Tcp(TcpStream, Vec<u8>),
    /// TLS (over TCP) or DTLS (over UDP) with a pre-shared key, and the bytes read
    /// but not yet split into messages.
    Secure(Box<Secure>, Vec<u8>),
}

/// A HART-IP session.
pub struct HartIpTransport {
    socket: Socket,
    addr: String,
    tcp: bool,
    /// The key of a secure (TLS/DTLS) session, kept to reconnect.
    psk: Option<hart_ip_tls::Psk>,
    peer: SocketAddr,
    start: Instant,
    sequence: u16,
    timer_ms: u32,
    last_tx: Instant,
    /// Bytes for the master: PDUs of replies and publish messages, with 2 preambles.
    pending: Vec<(u8, Micros)>,
    /// Sequence numbers of requests awaiting a reply.
    outstanding: Vec<u16>,
    /// The last request PDU (to repeat it after a reconnect, and to tell a retry of it
    /// from a new request).
    last_request: Option<Vec<u8>>,
    /// The server answered the request in progress with an empty response: the device
    /// did not reply on its loop (the status, named).
    no_reply: Option<String>,
}

fn proto_err(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

async fn open_socket(
    addr: &str,
    tcp: bool,
    psk: Option<&hart_ip_tls::Psk>,
) -> io::Result<(Socket, SocketAddr)> {
    let peer: SocketAddr = tokio::net::lookup_host(addr)
        .await?
        .next()
        .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, format!("{addr}: no address")))?;
    if let Some(psk) = psk {
        return Ok((secure_socket(peer, tcp, psk).await?, peer));
    }
    let socket = if tcp {
        let s = connect_tcp(peer).await?;
        Socket::Tcp(s, vec![])
    } else {
        let local = any_port(peer);
        Socket::Udp(UdpSocket::bind(local).await?)
    };
    Ok((socket, peer))
}

/// A TCP connection to `peer` (5 s at most), without Nagle's delay.
async fn connect_tcp(peer: SocketAddr) -> io::Result<TcpStream> {
    let s = tokio::time::timeout(Duration::from_secs(5), TcpStream::connect(peer))
        .await
        .map_err(|_| {
            io::Error::new(
                io::ErrorKind::TimedOut,
                format!("HART-IP server {peer}: TCP connect timed out"),
            )
        })??;
    s.set_nodelay(true)?;
    Ok(s)
}

/// The wildcard address of `peer`'s family, port 0: where a UDP client binds.
fn any_port(peer: SocketAddr) -> SocketAddr {
    if peer.is_ipv4() {
        SocketAddr::from(([0, 0, 0, 0], 0))
    } else {
        SocketAddr::from(([0u16; 8], 0))
    }
}

/// A TLS (`tcp`) or DTLS connection to `peer` with `psk`, handshake done.
async fn secure_socket(peer: SocketAddr, tcp: bool, psk: &hart_ip_tls::Psk) -> io::Result<Socket> {
    let what = if tcp { "TLS" } else { "DTLS" };
    let ctx = hart_ip_tls::client_context(psk, !tcp).map_err(io::Error::other)?;
    let ssl = hart_ip_tls::client_ssl(&ctx, !tcp).map_err(io::Error::other)?;
    let io: Box<dyn Stream> = if tcp {
        let s = connect_tcp(peer).await?;
        Box::new(s)
    } else {
        let local = any_port(peer);
        let s = UdpSocket::bind(local).await?;
        s.connect(peer).await?;
        Box::new(hart_ip_tls::DatagramStream::connected(s, peer))
    };
    let mut stream = hart_ip_tls::SslStream::new(ssl, io).map_err(io::Error::other)?;
    match tokio::time::timeout(
        Duration::from_secs(10),
        std::pin::Pin::new(&mut stream).connect(),
    )
    .await
    {
        Ok(Ok(())) => Ok(Socket::Secure(Box::new(stream), vec![])),
        Ok(Err(e)) => Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            format!(
                "HART-IP server {peer} refused the {what} handshake with identity {:?} ({e}); check the identity and the key (the server logs the cause), and that the server serves {what} there (hartkit serve --psk-file)",
                psk.identity
            ),
        )),
        Err(_) => Err(io::Error::new(
            io::ErrorKind::TimedOut,
            format!(
                "HART-IP server {peer}: no {what} handshake within 10 s; is a secure server there (hartkit serve --psk-file), and does a firewall let {} through?",
                if tcp { "TCP" } else { "UDP" }
            ),
        )),
    }
}

/// Reads what a stream (TCP, TLS or DTLS) has within `wait` onto `buf`: `false` on
/// time-out, an error when the server closed it.
async fn read_more(
    s: &mut (impl tokio::io::AsyncRead + Unpin),
    buf: &mut Vec<u8>,
    wait: Duration,
    peer: SocketAddr,
) -> io::Result<bool> {
    let mut tmp = [0u8; 4096];
    let Ok(r) = tokio::time::timeout(wait, s.read(&mut tmp)).await else {
        return Ok(false);
    };
    let n = r?;
    if n == 0 {
        return Err(io::Error::new(
            io::ErrorKind::ConnectionReset,
            format!("HART-IP server {peer} closed the connection"),
        ));
    }
    buf.extend_from_slice(&tmp[..n]);
    Ok(true)
}

/// What a session initiate response means: the inactivity timer the server granted (at
/// least 1 s), if it said, or the refusal, named. `again`: the session may still be
/// open at the server, which some servers answer with "access restricted" (16).
fn initiate_outcome(server: &str, st: u8, body: &[u8], again: bool) -> io::Result<Option<u32>> {
    match st {
        status::SUCCESS
        | status::SET_TO_NEAREST
        | status::VERSION_NOT_SUPPORTED
        | status::INSECURE_SESSION_EXISTS => Ok(
            match Body::parse(MessageId::SessionInitiate, MessageType::Response, body) {
                Ok(Body::SessionInitiate(s)) => Some(s.inactivity_timer_ms.max(1000)),
                _ => None,
            },
        ),
        status::ACCESS_RESTRICTED if again => Ok(None),
        code => Err(proto_err(format!(
            "{server} refused the session: {} ({code})",
            status::name(code)
        ))),
    }
}

impl HartIpTransport {
    /// Connects and initiates a session (primary master, `timer_ms` inactivity timer).
    pub async fn connect(addr: &str, tcp: bool, timer_ms: u32) -> io::Result<Self> {
        Self::connect_with(addr, tcp, None, timer_ms).await
    }

    /// Connects, with HART-IP version 2 security when `psk` is given (TLS over TCP,
    /// DTLS over UDP), and initiates a session.
    pub async fn connect_with(
        addr: &str,
        tcp: bool,
        psk: Option<hart_ip_tls::Psk>,
        timer_ms: u32,
    ) -> io::Result<Self> {
        let (socket, peer) = open_socket(addr, tcp, psk.as_ref()).await?;
        let mut t = HartIpTransport {
            socket,
            addr: addr.to_string(),
            tcp,
            psk,
            peer,
            start: Instant::now(),
            sequence: 0,
            timer_ms,
            last_tx: Instant::now(),
            pending: vec![],
            outstanding: vec![],
            last_request: None,
            no_reply: None,
        };
        t.initiate(Duration::from_secs(3), false).await?;
        Ok(t)
    }

    /// Session initiate on the current socket. `again`: the session may still be open
    /// at the server, which some servers answer with "access restricted" (16).
    async fn initiate(&mut self, wait: Duration, again: bool) -> io::Result<()> {
        let timer = self.timer_ms;
        let seq = self
            .send_message(
                MessageId::SessionInitiate,
                &hart_ip::session_initiate_body(1, timer),
            )
            .await?;
        let deadline = Instant::now() + wait;
        loop {
            let Some((header, body)) = self.read_message(deadline).await? else {
                return Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("HART-IP server {} did not answer the session initiate; is a server running there ({})?", self.peer, if self.tcp { "TCP" } else { "UDP" }),
                ));
            };
            if header.message_id == MessageId::SessionInitiate && header.sequence == seq {
                let server = format!("HART-IP server {}", self.peer);
                if let Some(timer) = initiate_outcome(&server, header.status, &body, again)? {
                    self.timer_ms = timer;
                }
                return Ok(());
            }
        }
    }

    /// A new connection and session after the server went away, then the last request
    /// again.
    async fn reconnect(&mut self) -> io::Result<()> {
        let (socket, peer) = open_socket(&self.addr, self.tcp, self.psk.as_ref()).await?;
        self.socket = socket;
        self.peer = peer;
        self.outstanding.clear();
        self.initiate(Duration::from_secs(2), false).await?;
        if let Some(pdu) = self.last_request.clone() {
            let seq = self.send_message(MessageId::TokenPassingPdu, &pdu).await?;
            self.outstanding.push(seq);
        }
        Ok(())
    }

    async fn send_message(&mut self, id: MessageId, body: &[u8]) -> io::Result<u16> {
        self.sequence = self.sequence.wrapping_add(1);
        let seq = self.sequence;
        let mut buf = vec![0u8; HEADER_LEN + body.len()];
        // HART-IP version 2 inside TLS/DTLS, 1 in the clear.
        let version = if self.psk.is_some() { 2 } else { 1 };
        encode(version, MessageType::Request, id, 0, seq, body, &mut buf)
            .map_err(|e| proto_err(e.to_string()))?;
        match &mut self.socket {
            Socket::Udp(s) => {
                s.send_to(&buf, self.peer).await?;
            }
            Socket::Tcp(s, _) => s.write_all(&buf).await?,
            Socket::Secure(s, _) => {
                s.write_all(&buf).await?;
                s.flush().await?;
            }
        }
        self.last_tx = Instant::now();
        Ok(seq)
    }

    /// Reads one message before `deadline` (`None` on time-out).
    async fn read_message(
        &mut self,
        deadline: Instant,
    ) -> io::Result<Option<(hart_ip::Header, Vec<u8>)>> {
        loop {
            if let Socket::Tcp(_, buf) | Socket::Secure(_, buf) = &mut self.socket {
                match Message::parse(buf) {
                    Ok((m, n)) => {
                        let out = (m.header, m.body.to_vec());
                        buf.drain(..n);
                        return Ok(Some(out));
                    }
                    Err(hart_ip::Error::ShortHeader { .. })
                    | Err(hart_ip::Error::Truncated { .. }) => {}
                    Err(e) => return Err(proto_err(format!("HART-IP server {}: {e}", self.peer))),
                }
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            let mut tmp = [0u8; 4096];
            match &mut self.socket {
                Socket::Udp(s) => {
                    let Ok(r) = tokio::time::timeout(deadline - now, s.recv_from(&mut tmp)).await
                    else {
                        return Ok(None);
                    };
                    let (n, from) = r?;
                    // A UDP server may answer from another port; the session follows it.
                    if from.ip() == self.peer.ip() {
                        self.peer = from;
                    }
                    if let Ok((m, _)) = Message::parse(&tmp[..n]) {
                        return Ok(Some((m.header, m.body.to_vec())));
                    }
                }
                Socket::Secure(s, buf) => {
                    if !read_more(s.as_mut(), buf, deadline - now, self.peer).await? {
                        return Ok(None);
                    }
                }
                Socket::Tcp(s, buf) => {
                    if !read_more(s, buf, deadline - now, self.peer).await? {
                        return Ok(None);
                    }
                }
            }
        }
    }

    /// Subscribes this session to the process data (burst messages) of every device
    /// behind the server (command 533 to the broadcast address, flags 0x0001). Servers
    /// that publish only to subscribers need it; others answer "not implemented", which
    /// is fine. Returns the response code, or `None` without an answer in 2 s.
    pub async fn subscribe_all(&mut self) -> io::Result<Option<u8>> {
        use hart_proto::command::{ClientSubscription, SubscriptionTarget};
        use hart_proto::frame::{Address, Frame, UniqueId};
        let every_device = hart_proto::Request::WriteClientSubscriptionFlags(ClientSubscription {
            unique_id: SubscriptionTarget::ALL,
            flags: hart_proto::command::subscription::PROCESS_DATA,
        });
        let broadcast = Address::long(UniqueId::from_bytes([0; 5]));
        let pdu = every_device
            .frame(broadcast)
            .map_err(|e| proto_err(e.to_string()))?;
        let seq = self
            .send_message(MessageId::TokenPassingPdu, pdu.as_slice())
            .await?;
        let deadline = Instant::now() + Duration::from_secs(2);
        while let Some((h, body)) = self.read_message(deadline).await? {
            match (h.message_type, h.message_id) {
                (MessageType::Response, MessageId::TokenPassingPdu) if h.sequence == seq => {
                    return Ok(Frame::parse_pdu(&body).ok().and_then(|f| f.response_code));
                }
                (MessageType::Publish, MessageId::TokenPassingPdu) => self.deliver(&body),
                _ => {}
            }
        }
        Ok(None)
    }

    /// Closes the session (best effort).
    pub async fn close(&mut self) {
        let _ = self.send_message(MessageId::SessionClose, &[]).await;
    }

    /// Sends one request message `id` with `body` and waits up to `timeout` for its
    /// response: the header's status and the body (publish messages that come
    /// meanwhile are kept for the loop's reader). For messages the transport does not
    /// send by itself: a Direct PDU ([`direct_pdu_body`]), a token-passing PDU whose
    /// HART-IP status matters.
    pub async fn exchange(
        &mut self,
        id: MessageId,
        body: &[u8],
        timeout: Duration,
    ) -> io::Result<(u8, Vec<u8>)> {
        let seq = self.send_message(id, body).await?;
        let deadline = Instant::now() + timeout;
        while let Some((h, body)) = self.read_message(deadline).await? {
            match (h.message_type, h.message_id) {
                (MessageType::Response | MessageType::Nak, m) if m == id && h.sequence == seq => {
                    return Ok((h.status, body));
                }
                (MessageType::Publish, MessageId::TokenPassingPdu) => self.deliver(&body),
                _ => {}
            }
        }
        Err(io::Error::new(
            io::ErrorKind::TimedOut,
            format!(
                "HART-IP server {} did not answer message {seq} within {} ms",
                self.peer,
                timeout.as_millis()
            ),
        ))
    }

    fn deliver(&mut self, pdu: &[u8]) {
        let now = self.now();
        self.pending
            .extend([0xFFu8, 0xFF].iter().chain(pdu).map(|&b| (b, now)));
    }
}

impl Transport for HartIpTransport {
    fn profile(&self) -> TimingProfile {
        TimingProfile::hart_ip()
    }

    fn now(&self) -> Micros {
        self.start.elapsed().as_micros() as Micros
    }

    async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
        let pdu = &bytes[pre..];
        let retry = !self.outstanding.is_empty() && self.last_request.as_deref() == Some(pdu);
        if retry {
            // The master repeats a request the server has not answered within STO.
            if self.tcp {
                // The stream lost nothing: the server is still working on it (a slow
                // loop or a queue); a second copy would only lengthen the queue.
                return Ok(());
            }
            // The datagram or its reply may be lost, or the server restarted and
            // forgot the session: open it again (harmless if it still exists), then
            // repeat. A late reply to the first copy answers the repeat too.
            if let Err(e) = self.initiate(Duration::from_secs(1), true).await {
                return Err(io::Error::new(
                    e.kind(),
                    format!(
                        "HART-IP server {} stopped answering: no reply to a request within {} s, nor to a new session initiate",
                        self.peer,
                        self.profile().sto / 1_000_000
                    ),
                ));
            }
        } else {
            // A new request: replies to earlier ones are stale from now on.
            self.outstanding.clear();
            self.last_request = Some(pdu.to_vec());
        }
        self.no_reply = None;
        let seq = self.send_message(MessageId::TokenPassingPdu, pdu).await?;
        self.outstanding.push(seq);
        Ok(())
    }

    fn take_no_reply(&mut self) -> Option<String> {
        self.no_reply.take()
    }

    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>> {
        loop {
            if !self.pending.is_empty() {
                return Ok(std::mem::take(&mut self.pending));
            }
            let now = self.now();
            if now >= deadline {
                return Ok(vec![]);
            }
            // A deadline nearer than the timer's 1 ms resolution (the master waits two
            // "characters", 20 µs, of quiet before its next request): a timed wait would
            // oversleep it by up to a millisecond, every transaction. Let the other
            // tasks run and the caller ask again; what arrives meanwhile stays in the
            // socket for the next call.
            if deadline - now < 1_000 {
                tokio::task::yield_now().await;
                return Ok(vec![]);
            }
            // Keep the session alive well before the inactivity timer runs out.
            if self.last_tx.elapsed() >= Duration::from_millis(u64::from(self.timer_ms) / 3) {
                self.send_message(MessageId::KeepAlive, &[]).await?;
            }
            let keepalive_at = self.last_tx + Duration::from_millis(u64::from(self.timer_ms) / 3);
            let until = self.start + Duration::from_micros(deadline);
            let recheck = Instant::now() + Duration::from_millis(250);
            let got = match self
                .read_message(until.min(keepalive_at).min(recheck))
                .await
            {
                Ok(g) => g,
                // A TCP server that went away: connect again and repeat the request.
                Err(e)
                    if self.tcp
                        && matches!(
                            e.kind(),
                            io::ErrorKind::ConnectionReset
                                | io::ErrorKind::ConnectionAborted
                                | io::ErrorKind::BrokenPipe
                                | io::ErrorKind::UnexpectedEof
                        ) =>
                {
                    self.reconnect().await?;
                    continue;
                }
                Err(e) => return Err(e),
            };
            let Some((h, body)) = got else {
                continue;
            };
            match (h.message_type, h.message_id) {
                (MessageType::Response, MessageId::TokenPassingPdu)
                    if self.outstanding.contains(&h.sequence) =>
                {
                    // One answer ends the request, whichever copy it answers.
                    self.outstanding.clear();
                    if body.is_empty() {
                        self.no_reply = Some(format!(
                            "HART-IP status {}: {}",
                            h.status,
                            status::name(h.status)
                        ));
                        return Ok(vec![]);
                    }
                    self.deliver(&body);
                }
                (MessageType::Publish, MessageId::TokenPassingPdu) => self.deliver(&body),
                (MessageType::Response, MessageId::SessionClose) | (MessageType::Nak, _) => {
                    return Err(io::Error::new(
                        io::ErrorKind::ConnectionAborted,
                        format!(
                            "HART-IP server {} ended the session ({})",
                            self.peer,
                            status::name(h.status)
                        ),
                    ));
                }
                _ => {}
            }
        }
    }

    fn describe(&self) -> String {
        format!(
            "HART-IP {} {}",
            match (&self.socket, self.tcp) {
                (Socket::Tcp(..), _) => "tcp",
                (Socket::Udp(..), _) => "udp",
                (Socket::Secure(..), true) => "tls",
                (Socket::Secure(..), false) => "dtls",
            },
            self.peer
        )
    }
}

impl Drop for HartIpTransport {
    fn drop(&mut self) {
        // Close the session on exit (best effort, without waiting).
        self.sequence = self.sequence.wrapping_add(1);
        let mut buf = [0u8; HEADER_LEN];
        if encode(
            1,
            MessageType::Request,
            MessageId::SessionClose,
            0,
            self.sequence,
            &[],
            &mut buf,
        )
        .is_ok()
        {
            match &self.socket {
                Socket::Udp(s) => {
                    let _ = s.try_send_to(&buf, self.peer);
                }
                Socket::Tcp(s, _) => {
                    let _ = s.try_write(&buf);
                }
                // A secure session ends with its connection (no blocking write here).
                Socket::Secure(..) => {}
            }
        }
    }
}

/// The writing half of a [`HartIpSession`]'s socket.
enum SessionWriter {
    Udp(std::sync::Arc<UdpSocket>),
    Tcp(tokio::net::tcp::OwnedWriteHalf),
}

/// Requests awaiting their response, by sequence number: the status and body.
type Waiters = std::sync::Arc<
    std::sync::Mutex<std::collections::HashMap<u16, tokio::sync::oneshot::Sender<(u8, Vec<u8>)>>>,
>;

/// A HART-IP session that carries several requests at once: each token-passing request
/// is matched to its response by sequence number, whatever order the server answers
/// in (a gateway with several loops answers each when its loop does). Publish messages
/// arrive on [`HartIpSession::next_publish`]. Share it between tasks behind an `Arc`.
///
/// The data-link master ([`crate::Client`] over [`HartIpTransport`]) runs one
/// transaction at a time, as on a wire; this is the lower-level path for hosts that
/// poll many devices behind one server.
pub struct HartIpSession {
    writer: tokio::sync::Mutex<SessionWriter>,
    /// Where requests go (a UDP server may answer from another port; the session
    /// follows it).
    peer: std::sync::Arc<std::sync::Mutex<SocketAddr>>,
    sequence: std::sync::atomic::AtomicU16,
    waiters: Waiters,
    publishes: tokio::sync::Mutex<tokio::sync::mpsc::Receiver<Vec<u8>>>,
    reader: tokio::task::JoinHandle<()>,
    timer_ms: u32,
}

impl HartIpSession {
    /// Connects to `addr` (`HOST:PORT`) over TCP or UDP and initiates a session as
    /// primary master with the inactivity timer `timer_ms`.
    pub async fn connect(addr: &str, tcp: bool, timer_ms: u32) -> io::Result<Self> {
        let (socket, peer) = open_socket(addr, tcp, None).await?;
        let waiters: Waiters = Default::default();
        let peer = std::sync::Arc::new(std::sync::Mutex::new(peer));
        let (ptx, prx) = tokio::sync::mpsc::channel(256);
        let (writer, reader) = match socket {
            Socket::Udp(s) => {
                let s = std::sync::Arc::new(s);
                let (r, w, p) = (s.clone(), waiters.clone(), peer.clone());
                let reader = tokio::spawn(async move {
                    let mut buf = [0u8; 4096];
                    while let Ok((n, from)) = r.recv_from(&mut buf).await {
                        if let Ok(mut p) = p.lock() {
                            if from.ip() != p.ip() {
                                continue;
                            }
                            *p = from;
                        }
                        let mut rest = &buf[..n];
                        while let Ok((m, used)) = Message::parse(rest) {
                            dispatch(&w, &ptx, m.header, m.body);
                            rest = &rest[used..];
                        }
                    }
                });
                (SessionWriter::Udp(s), reader)
            }
            Socket::Tcp(s, _) => {
                let (mut rd, wr) = s.into_split();
                let w = waiters.clone();
                let reader = tokio::spawn(async move {
                    let mut buf = vec![];
                    let mut tmp = [0u8; 4096];
                    loop {
                        while let Ok((m, used)) = Message::parse(&buf) {
                            dispatch(&w, &ptx, m.header, m.body);
                            buf.drain(..used);
                        }
                        match rd.read(&mut tmp).await {
                            Ok(n) if n > 0 && buf.len() < 65_536 => {
                                buf.extend_from_slice(&tmp[..n])
                            }
                            // Closed (or a stream that cannot be split): every waiter
                            // learns it from its dropped sender.
                            _ => {
                                if let Ok(mut w) = w.lock() {
                                    w.clear();
                                }
                                return;
                            }
                        }
                    }
                });
                (SessionWriter::Tcp(wr), reader)
            }
            // Opened without a key: never secure.
            Socket::Secure(..) => {
                return Err(io::Error::other("HartIpSession carries plain HART-IP only"))
            }
        };
        let mut session = HartIpSession {
            writer: tokio::sync::Mutex::new(writer),
            peer,
            sequence: std::sync::atomic::AtomicU16::new(0),
            waiters,
            publishes: tokio::sync::Mutex::new(prx),
            reader,
            timer_ms,
        };
        let what = session.describe();
        let (st, body) = session
            .exchange(
                MessageId::SessionInitiate,
                &hart_ip::session_initiate_body(1, timer_ms),
                Duration::from_secs(3),
            )
            .await
            .map_err(|e| match e.kind() {
                io::ErrorKind::TimedOut => io::Error::new(
                    e.kind(),
                    format!(
                        "{what} did not answer the session initiate; is a server running there?"
                    ),
                ),
                _ => e,
            })?;
        if let Some(timer) = initiate_outcome(&what, st, &body, false)? {
            session.timer_ms = timer;
        }
        Ok(session)
    }

    fn describe(&self) -> String {
        let peer = self
            .peer
            .lock()
            .map_or_else(|_| "?".into(), |p| p.to_string());
        format!("HART-IP server {peer}")
    }

    /// Sends a request message and waits up to `timeout` for the response with its
    /// sequence number: the status and body.
    async fn exchange(
        &self,
        id: MessageId,
        body: &[u8],
        timeout: Duration,
    ) -> io::Result<(u8, Vec<u8>)> {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let mut buf = vec![0u8; HEADER_LEN + body.len()];
        let seq = {
            // The sequence number and the send go together, so messages leave in order,
            // and the waiter is in place before a fast response can arrive.
            let mut writer = self.writer.lock().await;
            let seq = self
                .sequence
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
                .wrapping_add(1);
            encode(1, MessageType::Request, id, 0, seq, body, &mut buf)
                .map_err(|e| proto_err(e.to_string()))?;
            if let Ok(mut w) = self.waiters.lock() {
                w.insert(seq, tx);
            }
            let peer = self.peer.lock().map(|p| *p).ok();
            let sent = match (&mut *writer, peer) {
                (SessionWriter::Udp(s), Some(peer)) => s.send_to(&buf, peer).await.map(|_| ()),
                (SessionWriter::Tcp(s), _) => s.write_all(&buf).await,
                (_, None) => Err(io::Error::other("session state poisoned")),
            };
            if let Err(e) = sent {
                self.forget(seq);
                return Err(e);
            }
            seq
        };
        match tokio::time::timeout(timeout, rx).await {
            Ok(Ok(r)) => Ok(r),
            Ok(Err(_)) => Err(io::Error::new(
                io::ErrorKind::ConnectionReset,
                format!("{} closed the session", self.describe()),
            )),
            Err(_) => {
                self.forget(seq);
                Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!(
                        "{} did not answer message {seq} within {} ms",
                        self.describe(),
                        timeout.as_millis()
                    ),
                ))
            }
        }
    }

    /// Sends a token-passing request (a frame from the delimiter through the check
    /// byte) and waits up to `timeout` for its reply PDU. Other requests may be in
    /// flight meanwhile. An empty response (the device did not answer on the server's
    /// loop) is an error of kind `NotFound` that names the status.
    pub async fn request(&self, pdu: &[u8], timeout: Duration) -> io::Result<Vec<u8>> {
        let (st, body) = self
            .exchange(MessageId::TokenPassingPdu, pdu, timeout)
            .await?;
        if body.is_empty() {
            return Err(io::Error::new(
                io::ErrorKind::NotFound,
                format!(
                    "{}: no reply from the device on its loop (status {st}: {})",
                    self.describe(),
                    status::name(st)
                ),
            ));
        }
        Ok(body)
    }

    fn forget(&self, seq: u16) {
        if let Ok(mut w) = self.waiters.lock() {
            w.remove(&seq);
        }
    }

    /// Requests awaiting their reply now.
    pub fn in_flight(&self) -> usize {
        self.waiters.lock().map_or(0, |w| w.len())
    }

    /// The next publish message's PDU (a burst frame), or `None` once the session is
    /// over.
    pub async fn next_publish(&self) -> Option<Vec<u8>> {
        self.publishes.lock().await.recv().await
    }

    /// A keep-alive round trip (send one at least every third of
    /// [`HartIpSession::timer_ms`] while no request goes out).
    pub async fn keep_alive(&self) -> io::Result<()> {
        self.exchange(MessageId::KeepAlive, &[], Duration::from_secs(3))
            .await
            .map(|_| ())
    }

    /// The inactivity timer the server granted, ms.
    pub fn timer_ms(&self) -> u32 {
        self.timer_ms
    }

    /// Closes the session and waits briefly for the server to confirm.
    pub async fn close(self) {
        let _ = self
            .exchange(MessageId::SessionClose, &[], Duration::from_millis(500))
            .await;
    }
}

impl Drop for HartIpSession {
    fn drop(&mut self) {
        self.reader.abort();
    }
}

/// Hands a received message to the request waiting for it, or to the publish queue.
fn dispatch(
    waiters: &Waiters,
    publishes: &tokio::sync::mpsc::Sender<Vec<u8>>,
    h: hart_ip::Header,
    body: &[u8],
) {
    match h.message_type {
        MessageType::Response | MessageType::Nak => {
            let w = waiters.lock().ok().and_then(|mut w| w.remove(&h.sequence));
            if let Some(w) = w {
                let _ = w.send((h.status, body.to_vec()));
            }
        }
        MessageType::Publish if h.message_id == MessageId::TokenPassingPdu => {
            // A full queue drops the newest: nobody is reading.
            let _ = publishes.try_send(body.to_vec());
        }
        _ => {}
    }
}

/// The body of a Direct PDU request (message ID 4): device status and extended status
/// 0, then each command with its byte count and data (data longer than 255 bytes is
/// cut).
pub fn direct_pdu_body(entries: &[(u16, &[u8])]) -> Vec<u8> {
    let mut out = vec![0, 0];
    for (command, data) in entries {
        let data = &data[..data.len().min(255)];
        out.extend_from_slice(&command.to_be_bytes());
        out.push(data.len() as u8);
        out.extend_from_slice(data);
    }
    out
}

/// The entries of a Direct PDU response body: command, response code, data.
pub fn direct_pdu_reply(body: &[u8]) -> Vec<(u16, u8, Vec<u8>)> {
    match body.get(2..) {
        Some(entries) => hart_ip::DirectEntries(entries)
            .flatten()
            .map(|e| {
                (
                    e.command,
                    e.data.first().copied().unwrap_or(0),
                    e.data.get(1..).unwrap_or(&[]).to_vec(),
                )
            })
            .collect(),
        None => vec![],
    }
}
