//! One HART-IP session, whatever the transport: the message handler.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hart_ip::{status, Body, Header, MessageId, MessageType};
use hart_proto::frame::{Frame, FrameType};

use crate::audit::AuditRecord;
use crate::io_system::Route;
use crate::subscriptions::{subscription_command, Subscriptions};
use crate::{local_frame, lock, message, unix_now, Counters, Shared, MIN_TIMER_MS};

/// What to do with one received message of a session.
pub(crate) enum Action {
    Reply(Vec<u8>),
    ReplyAndClose(Vec<u8>),
    Close,
    /// Forward a token-passing request to a loop and answer with sequence number `seq`
    /// when the reply comes (over TCP, other requests and publish messages go on
    /// meanwhile).
    Forward {
        channel: usize,
        retries: u8,
        pdu: Vec<u8>,
        seq: u16,
    },
}

/// Waits for a loop's reply to a forwarded request and builds the response message:
/// the reply PDU, or, when the device did not answer after the loop's retries, the I/O
/// system's answer for a silent sub-device ([`not_responding`]).
pub(crate) async fn forwarded(
    shared: &Shared,
    channel: usize,
    retries: u8,
    pdu: Vec<u8>,
    seq: u16,
) -> Vec<u8> {
    let body = match shared.io.forward(channel, pdu.clone(), retries).await {
        Some(reply) => reply,
        None => not_responding(&pdu),
    };
    message(
        MessageType::Response,
        MessageId::TokenPassingPdu,
        status::SUCCESS,
        seq,
        &body,
    )
}

/// The answer to a request for a sub-device that did not reply or that the server does
/// not know: an ACK frame from the requested address with response code 35 ("delayed
/// response dead") and no data, HART-IP status 0. Clients read it as a HART reply
/// (hipserver and WirelessHART gateways answer in frames, never with an empty body)
/// and do not repeat it.
pub(crate) fn not_responding(request: &[u8]) -> Vec<u8> {
    match Frame::parse_pdu(request) {
        Ok(f) => local_frame(&f, crate::io_system::SUB_DEVICE_NOT_RESPONDING, 0, &[]),
        Err(_) => vec![],
    }
}

/// Session state shared by UDP and TCP.
pub(crate) struct Session {
    pub(crate) open: bool,
    pub(crate) timer: Duration,
    pub(crate) last_rx: Instant,
    pub(crate) publish_seq: u16,
    pub(crate) peer: SocketAddr,
    pub(crate) local_port: u16,
    /// Number of this session's audit record.
    pub(crate) audit: Option<u64>,
    /// Publish subscriptions (commands 532/533).
    pub(crate) subs: Subscriptions,
}

impl Session {
    pub(crate) fn new(peer: SocketAddr, local_port: u16) -> Self {
        Session {
            open: false,
            timer: Duration::from_secs(60),
            last_rx: Instant::now(),
            publish_seq: 0,
            peer,
            local_port,
            audit: None,
            subs: None,
        }
    }
}

pub(crate) async fn handle(shared: &Shared, s: &mut Session, h: Header, body: &[u8]) -> Action {
    s.last_rx = Instant::now();
    if h.message_type != MessageType::Request || h.reserved != 0 {
        Counters::count(&shared.stats.malformed);
        return Action::Close;
    }
    let reply = |st: u8, b: &[u8]| message(MessageType::Response, h.message_id, st, h.sequence, b);
    match h.message_id {
        MessageId::SessionInitiate => {
            if body.len() < 5 {
                Counters::count(&shared.stats.sessions_refused);
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            }
            let master = body[0];
            if master > 1 {
                Counters::count(&shared.stats.sessions_refused);
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            let asked = u32::from_be_bytes([body[1], body[2], body[3], body[4]]);
            if !s.open {
                let mut n = lock(&shared.sessions);
                if *n >= shared.config.max_sessions {
                    Counters::count(&shared.stats.sessions_refused);
                    return Action::Reply(reply(status::ALL_SESSIONS_IN_USE, &[]));
                }
                *n += 1;
                s.open = true;
                Counters::count(&shared.stats.sessions_opened);
                // Every HART-IP v1 session is an insecure session (0x0010).
                s.audit = Some(lock(&shared.audit).push(AuditRecord {
                    client: s.peer,
                    server_port: s.local_port,
                    connected: unix_now(),
                    disconnected: 0,
                    status: 0x0010,
                    publishes: 0,
                    requests: 0,
                    responses: 0,
                }));
            }
            let timer = asked.max(MIN_TIMER_MS);
            s.timer = Duration::from_millis(u64::from(timer));
            let mut st = if timer != asked {
                status::SET_TO_NEAREST
            } else {
                status::SUCCESS
            };
            if h.version != 1 {
                st = status::VERSION_NOT_SUPPORTED;
            }
            Action::Reply(reply(st, &hart_ip::session_initiate_body(master, timer)))
        }
        _ if !s.open => Action::Close,
        MessageId::SessionClose => Action::ReplyAndClose(reply(status::SUCCESS, &[])),
        MessageId::KeepAlive => Action::Reply(reply(status::SUCCESS, &[])),
        MessageId::TokenPassingPdu => {
            let parsed = Frame::parse_pdu(body);
            if let Some(i) = s.audit {
                if let Some(r) = lock(&shared.audit).get_mut(i) {
                    r.requests += 1;
                    r.responses += 1;
                    if parsed.as_ref().is_ok_and(|f| {
                        hart_proto::command::info(f.command).is_some_and(|c| c.writes)
                    }) && !shared.config.read_only
                    {
                        r.status |= 0x0001;
                    }
                }
            }
            let Ok(f) = parsed else {
                Counters::count(&shared.stats.malformed);
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            if f.frame_type() != FrameType::Stx {
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            if shared.config.read_only
                && hart_proto::command::info(f.command).is_some_and(|i| i.writes)
            {
                return Action::Reply(reply(
                    status::SUCCESS,
                    &local_frame(&f, hart_proto::tables::rc::ACCESS_RESTRICTED, 0, &[]),
                ));
            }
            if matches!(f.command, 532 | 533) {
                // Subscriptions belong to this session: the server answers them whatever
                // the address.
                let (code, data) =
                    subscription_command(shared, &mut s.subs, f.command, f.data).await;
                return Action::Reply(reply(status::SUCCESS, &local_frame(&f, code, 0, &data)));
            }
            let route = shared.io.route(&f).await;
            match route {
                Route::Local => {
                    let (code, status, data) =
                        shared.io.local(f.address.master(), f.command, f.data).await;
                    Action::Reply(reply(
                        status::SUCCESS,
                        &local_frame(&f, code, status, &data),
                    ))
                }
                Route::Loop { channel, retries } => {
                    Counters::count(&shared.stats.forwarded);
                    Action::Forward {
                        channel,
                        retries,
                        pdu: body.to_vec(),
                        seq: h.sequence,
                    }
                }
                Route::Nowhere => Action::Reply(reply(status::SUCCESS, &not_responding(body))),
            }
        }
        MessageId::DirectPdu => {
            let Ok(Body::Direct { entries, .. }) = Body::parse(h.message_id, h.message_type, body)
            else {
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            // Commands to the gateway itself, each answered in turn.
            let mut out = vec![0u8, 0u8];
            for e in hart_ip::DirectEntries(entries).flatten() {
                // Direct PDUs come from the session's host, a primary master.
                let (code, _, data) = shared
                    .io
                    .local(hart_proto::frame::MasterKind::Primary, e.command, e.data)
                    .await;
                let data = if hart_proto::tables::response_class(code)
                    == hart_proto::tables::ResponseClass::Error
                {
                    vec![]
                } else {
                    data
                };
                out.extend_from_slice(&e.command.to_be_bytes());
                out.push((1 + data.len()).min(255) as u8);
                out.push(code);
                out.extend_from_slice(&data[..data.len().min(254)]);
            }
            Action::Reply(reply(status::SUCCESS, &out))
        }
        MessageId::ReadAuditLog => {
            let (start, count) = match Body::parse(h.message_id, h.message_type, body) {
                Ok(Body::AuditLogRequest { start, count }) => (start, count),
                _ => return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[])),
            };
            let audit = lock(&shared.audit);
            let records: Vec<&AuditRecord> = audit
                .records
                .iter()
                .skip(usize::from(start))
                .take(usize::from(count))
                .collect();
            let mut out = vec![start, records.len() as u8];
            out.extend(shared.power_up.to_be_bytes());
            out.extend(0u64.to_be_bytes()); // last security change: never
            out.extend(0u16.to_be_bytes()); // server status: no syslog in use
            out.extend(58u16.to_be_bytes());
            for r in records {
                out.extend(r.bytes());
            }
            Action::Reply(reply(status::SUCCESS, &out))
        }
        MessageId::Other(_) => {
            Counters::count(&shared.stats.malformed);
            Action::Reply(message(
                MessageType::Nak,
                h.message_id,
                status::INVALID_SELECTION,
                h.sequence,
                &[],
            ))
        }
    }
}

/// Ends a session; `why` goes into its audit record (0 normal, 0x0004 aborted,
/// 0x0008 timed out).
pub(crate) async fn close_session(shared: &Shared, s: &mut Session, why: u16) {
    if s.open {
        s.open = false;
        if let Some(r) = s.audit {
            if let Some(rec) = lock(&shared.audit).get_mut(r) {
                rec.disconnected = unix_now();
                rec.status |= why;
            }
        }
        let mut n = lock(&shared.sessions);
        *n = n.saturating_sub(1);
    }
}
