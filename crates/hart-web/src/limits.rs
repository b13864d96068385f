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
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};

use axum_server::accept::Accept;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// Connections served at once.
pub const MAX_CONNECTIONS: usize = 512;
/// The longest wait for a request's head (the first, and each after it on a kept-alive
/// connection).
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// What the limit shares between connections.
#[derive(Default)]
pub(crate) struct Counts {
    open: AtomicUsize,
    refused: AtomicU64,
    warned: Mutex<Option<Instant>>,
    next: AtomicU64,
    /// Each open connection's switch, by number.
    conns: Mutex<std::collections::HashMap<u64, Arc<Switch>>>,
}

/// What the limit knows of one connection, and how it closes it.
struct Switch {
    opened: Instant,
    /// A byte has come from the client.
    spoke: std::sync::atomic::AtomicBool,
    /// Closed to admit another.
    killed: std::sync::atomic::AtomicBool,
    waker: Mutex<Option<std::task::Waker>>,
}

impl Counts {
    /// Closes the oldest connection that never sent a byte; whether there was one.
    fn evict_silent(&self) -> bool {
        let conns = self.conns.lock().unwrap_or_else(|e| e.into_inner());
        let victim = conns
            .values()
            .filter(|s| !s.spoke.load(Ordering::Relaxed) && !s.killed.load(Ordering::Relaxed))
            .min_by_key(|s| s.opened);
        let Some(v) = victim else { return false };
        v.killed.store(true, Ordering::SeqCst);
        if let Some(w) = v.waker.lock().unwrap_or_else(|e| e.into_inner()).take() {
            w.wake();
        }
        true
    }
}

/// An acceptor that refuses connections beyond the limit, around another (plain or
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

impl<A, I, S> Accept<I, S> for Limit<A>
where
    A: Accept<I, S>,
    A::Future: Send + 'static,
    A::Stream: Unpin,
{
    type Stream = Counted<A::Stream>;
    type Service = A::Service;
    type Future = Pin<Box<dyn Future<Output = io::Result<(Self::Stream, Self::Service)>> + Send>>;

    fn accept(&self, stream: I, service: S) -> Self::Future {
        let counts = self.counts.clone();
        if counts.open.fetch_add(1, Ordering::SeqCst) >= self.max && !counts.evict_silent() {
            counts.open.fetch_sub(1, Ordering::SeqCst);
            let refused = counts.refused.fetch_add(1, Ordering::Relaxed) + 1;
            let mut warned = counts.warned.lock().unwrap_or_else(|e| e.into_inner());
            if warned.is_none_or(|t| t.elapsed() >= Duration::from_secs(60)) {
                *warned = Some(Instant::now());
                tracing::warn!(
                    "web: {} connections are open (the limit); refusing more ({refused} so far)",
                    self.max
                );
            }
            drop(stream);
            return Box::pin(async { Err(io::Error::other("too many connections")) });
        }
        // Counted from here: a handshake that fails gives its place back.
        let number = counts.next.fetch_add(1, Ordering::Relaxed);
        let switch = Arc::new(Switch {
            opened: Instant::now(),
            spoke: Default::default(),
            killed: Default::default(),
            waker: Mutex::new(None),
        });
        counts
            .conns
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(number, switch.clone());
        let guard = Guard { counts, number };
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
    number: u64,
}

impl Drop for Guard {
    fn drop(&mut self) {
        self.counts
            .conns
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .remove(&self.number);
        self.counts.open.fetch_sub(1, Ordering::SeqCst);
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
            let mut w = self.switch.waker.lock().unwrap_or_else(|e| e.into_inner());
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
