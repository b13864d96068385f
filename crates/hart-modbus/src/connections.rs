//! Connection management of the Modbus TCP server, as the Modbus messaging
//! implementation guide describes it (Modbus Messaging on TCP/IP Implementation Guide
//! V1.0b, 4.2.1 "TCP connection management": a bounded pool of connections; when it is
//! full, the oldest connection not in use is closed to admit a new one, and
//! connections from priority addresses are kept), with the limits a plant's port needs
//! against port scanners, crashed clients and HMIs that open a connection per poll:
//!
//! * at most [`Limits::max_connections`] at once, at most [`Limits::max_per_address`]
//!   from one address (priority addresses are exempt);
//! * a new connection must complete a request within [`Limits::first_request`], and a
//!   request whose bytes have started must be whole within [`Limits::request`];
//! * a full pool evicts a connection to admit a new one: first one that never
//!   completed a request, then one stuck in a request, then the oldest idle one, each
//!   time from the host holding the most such connections (the shared pool's fair
//!   share); never a priority address's, never one being answered; with none to
//!   evict, the new one is refused.
//!
//! Every refusal, eviction and time-out is logged with the peer and the reason.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use hart_access::pool;
use tokio::sync::Notify;

/// The limits.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Most connections at once.
    pub max_connections: usize,
    /// Most connections from one address (priority addresses aside).
    pub max_per_address: usize,
    /// A new connection that has not completed a request by then is closed.
    pub first_request: Duration,
    /// A request whose first byte came must be whole by then.
    pub request: Duration,
    /// Addresses whose connections are never evicted nor limited per address (the
    /// SCADA hosts).
    pub priority: hart_access::NetList,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: 64,
            max_per_address: 16,
            first_request: Duration::from_secs(10),
            request: Duration::from_secs(5),
            priority: hart_access::NetList::empty(),
        }
    }
}

/// What a connection is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// Opened, no request completed yet.
    Fresh,
    /// Between requests.
    Idle,
    /// Part of a request has come (since then).
    Receiving(Instant),
    /// A request is being answered.
    Answering,
}

/// What the pool keeps of a connection.
struct Conn {
    /// When it last completed a request (or opened).
    last_used: Instant,
    phase: Phase,
    close: Arc<Notify>,
}

/// The pool of open connections: hart-access's pool, with the Modbus front end's
/// ranking, shared by the connections' tasks.
#[derive(Default)]
pub(crate) struct Pool {
    inner: Mutex<pool::Pool<Conn>>,
    /// Keeps a flood from flooding the log too.
    pub(crate) log: LogLimit,
}

pub use hart_access::pool::LOG_LINES_PER_SECOND;

/// A per-second budget of log lines, shared by the connections.
#[derive(Default)]
pub(crate) struct LogLimit(Mutex<pool::LogLimit>);

impl LogLimit {
    /// Whether a line may be logged now; when a second with lines left out ends, says
    /// how many first.
    pub(crate) fn allow(&self) -> bool {
        lock(&self.0).allow_logged(Instant::now(), "modbus")
    }
}

/// Why a connection was not admitted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Refused {
    PerAddress(usize),
    Full(usize),
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::PerAddress(n) => write!(
                f,
                "{n} connections from that address already (the per-address limit); \
                 list a SCADA host as a priority address to exempt it"
            ),
            Refused::Full(n) => {
                write!(f, "{n} connections open (the limit) and none idle to close")
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Pool {
    /// Admits a connection from `peer`, evicting one when the pool is full: its id and
    /// the notify that closes it.
    pub(crate) fn admit(
        &self,
        peer: SocketAddr,
        limits: &Limits,
        now: Instant,
    ) -> Result<(u64, Arc<Notify>), Refused> {
        let admission = pool::Admission {
            max_connections: limits.max_connections,
            max_per_address: limits.max_per_address,
            priority: &limits.priority,
            evict_at_address_limit: false,
        };
        let close = Arc::new(Notify::new());
        let fresh = Conn {
            last_used: now,
            phase: Phase::Fresh,
            close: close.clone(),
        };
        // Never one whose request is being answered. First one that has never
        // completed a request, then one stuck in a request (a Modbus request is a few
        // hundred bytes: on a network it comes whole in milliseconds), then the oldest
        // idle one: a client that does work is worth more than a socket that only
        // takes room, so a flood of new or half-sent connections does not push out a
        // SCADA between two of its polls.
        let rank = |e: &pool::Entry<Conn>| match e.state.phase {
            Phase::Fresh => Some((0, e.state.last_used)),
            Phase::Receiving(t) => Some((1, t)),
            Phase::Idle => Some((2, e.state.last_used)),
            Phase::Answering => None,
        };
        let admitted = lock(&self.inner).admit(peer, &admission, now, fresh, rank);
        let (id, evicted) = admitted.map_err(|r| match r {
            pool::Refused::PerAddress(n) => Refused::PerAddress(n),
            pool::Refused::Full(n) => Refused::Full(n),
        })?;
        if let Some((_, e)) = evicted {
            e.state.close.notify_one();
            if self.log.allow() {
                tracing::warn!(
                    "modbus: closing the connection from {} (idle {:.0} s, open {:.0} s) to admit {peer}: {} connections open (the limit)",
                    e.peer,
                    now.saturating_duration_since(e.state.last_used).as_secs_f64(),
                    now.saturating_duration_since(e.opened).as_secs_f64(),
                    limits.max_connections
                );
            }
        }
        Ok((id, close))
    }

    /// Records what connection `id` does now.
    pub(crate) fn set_phase(&self, id: u64, phase: Phase, now: Instant) {
        if let Some(e) = lock(&self.inner).get_mut(id) {
            if phase == Phase::Idle {
                e.state.last_used = now;
            }
            e.state.phase = phase;
        }
    }

    /// The phase of `id`; `None` once it was closed to admit another.
    pub(crate) fn phase(&self, id: u64) -> Option<Phase> {
        lock(&self.inner).get(id).map(|e| e.state.phase)
    }

    /// Forgets a closed connection.
    pub(crate) fn remove(&self, id: u64) {
        lock(&self.inner).remove(id);
    }

    /// Connections open now.
    pub(crate) fn len(&self) -> usize {
        lock(&self.inner).len()
    }
}

/// When connection `id` must have made progress by, from its phase: `None` while it
/// waits between requests or answers one.
pub(crate) fn deadline(phase: Phase, opened: Instant, limits: &Limits) -> Option<Instant> {
    match phase {
        Phase::Fresh => Some(opened + limits.first_request),
        Phase::Receiving(since) => Some(since + limits.request),
        Phase::Idle | Phase::Answering => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(s: &str) -> SocketAddr {
        s.parse().unwrap()
    }

    #[test]
    fn a_full_pool_evicts_its_oldest_idle_connection_but_never_a_priority_one() {
        let limits = Limits {
            max_connections: 3,
            max_per_address: 2,
            priority: hart_access::NetList::parse(&["10.0.0.1"]).unwrap(),
            ..Limits::default()
        };
        let pool = Pool::default();
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let (scada, _) = pool.admit(addr("10.0.0.1:1000"), &limits, at(0)).unwrap();
        let (a, a_close) = pool.admit(addr("10.0.0.2:1000"), &limits, at(1)).unwrap();
        let (b, _) = pool.admit(addr("10.0.0.3:1000"), &limits, at(2)).unwrap();
        pool.set_phase(scada, Phase::Idle, at(3));
        pool.set_phase(b, Phase::Answering, at(4));
        // Full: a (never used) goes before the SCADA's (idle, and older), which is a
        // priority connection anyway.
        let (c, _) = pool.admit(addr("10.0.0.4:1000"), &limits, at(5)).unwrap();
        assert!(pool.phase(a).is_none(), "a was closed");
        drop(a_close);
        pool.remove(a);
        // Full again, and nothing to close but the SCADA's: refused.
        pool.set_phase(c, Phase::Answering, at(6));
        assert!(matches!(
            pool.admit(addr("10.0.0.5:1000"), &limits, at(7)),
            Err(Refused::Full(3))
        ));
        assert!(pool.phase(scada).is_some(), "the SCADA's stays");
        // Per address: two from .3 at most; the priority host has no such limit.
        pool.remove(c);
        assert!(pool.admit(addr("10.0.0.3:1001"), &limits, at(8)).is_ok());
        pool.remove(b);
        assert_eq!(pool.len(), 2);
    }

    #[test]
    fn a_connection_never_used_goes_before_one_in_use() {
        let limits = Limits {
            max_connections: 2,
            ..Limits::default()
        };
        let pool = Pool::default();
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let (scada, _) = pool.admit(addr("10.0.0.1:1000"), &limits, at(0)).unwrap();
        pool.set_phase(scada, Phase::Idle, at(1));
        let (scan, _) = pool.admit(addr("10.0.0.9:1000"), &limits, at(2)).unwrap();
        pool.admit(addr("10.0.0.9:1001"), &limits, at(3)).unwrap();
        assert!(pool.phase(scan).is_none(), "the unused one goes");
        assert!(pool.phase(scada).is_some(), "the SCADA's stays");
    }

    #[test]
    fn a_connection_stuck_in_a_request_goes_before_an_idle_one() {
        let limits = Limits {
            max_connections: 2,
            ..Limits::default()
        };
        let pool = Pool::default();
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let (scada, _) = pool.admit(addr("10.0.0.1:1000"), &limits, at(0)).unwrap();
        pool.set_phase(scada, Phase::Idle, at(1));
        let (half, _) = pool.admit(addr("10.0.0.9:1000"), &limits, at(2)).unwrap();
        pool.set_phase(half, Phase::Receiving(at(2)), at(2));
        pool.admit(addr("10.0.0.9:1001"), &limits, at(3)).unwrap();
        assert!(pool.phase(half).is_none(), "the half-sent one goes");
        assert!(pool.phase(scada).is_some(), "the SCADA's stays");
    }

    #[test]
    fn deadlines_follow_the_phase() {
        let l = Limits::default();
        let t0 = Instant::now();
        assert_eq!(deadline(Phase::Fresh, t0, &l), Some(t0 + l.first_request));
        let t1 = t0 + Duration::from_secs(30);
        assert_eq!(deadline(Phase::Receiving(t1), t0, &l), Some(t1 + l.request));
        assert_eq!(deadline(Phase::Idle, t0, &l), None);
        assert_eq!(deadline(Phase::Answering, t0, &l), None);
    }
}
