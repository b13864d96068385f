//! HART-IP over byte streams: TCP, TLS with pre-shared keys over TCP, and the
//! session side of DTLS.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use hart_access::pool::{Admission, Pool};
use hart_ip::{Message, MessageId, MessageType};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Mutex;

use crate::session::{close_session, forwarded, handle, Action, Session};
use crate::{message, AbortOnDrop, Counters, Shared};

/// Requests of one TCP session waiting for loops at once; more are answered "busy".
pub(crate) const MAX_IN_FLIGHT: usize = 8;

/// Connections accepted beyond the session limit, for handshakes and initiates in
/// progress.
const PENDING_CONNECTIONS: usize = 16;

/// Connections one host may hold beyond its session limit
/// ([`crate::Config::max_sessions_per_host`]), to be answered "all available sessions
/// in use" rather than closed.
const PENDING_PER_HOST: usize = 2;

/// Longest a TLS or DTLS handshake may take before the peer is dropped.
pub(crate) const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Accepts TCP connections: each a plain session, or, with `tls`, a TLS handshake
/// first (pre-shared keys) and then the session inside it.
pub(crate) async fn serve_tcp(
    listener: TcpListener,
    shared: Arc<Shared>,
    tls: Option<Arc<crate::Security>>,
) {
    // Connections beyond the session limit (and a few in their handshake or initiate)
    // are closed at once: they could only be refused. So are those from a host that
    // already holds its share (and a couple more, so that a client over its limit
    // still hears status 15 rather than a closed connection): a connection carries at
    // most one session, so one host's connections, in their handshake or not, can
    // never keep the others out. None is closed to admit another.
    let none = hart_access::NetList::empty();
    let limits = Admission {
        max_connections: shared.config.max_sessions + PENDING_CONNECTIONS,
        max_per_address: shared.config.max_sessions_per_host + PENDING_PER_HOST,
        priority: &none,
        evict_at_address_limit: false,
    };
    // Each connection's task (its session ends with the server).
    let mut connections: Pool<Option<AbortOnDrop>> = Pool::default();
    loop {
        let Ok((stream, peer)) = listener.accept().await else {
            continue;
        };
        let _ = stream.set_nodelay(true);
        connections.retain(|c| c.state.as_ref().is_some_and(|t| !t.0.is_finished()));
        let Ok((id, _)) = connections.admit(peer, &limits, Instant::now(), None, |_| None) else {
            Counters::count(&shared.stats.sessions_refused);
            drop(stream);
            continue;
        };
        let shared = shared.clone();
        let task = match tls.clone() {
            None => tokio::task::spawn_local(async move {
                let local_port = stream.local_addr().map_or(0, |a| a.port());
                stream_session(stream, Session::new(peer, local_port), shared).await
            }),
            Some(tls) => tokio::task::spawn_local(tls_session(stream, peer, shared, tls)),
        };
        if let Some(c) = connections.get_mut(id) {
            c.state = Some(AbortOnDrop(task));
        }
    }
}

/// A TLS handshake with pre-shared keys, then the session; a refusal is logged with
/// its cause and ends only this connection.
async fn tls_session(
    stream: TcpStream,
    peer: SocketAddr,
    shared: Arc<Shared>,
    tls: Arc<crate::Security>,
) {
    let mut stream = stream;
    let local_port = stream.local_addr().map_or(0, |a| a.port());
    let mut first = [0u8; 1];
    let first_byte = match tokio::time::timeout(HANDSHAKE_TIMEOUT, stream.peek(&mut first)).await {
        Ok(Ok(1)) => Some(first[0]),
        _ => None,
    };
    // HART-IP version 2 in the clear first: the session initiate of the STARTTLS order
    // (HCF_SPEC-085 as hipserver and hartip-py implement it), then the handshake.
    let opened = if first_byte == Some(2) {
        match plaintext_initiate(&mut stream, peer, local_port, &shared).await {
            Some(s) => Some(s),
            None => return,
        }
    } else {
        None
    };
    secure_session(
        stream, peer, local_port, first_byte, shared, &tls, false, opened,
    )
    .await
}

/// The STARTTLS order: one session initiate of HART-IP version 2 in the clear, answered
/// in the clear; the session it opens (its identity still unknown) goes on inside the
/// TLS handshake that follows. `None` when it is no such initiate or the session is
/// refused (limits); the connection then ends.
async fn plaintext_initiate(
    stream: &mut TcpStream,
    peer: SocketAddr,
    local_port: u16,
    shared: &Arc<Shared>,
) -> Option<Session> {
    let mut header = [0u8; hart_ip::HEADER_LEN];
    let read = async {
        stream.read_exact(&mut header).await?;
        let len = usize::from(u16::from_be_bytes([header[6], header[7]]));
        let mut msg = header.to_vec();
        msg.resize(len.clamp(hart_ip::HEADER_LEN, 64), 0);
        stream.read_exact(&mut msg[hart_ip::HEADER_LEN..]).await?;
        Ok::<_, std::io::Error>(msg)
    };
    let msg = match tokio::time::timeout(HANDSHAKE_TIMEOUT, read).await {
        Ok(Ok(m)) => m,
        _ => {
            tracing::warn!("refused a session from {peer}: no complete session initiate");
            return None;
        }
    };
    let (m, _) = Message::parse(&msg).ok()?;
    if m.header.message_id != MessageId::SessionInitiate
        || m.header.message_type != MessageType::Request
    {
        Counters::count(&shared.stats.sessions_refused);
        tracing::warn!(
            "refused {peer}: plain HART-IP other than a version 2 session initiate on the TLS port"
        );
        return None;
    }
    // Rights and identity come with the handshake; read-only until then.
    let mut s = Session::secure(
        peer,
        local_port,
        String::new(),
        hart_ip_tls::Rights::ReadOnly,
    );
    if let Action::Reply(r) = handle(shared, &mut s, m.header, m.body).await {
        if stream.write_all(&r).await.is_err() {
            close_session(shared, &mut s, 0x0004).await;
            return None;
        }
    }
    s.open.then_some(s)
}

/// The server side of a TLS (over TCP) or DTLS (`dtls`, over one peer's datagrams)
/// handshake with pre-shared keys on `io`, then one session inside it. A refusal is
/// logged with its cause (`first_byte`, the first byte the peer sent, tells plain
/// HART-IP from a failed handshake) and ends only this peer.
/// `opened`: the session a plaintext initiate opened before the handshake (STARTTLS
/// order), which the handshake completes; without it the session starts inside.
#[allow(clippy::too_many_arguments)]
pub(crate) async fn secure_session<S>(
    io: S,
    peer: SocketAddr,
    local_port: u16,
    first_byte: Option<u8>,
    shared: Arc<Shared>,
    sec: &crate::Security,
    dtls: bool,
    opened: Option<Session>,
) where
    S: AsyncRead + AsyncWrite + Unpin + 'static,
{
    let what = if dtls { "DTLS" } else { "TLS" };
    let ctx = if dtls { &sec.dtls } else { &sec.tls };
    let (ssl, note) = match hart_ip_tls::server_ssl(ctx, dtls) {
        Ok(x) => x,
        Err(e) => {
            tracing::error!("{what} from {peer}: {e}");
            return;
        }
    };
    let Ok(mut stream) = hart_ip_tls::SslStream::new(ssl, io) else {
        return;
    };
    let accepted =
        tokio::time::timeout(HANDSHAKE_TIMEOUT, std::pin::Pin::new(&mut stream).accept()).await;
    let refused = match accepted {
        Ok(Ok(())) => None,
        Ok(Err(e)) => {
            let n = note.lock().map(|n| n.clone()).unwrap_or_default();
            Some(hart_ip_tls::refusal(&n, &e, first_byte).to_string())
        }
        Err(_) => Some(format!(
            "no complete handshake within {} s",
            HANDSHAKE_TIMEOUT.as_secs()
        )),
    };
    if let Some(why) = refused {
        Counters::count(&shared.stats.sessions_refused);
        tracing::warn!("refused {what} from {peer}: {why}");
        if let Some(mut s) = opened {
            close_session(&shared, &mut s, 0x0002).await; // bad session initialization
        }
        return;
    }
    let identity = stream
        .ssl()
        .psk_identity()
        .map(|i| String::from_utf8_lossy(i).into_owned())
        // TLS 1.3 sessions keep no identity there: the one the key was found for.
        .or_else(|| note.lock().ok().and_then(|n| n.identity.clone()))
        .unwrap_or_default();
    let rights = sec
        .keys
        .find(&identity)
        .map(|k| k.rights)
        .unwrap_or(hart_ip_tls::Rights::ReadOnly);
    tracing::info!("{what} session from {peer}, identity {identity:?} ({rights:?})");
    let s = match opened {
        Some(mut s) => {
            s.secure = Some((identity, rights));
            s
        }
        None => Session::secure(peer, local_port, identity, rights),
    };
    stream_session(stream, s, shared).await
}

/// One session over a byte stream: plain TCP, TLS over TCP, or DTLS (whose records
/// carry HART-IP messages just as a stream does). `s` is the fresh session.
pub(crate) async fn stream_session<S>(stream: S, mut s: Session, shared: Arc<Shared>)
where
    S: AsyncRead + AsyncWrite + 'static,
{
    let (mut rd, wr) = tokio::io::split(stream);
    let wr = Arc::new(Mutex::new(wr));
    let mut in_flight: Vec<AbortOnDrop> = vec![];
    let mut buf: Vec<u8> = vec![];
    let mut bursts = shared.bursts.subscribe();
    let mut tmp = [0u8; 4096];
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
                            let mut w = wr.lock().await;
                            let _ = w.write_all(&r).await;
                            // TLS: close_notify, so the client sees a clean end.
                            let _ = w.shutdown().await;
                            close_session(&shared, &mut s, 0).await;
                            return;
                        }
                        Action::Close => {
                            close_session(&shared, &mut s, 0x0004).await;
                            return;
                        }
                        Action::Forward {
                            channel,
                            retries,
                            pdu,
                            seq,
                            from,
                        } => {
                            // Several requests may be in flight on one connection: each
                            // reply goes out when its loop answers, with its sequence
                            // number, while this task reads on and publishes. The
                            // replies' writers end with the session.
                            let (shared, wr, version) = (shared.clone(), wr.clone(), s.version);
                            in_flight.retain(|t: &AbortOnDrop| !t.0.is_finished());
                            if in_flight.len() >= MAX_IN_FLIGHT {
                                // Enough of this session's requests are waiting already.
                                Counters::count(&shared.stats.busy);
                                let r = message(
                                    version,
                                    MessageType::Response,
                                    MessageId::TokenPassingPdu,
                                    0,
                                    seq,
                                    &crate::session::busy(&pdu),
                                );
                                if wr.lock().await.write_all(&r).await.is_err() {
                                    close_session(&shared, &mut s, 0x0004).await;
                                    return;
                                }
                                continue;
                            }
                            in_flight.push(AbortOnDrop(tokio::task::spawn_local(async move {
                                let r =
                                    forwarded(&shared, version, channel, retries, pdu, seq, from)
                                        .await;
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
                    Counters::count(&shared.stats.malformed);
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            }
        }
        let timer = s.silence_allowed();
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
            b = bursts.recv() => if let Some(m) = b.ok().and_then(|b| s.publish(&shared, &b)) {
                if wr.lock().await.write_all(&m).await.is_err() {
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            },
        }
    }
}
