//! The accept loop in front of `async-opcua` (which takes only a listener, and bounds
//! no number of connections): it accepts on the public address, admits or refuses each
//! connection by [`connections::Pool`], and splices an admitted one to the library's
//! listener on a loopback port (`copy` both ways), watching the server's side of the
//! handshake until the secure channel is open, and the client's requests for sessions
//! created and never activated ([`crate::sessions`]).

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Notify;

use crate::connections::{self, Handshake, HandshakeWatch, Limits, LogLimit, Pool};
use crate::sessions::{Request, RequestWatch, SessionGuard, SessionRefused};

/// BadTcpServerTooBusy.
const TOO_BUSY: u32 = 0x807D_0000;
/// BadTooManySessions.
const TOO_MANY_SESSIONS: u32 = 0x8056_0000;

/// Bytes read at once either way.
const BUFFER: usize = 16 * 1024;

/// The pool, the closers of its connections, the log budget.
#[derive(Default)]
pub(crate) struct Shared {
    pool: Mutex<(Pool, HashMap<u64, Arc<Notify>>)>,
    sessions: Mutex<SessionGuard>,
    log: Mutex<LogLimit>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Shared {
    /// Whether a line about a connection may be logged now (and says how many were
    /// left out in the last second(s) first).
    fn log(&self) -> bool {
        lock(&self.log).allow_logged(Instant::now(), "opcua")
    }
}

/// Accepts on `listener` for ever, splicing admitted connections to `backend`.
pub(crate) async fn run(
    listener: TcpListener,
    backend: SocketAddr,
    limits: Arc<Limits>,
    shared: Arc<Shared>,
) {
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(x) => x,
            Err(e) => {
                // Out of descriptors, mostly: wait rather than spin.
                if shared.log() {
                    tracing::warn!("opcua: accepting a connection: {e}");
                }
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let admitted = {
            let mut g = lock(&shared.pool);
            let (pool, closers) = &mut *g;
            match pool.admit(peer, &limits, Instant::now()) {
                Ok((id, evicted)) => {
                    let close = Arc::new(Notify::new());
                    closers.insert(id, close.clone());
                    if let Some(ev) = &evicted {
                        if let Some(c) = closers.remove(&ev.id) {
                            c.notify_one();
                        }
                    }
                    Ok((id, close, evicted))
                }
                Err(refused) => Err(refused),
            }
        };
        match admitted {
            Ok((id, close, evicted)) => {
                if let Some(ev) = evicted {
                    if shared.log() {
                        let what = match ev.phase {
                            connections::Phase::Handshake => "its secure channel not open yet",
                            connections::Phase::Open => "open",
                        };
                        tracing::warn!(
                            "opcua: closing the connection from {} ({what}, idle {:.0} s, open {:.0} s) to admit {peer}: {} connections open (the limit, [opcua] max_connections)",
                            ev.peer,
                            ev.idle.as_secs_f64(),
                            ev.age.as_secs_f64(),
                            limits.max_connections
                        );
                    }
                }
                tokio::spawn(splice(
                    stream,
                    peer,
                    id,
                    close,
                    backend,
                    limits.clone(),
                    shared.clone(),
                ));
            }
            Err(refused) => {
                if shared.log() {
                    tracing::warn!("opcua: refused the connection from {peer}: {refused}");
                }
                // Tell the client why, if its socket takes it at once; never wait.
                let _ = stream.try_write(&connections::err_message(
                    TOO_BUSY,
                    &format!("hartkit gateway: connection refused: {refused}"),
                ));
            }
        }
    }
}

/// Why a spliced connection ended, when it is worth a line.
enum End {
    Quiet,
    Timeout,
    Failed(&'static str),
    Evicted,
    Sessions(SessionRefused),
    Backend(std::io::Error),
}

async fn splice(
    client: TcpStream,
    peer: SocketAddr,
    id: u64,
    close: Arc<Notify>,
    backend: SocketAddr,
    limits: Arc<Limits>,
    shared: Arc<Shared>,
) {
    let end = match TcpStream::connect(backend).await {
        Ok(server) => pump(client, server, peer, id, &close, &limits, &shared).await,
        Err(e) => End::Backend(e),
    };
    let line = match end {
        End::Quiet | End::Evicted => None,
        End::Timeout => Some(format!(
            "no secure channel opened within {:.0} s ([opcua] handshake_timeout): a port scanner, a client that is not OPC UA, or one too slow",
            limits.handshake.as_secs_f64()
        )),
        End::Failed(why) => Some(format!("the handshake failed: {why}")),
        End::Sessions(why) => Some(format!("CreateSession refused: {why}")),
        End::Backend(e) => Some(format!(
            "the OPC UA server on {backend} (loopback) could not be reached: {e}"
        )),
    };
    {
        let mut g = lock(&shared.pool);
        g.0.remove(id);
        g.1.remove(&id);
    }
    lock(&shared.sessions).closed(id);
    if let Some(line) = line {
        if shared.log() {
            tracing::warn!("opcua: closed the connection from {peer}: {line}");
        }
    }
}

async fn pump(
    mut client: TcpStream,
    mut server: TcpStream,
    peer: SocketAddr,
    id: u64,
    close: &Notify,
    limits: &Limits,
    shared: &Shared,
) -> End {
    let _ = client.set_nodelay(true);
    let _ = server.set_nodelay(true);
    let (mut cr, mut cw) = client.split();
    let (mut sr, mut sw) = server.split();
    let mut cbuf = vec![0u8; BUFFER];
    let mut sbuf = vec![0u8; BUFFER];
    let mut watch = HandshakeWatch::default();
    let mut requests = RequestWatch::default();
    let mut open = false;
    let deadline = tokio::time::Instant::now() + limits.handshake;
    // The pool learns of the client's bytes at most once a second.
    let mut told = Instant::now();
    loop {
        tokio::select! {
            r = cr.read(&mut cbuf) => {
                let n = match r { Ok(0) | Err(_) => return End::Quiet, Ok(n) => n };
                let now = Instant::now();
                if open && now.saturating_duration_since(told) >= Duration::from_secs(1) {
                    lock(&shared.pool).0.sent(id, now);
                    told = now;
                }
                if let Err(why) = follow(&mut requests, &cbuf[..n], shared, id, peer, limits, now) {
                    // Not passed on: tell the client why, and close.
                    let reason = format!("hartkit gateway: {why}");
                    let _ = cw
                        .write_all(&connections::err_message(TOO_MANY_SESSIONS, &reason))
                        .await;
                    return End::Sessions(why);
                }
                if sw.write_all(&cbuf[..n]).await.is_err() {
                    return End::Quiet;
                }
            }
            r = sr.read(&mut sbuf) => {
                let n = match r { Ok(0) | Err(_) => return End::Quiet, Ok(n) => n };
                if !open {
                    match watch.feed(&sbuf[..n]) {
                        Handshake::Pending => {}
                        Handshake::Open => {
                            open = true;
                            lock(&shared.pool).0.opened(id, Instant::now());
                        }
                        Handshake::Failed(why) => {
                            // The server's ERR still goes to the client.
                            let _ = cw.write_all(&sbuf[..n]).await;
                            return End::Failed(why);
                        }
                    }
                }
                if cw.write_all(&sbuf[..n]).await.is_err() {
                    return End::Quiet;
                }
            }
            _ = close.notified() => return End::Evicted,
            _ = tokio::time::sleep_until(deadline), if !open => return End::Timeout,
        }
    }
}

/// Follows the sessions the client's `bytes` create and activate on connection `id`;
/// an error when a CreateSession among them may not go on.
fn follow(
    requests: &mut RequestWatch,
    bytes: &[u8],
    shared: &Shared,
    id: u64,
    peer: SocketAddr,
    limits: &Limits,
    now: Instant,
) -> Result<(), SessionRefused> {
    let mut g = lock(&shared.sessions);
    for r in requests.feed(bytes) {
        match r {
            Request::CreateSession => g.create(id, peer.ip(), limits, now)?,
            Request::ActivateSession => g.activate(id),
        }
    }
    Ok(())
}
