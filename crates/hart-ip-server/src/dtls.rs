//! HART-IP over DTLS 1.2 with pre-shared keys (UDP).
//!
//! One UDP socket serves every peer: datagrams are sorted by source address; a new
//! peer must start with a DTLS handshake record (a ClientHello), and then has its own
//! task that runs the handshake and, inside it, one HART-IP session, just as a TLS
//! connection does (`stream::stream_session`). Anything else from an unknown peer
//! (plain HART-IP on the secure port, stray datagrams) is dropped and logged.

use std::cell::RefCell;
use std::collections::HashMap;
use std::net::SocketAddr;
use std::rc::Rc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use tokio::net::UdpSocket;
use tokio::sync::mpsc;

use crate::stream::secure_session;
use crate::{AbortOnDrop, Counters, PeerTable, Peers, Security, Shared};

/// Associations started beyond the session limit, for handshakes in progress.
const PENDING_HANDSHAKES: usize = 16;

/// Datagrams queued for one peer's task before further ones are dropped (DTLS
/// repeats what is lost).
const PEER_QUEUE: usize = 64;

/// Logs refusals of non-DTLS datagrams at most once a second (a flood must not flood
/// the log), with the number left out meanwhile.
struct RefusalLog {
    last: Option<Instant>,
    quiet: u64,
}

impl RefusalLog {
    fn refuse(&mut self, peer: SocketAddr) {
        if self
            .last
            .is_some_and(|t| t.elapsed() < Duration::from_secs(1))
        {
            self.quiet += 1;
            return;
        }
        let more = std::mem::take(&mut self.quiet);
        tracing::warn!(
            "refused a datagram from {peer} on the DTLS port: not a DTLS handshake (plain HART-IP on a secure port? use the --plain port, or dtls:// with a key){}",
            if more > 0 {
                format!("; {more} more refused in the last second")
            } else {
                String::new()
            }
        );
        self.last = Some(Instant::now());
    }
}

/// Serves DTLS on `sock` until the server stops.
pub(crate) async fn serve_dtls(sock: Arc<UdpSocket>, shared: Arc<Shared>, sec: Arc<Security>) {
    let peers: Peers = Rc::new(RefCell::new(HashMap::new()));
    let mut log = RefusalLog {
        last: None,
        quiet: 0,
    };
    let mut buf = vec![0u8; 65536];
    loop {
        let Ok((n, peer)) = sock.recv_from(&mut buf).await else {
            continue;
        };
        let datagram = buf[..n].to_vec();
        let known = peers.borrow().get(&peer).map(|(tx, _)| tx.clone());
        if let Some(tx) = known {
            if !tx.is_closed() {
                let _ = tx.try_send(datagram);
                continue;
            }
            peers.borrow_mut().remove(&peer);
        }
        // A DTLS record: content type 20-23, version DTLS 1.x (0xFE..), 13-byte header.
        let dtls = n >= 13 && (20..=23).contains(&datagram[0]) && datagram[1] == 0xFE;
        if dtls && datagram[0] != 22 {
            // The end of an association the server has closed (a close_notify alert, a
            // late record): nothing to answer.
            tracing::debug!(
                "DTLS record of type {} from {peer} without an association",
                datagram[0]
            );
            continue;
        }
        if !dtls {
            Counters::count(&shared.stats.malformed);
            log.refuse(peer);
            continue;
        }
        // Bounded like UDP sessions: associations (handshakes included) up to the
        // session limit and a few more, and per client address.
        let (all, from_host) = {
            let p = peers.borrow();
            (p.len(), p.keys().filter(|a| a.ip() == peer.ip()).count())
        };
        if all >= shared.config.max_sessions + PENDING_HANDSHAKES
            || from_host >= shared.config.max_sessions_per_host
        {
            Counters::count(&shared.stats.sessions_refused);
            tracing::debug!("refused a DTLS handshake from {peer}: associations at their limit");
            continue;
        }
        let (tx, rx) = mpsc::channel(PEER_QUEUE);
        let _ = tx.try_send(datagram);
        let task = tokio::task::spawn_local(dtls_peer(
            sock.clone(),
            peer,
            rx,
            shared.clone(),
            sec.clone(),
            Rc::downgrade(&peers),
        ));
        peers.borrow_mut().insert(peer, (tx, AbortOnDrop(task)));
    }
}

/// One peer: the handshake, then its session; forgets the peer at the end.
async fn dtls_peer(
    sock: Arc<UdpSocket>,
    peer: SocketAddr,
    rx: mpsc::Receiver<Vec<u8>>,
    shared: Arc<Shared>,
    sec: Arc<Security>,
    peers: std::rc::Weak<RefCell<PeerTable>>,
) {
    let local_port = sock.local_addr().map_or(0, |a| a.port());
    run_peer(sock, peer, rx, &shared, &sec, local_port).await;
    // This task's own handle goes with the entry: the abort it asks for finds the task
    // already finishing.
    // (The table holds the tasks, so a task holds the table weakly: when the server
    // stops, table and tasks go together.)
    if let Some(peers) = peers.upgrade() {
        let entry = peers.borrow_mut().remove(&peer);
        drop(entry);
    }
}

async fn run_peer(
    sock: Arc<UdpSocket>,
    peer: SocketAddr,
    rx: mpsc::Receiver<Vec<u8>>,
    shared: &Arc<Shared>,
    sec: &Arc<Security>,
    local_port: u16,
) {
    let io = hart_ip_tls::DatagramStream::shared(sock, peer, rx);
    secure_session(
        io,
        peer,
        local_port,
        Some(0x16),
        shared.clone(),
        sec,
        true,
        None,
    )
    .await
}
