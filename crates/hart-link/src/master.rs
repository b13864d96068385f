//! The master (primary or secondary) side of the token-passing data link.
//!
//! Feed it received characters ([`Master::receive`]), the end of its own transmissions
//! ([`Master::transmitted`]) and the time ([`Master::poll`]); it says when to transmit
//! what, and reports each transaction's outcome and every burst frame it hears.
//! [`Master::next_deadline`] tells the caller when to poll again.
//!
//! Access rules (see `docs/data-link.md`), from the last frame on the line ending at E:
//!
//! | last frame | this master may start |
//! |---|---|
//! | ACK to this master (its transaction is done) | at E + RT2 (the other master has the grant until then) |
//! | ACK to the other master | at E + HOLD + 2 characters (the slot at E + HOLD is a burst device's), until E + RT2; later after RT1 |
//! | BACK to this master | at E + HOLD, until E + RT2; later after RT1 |
//! | anything else (request of the other master, BACK to the other, noise, power-up) | after RT1 of silence |
//! | its own request, when it has just given up on it | at E + max(STO + RT2, RT1 of the other master + 2 characters) |
//!
//! and never while characters are arriving.

use hart_proto::deframer::{DeframerEvent, UartFlags};
use hart_proto::frame::{Address, FrameBuf, FrameSpec, FrameType, MasterKind, MAX_PDU_LEN};
use hart_proto::tables::rc;
use hart_proto::wire::EncodeError;

use crate::line::{LastFrame, LineMonitor};
use crate::timing::{Micros, TimingProfile};

/// How a master retries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RetryPolicy {
    /// Retries after no reply or a communication error (3 = up to 4 transmissions).
    pub retries: u8,
    /// Retries after "busy" (response code 32).
    pub busy_retries: u8,
    /// Wait before repeating a request answered "busy".
    pub busy_delay: Micros,
    /// Repetitions of a request answered with delayed-response codes 33, 34 or 36.
    pub delayed_retries: u16,
    /// Wait before repeating a request with a delayed response pending.
    pub delayed_delay: Micros,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        RetryPolicy {
            retries: 3,
            busy_retries: 3,
            busy_delay: 100_000,
            delayed_retries: 100,
            delayed_delay: 500_000,
        }
    }
}

/// Why a transaction failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkError {
    /// No reply started within STO, on every attempt.
    NoReply {
        /// Transmissions made.
        attempts: u8,
    },
    /// Replies arrived damaged (or the device reported our request damaged) on every
    /// attempt; `last_error` is the last communication-error summary.
    CommunicationError {
        /// Transmissions made.
        attempts: u8,
        /// The last communication-error byte (bit 7 set).
        last_error: u8,
    },
}

impl core::fmt::Display for LinkError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            LinkError::NoReply { attempts } => write!(f, "no reply after {attempts} attempt(s); check the polling address or long address, the loop wiring and the modem"),
            LinkError::CommunicationError { attempts, last_error } => write!(
                f,
                "communication error on all {attempts} attempt(s) (last status 0x{last_error:02X}); check for noise, a second master or a bad connection"
            ),
        }
    }
}

/// What the master asks of its caller.
#[derive(Debug, Clone)]
pub enum MasterOutput {
    /// Transmit these bytes now (preambles included); call [`Master::transmitted`]
    /// when the last one has left.
    Transmit(FrameBuf, usize),
    /// A transaction ended.
    Done(Result<FrameBuf, LinkError>),
    /// A burst frame (BACK) was heard.
    Burst(FrameBuf),
}

/// Counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MasterStats {
    /// Transactions that got a reply.
    pub completed: u64,
    /// Transactions that failed.
    pub failed: u64,
    /// Repeated transmissions (no reply, damage, busy, delayed response).
    pub retries: u64,
    /// Burst frames heard.
    pub bursts: u64,
    /// Damaged frames and noise heard (parity, framing or check-byte errors, gaps
    /// inside a frame), whoever sent them: a loop with a babbling device shows them
    /// climbing while nothing completes.
    pub damaged: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    /// Waiting for the line; `not_before` holds busy/delayed-response waits. A retry
    /// after no reply or a damaged reply still owns the line while nothing new has been
    /// heard since the failure (`owns_line` holds the end of the last thing heard then):
    /// it goes out after HOLD without waiting for a grant (the other master waits RT1,
    /// which is longer than STO).
    WaitLine {
        not_before: Micros,
        owns_line: Option<Micros>,
    },
    /// Our request is being sent.
    Sending,
    /// Request sent at `sent`; waiting for the reply to start (STO) and complete.
    AwaitReply {
        sent: Micros,
    },
}

struct Pending {
    frame: FrameBuf,
    preambles: usize,
    address: Address,
    command_byte: u8,
    attempts: u8,
    busy: u8,
    delayed: u16,
    last_error: u8,
}

const OUT_CAP: usize = 4;

/// A HART master. See the [module documentation](self).
pub struct Master {
    kind: MasterKind,
    policy: RetryPolicy,
    line: LineMonitor,
    state: State,
    pending: Option<Pending>,
    burst_seen: bool,
    /// After giving up on a request: not before this, so the other master, which
    /// counts its RT1 from the last frame it heard, gets the line first.
    yield_until: Micros,
    out: [Option<MasterOutput>; OUT_CAP],
    out_len: usize,
    stats: MasterStats,
}

impl Master {
    /// A master of `kind` on a line with `profile`, started at `now` (it waits RT1 before
    /// its first transmission unless it hears a frame that grants it the line).
    pub fn new(kind: MasterKind, profile: TimingProfile, policy: RetryPolicy, now: Micros) -> Self {
        Master {
            kind,
            policy,
            line: LineMonitor::new(profile, now),
            state: State::Idle,
            pending: None,
            burst_seen: false,
            yield_until: 0,
            out: Default::default(),
            out_len: 0,
            stats: MasterStats::default(),
        }
    }

    /// Replaces the retry policy (e.g. a short one for a scan).
    pub fn set_policy(&mut self, policy: RetryPolicy) {
        self.policy = policy;
    }

    /// Primary or secondary.
    pub fn kind(&self) -> MasterKind {
        self.kind
    }

    /// Counters so far.
    pub fn stats(&self) -> MasterStats {
        self.stats
    }

    /// True when a transaction is in progress.
    pub fn is_busy(&self) -> bool {
        self.pending.is_some()
    }

    /// True once a burst frame has been heard on this line.
    pub fn burst_device_seen(&self) -> bool {
        self.burst_seen
    }

    /// Starts a transaction. The master bit of `request.address` is set to this master's;
    /// the frame is sent with `request.preambles`. Fails while another is in progress.
    pub fn request(&mut self, request: &FrameSpec<'_>, now: Micros) -> Result<(), EncodeError> {
        if self.pending.is_some() {
            return Err(EncodeError::Invalid("a transaction is already in progress"));
        }
        let spec = FrameSpec {
            frame_type: FrameType::Stx,
            address: request.address.with_master(self.kind).with_burst(false),
            ..*request
        };
        let frame = FrameBuf::encode(&spec)?;
        self.pending = Some(Pending {
            command_byte: frame.as_slice()[1 + spec.address.len() + spec.expansion.len()],
            frame,
            preambles: request.preambles,
            address: spec.address,
            attempts: 0,
            busy: 0,
            delayed: 0,
            last_error: 0,
        });
        self.state = State::WaitLine {
            not_before: now,
            owns_line: None,
        };
        Ok(())
    }

    /// Ends the transaction in progress without an outcome, because the far end has
    /// reported that no reply will come (a HART-IP gateway whose device did not answer
    /// on its loop already made the retries). Returns the transmissions made, or `None`
    /// when nothing was in progress. Counts as a failed transaction.
    pub fn abandon(&mut self) -> Option<u8> {
        let p = self.pending.take()?;
        self.state = State::Idle;
        self.stats.failed += 1;
        Some(p.attempts)
    }

    /// The carrier-detect line changed (optional: stations also work from received
    /// characters alone, but carrier detect lets a reply that starts just before STO
    /// count as started).
    pub fn carrier(&mut self, on: bool) {
        self.line.set_carrier(on);
    }

    /// Feeds a character that finished arriving at `now`.
    pub fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        let mut got: Option<(FrameBuf, FrameType, Address, Option<u8>)> = None;
        let mut damage = 0u8;
        let mut damaged = 0u64;
        self.line.receive(byte, flags, now, &mut |e, _| match e {
            DeframerEvent::Frame(f) => {
                if let Some(fb) = FrameBuf::from_pdu(f.pdu) {
                    got = Some((fb, f.frame_type(), f.address, f.response_code));
                }
            }
            DeframerEvent::Damaged(d) => {
                damage |= d.errors;
                damaged += 1;
            }
            _ => {}
        });
        self.stats.damaged += damaged;
        if damage != 0 && matches!(self.state, State::AwaitReply { .. }) {
            if let Some(p) = self.pending.as_mut() {
                p.last_error = damage;
            }
        }
        if let Some((fb, ft, address, rc)) = got {
            self.frame(fb, ft, address, rc, now);
        }
    }

    fn frame(
        &mut self,
        fb: FrameBuf,
        ft: FrameType,
        address: Address,
        rc: Option<u8>,
        now: Micros,
    ) {
        match ft {
            FrameType::Back => {
                self.burst_seen = true;
                self.stats.bursts += 1;
                self.push(MasterOutput::Burst(fb));
            }
            FrameType::Ack if address.master() == self.kind => {
                let State::AwaitReply { .. } = self.state else {
                    return;
                };
                let Some(p) = &self.pending else { return };
                let matches = address.with_burst(false) == p.address
                    && fb.as_slice().get(1 + address.len()) == Some(&p.command_byte);
                if !matches {
                    return self.reply_failed(0x80, now);
                }
                let rc = rc.unwrap_or(0);
                if rc & 0x80 != 0 {
                    return self.reply_failed(rc, now);
                }
                let policy = self.policy;
                let Some(p) = self.pending.as_mut() else {
                    return;
                };
                match rc {
                    rc::BUSY if p.busy < policy.busy_retries => {
                        p.busy += 1;
                        self.stats.retries += 1;
                        self.state = State::WaitLine {
                            not_before: now + policy.busy_delay,
                            owns_line: None,
                        };
                    }
                    rc::DR_INITIATED | rc::DR_RUNNING | rc::DR_CONFLICT
                        if p.delayed < policy.delayed_retries =>
                    {
                        p.delayed += 1;
                        self.stats.retries += 1;
                        self.state = State::WaitLine {
                            not_before: now + policy.delayed_delay,
                            owns_line: None,
                        };
                    }
                    _ => {
                        self.pending = None;
                        self.state = State::Idle;
                        self.stats.completed += 1;
                        self.push(MasterOutput::Done(Ok(fb)));
                    }
                }
            }
            _ => {}
        }
    }

    /// The reply to our request reported our request damaged, or was not ours.
    fn reply_failed(&mut self, error: u8, now: Micros) {
        if let State::AwaitReply { .. } = self.state {
            if let Some(p) = self.pending.as_mut() {
                p.last_error = error;
            }
            let hold = self.line.profile().hold;
            self.attempt_failed(now, now + hold);
        }
    }

    /// One attempt failed; retry at `retry_at` or give up.
    fn attempt_failed(&mut self, now: Micros, retry_at: Micros) {
        let retries = self.policy.retries;
        let Some(p) = self.pending.as_mut() else {
            return;
        };
        if p.attempts <= retries {
            self.stats.retries += 1;
            self.state = State::WaitLine {
                not_before: retry_at,
                owns_line: Some(self.line.last().1),
            };
        } else {
            let err = if p.last_error != 0 {
                LinkError::CommunicationError {
                    attempts: p.attempts,
                    last_error: p.last_error,
                }
            } else {
                LinkError::NoReply {
                    attempts: p.attempts,
                }
            };
            self.pending = None;
            self.state = State::Idle;
            self.stats.failed += 1;
            // Like a finished transaction, the other master may take the line. It has
            // not heard the transaction end: it waits its RT1 from the last frame on
            // the line, which for a secondary (41 characters) is later than this
            // master's STO + RT2 (36). Leave it that slot, and two characters to be
            // heard in, before starting again.
            let other = match self.kind {
                MasterKind::Primary => MasterKind::Secondary,
                MasterKind::Secondary => MasterKind::Primary,
            };
            let p = *self.line.profile();
            self.yield_until = self.line.last().1 + p.rt1(other) + p.chars(2);
            self.line.sent(LastFrame::Ack { to: self.kind }, now);
            self.push(MasterOutput::Done(Err(err)));
        }
    }

    /// Records that the bytes of the last [`MasterOutput::Transmit`] have all left.
    pub fn transmitted(&mut self, now: Micros) {
        if self.state == State::Sending {
            if let Some(p) = &self.pending {
                self.line.sent(
                    LastFrame::Stx {
                        from: self.kind,
                        to: p.address,
                    },
                    now,
                );
            }
            self.state = State::AwaitReply { sent: now };
        }
    }

    /// Advances timers to `now` and returns the next thing to do, if any. Call until it
    /// returns `None`, then again at [`Master::next_deadline`] or when a character
    /// arrives.
    pub fn poll(&mut self, now: Micros) -> Option<MasterOutput> {
        if let Some(o) = self.pop() {
            return Some(o);
        }
        let mut damage = 0u8;
        let mut damaged = 0u64;
        self.line.poll_gap(now, &mut |e, _| {
            if let DeframerEvent::Damaged(d) = e {
                damage |= d.errors;
                damaged += 1;
            }
        });
        self.stats.damaged += damaged;
        if damage != 0 && matches!(self.state, State::AwaitReply { .. }) {
            if let Some(p) = self.pending.as_mut() {
                p.last_error = damage;
            }
        }
        let profile = *self.line.profile();
        if let State::AwaitReply { sent } = self.state {
            let started = self.line.last().1 > sent || self.line.busy(now);
            if !started && now >= sent + profile.sto {
                // No reply started within STO: retry at once, the line is still ours.
                self.attempt_failed(now, now);
            } else if started && !self.line.busy(now) {
                // Something arrived and ended, but not our reply (a good reply ends
                // the wait in `frame`): damaged, noise or a stranger's frame.
                let p = self.pending.as_mut()?;
                if p.last_error == 0 {
                    p.last_error = 0x80;
                }
                let end = self.line.last().1;
                self.attempt_failed(now, end + profile.hold);
            }
        }
        if let State::WaitLine { .. } = self.state {
            if let Some(at) = self.earliest_start() {
                if now >= at && !self.line.busy(now) {
                    let p = self.pending.as_mut()?;
                    p.attempts += 1;
                    self.state = State::Sending;
                    let (frame, preambles) = (p.frame.clone(), p.preambles);
                    return Some(MasterOutput::Transmit(frame, preambles));
                }
            }
        }
        self.pop()
    }

    /// When this master may start its pending request, by the access rules.
    fn earliest_start(&self) -> Option<Micros> {
        let State::WaitLine {
            not_before,
            owns_line,
        } = self.state
        else {
            return None;
        };
        let p = self.line.profile();
        let (last, end) = self.line.last();
        let at = if owns_line == Some(end) {
            match last {
                // No reply at all: the line has been silent since our request.
                LastFrame::Stx { .. } => end + p.hold,
                // After a damaged or unusable reply: the slots after a reply belong to
                // a burst device (HOLD) and to the master the reply granted the line
                // (HOLD + 2 characters), which may have heard it intact; take the next.
                _ => end + p.hold + p.chars(4),
            }
        } else {
            let rt1 = end + p.rt1(self.kind);
            match last {
                LastFrame::Ack { to } if to == self.kind => end + p.rt2,
                LastFrame::Ack { .. } => {
                    // The first slot after an ACK belongs to a burst device (whose
                    // BACK must follow the ACK); start two characters later, when its
                    // carrier would already be heard.
                    let start = end + p.hold + p.chars(2);
                    if not_before <= end + p.rt2 {
                        start
                    } else {
                        rt1
                    }
                }
                LastFrame::Back { to } if to == self.kind => {
                    if not_before <= end + p.rt2 {
                        end + p.hold
                    } else {
                        rt1
                    }
                }
                _ => rt1,
            }
        };
        // Never while characters are arriving.
        Some(
            at.max(not_before)
                .max(self.yield_until)
                .max(self.line.quiet_from()?),
        )
    }

    /// The next time [`Master::poll`] has something to do (absent new characters).
    pub fn next_deadline(&self) -> Option<Micros> {
        let gap = self.line.gap_deadline();
        let own = match self.state {
            State::AwaitReply { sent } => {
                let started = self.line.last().1 > sent || self.line.quiet_from().is_none();
                if started {
                    // The reply is arriving: decide once the line is quiet again.
                    self.line.quiet_from()
                } else {
                    Some(sent + self.line.profile().sto)
                }
            }
            State::WaitLine { .. } => self.earliest_start(),
            State::Idle | State::Sending => None,
        };
        match (gap, own) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn push(&mut self, o: MasterOutput) {
        if self.out_len < OUT_CAP {
            self.out[self.out_len] = Some(o);
            self.out_len += 1;
        }
    }

    fn pop(&mut self) -> Option<MasterOutput> {
        if self.out_len == 0 {
            return None;
        }
        let o = self.out[0].take();
        self.out.rotate_left(1);
        self.out_len -= 1;
        o
    }
}

/// Largest transmission: 30 preambles plus the largest PDU.
pub const MAX_TX_LEN: usize = 30 + MAX_PDU_LEN;
