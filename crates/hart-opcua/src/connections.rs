//! The limits of the OPC UA front end, and the admission of its TCP connections.
//!
//! `async-opcua` bounds sessions, message sizes and subscriptions, and closes a
//! connection that sends no HEL (or no OPN after its ACK) within its hello time-out; it
//! does not bound the number of TCP connections, so a flood of them would take a
//! descriptor, a task and buffers each without end. The gateway therefore accepts on
//! the public address itself and hands each admitted connection to the library (see
//! `front` in the crate), with the limits a plant's port needs, as its Modbus TCP server
//! does:
//!
//! * at most [`Limits::max_connections`] at once, at most [`Limits::max_per_address`]
//!   from one address (priority addresses are exempt);
//! * a new connection must have its secure channel open (HEL/ACK, then OPN answered)
//!   within [`Limits::handshake`];
//! * a full pool evicts a connection to admit a new one: first the oldest that has not
//!   opened its secure channel, then the one idle longest of those that sent nothing
//!   for [`EVICTABLE_IDLE`]; never a priority address's; with none to evict, the new
//!   one is refused (and told so with an OPC UA `ERR` message, BadTcpServerTooBusy).
//!
//! Every refusal, eviction and time-out is logged with the peer and the reason, at most
//! [`LOG_LINES_PER_SECOND`] lines a second (the rest counted).
//!
//! This module is sans-IO: the pool and the handshake watcher take the time and the
//! bytes and say what to do.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hart_access::pool;

/// The limits of the OPC UA front end.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Most TCP connections at once (each is also a session's transport).
    pub max_connections: usize,
    /// Most TCP connections from one address (priority addresses aside).
    pub max_per_address: usize,
    /// Addresses whose connections are never evicted nor limited per address (the
    /// SCADA hosts).
    pub priority: hart_access::NetList,
    /// A new connection must have opened its secure channel (HEL/ACK and OPN) by then;
    /// also the library's hello time-out (whole seconds, at least 1).
    pub handshake: Duration,
    /// Most sessions at once, over all connections (async-opcua answers
    /// BadTooManySessions beyond).
    pub max_sessions: usize,
    /// The longest session time-out granted: a session that receives no request for
    /// that long (one created and never activated among them) is closed and its
    /// subscriptions deleted.
    pub session_timeout: Duration,
    /// The largest message in bytes, either way (larger requests are refused with
    /// BadRequestTooLarge; clients learn it in the ACK).
    pub max_message_size: usize,
    /// The most chunks in one message.
    pub max_chunk_count: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: 64,
            max_per_address: 16,
            priority: hart_access::NetList::empty(),
            handshake: Duration::from_secs(10),
            max_sessions: 100,
            session_timeout: Duration::from_secs(30),
            max_message_size: 2 * 1024 * 1024,
            max_chunk_count: chunks_for(2 * 1024 * 1024),
        }
    }
}

impl Limits {
    /// Refuses limits that would refuse every client.
    pub fn check(&self) -> Result<(), String> {
        let zero = [
            ("max_connections", self.max_connections),
            ("max_per_address", self.max_per_address),
            ("max_sessions", self.max_sessions),
            ("max_chunk_count", self.max_chunk_count),
        ];
        if let Some((name, _)) = zero.iter().find(|(_, v)| *v == 0) {
            return Err(format!(
                "{name} is 0: no client could connect; give 1 or more"
            ));
        }
        if self.handshake < Duration::from_secs(1) {
            return Err(format!(
                "handshake_timeout {:?} is under a second: even a client on the same host \
                 may need longer to open a secure channel; give 1 s or more",
                self.handshake
            ));
        }
        if self.session_timeout < Duration::from_secs(1) {
            return Err(format!(
                "session_timeout {:?} is under a second: sessions would expire between \
                 two requests; give 10 s or more",
                self.session_timeout
            ));
        }
        if self.max_message_size < 8192 {
            return Err(format!(
                "max_message_size {} is under 8192 bytes, the least OPC UA allows a \
                 client to assume",
                self.max_message_size
            ));
        }
        Ok(())
    }
}

/// The chunk count that lets a message of `max_message_size` bytes through in chunks
/// of 8192 bytes (the least chunk size OPC UA allows), so that the message size is the
/// bound that counts.
pub fn chunks_for(max_message_size: usize) -> usize {
    max_message_size.div_ceil(8192).max(1)
}

/// A connection that sent nothing for this long may be closed to admit a new one when
/// the pool is full (one that did may be a client at work, between two reads).
pub const EVICTABLE_IDLE: Duration = Duration::from_secs(10);

/// Where a connection is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Phase {
    /// Opened; its secure channel is not open yet.
    Handshake,
    /// Its secure channel is open.
    Open,
}

/// What the pool keeps of a connection.
#[derive(Debug, Clone, Copy)]
struct Conn {
    /// When the client last sent bytes (or the connection opened).
    last_sent: Instant,
    phase: Phase,
}

/// A connection closed to admit another.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Evicted {
    pub(crate) id: u64,
    pub(crate) peer: SocketAddr,
    pub(crate) phase: Phase,
    /// Since when it sent nothing.
    pub(crate) idle: Duration,
    /// How long it was open.
    pub(crate) age: Duration,
}

/// Why a connection was not admitted.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Refused {
    /// So many from that address already.
    PerAddress(usize),
    /// So many open, and none that may be closed.
    Full(usize),
}

impl From<pool::Refused> for Refused {
    fn from(r: pool::Refused) -> Self {
        match r {
            pool::Refused::PerAddress(n) => Refused::PerAddress(n),
            pool::Refused::Full(n) => Refused::Full(n),
        }
    }
}

impl std::fmt::Display for Refused {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refused::PerAddress(n) => write!(
                f,
                "{n} connections from that address already (the per-address limit, \
                 [opcua] max_per_address); list a SCADA host in [opcua] priority to \
                 exempt it"
            ),
            Refused::Full(n) => write!(
                f,
                "{n} connections open (the limit, [opcua] max_connections), all in use \
                 or from priority hosts"
            ),
        }
    }
}

/// The open connections: hart-access's pool, with the OPC UA front end's ranking.
#[derive(Default)]
pub(crate) struct Pool(pool::Pool<Conn>);

impl Pool {
    /// Admits a connection from `peer` at `now`: its id, and the connection closed to
    /// make room if the pool was full (already forgotten here; the caller closes it).
    pub(crate) fn admit(
        &mut self,
        peer: SocketAddr,
        limits: &Limits,
        now: Instant,
    ) -> Result<(u64, Option<Evicted>), Refused> {
        let admission = pool::Admission {
            max_connections: limits.max_connections,
            max_per_address: limits.max_per_address,
            priority: &limits.priority,
            evict_at_address_limit: false,
        };
        let fresh = Conn {
            last_sent: now,
            phase: Phase::Handshake,
        };
        // First the oldest still in its handshake (a client opens its secure channel
        // in milliseconds: the rest are scanners or floods), then the one idle longest
        // among those idle for EVICTABLE_IDLE; a client at work is kept.
        let rank = |e: &pool::Entry<Conn>| match e.state.phase {
            Phase::Handshake => Some((0, e.opened)),
            Phase::Open if now.saturating_duration_since(e.state.last_sent) >= EVICTABLE_IDLE => {
                Some((1, e.state.last_sent))
            }
            Phase::Open => None,
        };
        let (id, evicted) = self.0.admit(peer, &admission, now, fresh, rank)?;
        Ok((
            id,
            evicted.map(|(id, e)| Evicted {
                id,
                peer: e.peer,
                phase: e.state.phase,
                idle: now.saturating_duration_since(e.state.last_sent),
                age: now.saturating_duration_since(e.opened),
            }),
        ))
    }

    /// Connection `id` has opened its secure channel.
    pub(crate) fn opened(&mut self, id: u64, now: Instant) {
        if let Some(e) = self.0.get_mut(id) {
            e.state.phase = Phase::Open;
            e.state.last_sent = now;
        }
    }

    /// The client of connection `id` sent bytes at `now`.
    pub(crate) fn sent(&mut self, id: u64, now: Instant) {
        if let Some(e) = self.0.get_mut(id) {
            e.state.last_sent = now;
        }
    }

    /// Whether connection `id` is still in the pool (not evicted).
    #[cfg(test)]
    pub(crate) fn contains(&self, id: u64) -> bool {
        self.0.get(id).is_some()
    }

    /// Forgets a closed connection.
    pub(crate) fn remove(&mut self, id: u64) {
        self.0.remove(id);
    }

    /// Connections open now.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.0.len()
    }
}

/// What the server has said on a connection so far, from the bytes it sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Handshake {
    /// Neither ACK nor OPN yet (or only the ACK).
    Pending,
    /// The server answered the OPN: the secure channel is open.
    Open,
    /// The server sent an ERR (it refused the HEL or the OPN) or something that is not
    /// OPC UA TCP.
    Failed(&'static str),
}

/// Follows the server's side of a connection's handshake: OPC UA TCP messages are an
/// 8-byte header (3-byte type, 1-byte chunk type, 4-byte little-endian size including
/// the header) and a body; the server answers a HEL with an ACK (or an ERR) and an OPN
/// with an OPN.
#[derive(Debug, Clone)]
pub(crate) struct HandshakeWatch {
    header: [u8; 8],
    have: usize,
    /// Body bytes of the current message still to pass.
    skip: usize,
    acked: bool,
    state: Handshake,
}

impl Default for HandshakeWatch {
    fn default() -> Self {
        HandshakeWatch {
            header: [0; 8],
            have: 0,
            skip: 0,
            acked: false,
            state: Handshake::Pending,
        }
    }
}

impl HandshakeWatch {
    /// Takes bytes the server sent; the state after them.
    pub(crate) fn feed(&mut self, mut bytes: &[u8]) -> Handshake {
        while !bytes.is_empty() && self.state == Handshake::Pending {
            if self.skip > 0 {
                let n = self.skip.min(bytes.len());
                self.skip -= n;
                bytes = &bytes[n..];
                continue;
            }
            let n = (8 - self.have).min(bytes.len());
            self.header[self.have..self.have + n].copy_from_slice(&bytes[..n]);
            self.have += n;
            bytes = &bytes[n..];
            if self.have < 8 {
                break;
            }
            self.have = 0;
            let size = u32::from_le_bytes([
                self.header[4],
                self.header[5],
                self.header[6],
                self.header[7],
            ]) as usize;
            if size < 8 {
                self.state = Handshake::Failed("a message header announcing under 8 bytes");
                break;
            }
            self.skip = size - 8;
            self.state = match (&self.header[..3], self.acked) {
                (b"ACK", false) => {
                    self.acked = true;
                    Handshake::Pending
                }
                (b"OPN", true) => Handshake::Open,
                (b"ERR", _) => Handshake::Failed("the server refused the connection (ERR)"),
                _ => Handshake::Failed("a message out of the handshake's order"),
            };
        }
        self.state
    }
}

pub(crate) use hart_access::pool::LogLimit;
pub use hart_access::pool::LOG_LINES_PER_SECOND;

/// The OPC UA TCP `ERR` message telling a client why it is closed.
pub(crate) fn err_message(status: u32, reason: &str) -> Vec<u8> {
    // Error (UInt32), Reason (String: Int32 length, UTF-8); 4096 bytes at most.
    let mut reason = reason.as_bytes();
    if reason.len() > 4000 {
        reason = &reason[..4000];
    }
    let size = 8 + 4 + 4 + reason.len();
    let mut m = Vec::with_capacity(size);
    m.extend_from_slice(b"ERRF");
    m.extend_from_slice(&(size as u32).to_le_bytes());
    m.extend_from_slice(&status.to_le_bytes());
    m.extend_from_slice(&(reason.len() as i32).to_le_bytes());
    m.extend_from_slice(reason);
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(s: &str) -> SocketAddr {
        s.parse().unwrap()
    }

    fn secs(t0: Instant) -> impl Fn(u64) -> Instant {
        move |s| t0 + Duration::from_secs(s)
    }

    #[test]
    fn a_full_pool_evicts_a_connection_still_in_its_handshake_first_and_never_a_priority_one() {
        let limits = Limits {
            max_connections: 3,
            max_per_address: 2,
            priority: hart_access::NetList::parse(&["10.0.0.1"]).unwrap(),
            ..Limits::default()
        };
        let mut pool = Pool::default();
        let at = secs(Instant::now());
        let (scada, _) = pool.admit(addr("10.0.0.1:1000"), &limits, at(0)).unwrap();
        pool.opened(scada, at(0));
        let (a, _) = pool.admit(addr("10.0.0.2:1000"), &limits, at(1)).unwrap();
        let (b, _) = pool.admit(addr("10.0.0.3:1000"), &limits, at(2)).unwrap();
        pool.opened(b, at(2));
        // Full, at 100 s: the SCADA's is idle longest but a priority host's; a is still
        // in its handshake and goes before b (idle, open).
        let (c, ev) = pool.admit(addr("10.0.0.4:1000"), &limits, at(100)).unwrap();
        let ev = ev.unwrap();
        assert_eq!((ev.id, ev.phase), (a, Phase::Handshake));
        assert_eq!(ev.age, Duration::from_secs(99));
        assert!(!pool.contains(a));
        // Next: b, open and idle for 98 s; then c (in its handshake) would go before
        // anything open.
        pool.opened(c, at(100));
        let (_, ev) = pool.admit(addr("10.0.0.5:1000"), &limits, at(101)).unwrap();
        assert_eq!(ev.unwrap().id, b);
        assert!(pool.contains(scada), "the SCADA's stays");
        assert_eq!(pool.len(), 3);
    }

    #[test]
    fn a_client_at_work_is_never_evicted_the_new_one_is_refused() {
        let limits = Limits {
            max_connections: 2,
            ..Limits::default()
        };
        let mut pool = Pool::default();
        let at = secs(Instant::now());
        let (x, _) = pool.admit(addr("10.0.0.1:1000"), &limits, at(0)).unwrap();
        let (y, _) = pool.admit(addr("10.0.0.2:1000"), &limits, at(0)).unwrap();
        pool.opened(x, at(1));
        pool.opened(y, at(1));
        pool.sent(x, at(20));
        pool.sent(y, at(25));
        // At 29 s both sent within EVICTABLE_IDLE (10 s): refused.
        assert_eq!(
            pool.admit(addr("10.0.0.9:1000"), &limits, at(29)),
            Err(Refused::Full(2))
        );
        // At 31 s x has been idle 11 s: it goes, y stays.
        let (_, ev) = pool.admit(addr("10.0.0.9:1000"), &limits, at(31)).unwrap();
        let ev = ev.unwrap();
        assert_eq!((ev.id, ev.idle), (x, Duration::from_secs(11)));
        assert!(pool.contains(y));
    }

    #[test]
    fn per_address_limit_but_not_for_priority_hosts_and_ipv4_mapped_is_the_same_host() {
        let limits = Limits {
            max_per_address: 2,
            priority: hart_access::NetList::parse(&["10.0.0.1"]).unwrap(),
            ..Limits::default()
        };
        let mut pool = Pool::default();
        let at = secs(Instant::now());
        pool.admit(addr("10.0.0.7:1"), &limits, at(0)).unwrap();
        pool.admit(addr("[::ffff:10.0.0.7]:2"), &limits, at(0))
            .unwrap();
        assert_eq!(
            pool.admit(addr("10.0.0.7:3"), &limits, at(0)),
            Err(Refused::PerAddress(2))
        );
        for port in 0..5 {
            pool.admit(
                SocketAddr::new("10.0.0.1".parse().unwrap(), port),
                &limits,
                at(0),
            )
            .unwrap();
        }
        // A closed one frees its room.
        let (id, _) = pool.admit(addr("10.0.0.8:1"), &limits, at(0)).unwrap();
        pool.remove(id);
        assert!(!pool.contains(id));
        assert_eq!(pool.len(), 7);
    }

    #[test]
    fn the_handshake_is_followed_across_any_split_of_the_bytes() {
        let mut ack = b"ACKF".to_vec();
        ack.extend_from_slice(&28u32.to_le_bytes());
        ack.extend_from_slice(&[7; 20]);
        let mut opn = b"OPNF".to_vec();
        opn.extend_from_slice(&12u32.to_le_bytes());
        opn.extend_from_slice(&[1; 4]);
        let all: Vec<u8> = [ack.clone(), opn.clone(), b"MSGF".to_vec()].concat();
        for split in 0..all.len() {
            let mut w = HandshakeWatch::default();
            let first = w.feed(&all[..split]);
            // Open with the OPN's header (the server answers an OPN only once it
            // opened the channel).
            let end = ack.len() + 8;
            assert_eq!(
                first,
                if split >= end {
                    Handshake::Open
                } else {
                    Handshake::Pending
                },
                "split at {split}"
            );
            assert_eq!(w.feed(&all[split..]), Handshake::Open, "split at {split}");
        }
        // One byte at a time.
        let mut w = HandshakeWatch::default();
        let states: Vec<Handshake> = all.iter().map(|b| w.feed(&[*b])).collect();
        assert_eq!(states[ack.len() + 6], Handshake::Pending);
        assert_eq!(states[ack.len() + 7], Handshake::Open);
    }

    #[test]
    fn an_err_a_message_out_of_order_or_a_bad_size_fails_the_handshake() {
        let mut w = HandshakeWatch::default();
        assert!(matches!(
            w.feed(&err_message(0x807D_0000, "busy")),
            Handshake::Failed(_)
        ));
        let mut w = HandshakeWatch::default();
        let mut opn = b"OPNF".to_vec();
        opn.extend_from_slice(&8u32.to_le_bytes());
        assert!(
            matches!(w.feed(&opn), Handshake::Failed(_)),
            "OPN before ACK"
        );
        let mut w = HandshakeWatch::default();
        assert!(matches!(
            w.feed(b"ACKF\x03\x00\x00\x00"),
            Handshake::Failed(_)
        ));
        // Failed stays failed.
        assert!(matches!(w.feed(b"anything"), Handshake::Failed(_)));
    }

    #[test]
    fn the_err_message_is_well_formed_and_its_reason_bounded() {
        let m = err_message(0x807D_0000, "too busy");
        assert_eq!(&m[..4], b"ERRF");
        assert_eq!(
            u32::from_le_bytes(m[4..8].try_into().unwrap()) as usize,
            m.len()
        );
        assert_eq!(&m[8..12], &0x807D_0000u32.to_le_bytes());
        assert_eq!(&m[16..], b"too busy");
        assert!(err_message(0, &"x".repeat(10_000)).len() <= 4096);
    }

    #[test]
    fn limits_that_would_refuse_every_client_are_refused() {
        assert!(Limits::default().check().is_ok());
        let e = Limits {
            max_connections: 0,
            ..Limits::default()
        }
        .check()
        .unwrap_err();
        assert!(e.contains("max_connections"), "{e}");
        assert!(Limits {
            handshake: Duration::from_millis(10),
            ..Limits::default()
        }
        .check()
        .is_err());
        assert!(Limits {
            max_message_size: 100,
            ..Limits::default()
        }
        .check()
        .is_err());
    }
}
