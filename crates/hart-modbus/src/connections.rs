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
//!   completed a request, then one stuck in a request, then the oldest idle one; never
//!   a priority address's, never one being answered; with none to evict, the new one
//!   is refused.
//!
//! Every refusal, eviction and time-out is logged with the peer and the reason.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

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

struct Entry {
    peer: SocketAddr,
    priority: bool,
    opened: Instant,
    /// When it last completed a request (or opened).
    last_used: Instant,
    phase: Phase,
    close: Arc<Notify>,
    /// Why it is being closed (set before `close` is notified).
    closing: Option<&'static str>,
}

/// The pool of open connections.
#[derive(Default)]
pub(crate) struct Pool {
    entries: Mutex<HashMap<u64, Entry>>,
    next: std::sync::atomic::AtomicU64,
    /// Keeps a flood from flooding the log too.
    pub(crate) log: LogLimit,
}

/// Lines about connections logged per second at most; the rest are counted and the
/// count logged when the next second begins, so a flood of connections cannot fill
/// the disk with log lines.
pub const LOG_LINES_PER_SECOND: u32 = 20;

/// A per-second budget of log lines.
#[derive(Default)]
pub(crate) struct LogLimit(Mutex<(Option<Instant>, u32, u64)>);

impl LogLimit {
    /// Whether a line may be logged now; when a second with lines left out ends, says
    /// how many first.
    pub(crate) fn allow(&self) -> bool {
        let now = Instant::now();
        let mut g = lock(&self.0);
        let (start, _, left_out) = &mut *g;
        if start.is_none_or(|s| now.saturating_duration_since(s) >= Duration::from_secs(1)) {
            if *left_out > 0 {
                tracing::warn!(
                    "modbus: {left_out} more connection refusals, closings and time-outs in the last second(s), not logged one by one"
                );
            }
            *g = (Some(now), 0, 0);
        }
        let (_, lines, left_out) = &mut *g;
        if *lines < LOG_LINES_PER_SECOND {
            *lines += 1;
            true
        } else {
            *left_out += 1;
            false
        }
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
    /// Admits a connection from `peer`, evicting the oldest idle one when the pool is
    /// full: its id and the notify that closes it.
    pub(crate) fn admit(
        &self,
        peer: SocketAddr,
        limits: &Limits,
        now: Instant,
    ) -> Result<(u64, Arc<Notify>), Refused> {
        let priority = limits.priority.contains(peer.ip());
        let mut entries = lock(&self.entries);
        let from_here = entries
            .values()
            .filter(|e| same_host(e.peer.ip(), peer.ip()) && e.closing.is_none())
            .count();
        if !priority && from_here >= limits.max_per_address {
            return Err(Refused::PerAddress(from_here));
        }
        let open = entries.values().filter(|e| e.closing.is_none()).count();
        if open >= limits.max_connections {
            // Never a priority connection, nor one whose request is being answered.
            // First one that has never completed a request, then one stuck in a
            // request (a Modbus request is a few hundred bytes: on a network it comes
            // whole in milliseconds), then the oldest idle one: a client that does
            // work is worth more than a socket that only takes room, so a flood of
            // new or half-sent connections does not push out a SCADA between two of
            // its polls.
            let rank = |p: Phase| match p {
                Phase::Fresh => Some(0),
                Phase::Receiving(_) => Some(1),
                Phase::Idle => Some(2),
                Phase::Answering => None,
            };
            let victim = entries
                .iter()
                .filter(|(_, e)| !e.priority && e.closing.is_none())
                .filter_map(|(id, e)| {
                    let since = match e.phase {
                        Phase::Receiving(t) => t,
                        _ => e.last_used,
                    };
                    rank(e.phase).map(|r| ((r, since), *id))
                })
                .min()
                .map(|(_, id)| id);
            let Some(id) = victim else {
                return Err(Refused::Full(open));
            };
            if let Some(e) = entries.get_mut(&id) {
                e.closing = Some("closed to admit a new connection: the pool was full");
                e.close.notify_one();
                if self.log.allow() {
                    tracing::warn!(
                        "modbus: closing the connection from {} (idle {:.0} s, open {:.0} s) to admit {peer}: {} connections open (the limit)",
                        e.peer,
                        now.saturating_duration_since(e.last_used).as_secs_f64(),
                        now.saturating_duration_since(e.opened).as_secs_f64(),
                        limits.max_connections
                    );
                }
            }
        }
        let id = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let close = Arc::new(Notify::new());
        entries.insert(
            id,
            Entry {
                peer,
                priority,
                opened: now,
                last_used: now,
                phase: Phase::Fresh,
                close: close.clone(),
                closing: None,
            },
        );
        Ok((id, close))
    }

    /// Records what connection `id` does now.
    pub(crate) fn set_phase(&self, id: u64, phase: Phase, now: Instant) {
        if let Some(e) = lock(&self.entries).get_mut(&id) {
            if phase == Phase::Idle {
                e.last_used = now;
            }
            e.phase = phase;
        }
    }

    /// The phase of `id`, and why it is being closed if it is.
    pub(crate) fn state(&self, id: u64) -> Option<(Phase, Option<&'static str>)> {
        lock(&self.entries).get(&id).map(|e| (e.phase, e.closing))
    }

    /// Forgets a closed connection.
    pub(crate) fn remove(&self, id: u64) {
        lock(&self.entries).remove(&id);
    }

    /// Connections open now.
    pub(crate) fn len(&self) -> usize {
        lock(&self.entries).len()
    }
}

/// Whether two addresses are the same host (an IPv4 client seen as `::ffff:a.b.c.d`
/// counts as its IPv4 address).
fn same_host(a: IpAddr, b: IpAddr) -> bool {
    let v4 = |ip: IpAddr| match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    };
    v4(a) == v4(b)
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
        assert!(pool.state(a).unwrap().1.is_some(), "a is being closed");
        drop(a_close);
        pool.remove(a);
        // Full again, and nothing to close but the SCADA's: refused.
        pool.set_phase(c, Phase::Answering, at(6));
        assert!(matches!(
            pool.admit(addr("10.0.0.5:1000"), &limits, at(7)),
            Err(Refused::Full(3))
        ));
        assert!(pool.state(scada).unwrap().1.is_none(), "the SCADA's stays");
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
        assert!(pool.state(scan).unwrap().1.is_some(), "the unused one goes");
        assert!(pool.state(scada).unwrap().1.is_none(), "the SCADA's stays");
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
        assert!(
            pool.state(half).unwrap().1.is_some(),
            "the half-sent one goes"
        );
        assert!(pool.state(scada).unwrap().1.is_none(), "the SCADA's stays");
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
