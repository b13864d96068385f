//! Connection limits of the dashboard's server, so port scanners, crashed clients,
//! slow-header attacks and idle keep-alive connections cannot hold its sockets. The
//! connections go through hart-access's connection pool, as Modbus TCP's and OPC UA's
//! do:
//!
//! * at most [`Limits::max_connections`] open at once ([`MAX_CONNECTIONS`]), and at
//!   most [`Limits::max_per_address`] from one address ([`MAX_PER_ADDRESS`]; priority
//!   hosts, [`Limits::priority`], are exempt);
//! * a full pool closes a connection to admit the new one: first one that has not
//!   completed a request (it sent nothing, or part of a request's head), then one
//!   part-way through the head of its next request, then the one idle (kept alive
//!   between requests) longest, each time from the host holding the most such
//!   connections; never one whose request is being answered (an event stream
//!   included), never a priority host's. A host at its own limit closes its own
//!   connections in the same order. With none to close, the new one is refused,
//!   counted and logged within a budget of lines per second;
//! * a request's head must come whole within [`Limits::header_timeout`]
//!   ([`HEADER_TIMEOUT`]) of the connection's opening or of the head's first byte,
//!   and its body within as long again after the head;
//! * a connection kept alive without a request for [`Limits::idle_timeout`]
//!   ([`IDLE_TIMEOUT`]) is closed.
//!
//! The time limits are the connection's own (a timer on its socket), not hyper's
//! `header_read_timeout`, which cannot tell a head that is slow to come from a
//! connection idle between requests.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, Waker};
use std::time::{Duration, Instant};

use axum::body::{Body, Bytes, HttpBody};
use axum::http::{Request, Response};
use axum_server::accept::Accept;
use hart_access::pool::{self, Admission, LogLimit, Pool};
use hart_access::NetList;
use http_body::Frame;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;

/// Connections served at once, by default.
pub const MAX_CONNECTIONS: usize = 512;
/// Connections from one address, by default (as Modbus TCP and OPC UA).
pub const MAX_PER_ADDRESS: usize = 16;
/// The longest wait for a request's head, by default: from the connection's opening
/// for its first request, from the head's first byte for the next ones; and for its
/// body after the head.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// The longest a connection is kept alive between requests, by default.
pub const IDLE_TIMEOUT: Duration = Duration::from_secs(60);

/// The dashboard's connection limits (`[web]` `max_connections`, `max_per_address`,
/// `priority`, `header_timeout`, `idle_timeout`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Limits {
    /// Most connections at once.
    pub max_connections: usize,
    /// Most connections from one address (priority hosts aside).
    pub max_per_address: usize,
    /// Hosts whose connections are never closed to admit others nor limited per
    /// address (a reverse proxy in front of the dashboard, the control room's
    /// consoles).
    pub priority: NetList,
    /// A request's head must come whole within this (of the connection's opening, or
    /// of the head's first byte on a kept-alive connection), and its body within this
    /// after its head.
    pub header_timeout: Duration,
    /// A kept-alive connection without a request for this long is closed.
    pub idle_timeout: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: MAX_CONNECTIONS,
            max_per_address: MAX_PER_ADDRESS,
            priority: NetList::empty(),
            header_timeout: HEADER_TIMEOUT,
            idle_timeout: IDLE_TIMEOUT,
        }
    }
}

/// What a connection is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Opened; no request's head has come whole yet (it may have sent part of one).
    Fresh,
    /// Between requests, since then.
    Idle(Instant),
    /// The head of its next request has begun (then).
    Receiving(Instant),
    /// This many of its requests are being answered (HTTP/2: several at once).
    Answering(u32),
}

/// What the pool and the server share of one connection, and how it is closed.
struct Switch {
    opened: Instant,
    phase: Mutex<Phase>,
    /// Closed to admit another.
    killed: AtomicBool,
    /// The task serving it, woken to close it or to re-arm its timer.
    waker: Mutex<Option<Waker>>,
}

impl Switch {
    /// When the connection is closed if nothing changes; `None`: a request is being
    /// answered.
    fn deadline(&self, limits: &Limits) -> Option<Instant> {
        match *lock(&self.phase) {
            Phase::Fresh => Some(self.opened + limits.header_timeout),
            Phase::Receiving(t) => Some(t + limits.header_timeout),
            Phase::Idle(t) => Some(t + limits.idle_timeout),
            Phase::Answering(_) => None,
        }
    }

    /// A request's head came whole: it is being answered.
    fn begin(&self) {
        let mut p = lock(&self.phase);
        *p = match *p {
            Phase::Answering(n) => Phase::Answering(n.saturating_add(1)),
            _ => Phase::Answering(1),
        };
    }

    /// A request's answer is over (sent, or abandoned).
    fn end(&self) {
        {
            let mut p = lock(&self.phase);
            if let Phase::Answering(n) = *p {
                *p = if n > 1 {
                    Phase::Answering(n - 1)
                } else {
                    Phase::Idle(Instant::now())
                };
            }
        }
        // Its task re-arms the connection's timer.
        self.wake();
    }

    fn wake(&self) {
        if let Some(w) = lock(&self.waker).take() {
            w.wake();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// What the limit shares between connections: hart-access's connection pool, a
/// budget of log lines, and the count of refusals.
#[derive(Default)]
struct Counts {
    pool: Mutex<Pool<Arc<Switch>>>,
    log: Mutex<LogLimit>,
    refused: AtomicU64,
}

impl Counts {
    /// Whether a line about a connection may be logged now.
    fn may_log(&self) -> bool {
        lock(&self.log).allow_logged(Instant::now(), "web")
    }
}

/// An acceptor that admits connections through the pool, around another (plain or
/// TLS), and serves each with its time limits.
#[derive(Clone)]
pub(crate) struct Limit<A> {
    inner: A,
    counts: Arc<Counts>,
    limits: Arc<Limits>,
}

impl<A> Limit<A> {
    pub(crate) fn new(inner: A, limits: Limits) -> Self {
        Limit {
            inner,
            counts: Arc::default(),
            limits: Arc::new(limits),
        }
    }
}

/// The local address a request came in on (the address the client connected to), for
/// the `Host` check of a wildcard listener.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct LocalAddr(pub(crate) SocketAddr);

impl<A, S> Accept<TcpStream, S> for Limit<A>
where
    A: Accept<TcpStream, S>,
    A::Future: Send + 'static,
    A::Stream: Unpin,
{
    type Stream = Counted<A::Stream>;
    type Service = Tracked<A::Service>;
    type Future = Pin<Box<dyn Future<Output = io::Result<(Self::Stream, Self::Service)>> + Send>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        let counts = self.counts.clone();
        let limits = self.limits.clone();
        let now = Instant::now();
        let unknown = SocketAddr::from(([0, 0, 0, 0], 0));
        let peer = stream.peer_addr().unwrap_or(unknown);
        let local = stream.local_addr().unwrap_or(unknown);
        let switch = Arc::new(Switch {
            opened: now,
            phase: Mutex::new(Phase::Fresh),
            killed: AtomicBool::new(false),
            waker: Mutex::new(None),
        });
        let admission = Admission {
            max_connections: limits.max_connections,
            max_per_address: limits.max_per_address,
            priority: &limits.priority,
            evict_at_address_limit: true,
        };
        // Never one being answered; first one that has not completed a request (a
        // browser's comes whole in milliseconds), then one stuck in the head of its
        // next, then the one idle longest: a browser that does work is worth more than
        // a socket that only takes room.
        let rank = |e: &pool::Entry<Arc<Switch>>| match *lock(&e.state.phase) {
            Phase::Fresh => Some((0, e.opened)),
            Phase::Receiving(t) => Some((1, t)),
            Phase::Idle(t) => Some((2, t)),
            Phase::Answering(_) => None,
        };
        let admitted = lock(&counts.pool).admit(peer, &admission, now, switch.clone(), rank);
        let id = match admitted {
            Ok((id, evicted)) => {
                if let Some((_, e)) = evicted {
                    e.state.killed.store(true, Ordering::SeqCst);
                    e.state.wake();
                    if counts.may_log() {
                        tracing::info!(
                            "web: closing the connection from {} (open {:.0} s, {}) to admit {peer}",
                            e.peer,
                            now.saturating_duration_since(e.opened).as_secs_f64(),
                            match *lock(&e.state.phase) {
                                Phase::Fresh => "no request completed",
                                Phase::Receiving(_) => "part of a request's head",
                                _ => "idle",
                            }
                        );
                    }
                }
                id
            }
            Err(why) => {
                let refused = counts.refused.fetch_add(1, Ordering::Relaxed) + 1;
                if counts.may_log() {
                    let why = match why {
                        pool::Refused::PerAddress(n) => format!(
                            "{n} connections from that address, all in use (the per-address \
                             limit, [web] max_per_address; list a proxy in [web] priority)"
                        ),
                        pool::Refused::Full(n) => format!(
                            "{n} connections open, all in use (the limit, [web] max_connections)"
                        ),
                    };
                    tracing::warn!(
                        "web: refused the connection from {peer}: {why} ({refused} refused so far)"
                    );
                }
                drop(stream);
                return Box::pin(async { Err(io::Error::other("too many connections")) });
            }
        };
        // A handshake that fails gives its place back.
        let guard = Guard {
            counts: counts.clone(),
            id,
        };
        let fut = self.inner.accept(stream, service);
        Box::pin(async move {
            let (s, service) = fut.await?;
            Ok((
                Counted {
                    inner: s,
                    switch: switch.clone(),
                    limits: limits.clone(),
                    counts,
                    timer: Box::pin(tokio::time::sleep_until(now.into())),
                    armed: None,
                    _guard: guard,
                },
                Tracked {
                    inner: service,
                    switch,
                    local: LocalAddr(local),
                    body_timeout: limits.header_timeout,
                },
            ))
        })
    }
}

/// Gives a connection's place back when dropped.
struct Guard {
    counts: Arc<Counts>,
    id: u64,
}

impl Drop for Guard {
    fn drop(&mut self) {
        lock(&self.counts.pool).remove(self.id);
    }
}

/// A connection that holds a place of the pool while it lives, and is closed when its
/// time limit passes or the pool needs its place.
pub(crate) struct Counted<S> {
    inner: S,
    switch: Arc<Switch>,
    limits: Arc<Limits>,
    counts: Arc<Counts>,
    timer: Pin<Box<tokio::time::Sleep>>,
    /// The deadline the timer is set to.
    armed: Option<Instant>,
    _guard: Guard,
}

fn closed_for_another() -> io::Error {
    io::Error::new(
        io::ErrorKind::ConnectionAborted,
        "closed to admit another connection",
    )
}

impl<S> Counted<S> {
    /// `Some(error)` once the connection must close: evicted, or past its deadline
    /// (the timer is armed for the deadline otherwise).
    fn check(&mut self, cx: &mut Context<'_>) -> Option<io::Error> {
        if self.switch.killed.load(Ordering::SeqCst) {
            return Some(closed_for_another());
        }
        {
            let mut w = lock(&self.switch.waker);
            if !w.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
                *w = Some(cx.waker().clone());
            }
        }
        let deadline = self.switch.deadline(&self.limits)?;
        if self.armed != Some(deadline) {
            self.timer.as_mut().reset(deadline.into());
            self.armed = Some(deadline);
        }
        if self.timer.as_mut().poll(cx).is_pending() {
            return None;
        }
        let what = match *lock(&self.switch.phase) {
            Phase::Idle(_) => format!(
                "idle for {} s (the limit, [web] idle_timeout)",
                self.limits.idle_timeout.as_secs_f64()
            ),
            _ => format!(
                "no whole request head within {} s (the limit, [web] header_timeout)",
                self.limits.header_timeout.as_secs_f64()
            ),
        };
        if !matches!(*lock(&self.switch.phase), Phase::Idle(_)) && self.counts.may_log() {
            tracing::info!("web: closed a connection: {what}");
        }
        // Closed: the pool sees it no more, and the next poll says so at once.
        self.switch.killed.store(true, Ordering::SeqCst);
        Some(io::Error::new(io::ErrorKind::TimedOut, what))
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for Counted<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if let Some(e) = self.check(cx) {
            return Poll::Ready(Err(e));
        }
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            let mut p = lock(&self.switch.phase);
            if let Phase::Idle(_) = *p {
                *p = Phase::Receiving(Instant::now());
            }
        }
        r
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for Counted<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        if self.switch.killed.load(Ordering::SeqCst) {
            return Poll::Ready(Err(closed_for_another()));
        }
        Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        if self.switch.killed.load(Ordering::SeqCst) {
            return Poll::Ready(Err(closed_for_another()));
        }
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}

/// The connection's service: marks the connection answering from a request's head
/// until its answer is sent (or abandoned), limits the time its body takes, and tells
/// the handlers the address the client reached.
#[derive(Clone)]
pub(crate) struct Tracked<S> {
    inner: S,
    switch: Arc<Switch>,
    local: LocalAddr,
    body_timeout: Duration,
}

/// A request being answered: ends the answering when dropped.
struct Busy(Arc<Switch>);

impl Busy {
    fn new(switch: Arc<Switch>) -> Busy {
        switch.begin();
        Busy(switch)
    }
}

impl Drop for Busy {
    fn drop(&mut self) {
        self.0.end();
    }
}

type BoxError = Box<dyn std::error::Error + Send + Sync>;

impl<S, B> tower_service::Service<Request<B>> for Tracked<S>
where
    S: tower_service::Service<Request<Body>, Response = Response<Body>>,
    S::Future: Send + 'static,
    B: HttpBody<Data = Bytes> + Send + Unpin + 'static,
    B::Error: Into<BoxError>,
{
    type Response = Response<Body>;
    type Error = S::Error;
    type Future = Pin<Box<dyn Future<Output = Result<Response<Body>, S::Error>> + Send>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request<B>) -> Self::Future {
        let busy = Busy::new(self.switch.clone());
        let timeout = self.body_timeout;
        let mut req = req.map(|b| {
            Body::new(Timed {
                inner: b,
                timer: Box::pin(tokio::time::sleep(timeout)),
                timeout,
            })
        });
        req.extensions_mut().insert(self.local);
        let fut = self.inner.call(req);
        Box::pin(async move {
            let res = fut.await?;
            Ok(res.map(|b| {
                Body::new(Held {
                    inner: b,
                    _busy: busy,
                })
            }))
        })
    }
}

/// A request's body that must come whole in time.
struct Timed<B> {
    inner: B,
    timer: Pin<Box<tokio::time::Sleep>>,
    timeout: Duration,
}

impl<B> HttpBody for Timed<B>
where
    B: HttpBody<Data = Bytes> + Unpin,
    B::Error: Into<BoxError>,
{
    type Data = Bytes;
    type Error = BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, BoxError>>> {
        match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Ready(f) => Poll::Ready(f.map(|r| r.map_err(Into::into))),
            Poll::Pending => {
                if self.timer.as_mut().poll(cx).is_ready() {
                    let s = self.timeout.as_secs_f64();
                    Poll::Ready(Some(Err(format!(
                        "the request's body did not come whole within {s} s"
                    )
                    .into())))
                } else {
                    Poll::Pending
                }
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// An answer's body; the request is answered when it is dropped.
struct Held {
    inner: Body,
    _busy: Busy,
}

impl HttpBody for Held {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}
