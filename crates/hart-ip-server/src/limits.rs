//! The session limits ([`crate::Config::max_sessions`],
//! [`crate::Config::max_sessions_per_host`]) kept in the gateway's connection pool
//! ([`hart_access::pool`]), as the TCP front ends keep theirs: a session holds a place
//! from its initiate to its close, and a host at its share or a full server is
//! refused. HART-IP closes no session to admit another (no place is ranked for
//! eviction) and has no priority addresses.

use std::net::SocketAddr;
use std::sync::{Mutex, MutexGuard};
use std::time::Instant;

use hart_access::pool::{Admission, Pool, Refused};
use hart_access::NetList;

/// The open sessions of a server, UDP, TCP, TLS and DTLS together.
pub(crate) struct SessionPool {
    pool: Mutex<Pool<()>>,
    max_sessions: usize,
    max_per_host: usize,
    /// No address has priority.
    none: NetList,
}

impl SessionPool {
    /// An empty pool with these limits.
    pub(crate) fn new(max_sessions: usize, max_per_host: usize) -> Self {
        SessionPool {
            pool: Mutex::new(Pool::default()),
            max_sessions,
            max_per_host,
            none: NetList::empty(),
        }
    }

    fn limits(&self) -> Admission<'_> {
        Admission {
            max_connections: self.max_sessions,
            max_per_address: self.max_per_host,
            priority: &self.none,
            evict_at_address_limit: false,
        }
    }

    /// The pool; a panic that poisoned the lock left it consistent (each critical
    /// section is one call), so it is taken anyway.
    fn lock(&self) -> MutexGuard<'_, Pool<()>> {
        self.pool.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Opens a session for `peer`: its place in the pool, or why it is refused.
    pub(crate) fn open(&self, peer: SocketAddr) -> Result<u64, Refusal> {
        let limits = self.limits();
        let mut pool = self.lock();
        match pool.admit(peer, &limits, Instant::now(), (), |_| None) {
            Ok((id, _)) => Ok(id),
            // A server both full and at the host's share says it is full.
            Err(Refused::PerAddress(n)) if pool.len() < self.max_sessions => {
                Err(Refusal::PerHost(n))
            }
            Err(_) => Err(Refusal::Full),
        }
    }

    /// Whether a session for `peer` would be refused now.
    pub(crate) fn would_refuse(&self, peer: SocketAddr) -> bool {
        self.lock().refusal(peer, &self.limits()).is_some()
    }

    /// Closes session `id` (its place is free again).
    pub(crate) fn close(&self, id: u64) {
        self.lock().remove(id);
    }

    /// Sessions open now.
    pub(crate) fn len(&self) -> usize {
        self.lock().len()
    }
}

/// Why a session was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Refusal {
    /// [`crate::Config::max_sessions`] are open.
    Full,
    /// So many sessions from that host already ([`crate::Config::max_sessions_per_host`]).
    PerHost(usize),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limits_total_and_per_host() {
        let p = SessionPool::new(3, 2);
        let a = |s: &str| s.parse::<SocketAddr>().unwrap();
        let first = p.open(a("10.0.0.1:1")).unwrap();
        p.open(a("10.0.0.1:2")).unwrap();
        assert!(p.would_refuse(a("10.0.0.1:3")));
        assert_eq!(p.open(a("10.0.0.1:3")), Err(Refusal::PerHost(2)));
        p.open(a("10.0.0.2:1")).unwrap();
        assert_eq!(p.open(a("10.0.0.3:1")), Err(Refusal::Full));
        // Full and at the host's share: full.
        assert_eq!(p.open(a("10.0.0.1:4")), Err(Refusal::Full));
        p.close(first);
        assert_eq!(p.len(), 2);
        assert!(!p.would_refuse(a("10.0.0.1:5")));
        p.open(a("10.0.0.1:5")).unwrap();
    }
}
