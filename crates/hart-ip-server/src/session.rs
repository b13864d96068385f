//! One HART-IP session, whatever the transport: the message handler.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use hart_ip::{status, Body, Header, MessageId, MessageType};
use hart_proto::frame::{Frame, FrameType};

use crate::audit::AuditRecord;
use crate::io_system::{LoopOutcome, Requester, Route};
use crate::limits::Refusal;
use crate::subscriptions::{subscription_command, Subscriptions};
use crate::{local_frame, lock, message, unix_now, Counters, Shared};
use hart_access::{Allowed, Rights, WriteRecord};

/// What to do with one received message of a session.
pub(crate) enum Action {
    Reply(Vec<u8>),
    ReplyAndClose(Vec<u8>),
    Close,
    /// Forward a token-passing request to a loop through the engine's gate (which
    /// judges it again by the gateway's rule and audits a write with its outcome) and
    /// answer with sequence number `seq` when the reply comes (over TCP, other
    /// requests and publish messages go on meanwhile).
    Forward {
        channel: usize,
        retries: u8,
        pdu: Vec<u8>,
        seq: u16,
        from: Requester,
    },
}

/// A write to the I/O system itself let through and recorded in the audit, waiting for
/// its outcome (the audit's second record of it). Writes to devices on the loops are
/// audited by the engine's gate.
pub(crate) struct PendingWrite {
    id: u64,
    record: WriteRecord,
}

impl PendingWrite {
    /// Records `record` in the audit, before the write is carried out.
    fn start(shared: &Shared, record: WriteRecord) -> Self {
        let id = shared.write_audit.record(&record);
        PendingWrite { id, record }
    }

    /// Records what became of the write: the device's reply to `request` (or none).
    fn done(self, shared: &Shared, reply: Option<&[u8]>) {
        let outcome = hart_poller::write::outcome_of(self.record.command, reply);
        shared.write_audit.outcome(self.id, &self.record, &outcome);
    }
}

/// Waits for a loop's reply to a forwarded request and builds the response message:
/// the reply PDU, or, when the device did not answer after the loop's retries, the I/O
/// system's answer for a silent sub-device ([`not_responding`]); a request the
/// engine's gate refuses is answered "access restricted".
pub(crate) async fn forwarded(
    shared: &Shared,
    version: u8,
    channel: usize,
    retries: u8,
    pdu: Vec<u8>,
    seq: u16,
    from: Requester,
) -> Vec<u8> {
    let outcome = shared
        .io
        .forward(channel, pdu.clone(), retries, &from)
        .await;
    let body = match outcome {
        Ok(LoopOutcome::Reply(reply)) => reply,
        Ok(LoopOutcome::NoReply) => not_responding(&pdu),
        Ok(LoopOutcome::Busy) => {
            Counters::count(&shared.stats.busy);
            busy(&pdu)
        }
        Err(why) => {
            tracing::warn!(
                "hart-ip: refused token-passing request from {}: {why}",
                from.record.peer
            );
            match Frame::parse_pdu(&pdu) {
                Ok(f) => local_frame(&f, hart_proto::tables::rc::ACCESS_RESTRICTED, 0, &[]),
                Err(_) => vec![],
            }
        }
    };
    message(
        version,
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

/// The answer to a request the server did not send because its loop's queue was full
/// (or it waited there too long): an ACK from the requested address with response
/// code 32 "busy", which hosts repeat after a pause.
pub(crate) fn busy(request: &[u8]) -> Vec<u8> {
    match Frame::parse_pdu(request) {
        Ok(f) => local_frame(&f, hart_proto::tables::rc::BUSY, 0, &[]),
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
    /// HART-IP version of the session's messages: 1 plain, 2 (or what a secure
    /// client's initiate asked) inside TLS/DTLS.
    pub(crate) version: u8,
    /// The PSK identity of a secure session and what it may do.
    pub(crate) secure: Option<(String, hart_ip_tls::Rights)>,
    /// Messages the client sent since its session initiate.
    pub(crate) after_initiate: u64,
    /// Its place in the server's session pool, while it is open.
    pub(crate) place: Option<u64>,
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
            version: 1,
            secure: None,
            after_initiate: 0,
            place: None,
        }
    }

    /// How long the session may stay silent: its inactivity timer, but only
    /// [`crate::INITIATE_GRACE`] before the first message after the initiate (and
    /// before the initiate itself).
    pub(crate) fn silence_allowed(&self) -> Duration {
        if self.open && self.after_initiate > 0 {
            self.timer
        } else {
            self.timer.min(crate::INITIATE_GRACE)
        }
    }

    /// The publish message carrying burst frame `burst` for this session's client, if
    /// it is open and subscribed to that device (counted, and in its audit record).
    pub(crate) fn publish(&mut self, shared: &Shared, burst: &[u8]) -> Option<Vec<u8>> {
        if !self.open || !crate::subscriptions::subscribed(&self.subs, burst) {
            return None;
        }
        self.publish_seq = self.publish_seq.wrapping_add(1);
        Counters::count(&shared.stats.published);
        if let Some(r) = self.audit {
            if let Some(rec) = lock(&shared.audit).get_mut(r) {
                rec.publishes += 1;
            }
        }
        Some(message(
            self.version,
            MessageType::Publish,
            MessageId::TokenPassingPdu,
            0,
            self.publish_seq,
            burst,
        ))
    }

    /// Whether the session has been silent longer than it may.
    pub(crate) fn expired(&self) -> bool {
        self.last_rx.elapsed() > self.silence_allowed()
    }

    /// A session inside TLS/DTLS, authenticated with PSK `identity`.
    pub(crate) fn secure(
        peer: SocketAddr,
        local_port: u16,
        identity: String,
        rights: hart_ip_tls::Rights,
    ) -> Self {
        Session {
            version: 2,
            secure: Some((identity, rights)),
            ..Session::new(peer, local_port)
        }
    }

    /// What this session may do: its PSK identity's rights, or the plain listener's
    /// (`--plain-rights`), and read-only whatever they are on a `--read-only` server.
    pub(crate) fn rights(&self, shared: &Shared) -> Rights {
        let own = match &self.secure {
            Some((_, r)) => *r,
            None => shared.config.plain_rights,
        };
        if shared.config.read_only {
            Rights::ReadOnly
        } else {
            own
        }
    }
}

/// Who session `s` is, for the engine's gate and the audit: its rights, and the
/// audit's front end, session, peer and identity; `via` names the path
/// (`token-passing`, `direct PDU`).
fn requester(shared: &Shared, s: &Session, via: &str) -> Requester {
    Requester {
        rights: s.rights(shared),
        record: WriteRecord {
            front_end: "hart-ip",
            session: s.audit,
            peer: s.peer.to_string(),
            identity: s.secure.as_ref().map(|(i, _)| i.clone()),
            via: via.to_string(),
            ..WriteRecord::default()
        },
        unwrapped: 0,
    }
}

/// The audit record of a write session `s` makes to the I/O system itself (`t`, at
/// depth 0).
fn own_write(shared: &Shared, s: &Session, t: &hart_access::Target, via: &str) -> WriteRecord {
    WriteRecord {
        device: t.device.clone(),
        command: t.command,
        operation: hart_proto::command::title(t.command).map(str::to_string),
        ..requester(shared, s, via).record
    }
}

/// Asks the server's policy whether session `s` may send request frame `f` and whether
/// it writes (the session's audit-log record then says writes occurred); a refusal is
/// logged and audited. Writes are audited where they are carried out: by the engine's
/// gate for a device on a loop (also inside command 77), by the caller for the I/O
/// system itself. `via` names the path (`token-passing`, `direct PDU`).
async fn admit(
    shared: &Shared,
    s: &Session,
    f: &Frame<'_>,
    via: &str,
) -> Result<Allowed, hart_access::Refusal> {
    let device_type = shared.io.device_type(f).await;
    let rights = s.rights(shared);
    let verdict = if hart_access::SESSION_COMMANDS.contains(&f.command) {
        shared.policy.check_session_command(f.command)
    } else {
        shared.policy.check(rights, f, device_type)
    };
    match verdict {
        Ok(Allowed::Write(t)) => {
            if let Some(i) = s.audit {
                if let Some(r) = lock(&shared.audit).get_mut(i) {
                    r.status |= 0x0001; // writes occurred
                }
            }
            Ok(Allowed::Write(t))
        }
        Ok(Allowed::Read) => Ok(Allowed::Read),
        Err(why) => {
            let (command, depth) = match &why {
                hart_access::Refusal::NotListed { command, depth }
                | hart_access::Refusal::ReadOnly { command, depth, .. } => (*command, *depth),
                hart_access::Refusal::TooDeep => (f.command, 0),
            };
            let via = match depth {
                0 => via.to_string(),
                1 => format!("{via}, command 77"),
                n => format!("{via}, command 77 ({n} levels)"),
            };
            shared.write_audit.refused(
                &WriteRecord {
                    device: f.address.to_string(),
                    command,
                    operation: hart_proto::command::title(command).map(str::to_string),
                    ..requester(shared, s, &via).record
                },
                &why.to_string(),
            );
            tracing::warn!(
                "hart-ip: refused {via} request from {} ({}, {}): {why}",
                s.peer,
                s.secure
                    .as_ref()
                    .map_or("plain".to_string(), |(i, _)| format!("identity {i:?}")),
                rights
            );
            Err(why)
        }
    }
}

/// Most command entries in one Direct PDU; a message with more is refused whole
/// (HART-IP status "invalid selection"), nothing carried out. Each entry may forward
/// to a loop (commands 75, 77), so the cap bounds the line time one message takes; it
/// also keeps the reply (at most 3 + 255 bytes an entry) far below the largest
/// HART-IP message.
pub const MAX_DIRECT_ENTRIES: usize = 32;

pub(crate) async fn handle(shared: &Shared, s: &mut Session, h: Header, body: &[u8]) -> Action {
    s.last_rx = Instant::now();
    if s.open && h.message_id != MessageId::SessionInitiate {
        s.after_initiate += 1;
    }
    if h.message_type != MessageType::Request || h.reserved != 0 {
        Counters::count(&shared.stats.malformed);
        return Action::Close;
    }
    let version = s.version;
    let reply = |st: u8, b: &[u8]| {
        message(
            version,
            MessageType::Response,
            h.message_id,
            st,
            h.sequence,
            b,
        )
    };
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
                match shared.sessions.open(s.peer) {
                    Ok(place) => s.place = Some(place),
                    Err(refusal) => {
                        Counters::count(&shared.stats.sessions_refused);
                        if let Refusal::PerHost(from_host) = refusal {
                            tracing::debug!(
                                "refused a session from {}: {} sessions from that address already (max_sessions_per_host)",
                                s.peer,
                                from_host
                            );
                        }
                        return Action::Reply(reply(status::ALL_SESSIONS_IN_USE, &[]));
                    }
                }
                s.open = true;
                Counters::count(&shared.stats.sessions_opened);
                // A plain session is an insecure session (0x0010).
                s.audit = Some(lock(&shared.audit).push(AuditRecord {
                    client: s.peer,
                    server_port: s.local_port,
                    connected: unix_now(),
                    disconnected: 0,
                    status: if s.secure.is_some() { 0 } else { 0x0010 },
                    publishes: 0,
                    requests: 0,
                    responses: 0,
                }));
            }
            let (timer, changed) = crate::granted_timer(asked, shared.config.max_timer_ms);
            s.timer = Duration::from_millis(u64::from(timer));
            let mut st = if changed {
                status::SET_TO_NEAREST
            } else {
                status::SUCCESS
            };
            if s.secure.is_some() {
                // Inside TLS/DTLS: HART-IP 2, or 1 from a client that predates it.
                s.version = h.version.clamp(1, 2);
                if h.version > 2 {
                    st = status::VERSION_NOT_SUPPORTED;
                }
            } else if h.version != 1 {
                st = status::VERSION_NOT_SUPPORTED;
            }
            Action::Reply(message(
                s.version,
                MessageType::Response,
                h.message_id,
                st,
                h.sequence,
                &hart_ip::session_initiate_body(master, timer),
            ))
        }
        _ if !s.open => Action::Close,
        MessageId::SessionClose => Action::ReplyAndClose(reply(status::SUCCESS, &[])),
        MessageId::KeepAlive => Action::Reply(reply(status::SUCCESS, &[])),
        MessageId::TokenPassingPdu => {
            if let Some(i) = s.audit {
                if let Some(r) = lock(&shared.audit).get_mut(i) {
                    r.requests += 1;
                    r.responses += 1;
                }
            }
            let Ok(f) = Frame::parse_pdu(body) else {
                Counters::count(&shared.stats.malformed);
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            if f.frame_type() != FrameType::Stx {
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            let verdict = match admit(shared, s, &f, "token-passing").await {
                Ok(v) => v,
                Err(_) => {
                    return Action::Reply(reply(
                        status::SUCCESS,
                        &local_frame(&f, hart_proto::tables::rc::ACCESS_RESTRICTED, 0, &[]),
                    ))
                }
            };
            if hart_access::SESSION_COMMANDS.contains(&f.command) {
                // Subscriptions belong to this session: the server answers them whatever
                // the address.
                let (code, data) =
                    subscription_command(shared, &mut s.subs, f.command, f.data).await;
                return Action::Reply(reply(status::SUCCESS, &local_frame(&f, code, 0, &data)));
            }
            let route = shared.io.route(&f).await;
            let from = requester(shared, s, "token-passing");
            // A write to the I/O system itself (or to no device at all) is audited here;
            // one carried to a loop, by the engine's gate.
            let own = match (&verdict, route) {
                (Allowed::Write(t), Route::Local | Route::Nowhere) if t.depth == 0 => Some(
                    PendingWrite::start(shared, own_write(shared, s, t, "token-passing")),
                ),
                _ => None,
            };
            match route {
                Route::Local => {
                    let (code, status, data) = shared
                        .io
                        .local(f.address.master(), f.command, f.data, &from)
                        .await;
                    let frame = local_frame(&f, code, status, &data);
                    if let Some(w) = own {
                        w.done(shared, Some(&frame));
                    }
                    Action::Reply(reply(status::SUCCESS, &frame))
                }
                Route::Loop { channel, retries } => {
                    Counters::count(&shared.stats.forwarded);
                    Action::Forward {
                        channel,
                        retries,
                        pdu: body.to_vec(),
                        seq: h.sequence,
                        from,
                    }
                }
                Route::Nowhere => {
                    if let Some(w) = own {
                        w.done(shared, None);
                    }
                    Action::Reply(reply(status::SUCCESS, &not_responding(body)))
                }
            }
        }
        MessageId::DirectPdu => {
            let Ok(Body::Direct { entries, .. }) = Body::parse(h.message_id, h.message_type, body)
            else {
                return Action::Reply(reply(status::TOO_FEW_DATA_BYTES, &[]));
            };
            let entries: Vec<hart_ip::DirectEntry<'_>> =
                hart_ip::DirectEntries(entries).flatten().collect();
            if entries.len() > MAX_DIRECT_ENTRIES {
                tracing::warn!(
                    "hart-ip: refused a direct PDU from {} with {} commands (at most {MAX_DIRECT_ENTRIES})",
                    s.peer,
                    entries.len()
                );
                return Action::Reply(reply(status::INVALID_SELECTION, &[]));
            }
            // Commands to the gateway itself, each checked as a frame to its own address
            // and answered in turn.
            let own = hart_proto::frame::Address::long(shared.io.unique_id())
                .with_master(hart_proto::frame::MasterKind::Primary);
            let mut out = vec![0u8, 0u8];
            for e in entries {
                let spec = hart_proto::frame::FrameSpec::request(own, e.command, e.data);
                let pdu = crate::pdu(&spec);
                let admitted = match Frame::parse_pdu(&pdu) {
                    Ok(f) => admit(shared, s, &f, "direct PDU").await.ok(),
                    Err(_) => None,
                };
                let (code, data) = match admitted {
                    None => (hart_proto::tables::rc::ACCESS_RESTRICTED, vec![]),
                    Some(verdict) => {
                        let own = match &verdict {
                            Allowed::Write(t) if t.depth == 0 => Some(PendingWrite::start(
                                shared,
                                own_write(shared, s, t, "direct PDU"),
                            )),
                            _ => None,
                        };
                        let from = requester(shared, s, "direct PDU");
                        // Direct PDUs come from the session's host, a primary master.
                        let (code, status, data) = shared
                            .io
                            .local(
                                hart_proto::frame::MasterKind::Primary,
                                e.command,
                                e.data,
                                &from,
                            )
                            .await;
                        if let (Some(w), Ok(f)) = (own, Frame::parse_pdu(&pdu)) {
                            w.done(shared, Some(&local_frame(&f, code, status, &data)));
                        }
                        (code, data)
                    }
                };
                let data = if hart_proto::tables::response_class(code)
                    == hart_proto::tables::ResponseClass::Error
                {
                    vec![]
                } else {
                    data
                };
                let data = &data[..data.len().min(254)];
                out.extend_from_slice(&e.command.to_be_bytes());
                out.push(1 + data.len() as u8);
                out.push(code);
                out.extend_from_slice(data);
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
                s.version,
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
        if let Some(place) = s.place.take() {
            shared.sessions.close(place);
        }
    }
}
