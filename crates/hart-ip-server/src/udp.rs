//! HART-IP over UDP.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use hart_ip::{Message, MessageId, MessageType};
use tokio::net::UdpSocket;
use tokio::sync::Mutex;

use crate::session::{close_session, forwarded, handle, Action, Session};
use crate::subscriptions::subscribed;
use crate::{lock, message, AbortOnDrop, Counters, Shared};

/// UDP sessions by client address. Each session has its own (async) lock, so datagrams
/// from one client are handled one after another, in the order they arrived, while
/// other clients' requests go on. The table's lock is a `std` one, held only to look
/// up, insert or remove, never across an `.await`.
pub(crate) type UdpSessions = Arc<std::sync::Mutex<HashMap<SocketAddr, Arc<Mutex<Session>>>>>;

/// Drops a closed session from the table unless another task still holds it (that task
/// may reopen it, or the next sweep drops it).
pub(crate) fn forget_udp_session(
    sessions: &UdpSessions,
    peer: SocketAddr,
    cell: &Arc<Mutex<Session>>,
) {
    let mut map = lock(sessions);
    if map.get(&peer).is_some_and(|c| Arc::ptr_eq(c, cell)) && Arc::strong_count(cell) == 2 {
        map.remove(&peer);
    }
}

pub(crate) async fn serve_udp(sock: Arc<UdpSocket>, shared: Arc<Shared>) {
    let local_port = sock.local_addr().map_or(0, |a| a.port());
    let sessions: UdpSessions = Arc::new(std::sync::Mutex::new(HashMap::new()));
    // Publish bursts and close idle sessions.
    let _publisher = {
        let (sock, shared, sessions) = (sock.clone(), shared.clone(), sessions.clone());
        AbortOnDrop(tokio::task::spawn_local(async move {
            let mut bursts = shared.bursts.subscribe();
            loop {
                let burst = tokio::select! {
                    b = bursts.recv() => b.ok(),
                    _ = tokio::time::sleep(Duration::from_millis(200)) => None,
                };
                let mut idle = vec![];
                for (peer, cell) in lock(&sessions).iter() {
                    // A session busy with a request is not idle.
                    if let Ok(s) = cell.try_lock() {
                        if !s.open || s.last_rx.elapsed() > s.timer {
                            idle.push((*peer, cell.clone()));
                            continue;
                        }
                    }
                    if let Some(b) = &burst {
                        // Each session gets its publish message after the reply it is
                        // working on, without holding up the others.
                        let (sock, shared, cell, b) =
                            (sock.clone(), shared.clone(), cell.clone(), b.clone());
                        let peer = *peer;
                        tokio::task::spawn_local(async move {
                            let mut s = cell.lock().await;
                            if !s.open || !subscribed(&s.subs, &b) {
                                return;
                            }
                            s.publish_seq = s.publish_seq.wrapping_add(1);
                            let m = message(
                                MessageType::Publish,
                                MessageId::TokenPassingPdu,
                                0,
                                s.publish_seq,
                                &b,
                            );
                            let _ = sock.send_to(&m, peer).await;
                            Counters::count(&shared.stats.published);
                            if let Some(r) = s.audit {
                                if let Some(rec) = lock(&shared.audit).get_mut(r) {
                                    rec.publishes += 1;
                                }
                            }
                        });
                    }
                }
                for (peer, cell) in idle {
                    {
                        let mut s = cell.lock().await;
                        if s.open && s.last_rx.elapsed() <= s.timer {
                            continue; // a request came in meanwhile
                        }
                        close_session(&shared, &mut s, 0x0008).await;
                    }
                    forget_udp_session(&sessions, peer, &cell);
                }
            }
        }))
    };
    let mut buf = vec![0u8; 65536];
    loop {
        let Ok((n, peer)) = sock.recv_from(&mut buf).await else {
            continue;
        };
        let data = buf[..n].to_vec();
        let (sock, shared, sessions) = (sock.clone(), shared.clone(), sessions.clone());
        tokio::task::spawn_local(udp_datagram(sock, shared, sessions, peer, local_port, data));
    }
}

pub(crate) async fn udp_datagram(
    sock: Arc<UdpSocket>,
    shared: Arc<Shared>,
    sessions: UdpSessions,
    peer: SocketAddr,
    local_port: u16,
    data: Vec<u8>,
) {
    let cell = lock(&sessions)
        .entry(peer)
        .or_insert_with(|| Arc::new(Mutex::new(Session::new(peer, local_port))))
        .clone();
    let mut s = cell.lock().await;
    let mut rest = &data[..];
    while !rest.is_empty() {
        let (h, body, used) = match Message::parse(rest) {
            Ok((m, used)) => (m.header, m.body, used),
            Err(_) => {
                Counters::count(&shared.stats.malformed);
                break;
            }
        };
        rest = &rest[used..];
        let action = handle(&shared, &mut s, h, body).await;
        let why = match action {
            Action::Reply(r) => {
                let _ = sock.send_to(&r, peer).await;
                if s.open {
                    continue;
                }
                0x0004
            }
            Action::Forward {
                channel,
                retries,
                pdu,
                seq,
            } => {
                // In order, per client: the session waits for its loop's reply.
                let r = forwarded(&shared, channel, retries, pdu, seq).await;
                let _ = sock.send_to(&r, peer).await;
                continue;
            }
            Action::ReplyAndClose(r) => {
                let _ = sock.send_to(&r, peer).await;
                0
            }
            Action::Close => 0x0004,
        };
        close_session(&shared, &mut s, why).await;
        break;
    }
    let open = s.open;
    if open {
        // Back in the table if a sweep dropped it while this datagram waited.
        lock(&sessions).entry(peer).or_insert_with(|| cell.clone());
    }
    drop(s);
    if !open {
        forget_udp_session(&sessions, peer, &cell);
    }
}
