//! HART-IP over TCP.

use std::net::SocketAddr;
use std::sync::Arc;

use hart_ip::{Message, MessageId, MessageType};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Mutex;

use crate::session::{close_session, forwarded, handle, Action, Session};
use crate::subscriptions::subscribed;
use crate::{message, AbortOnDrop, Counters, Shared};

pub(crate) async fn serve_tcp(listener: TcpListener, shared: Arc<Shared>) {
    // Sessions end with the server.
    let mut sessions: Vec<AbortOnDrop> = vec![];
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            continue;
        };
        let _ = stream.set_nodelay(true);
        sessions.retain(|s: &AbortOnDrop| !s.0.is_finished());
        sessions.push(AbortOnDrop(tokio::task::spawn_local(tcp_session(
            stream,
            shared.clone(),
        ))));
    }
}

pub(crate) async fn tcp_session(stream: TcpStream, shared: Arc<Shared>) {
    let peer = stream
        .peer_addr()
        .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)));
    let local_port = stream.local_addr().map_or(0, |a| a.port());
    let (mut rd, wr) = stream.into_split();
    let wr = Arc::new(Mutex::new(wr));
    let mut s = Session::new(peer, local_port);
    let mut in_flight: Vec<AbortOnDrop> = vec![];
    let mut buf: Vec<u8> = vec![];
    let mut bursts = shared.bursts.subscribe();
    let mut tmp = [0u8; 4096];
    let mut publish_seq = 0u16;
    loop {
        // Complete messages first.
        loop {
            match Message::parse(&buf) {
                Ok((m, used)) => {
                    let action = handle(&shared, &mut s, m.header, m.body).await;
                    buf.drain(..used);
                    match action {
                        Action::Reply(r) => {
                            if wr.lock().await.write_all(&r).await.is_err() {
                                close_session(&shared, &mut s, 0x0004).await;
                                return;
                            }
                        }
                        Action::ReplyAndClose(r) => {
                            let _ = wr.lock().await.write_all(&r).await;
                            close_session(&shared, &mut s, 0).await;
                            return;
                        }
                        Action::Close => {
                            close_session(&shared, &mut s, 0x0004).await;
                            return;
                        }
                        Action::Forward {
                            channel,
                            retries,
                            pdu,
                            seq,
                        } => {
                            // Several requests may be in flight on one connection: each
                            // reply goes out when its loop answers, with its sequence
                            // number, while this task reads on and publishes. The
                            // replies' writers end with the session.
                            let (shared, wr) = (shared.clone(), wr.clone());
                            in_flight.retain(|t: &AbortOnDrop| !t.0.is_finished());
                            in_flight.push(AbortOnDrop(tokio::task::spawn_local(async move {
                                let r = forwarded(&shared, channel, retries, pdu, seq).await;
                                let _ = wr.lock().await.write_all(&r).await;
                            })));
                        }
                    }
                }
                Err(hart_ip::Error::ShortHeader { .. }) | Err(hart_ip::Error::Truncated { .. })
                    if buf.len() < 65536 =>
                {
                    break
                }
                Err(_) => {
                    // A stream that cannot be split any more: this session ends.
                    Counters::count(&shared.stats.malformed);
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            }
        }
        let timer = s.timer;
        tokio::select! {
            r = tokio::time::timeout(timer, rd.read(&mut tmp)) => match r {
                Ok(Ok(n)) if n > 0 => buf.extend_from_slice(&tmp[..n]),
                Err(_) => {
                    close_session(&shared, &mut s, 0x0008).await;
                    return;
                }
                _ => {
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
            },
            b = bursts.recv() => if let (Ok(b), true) = (b, s.open) {
                if !subscribed(&s.subs, &b) {
                    continue;
                }
                publish_seq = publish_seq.wrapping_add(1);
                let m = message(MessageType::Publish, MessageId::TokenPassingPdu, 0, publish_seq, &b);
                if wr.lock().await.write_all(&m).await.is_err() {
                    close_session(&shared, &mut s, 0x0004).await;
                    return;
                }
                Counters::count(&shared.stats.published);
            },
        }
    }
}
