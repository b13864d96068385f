//! Connection limits of the dashboard's server, so port scanners, crashed clients and
//! slow-header attacks cannot hold its sockets:
//!
//! * at most [`MAX_CONNECTIONS`] open at once; when the limit is reached, the oldest
//!   connection that has not sent a byte is closed to admit the new one (a flood of
//!   silent connections does not lock browsers out); with none such, the new one is
//!   refused, counted and logged at most once a minute;
//! * each connection must send a request's head within [`HEADER_TIMEOUT`] (hyper's
//!   header read timeout), the first and each one after it on a kept-alive connection.

use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum_server::accept::Accept;
use hart_access::pool::{self, Admission, LogLimit, Pool};
use hart_access::NetList;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpStream;

/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 512;
/// The longest wait for a request's head (the first, and each after it on a kept-alive
/// connection).
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// What the limit shares between connections: hart-access's connection pool (the
/// one the Modbus and OPC UA front ends use), ranking a connection that never sent a
/// byte first and keeping every other.
#[derive(Default)]
pub(crate) struct Counts {
    pool: Mutex<Pool<Arc<Switch>>>,
    log: Mutex<LogLimit>,
    refused: AtomicU64,
}

/// What the limit knows of one connection, and how it closes it.
struct Switch {
    /// A byte has come from the client.
    spoke: std::sync::atomic::AtomicBool,
    /// Closed to admit another.
    killed: std::sync::atomic::AtomicBool,
    waker: Mutex<Option<std::task::Waker>>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// An acceptor that admits connections through the pool, around another (plain or
/// TLS).
#[derive(Clone)]
pub(crate) struct Limit<A> {
    inner: A,
    counts: Arc<Counts>,
    max: usize,
}

impl<A> Limit<A> {
    pub(crate) fn new(inner: A, max: usize) -> Self {
        Limit {
            inner,
            counts: Arc::default(),
            max,
        }
    }
}

/// No address is a priority host of the dashboard, and one address may hold every
/// place (browsers behind one proxy).
static NO_PRIORITY: std::sync::LazyLock<NetList> = std::sync::LazyLock::new(NetList::empty);

impl<A, S> Accept<TcpStream, S> for Limit<A>
where
    A: Accept<TcpStream, S>,
    A::Future: Send + 'static,
    A::Stream: Unpin,
{
    type Stream = Counted<A::Stream>;
    type Service = A::Service;
    type Future = Pin<Box<dyn Future<Output = io::Result<(Self::Stream, Self::Service)>> + Send>>;

    fn accept(&self, stream: TcpStream, service: S) -> Self::Future {
        let counts = self.counts.clone();
        let now = Instant::now();
        let peer = stream
            .peer_addr()
            .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)));
        let switch = Arc::new(Switch {
            spoke: Default::default(),
            killed: Default::default(),
            waker: Mutex::new(None),
        });
        let admission = Admission {
            max_connections: self.max,
            max_per_address: usize::MAX,
            priority: &NO_PRIORITY,
        };
        let rank = |e: &pool::Entry<Arc<Switch>>| {
            (!e.state.spoke.load(Ordering::Relaxed)).then_some((0, e.opened))
        };
        let admitted = lock(&counts.pool).admit(peer, &admission, now, switch.clone(), rank);
        let id = match admitted {
            Ok((id, evicted)) => {
                if let Some((_, e)) = evicted {
                    e.state.killed.store(true, Ordering::SeqCst);
                    if let Some(w) = lock(&e.state.waker).take() {
                        w.wake();
                    }
                }
                id
            }
            Err(_) => {
                let refused = counts.refused.fetch_add(1, Ordering::Relaxed) + 1;
                if lock(&counts.log).allow_logged(now, "web") {
                    tracing::warn!(
                        "web: refused the connection from {peer}: {} connections are open (the limit), all in use ({refused} refused so far)",
                        self.max
                    );
                }
                drop(stream);
                return Box::pin(async { Err(io::Error::other("too many connections")) });
            }
        };
        // A handshake that fails gives its place back.
        let guard = Guard { counts, id };
        let fut = self.inner.accept(stream, service);
        Box::pin(async move {
            let (s, service) = fut.await?;
            Ok((
                Counted {
                    inner: s,
                    switch,
                    _guard: guard,
                },
                service,
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

/// A connection that holds a place of the limit while it lives.
pub(crate) struct Counted<S> {
    inner: S,
    switch: Arc<Switch>,
    _guard: Guard,
}

fn closed_for_another() -> io::Error {
    io::Error::new(
        io::ErrorKind::ConnectionAborted,
        "closed to admit another connection: it had sent nothing",
    )
}

impl<S: AsyncRead + Unpin> AsyncRead for Counted<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        if self.switch.killed.load(Ordering::SeqCst) {
            return Poll::Ready(Err(closed_for_another()));
        }
        if !self.switch.spoke.load(Ordering::Relaxed) {
            // Kept so that an eviction wakes the connection's task.
            let mut w = lock(&self.switch.waker);
            if !w.as_ref().is_some_and(|w| w.will_wake(cx.waker())) {
                *w = Some(cx.waker().clone());
            }
        }
        let before = buf.filled().len();
        let r = Pin::new(&mut self.inner).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.switch.spoke.store(true, Ordering::Relaxed);
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
        Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}
