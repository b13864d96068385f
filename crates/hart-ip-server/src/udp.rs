//! HART-IP over UDP: one socket, sessions by client address.
//!
//! The receive loop waits for nothing but the socket. A datagram from a client with a
//! session goes to that session's own task through a short queue (full: the datagram
//! is dropped and counted; UDP clients repeat). A datagram from any other address is
//! looked at only if it is a session initiate: the session limits are checked at once
//! (all sessions in use: answered "all sessions in use" from the receive loop, with no
//! task), otherwise a task is started for it. Anything else from an address without a
//! session is dropped, as hipserver does. So a flood of datagrams from many ports costs
//! a counter each, never a task or a table entry, and a new client's initiate is
//! answered whatever the flood.
//!
//! A session task handles its datagrams in order (a request to a loop is answered
//! before the next one is read), publishes burst frames to its client, and ends at
//! session close, at a malformed message, or when its client has been silent for its
//! inactivity timer ([`crate::INITIATE_GRACE`] before its first request). When it
//! ends, its queued datagrams and any request it had queued for a loop go with it.

use std::cell::RefCell;
use std::collections::HashMap;
use std::net::SocketAddr;
use std::rc::Rc;
use std::sync::Arc;

use hart_ip::{status, Message, MessageId, MessageType};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;

use crate::session::{close_session, forwarded, handle, Action, Session};
use crate::{message, AbortOnDrop, Counters, PeerTable, Peers, Shared};

/// Datagrams queued for one session's task; more are dropped until it catches up.
pub(crate) const SESSION_QUEUE: usize = 8;

/// Longest datagram taken as HART-IP (a token-passing PDU is at most 8 + 267 bytes; a
/// direct PDU about 1 KiB); longer ones are dropped unread.
pub(crate) const MAX_DATAGRAM: usize = 4096;

/// Receive buffer the server asks for its UDP socket, bytes: room for a request from
/// each of many sessions at once (the kernel caps it at net.core.rmem_max).
pub const UDP_RECEIVE_BUFFER: usize = 4 << 20;

/// Session tasks started beyond the session limit, for initiates in progress.
const PENDING_INITIATES: usize = 16;

/// Serves UDP on `sock` until the server stops.
pub(crate) async fn serve_udp(sock: Arc<UdpSocket>, shared: Arc<Shared>) {
    let _ = socket2::SockRef::from(sock.as_ref()).set_recv_buffer_size(UDP_RECEIVE_BUFFER);
    let local_port = sock.local_addr().map_or(0, |a| a.port());
    let peers: Peers = Rc::new(RefCell::new(HashMap::new()));
    let mut buf = vec![0u8; 65536];
    loop {
        let Ok((n, peer)) = sock.recv_from(&mut buf).await else {
            continue;
        };
        if n > MAX_DATAGRAM {
            Counters::count(&shared.stats.dropped);
            continue;
        }
        let datagram = &buf[..n];
        let queue = peers.borrow().get(&peer).map(|(q, _)| q.clone());
        if let Some(q) = queue {
            match q.try_send(datagram.to_vec()) {
                Ok(()) => continue,
                Err(mpsc::error::TrySendError::Full(_)) => {
                    Counters::count(&shared.stats.dropped);
                    continue;
                }
                // The task has ended: the address starts afresh below.
                Err(mpsc::error::TrySendError::Closed(_)) => {
                    peers.borrow_mut().remove(&peer);
                }
            }
        }
        // No session at this address: only a session initiate opens one.
        let initiate = match Message::parse(datagram) {
            Ok((m, _)) => {
                m.header.message_id == MessageId::SessionInitiate
                    && m.header.message_type == MessageType::Request
            }
            Err(_) => false,
        };
        if !initiate {
            Counters::count(&shared.stats.malformed);
            continue;
        }
        // The limits, checked here so that a refusal costs no task. (The session's
        // own initiate checks them again, with the count it then takes.)
        let full = {
            shared.sessions.would_refuse(peer)
                // Tasks of initiates still being handled count too.
                || peers.borrow().len() >= shared.config.max_sessions + PENDING_INITIATES
        };
        if full {
            Counters::count(&shared.stats.sessions_refused);
            if let Ok((m, _)) = Message::parse(datagram) {
                let r = message(
                    1,
                    MessageType::Response,
                    MessageId::SessionInitiate,
                    status::ALL_SESSIONS_IN_USE,
                    m.header.sequence,
                    &[],
                );
                let _ = sock.try_send_to(&r, peer);
            }
            continue;
        }
        let (tx, rx) = mpsc::channel(SESSION_QUEUE);
        let _ = tx.try_send(datagram.to_vec());
        let task = tokio::task::spawn_local(udp_session(
            sock.clone(),
            shared.clone(),
            Rc::downgrade(&peers),
            peer,
            local_port,
            rx,
        ));
        peers.borrow_mut().insert(peer, (tx, AbortOnDrop(task)));
    }
}

/// One UDP session: its datagrams in order, its publish messages, its timer.
async fn udp_session(
    sock: Arc<UdpSocket>,
    shared: Arc<Shared>,
    peers: std::rc::Weak<RefCell<PeerTable>>,
    peer: SocketAddr,
    local_port: u16,
    mut rx: mpsc::Receiver<Vec<u8>>,
) {
    let mut s = Session::new(peer, local_port);
    let mut bursts = shared.bursts.subscribe();
    let why = loop {
        let wait = s.silence_allowed().saturating_sub(s.last_rx.elapsed());
        tokio::select! {
            d = rx.recv() => {
                let Some(d) = d else { break 0x0004 };
                if let Some(why) = datagram(&sock, &shared, &mut s, peer, &d).await {
                    break why;
                }
                if !s.open {
                    // The initiate was refused (limits, a bad body): nothing to keep.
                    break 0;
                }
            }
            b = bursts.recv() => {
                if let Some(m) = b.ok().and_then(|b| s.publish(&shared, &b)) {
                    let _ = sock.send_to(&m, peer).await;
                }
            }
            _ = tokio::time::sleep(wait) => {
                if s.expired() {
                    break 0x0008;
                }
            }
        }
    };
    close_session(&shared, &mut s, why).await;
    // This task's own entry goes; the abort it asks for finds the task finishing.
    // (The table holds the tasks, so a task holds the table weakly: when the server
    // stops, table and tasks go together.)
    if let Some(peers) = peers.upgrade() {
        let entry = peers.borrow_mut().remove(&peer);
        drop(entry);
    }
}

/// Handles the messages of one datagram; `Some(why)` when the session ends (0 normal
/// close, 0x0004 aborted).
async fn datagram(
    sock: &UdpSocket,
    shared: &Shared,
    s: &mut Session,
    peer: SocketAddr,
    data: &[u8],
) -> Option<u16> {
    let mut rest = data;
    while !rest.is_empty() {
        let (h, body, used) = match Message::parse(rest) {
            Ok((m, used)) => (m.header, m.body, used),
            Err(_) => {
                Counters::count(&shared.stats.malformed);
                return None;
            }
        };
        rest = &rest[used..];
        match handle(shared, s, h, body).await {
            Action::Reply(r) => {
                let _ = sock.send_to(&r, peer).await;
                if !s.open {
                    return Some(0x0004);
                }
            }
            Action::Forward {
                channel,
                retries,
                pdu,
                seq,
                from,
            } => {
                // In order, per client: the session waits for its loop's reply.
                let r = forwarded(shared, s.version, channel, retries, pdu, seq, from).await;
                let _ = sock.send_to(&r, peer).await;
            }
            Action::ReplyAndClose(r) => {
                let _ = sock.send_to(&r, peer).await;
                return Some(0);
            }
            Action::Close => return Some(0x0004),
        }
    }
    None
}
