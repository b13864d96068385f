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

enum Socket {
    Udp(UdpSocket),
    Tcp(TcpStream, Vec<u8>),
}

/// A HART-IP session.
pub struct HartIpTransport {
    socket: Socket,
    addr: String,
    tcp: bool,
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

async fn open_socket(addr: &str, tcp: bool) -> io::Result<(Socket, SocketAddr)> {
    let peer: SocketAddr = tokio::net::lookup_host(addr)
        .await?
        .next()
        .ok_or_else(|| io::Error::new(io::ErrorKind::NotFound, format!("{addr}: no address")))?;
    let socket = if tcp {
        let s = tokio::time::timeout(Duration::from_secs(5), TcpStream::connect(peer))
            .await
            .map_err(|_| {
                io::Error::new(
                    io::ErrorKind::TimedOut,
                    format!("HART-IP server {peer}: TCP connect timed out"),
                )
            })??;
        s.set_nodelay(true)?;
        Socket::Tcp(s, vec![])
    } else {
        let local: SocketAddr = if peer.is_ipv4() {
            "0.0.0.0:0".parse().unwrap()
        } else {
            "[::]:0".parse().unwrap()
        };
        Socket::Udp(UdpSocket::bind(local).await?)
    };
    Ok((socket, peer))
}

impl HartIpTransport {
    /// Connects and initiates a session (primary master, `timer_ms` inactivity timer).
    pub async fn connect(addr: &str, tcp: bool, timer_ms: u32) -> io::Result<Self> {
        let (socket, peer) = open_socket(addr, tcp).await?;
        let mut t = HartIpTransport {
            socket,
            addr: addr.to_string(),
            tcp,
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
                return match header.status {
                    status::SUCCESS
                    | status::SET_TO_NEAREST
                    | status::VERSION_NOT_SUPPORTED
                    | status::INSECURE_SESSION_EXISTS => {
                        if let Ok(Body::SessionInitiate(s)) =
                            Body::parse(header.message_id, header.message_type, &body)
                        {
                            self.timer_ms = s.inactivity_timer_ms.max(1000);
                        }
                        Ok(())
                    }
                    status::ACCESS_RESTRICTED if again => Ok(()),
                    code => Err(proto_err(format!(
                        "HART-IP server {} refused the session: {} ({code})",
                        self.peer,
                        status::name(code)
                    ))),
                };
            }
        }
    }

    /// A new connection and session after the server went away, then the last request
    /// again.
    async fn reconnect(&mut self) -> io::Result<()> {
        let (socket, peer) = open_socket(&self.addr, self.tcp).await?;
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
        encode(1, MessageType::Request, id, 0, seq, body, &mut buf)
            .map_err(|e| proto_err(e.to_string()))?;
        match &mut self.socket {
            Socket::Udp(s) => {
                s.send_to(&buf, self.peer).await?;
            }
            Socket::Tcp(s, _) => s.write_all(&buf).await?,
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
            if let Socket::Tcp(_, buf) = &mut self.socket {
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
                Socket::Tcp(s, buf) => {
                    let Ok(r) = tokio::time::timeout(deadline - now, s.read(&mut tmp)).await else {
                        return Ok(None);
                    };
                    let n = r?;
                    if n == 0 {
                        return Err(io::Error::new(
                            io::ErrorKind::ConnectionReset,
                            format!("HART-IP server {} closed the connection", self.peer),
                        ));
                    }
                    buf.extend_from_slice(&tmp[..n]);
                }
            }
        }
    }

    /// Closes the session (best effort).
    pub async fn close(&mut self) {
        let _ = self.send_message(MessageId::SessionClose, &[]).await;
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
            if matches!(self.socket, Socket::Tcp(..)) {
                "tcp"
            } else {
                "udp"
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
            }
        }
    }
}
