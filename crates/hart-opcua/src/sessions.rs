//! Sessions created and never activated. async-opcua keeps a session that was created
//! and never activated until its session time-out, and it bounds sessions only in
//! total ([`Limits::max_sessions`]): a client that creates sessions and drops them
//! would fill the table for everyone, a SCADA coming back after a restart included. The
//! front therefore follows, on channels with security policy None (the only ones a
//! client without a trusted certificate can open, and the only ones whose requests it
//! can read), which requests are CreateSession and ActivateSession, and refuses a
//! CreateSession from an address that already holds [`PENDING_PER_ADDRESS`] sessions
//! created and not activated, or when such sessions from all addresses but the priority
//! hosts reach half of `max_sessions`. The other half is always left to sessions that
//! are activated, and to the priority hosts.
//!
//! Sans-IO: `RequestWatch` takes the client's bytes, `SessionGuard` the requests
//! with the time, and says whether a CreateSession may go on.

use std::collections::{HashMap, VecDeque};
use std::net::IpAddr;
use std::time::{Duration, Instant};

use hart_access::pool::same_host;

use crate::connections::Limits;

/// Sessions created and not activated that one address may hold at once (a client
/// activates its session right after creating it: one is pending at a time).
pub const PENDING_PER_ADDRESS: usize = 4;

/// The encoding id of CreateSessionRequest (binary), namespace 0.
const CREATE_SESSION: u32 = 461;
/// The encoding id of ActivateSessionRequest (binary), namespace 0.
const ACTIVATE_SESSION: u32 = 467;

/// The security policy whose messages travel in clear.
const POLICY_NONE: &[u8] = b"http://opcfoundation.org/UA/SecurityPolicy#None";

/// Bytes of a message's start kept to read what it is: the header (8), an OPN's
/// channel id and policy URI (4 + 4 + 47), or a MSG's security and sequence headers
/// (16) and the request's type id (at most 7).
const KEEP: usize = 96;

/// A request the front follows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Request {
    /// CreateSession.
    CreateSession,
    /// ActivateSession.
    ActivateSession,
}

/// Follows the client's side of a connection: the OPC UA TCP messages (an 8-byte
/// header: 3-byte type, chunk type, 4-byte little-endian size), the security policy of
/// each OPN, and on a channel whose policy is None, the type of each request (the
/// first chunk of a MSG message: secure channel id, token id, sequence number and
/// request id, then the request's type as a NodeId).
#[derive(Debug, Clone, Default)]
pub(crate) struct RequestWatch {
    start: Vec<u8>,
    /// Bytes of the current message still to come after `start` is full.
    skip: usize,
    /// The size of the current message (0 before its header is whole).
    size: usize,
    /// The channel's policy is None (from its last OPN).
    plain: bool,
    /// The last MSG chunk was an intermediate one ('C').
    mid_message: bool,
}

impl RequestWatch {
    /// Takes bytes the client sent; the requests that they begin.
    pub(crate) fn feed(&mut self, mut bytes: &[u8]) -> Vec<Request> {
        let mut found = vec![];
        while !bytes.is_empty() {
            if self.skip > 0 {
                let n = self.skip.min(bytes.len());
                self.skip -= n;
                bytes = &bytes[n..];
                continue;
            }
            let want = if self.size == 0 {
                8
            } else {
                self.size.min(KEEP)
            };
            let n = (want - self.start.len()).min(bytes.len());
            self.start.extend_from_slice(&bytes[..n]);
            bytes = &bytes[n..];
            if self.start.len() < want {
                break;
            }
            if self.size == 0 {
                let size = u32::from_le_bytes([
                    self.start[4],
                    self.start[5],
                    self.start[6],
                    self.start[7],
                ]) as usize;
                // A size under the header's is broken: the server closes it; take it
                // as a bare header.
                self.size = size.max(8);
                if self.size > 8 {
                    continue;
                }
            }
            if let Some(r) = self.message() {
                found.push(r);
            }
            self.skip = self.size - self.start.len();
            self.size = 0;
            self.start.clear();
        }
        found
    }

    /// What the message whose start is in `start` is.
    fn message(&mut self) -> Option<Request> {
        let m = &self.start;
        match &m[..3] {
            b"OPN" => {
                let len = m
                    .get(12..16)
                    .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]));
                self.plain = len
                    .and_then(|l| usize::try_from(l).ok())
                    .is_some_and(|l| m.get(16..16 + l) == Some(POLICY_NONE));
                None
            }
            b"MSG" => {
                let first = !self.mid_message;
                self.mid_message = m[3] == b'C';
                if !(self.plain && first) {
                    return None;
                }
                match type_id(m.get(24..)?)? {
                    (0, CREATE_SESSION) => Some(Request::CreateSession),
                    (0, ACTIVATE_SESSION) => Some(Request::ActivateSession),
                    _ => None,
                }
            }
            _ => None,
        }
    }
}

/// A NodeId at the start of `b`, numeric forms only: (namespace, id).
fn type_id(b: &[u8]) -> Option<(u16, u32)> {
    match *b.first()? {
        0x00 => Some((0, u32::from(*b.get(1)?))),
        0x01 => {
            let ns = u16::from(*b.get(1)?);
            let id = u16::from_le_bytes([*b.get(2)?, *b.get(3)?]);
            Some((ns, u32::from(id)))
        }
        0x02 => {
            let ns = u16::from_le_bytes([*b.get(1)?, *b.get(2)?]);
            let id = u32::from_le_bytes([*b.get(3)?, *b.get(4)?, *b.get(5)?, *b.get(6)?]);
            Some((ns, id))
        }
        _ => None,
    }
}

/// Why a CreateSession is refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum SessionRefused {
    /// That address holds so many sessions created and not activated.
    PerAddress(usize),
    /// All addresses but the priority hosts hold so many.
    Total(usize),
}

impl std::fmt::Display for SessionRefused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SessionRefused::PerAddress(n) => write!(
                f,
                "{n} sessions from that address created and never activated (the limit); a \
                 client must activate the session it creates"
            ),
            SessionRefused::Total(n) => write!(
                f,
                "{n} sessions created and never activated (half of [opcua] max_sessions, \
                 the limit); list a SCADA host in [opcua] priority to exempt it"
            ),
        }
    }
}

/// The sessions created and not yet activated, by connection (while it is open) and by
/// address (after it closed, until the session time-out ends them).
#[derive(Debug, Default)]
pub(crate) struct SessionGuard {
    live: HashMap<u64, (IpAddr, VecDeque<Instant>)>,
    orphans: Vec<(IpAddr, Instant)>,
}

impl SessionGuard {
    /// A CreateSession on connection `conn` from `peer` at `now`: whether it may go on
    /// (then it is counted as pending until an ActivateSession on the connection).
    pub(crate) fn create(
        &mut self,
        conn: u64,
        peer: IpAddr,
        limits: &Limits,
        now: Instant,
    ) -> Result<(), SessionRefused> {
        if limits.priority.contains(peer) {
            return Ok(());
        }
        self.expire(now, limits.session_timeout);
        let live = self
            .live
            .values()
            .flat_map(|(a, q)| q.iter().map(move |_| *a));
        let all: Vec<IpAddr> = live.chain(self.orphans.iter().map(|(a, _)| *a)).collect();
        let here = all.iter().filter(|a| same_host(**a, peer)).count();
        if here >= PENDING_PER_ADDRESS {
            return Err(SessionRefused::PerAddress(here));
        }
        let total_limit = (limits.max_sessions / 2).max(1);
        if all.len() >= total_limit {
            return Err(SessionRefused::Total(all.len()));
        }
        self.live
            .entry(conn)
            .or_insert_with(|| (peer, VecDeque::new()))
            .1
            .push_back(now);
        Ok(())
    }

    /// An ActivateSession on connection `conn`: its oldest pending session is active.
    pub(crate) fn activate(&mut self, conn: u64) {
        if let Some((_, q)) = self.live.get_mut(&conn) {
            q.pop_front();
        }
    }

    /// Connection `conn` closed: its pending sessions stay pending, by address, until
    /// the session time-out ends them.
    pub(crate) fn closed(&mut self, conn: u64) {
        if let Some((peer, q)) = self.live.remove(&conn) {
            self.orphans.extend(q.into_iter().map(|t| (peer, t)));
        }
    }

    /// Forgets what the session time-out has ended.
    fn expire(&mut self, now: Instant, timeout: Duration) {
        let alive = |t: &Instant| now.saturating_duration_since(*t) < timeout;
        self.orphans.retain(|(_, t)| alive(t));
        for (_, q) in self.live.values_mut() {
            q.retain(alive);
        }
    }

    /// Sessions counted as pending now (for tests).
    #[cfg(test)]
    fn pending(&self) -> usize {
        self.live.values().map(|(_, q)| q.len()).sum::<usize>() + self.orphans.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An OPN request with `policy` (header, channel id 0, the policy URI, no
    /// certificates; the rest of the message is not read).
    fn opn(policy: &[u8]) -> Vec<u8> {
        let mut m = b"OPNF\0\0\0\0".to_vec();
        m.extend_from_slice(&0u32.to_le_bytes());
        m.extend_from_slice(&(policy.len() as i32).to_le_bytes());
        m.extend_from_slice(policy);
        m.extend_from_slice(&(-1i32).to_le_bytes());
        m.extend_from_slice(&(-1i32).to_le_bytes());
        m.extend_from_slice(&[0; 40]);
        let size = m.len() as u32;
        m[4..8].copy_from_slice(&size.to_le_bytes());
        m
    }

    /// A MSG chunk (`chunk` F or C) whose body starts with the four-byte NodeId `id`.
    fn msg(chunk: u8, id: u16, body: usize) -> Vec<u8> {
        let mut m = vec![b'M', b'S', b'G', chunk, 0, 0, 0, 0];
        m.extend_from_slice(&[7, 0, 0, 0, 1, 0, 0, 0, 51, 0, 0, 0, 1, 0, 0, 0]);
        m.extend_from_slice(&[0x01, 0]);
        m.extend_from_slice(&id.to_le_bytes());
        m.extend(std::iter::repeat_n(0xAA, body));
        let size = m.len() as u32;
        m[4..8].copy_from_slice(&size.to_le_bytes());
        m
    }

    #[test]
    fn requests_are_read_on_a_none_channel_byte_by_byte_or_at_once() {
        let mut stream = b"HELF\x1c\0\0\0".to_vec();
        stream.extend_from_slice(&[0; 20]);
        stream.extend(opn(POLICY_NONE));
        stream.extend(msg(b'F', 461, 300));
        stream.extend(msg(b'F', 631, 10)); // a ReadRequest
        stream.extend(msg(b'F', 467, 200));
        // A request in two chunks: only the first carries the type; the second's
        // bytes where a type would be are 0x01 0x00 0xCD 0x01 (461) and must not count.
        stream.extend(msg(b'C', 631, 5));
        stream.extend(msg(b'F', 461, 5));
        let want = vec![Request::CreateSession, Request::ActivateSession];
        assert_eq!(RequestWatch::default().feed(&stream), want);
        let mut w = RequestWatch::default();
        let one_by_one: Vec<Request> = stream.iter().flat_map(|b| w.feed(&[*b])).collect();
        assert_eq!(one_by_one, want);
    }

    #[test]
    fn an_encrypted_channel_is_not_read() {
        let mut stream = opn(b"http://opcfoundation.org/UA/SecurityPolicy#Basic256Sha256");
        stream.extend(msg(b'F', 461, 300));
        assert!(RequestWatch::default().feed(&stream).is_empty());
    }

    #[test]
    fn garbage_never_panics() {
        let mut w = RequestWatch::default();
        for seed in 0u32..2000 {
            let bytes: Vec<u8> = (0..(seed % 97))
                .map(|i| (seed.wrapping_mul(2_654_435_761).wrapping_add(i * 40_503) >> 13) as u8)
                .collect();
            let _ = w.feed(&bytes);
        }
        let _ = type_id(&[0x02, 0, 0]);
    }

    #[test]
    fn pending_sessions_are_bounded_per_address_and_in_all_but_priority_hosts_pass() {
        let limits = Limits {
            max_sessions: 20,
            priority: hart_access::NetList::parse(&["10.0.0.1"]).unwrap(),
            ..Limits::default()
        };
        let t0 = Instant::now();
        let ip = |s: &str| s.parse::<IpAddr>().unwrap();
        let mut g = SessionGuard::default();
        // One address: four, then refused, on any of its connections.
        for conn in 0..PENDING_PER_ADDRESS as u64 {
            g.create(conn, ip("10.0.0.9"), &limits, t0).unwrap();
            g.closed(conn);
        }
        assert_eq!(
            g.create(99, ip("10.0.0.9"), &limits, t0),
            Err(SessionRefused::PerAddress(4))
        );
        // A client that activates what it creates is never held up.
        for _ in 0..50 {
            g.create(100, ip("10.0.0.8"), &limits, t0).unwrap();
            g.activate(100);
        }
        // In all: half of max_sessions (10), then refused; the priority host passes.
        for (n, a) in ["10.0.0.2", "10.0.0.3"].iter().enumerate() {
            for k in 0..3 {
                g.create(200 + n as u64 * 10 + k, ip(a), &limits, t0)
                    .unwrap();
            }
        }
        assert_eq!(g.pending(), 10);
        assert_eq!(
            g.create(300, ip("10.0.0.4"), &limits, t0),
            Err(SessionRefused::Total(10))
        );
        assert!(g.create(301, ip("10.0.0.1"), &limits, t0).is_ok());
        // The session time-out ends them.
        let later = t0 + limits.session_timeout;
        assert!(g.create(302, ip("10.0.0.4"), &limits, later).is_ok());
        assert_eq!(g.pending(), 1);
    }
}
