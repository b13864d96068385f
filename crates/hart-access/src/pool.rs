//! The connection pool of the gateway's TCP front ends (Modbus TCP, OPC UA, the web
//! dashboard, HART-IP), sans-IO: the time is given, and the caller closes what the pool says.
//!
//! As the Modbus messaging implementation guide describes connection management
//! (Modbus Messaging on TCP/IP Implementation Guide V1.0b, 4.2.1: a bounded pool; when
//! it is full, a connection not in use is closed to admit a new one; connections from
//! priority addresses are kept), with the limits a plant's port needs against port
//! scanners, crashed clients and clients that open a connection per request:
//!
//! * at most `max_connections` at once and at most `max_per_address` from one address
//!   (priority addresses are exempt from both the per-address limit and eviction); a
//!   host at its limit is refused, or, when the front end says so
//!   ([`Admission::evict_at_address_limit`]), one of that host's own connections is
//!   closed for the new one, ranked as below (the web dashboard: a browser behind a
//!   proxy or a NAT shared with a broken client still gets in);
//! * a full pool evicts one connection to admit the new one: of the class the front
//!   end ranks lowest (its `rank` function: a class, then the time it has been so;
//!   `None` for a connection that must not be closed, such as one being answered),
//!   one from the host that holds the most connections, its oldest first; with none
//!   to evict, the new one is refused.
//!
//! Taking from the heaviest host first is a fair share of the pool: a flood of
//! connections from a few hosts reopening as fast as they are closed turns the
//! lowest class over in milliseconds, and a client whose connection is briefly in
//! that class (a SCADA between its connect and its first request, on a loaded
//! machine) would otherwise be closed with the flood. It is closed only once no host
//! holds more connections in that class than its own.
//!
//! Each front end keeps its own per-connection state in the pool (`S`), ranks it, and
//! logs refusals and evictions through a [`LogLimit`]. The HART-IP server keeps its
//! sessions here too (its limits per server and per host, nothing evicted; a UDP
//! initiate is refused from [`Pool::refusal`] before any task is started for it), and
//! its TCP connections.

use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::time::Instant;

use crate::NetList;

/// The pool's limits.
#[derive(Debug, Clone, Copy)]
pub struct Admission<'a> {
    /// Most connections at once.
    pub max_connections: usize,
    /// Most connections from one address (priority addresses aside).
    pub max_per_address: usize,
    /// Addresses whose connections are never evicted nor limited per address.
    pub priority: &'a NetList,
    /// At the per-address limit, close that host's lowest-ranked connection for the
    /// new one instead of refusing it (refused all the same when `rank` spares all).
    pub evict_at_address_limit: bool,
}

/// One open connection.
#[derive(Debug, Clone)]
pub struct Entry<S> {
    /// The client.
    pub peer: SocketAddr,
    /// From a priority address.
    pub priority: bool,
    /// When it was admitted.
    pub opened: Instant,
    /// The front end's state of it.
    pub state: S,
}

/// Why a connection was not admitted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// So many connections from that address already.
    PerAddress(usize),
    /// So many open, and none that may be closed.
    Full(usize),
}

/// A connection admitted: its id, and the connection closed to make room (already
/// out of the pool; the caller closes its socket).
pub type Admitted<S> = (u64, Option<(u64, Entry<S>)>);

/// The open connections.
#[derive(Debug)]
pub struct Pool<S> {
    entries: HashMap<u64, Entry<S>>,
    next: u64,
}

impl<S> Default for Pool<S> {
    fn default() -> Self {
        Pool {
            entries: HashMap::new(),
            next: 0,
        }
    }
}

impl<S> Pool<S> {
    /// Admits a connection from `peer` at `now` with `state`; when the pool is full,
    /// evicts the lowest-ranked connection (`rank`: smallest first, `None` never).
    pub fn admit(
        &mut self,
        peer: SocketAddr,
        limits: &Admission<'_>,
        now: Instant,
        state: S,
        rank: impl Fn(&Entry<S>) -> Option<(u8, Instant)>,
    ) -> Result<Admitted<S>, Refused> {
        let priority = limits.priority.contains(peer.ip());
        let from_here = self.from_host(peer.ip());
        let mut evicted = None;
        if !priority && from_here >= limits.max_per_address {
            let own = host(peer.ip());
            let victim = limits
                .evict_at_address_limit
                .then(|| self.victim(Some(own), &rank))
                .flatten();
            let Some(id) = victim else {
                return Err(Refused::PerAddress(from_here));
            };
            evicted = self.entries.remove(&id).map(|e| (id, e));
        }
        if evicted.is_none() && self.entries.len() >= limits.max_connections {
            let victim = self.victim(None, &rank);
            let Some(id) = victim else {
                return Err(Refused::Full(self.entries.len()));
            };
            evicted = self.entries.remove(&id).map(|e| (id, e));
        }
        let id = self.next;
        self.next += 1;
        self.entries.insert(
            id,
            Entry {
                peer,
                priority,
                opened: now,
                state,
            },
        );
        Ok((id, evicted))
    }

    /// The connection to close for a new one (of host `only`'s, if given): of the
    /// lowest class, from the host with the most connections in it, the oldest; never a
    /// priority one nor one `rank` spares.
    fn victim(
        &self,
        only: Option<IpAddr>,
        rank: &impl Fn(&Entry<S>) -> Option<(u8, Instant)>,
    ) -> Option<u64> {
        let candidates: Vec<(u64, IpAddr, u8, Instant)> = self
            .entries
            .iter()
            .filter(|(_, e)| !e.priority)
            .filter(|(_, e)| only.is_none_or(|h| host(e.peer.ip()) == h))
            .filter_map(|(id, e)| rank(e).map(|(class, t)| (*id, host(e.peer.ip()), class, t)))
            .collect();
        let lowest = candidates.iter().map(|c| c.2).min()?;
        let mut per_host: HashMap<IpAddr, usize> = HashMap::new();
        for c in candidates.iter().filter(|c| c.2 == lowest) {
            *per_host.entry(c.1).or_default() += 1;
        }
        candidates
            .iter()
            .filter(|c| c.2 == lowest)
            .min_by_key(|c| (std::cmp::Reverse(per_host[&c.1]), c.3, c.0))
            .map(|c| c.0)
    }

    /// What [`Pool::admit`] would refuse a connection from `peer` now, were no
    /// connection to be closed for it (`None`: it would be admitted): for a front end
    /// that answers a refusal before it starts anything for the new connection.
    pub fn refusal(&self, peer: SocketAddr, limits: &Admission<'_>) -> Option<Refused> {
        let from_here = self.from_host(peer.ip());
        if !limits.priority.contains(peer.ip()) && from_here >= limits.max_per_address {
            Some(Refused::PerAddress(from_here))
        } else if self.entries.len() >= limits.max_connections {
            Some(Refused::Full(self.entries.len()))
        } else {
            None
        }
    }

    /// Connections open now from `ip`'s host ([`same_host`]).
    pub fn from_host(&self, ip: IpAddr) -> usize {
        self.entries
            .values()
            .filter(|e| same_host(e.peer.ip(), ip))
            .count()
    }

    /// Forgets every connection `keep` does not keep (those that have ended).
    pub fn retain(&mut self, mut keep: impl FnMut(&Entry<S>) -> bool) {
        self.entries.retain(|_, e| keep(e));
    }

    /// Connection `id`, while it is in the pool.
    pub fn get(&self, id: u64) -> Option<&Entry<S>> {
        self.entries.get(&id)
    }

    /// Connection `id`, to change its state.
    pub fn get_mut(&mut self, id: u64) -> Option<&mut Entry<S>> {
        self.entries.get_mut(&id)
    }

    /// Forgets a closed connection.
    pub fn remove(&mut self, id: u64) -> Option<Entry<S>> {
        self.entries.remove(&id)
    }

    /// Connections open now.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether none is open.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

/// Whether two addresses are the same host (an IPv4 client seen as `::ffff:a.b.c.d`
/// counts as its IPv4 address).
pub fn same_host(a: IpAddr, b: IpAddr) -> bool {
    host(a) == host(b)
}

/// The host an address names (an IPv4-mapped IPv6 address as its IPv4 address).
fn host(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    }
}

/// Lines about connections logged per second at most; the rest are counted and the
/// count logged when the next second begins, so a flood of connections cannot fill
/// the disk with log lines.
pub const LOG_LINES_PER_SECOND: u32 = 20;

/// A per-second budget of log lines (the time is given).
#[derive(Debug, Default)]
pub struct LogLimit {
    /// When the current second began, ms on the caller's clock.
    start: Option<u64>,
    lines: u32,
    left_out: u64,
}

impl LogLimit {
    /// Whether a line may be logged at `now`; and, when a second with lines left out
    /// has ended, how many were left out (to be logged first).
    pub fn allow(&mut self, now: Instant) -> (bool, u64) {
        // Instants as ms since the first one this process asked about: one clock for
        // every limit, so the budget is kept in one way for both kinds of time.
        static BASE: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
        let base = *BASE.get_or_init(|| now);
        self.allow_ms(now.saturating_duration_since(base).as_millis() as u64)
    }

    /// [`LogLimit::allow`] with the time as milliseconds on any clock that does not go
    /// back (a sans-IO core's injected time).
    pub fn allow_ms(&mut self, now_ms: u64) -> (bool, u64) {
        let mut left_out = 0;
        if self
            .start
            .is_none_or(|s| now_ms.saturating_sub(s) >= 1000 || now_ms < s)
        {
            left_out = self.left_out;
            *self = LogLimit {
                start: Some(now_ms),
                lines: 0,
                left_out: 0,
            };
        }
        if self.lines < LOG_LINES_PER_SECOND {
            self.lines += 1;
            (true, left_out)
        } else {
            self.left_out += 1;
            (false, left_out)
        }
    }

    /// [`LogLimit::allow`], logging first (as `front_end`) how many lines the last
    /// second(s) left out.
    pub fn allow_logged(&mut self, now: Instant, front_end: &str) -> bool {
        let (ok, left_out) = self.allow(now);
        if left_out > 0 {
            tracing::warn!(
                "{front_end}: {left_out} more connection refusals, closings and time-outs in the last second(s), not logged one by one"
            );
        }
        ok
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn addr(s: &str) -> SocketAddr {
        s.parse().unwrap()
    }

    /// A state that says how it ranks.
    type Rank = Option<(u8, u64)>;

    #[test]
    fn a_full_pool_evicts_the_lowest_rank_never_a_priority_one() {
        let priority = NetList::parse(&["10.0.0.1"]).unwrap();
        let limits = Admission {
            max_connections: 3,
            max_per_address: 2,
            priority: &priority,
            evict_at_address_limit: false,
        };
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let rank = |e: &Entry<Rank>| e.state.map(|(c, s)| (c, at(s)));
        let mut pool: Pool<Rank> = Pool::default();
        let (scada, _) = pool
            .admit(addr("10.0.0.1:1000"), &limits, at(0), Some((0, 0)), rank)
            .unwrap();
        let (a, _) = pool
            .admit(addr("10.0.0.2:1000"), &limits, at(1), Some((1, 1)), rank)
            .unwrap();
        let (b, _) = pool
            .admit(addr("10.0.0.3:1000"), &limits, at(2), Some((0, 2)), rank)
            .unwrap();
        // Full: b ranks lowest (class 0); the SCADA's ranks lower still but is a
        // priority connection.
        let (c, ev) = pool
            .admit(addr("10.0.0.4:1000"), &limits, at(3), None, rank)
            .unwrap();
        assert_eq!(ev.map(|(id, _)| id), Some(b));
        // Then a; then nothing but the SCADA's and c (never): refused.
        let (_, ev) = pool
            .admit(addr("10.0.0.5:1000"), &limits, at(4), None, rank)
            .unwrap();
        assert_eq!(ev.map(|(id, _)| id), Some(a));
        assert_eq!(
            pool.admit(addr("10.0.0.6:1000"), &limits, at(5), None, rank)
                .err(),
            Some(Refused::Full(3))
        );
        assert!(pool.get(scada).is_some() && pool.get(c).is_some());
        // Per address: two at most, but the priority host has no such limit.
        pool.remove(c);
        let (d, _) = pool
            .admit(addr("10.0.0.4:1001"), &limits, at(6), None, rank)
            .unwrap();
        pool.remove(d);
        assert!(pool
            .admit(addr("10.0.0.1:1001"), &limits, at(7), None, rank)
            .is_ok());
        assert_eq!(pool.len(), 3);
    }

    #[test]
    fn a_flood_from_a_few_hosts_is_closed_before_a_single_client_of_the_same_class() {
        let none = NetList::empty();
        let limits = Admission {
            max_connections: 4,
            max_per_address: 16,
            priority: &none,
            evict_at_address_limit: false,
        };
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        // Every connection is of one class, ranked by when it opened.
        let rank = |e: &Entry<()>| Some((0, e.opened));
        let mut pool: Pool<()> = Pool::default();
        // The SCADA connects first: the oldest of its class.
        let (scada, _) = pool
            .admit(addr("10.0.0.1:1000"), &limits, at(0), (), rank)
            .unwrap();
        let (f1, _) = pool
            .admit(addr("10.0.0.7:1"), &limits, at(1), (), rank)
            .unwrap();
        pool.admit(addr("10.0.0.7:2"), &limits, at(2), (), rank)
            .unwrap();
        pool.admit(addr("10.0.0.8:1"), &limits, at(3), (), rank)
            .unwrap();
        // Full: 10.0.0.7 holds the most; its oldest goes, not the SCADA's.
        let (_, ev) = pool
            .admit(addr("10.0.0.8:2"), &limits, at(4), (), rank)
            .unwrap();
        assert_eq!(ev.map(|(id, _)| id), Some(f1));
        // A hundred more from the flood: the SCADA's stays throughout.
        for n in 0..100u16 {
            let host = if n % 2 == 0 { "10.0.0.7" } else { "10.0.0.8" };
            let peer = addr(&format!("{host}:{}", 100 + n));
            pool.admit(peer, &limits, at(5 + u64::from(n)), (), rank)
                .unwrap();
            assert!(pool.get(scada).is_some(), "after {n}");
        }
        // Once every host holds one, the oldest goes: the SCADA's.
        let mut pool: Pool<()> = Pool::default();
        let (scada, _) = pool
            .admit(addr("10.0.0.1:1000"), &limits, at(0), (), rank)
            .unwrap();
        for h in 2..=4 {
            pool.admit(addr(&format!("10.0.0.{h}:1")), &limits, at(h), (), rank)
                .unwrap();
        }
        let (_, ev) = pool
            .admit(addr("10.0.0.5:1"), &limits, at(9), (), rank)
            .unwrap();
        assert_eq!(ev.map(|(id, _)| id), Some(scada));
    }

    #[test]
    fn per_address_counts_v4_mapped_addresses_as_one_host() {
        let none = NetList::empty();
        let limits = Admission {
            max_connections: 10,
            max_per_address: 1,
            priority: &none,
            evict_at_address_limit: false,
        };
        let mut pool: Pool<()> = Pool::default();
        let now = Instant::now();
        pool.admit(addr("10.0.0.9:1"), &limits, now, (), |_| None)
            .unwrap();
        assert_eq!(
            pool.admit(addr("[::ffff:10.0.0.9]:2"), &limits, now, (), |_| None)
                .err(),
            Some(Refused::PerAddress(1))
        );
    }

    #[test]
    fn a_refusal_is_told_before_admitting_and_ended_connections_are_forgotten() {
        let none = NetList::empty();
        let limits = Admission {
            max_connections: 2,
            max_per_address: 1,
            priority: &none,
            evict_at_address_limit: false,
        };
        let now = Instant::now();
        let mut pool: Pool<bool> = Pool::default();
        assert_eq!(pool.refusal(addr("10.0.0.1:1"), &limits), None);
        pool.admit(addr("10.0.0.1:1"), &limits, now, true, |_| None)
            .unwrap();
        assert_eq!(
            pool.refusal(addr("10.0.0.1:2"), &limits),
            Some(Refused::PerAddress(1))
        );
        assert_eq!(pool.from_host("10.0.0.1".parse().unwrap()), 1);
        pool.admit(addr("10.0.0.2:1"), &limits, now, false, |_| None)
            .unwrap();
        assert_eq!(
            pool.refusal(addr("10.0.0.3:1"), &limits),
            Some(Refused::Full(2))
        );
        // The one whose state says it ended goes.
        pool.retain(|e| e.state);
        assert_eq!(pool.len(), 1);
        assert_eq!(pool.refusal(addr("10.0.0.3:1"), &limits), None);
    }

    #[test]
    fn the_log_keeps_to_its_budget_and_counts_the_rest() {
        let mut log = LogLimit::default();
        let t0 = Instant::now();
        for _ in 0..LOG_LINES_PER_SECOND {
            assert_eq!(log.allow(t0), (true, 0));
        }
        assert_eq!(log.allow(t0), (false, 0));
        assert_eq!(log.allow(t0), (false, 0));
        assert_eq!(log.allow(t0 + Duration::from_secs(1)), (true, 2));
    }

    #[test]
    fn at_its_limit_a_host_can_be_made_to_close_its_own_connections() {
        let none = NetList::empty();
        let mut limits = Admission {
            max_connections: 10,
            max_per_address: 2,
            priority: &none,
            evict_at_address_limit: true,
        };
        let t0 = Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        // The state: None for a connection being answered, else its class.
        let rank = |e: &Entry<Option<u8>>| e.state.map(|c| (c, e.opened));
        let mut pool: Pool<Option<u8>> = Pool::default();
        let (other, _) = pool
            .admit(addr("10.0.0.2:1"), &limits, at(0), Some(0), rank)
            .unwrap();
        let (busy, _) = pool
            .admit(addr("10.0.0.1:1"), &limits, at(1), None, rank)
            .unwrap();
        let (idle, _) = pool
            .admit(addr("10.0.0.1:2"), &limits, at(2), Some(2), rank)
            .unwrap();
        // 10.0.0.1 is at its limit: its idle one goes (not the older one of another
        // host, not its busy one).
        let (new, ev) = pool
            .admit(addr("10.0.0.1:3"), &limits, at(3), None, rank)
            .unwrap();
        assert_eq!(ev.map(|(id, _)| id), Some(idle));
        // Now both of its connections are busy: refused.
        assert_eq!(
            pool.admit(addr("10.0.0.1:4"), &limits, at(4), Some(0), rank)
                .err(),
            Some(Refused::PerAddress(2))
        );
        assert!(pool.get(other).is_some() && pool.get(busy).is_some());
        assert!(pool.get(new).is_some());
        // Without the option, a host at its limit is refused whatever it holds.
        limits.evict_at_address_limit = false;
        pool.get_mut(new).unwrap().state = Some(0);
        assert_eq!(
            pool.admit(addr("10.0.0.1:5"), &limits, at(5), Some(0), rank)
                .err(),
            Some(Refused::PerAddress(2))
        );
    }
}
