//! The field-device (slave) side of the data link, including burst mode.
//!
//! * Address match: short frames by polling address (0-63), long frames by unique ID,
//!   the broadcast address for commands 11 and 21 only. Frames for others: silence.
//! * Replies go out a configurable delay after the request's check byte (default HOLD,
//!   well inside STO).
//! * A request that arrived damaged but whose address arrived intact and is ours gets a
//!   communication-error reply (parity, overrun, framing, check byte, buffer overflow
//!   bits); a damaged address gets silence.
//! * An inter-character gap of more than one character time aborts a frame.
//! * Burst mode: a BACK when the burst period is due, right after an ACK on the line
//!   (after HOLD), or after RT1 of the requesting master when a request to another
//!   device got no reply, or after a long silence. Master bits alternate
//!   primary/secondary.
//!
//! The application is a [`Handler`]: `hart-sim`'s minimal responders and the full
//! field device plug in there.

use hart_proto::deframer::{DeframerEvent, UartFlags};
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType, MasterKind, UniqueId};

use crate::line::{LastFrame, LineMonitor};
use crate::master::MAX_TX_LEN;
use crate::timing::{Micros, TimingProfile};

/// A reply being built by a [`Handler`].
#[derive(Clone)]
pub struct Reply {
    /// Response code (first status byte).
    pub response_code: u8,
    /// Field device status (second status byte).
    pub device_status: u8,
    data: [u8; 253],
    len: usize,
}

impl Default for Reply {
    fn default() -> Self {
        Reply {
            response_code: 0,
            device_status: 0,
            data: [0; 253],
            len: 0,
        }
    }
}

impl Reply {
    /// Replaces the data (at most 253 bytes; the rest is cut off).
    pub fn set_data(&mut self, data: &[u8]) {
        self.len = data.len().min(253);
        self.data[..self.len].copy_from_slice(&data[..self.len]);
    }

    /// The data.
    pub fn data(&self) -> &[u8] {
        &self.data[..self.len]
    }

    /// A mutable buffer of `len` data bytes (at most 253) to write into.
    pub fn data_mut(&mut self, len: usize) -> &mut [u8] {
        self.len = len.min(253);
        &mut self.data[..self.len]
    }
}

/// The application behind a slave.
pub trait Handler {
    /// A request addressed to this device arrived intact at `now`. Fill `reply` and
    /// return `true`, or return `false` to stay silent (e.g. command 11 with another tag).
    fn request(&mut self, request: &Frame<'_>, reply: &mut Reply, now: Micros) -> bool;
    /// A burst frame is about to be sent at `now`: fill `reply` with the published
    /// command's reply and return its command number.
    fn burst(&mut self, reply: &mut Reply, now: Micros) -> u16;
    /// The field device status to put in communication-error replies.
    fn device_status(&self) -> u8 {
        0
    }
}

/// Burst mode settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BurstConfig {
    /// Burst (update) period.
    pub period: Micros,
}

/// Slave settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlaveConfig {
    /// Polling address, 0..=63.
    pub polling_address: u8,
    /// Unique ID for long frames.
    pub unique_id: UniqueId,
    /// Delay from the request's last character to the reply's first (default HOLD).
    pub reply_delay: Option<Micros>,
    /// Preambles in replies.
    pub response_preambles: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    Idle,
    /// A reply (or BACK) is ready in `tx` and goes out at `at`.
    Ready {
        at: Micros,
        back: bool,
    },
    Sending {
        back: bool,
        to: MasterKind,
    },
}

/// A slave's transmission: bytes to send now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Transmit<'a> {
    /// The bytes, preambles included.
    pub bytes: &'a [u8],
    /// True for a burst frame (BACK).
    pub burst: bool,
}

/// Counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SlaveStats {
    /// Requests addressed to this device.
    pub requests: u64,
    /// Replies sent (ACK).
    pub replies: u64,
    /// Communication-error replies among them.
    pub comm_error_replies: u64,
    /// Burst frames sent.
    pub bursts: u64,
}

/// A HART slave. See the [module documentation](self).
pub struct Slave {
    config: SlaveConfig,
    line: LineMonitor,
    state: State,
    tx: [u8; MAX_TX_LEN],
    tx_len: usize,
    tx_to: MasterKind,
    burst_mode: bool,
    burst_period: Option<Micros>,
    burst_due: Option<Micros>,
    burst_to: MasterKind,
    stats: SlaveStats,
    /// Fault injection (conformance testing): answer every address.
    fault_any_address: bool,
    /// Fault injection: execute requests whose only error is the check byte.
    fault_bad_check: bool,
}

impl Slave {
    /// A slave on a line with `profile`, powered up at `now`.
    pub fn new(config: SlaveConfig, profile: TimingProfile, now: Micros) -> Self {
        Slave {
            config,
            line: LineMonitor::new(profile, now),
            state: State::Idle,
            tx: [0; MAX_TX_LEN],
            tx_len: 0,
            tx_to: MasterKind::Primary,
            burst_mode: false,
            burst_period: None,
            burst_due: None,
            burst_to: MasterKind::Primary,
            stats: SlaveStats::default(),
            fault_any_address: false,
            fault_bad_check: false,
        }
    }

    /// Settings.
    pub fn config(&self) -> &SlaveConfig {
        &self.config
    }

    /// Counters so far.
    pub fn stats(&self) -> SlaveStats {
        self.stats
    }

    /// Turns periodic burst mode on (first BACK due at `first_due`, then every period)
    /// or off.
    pub fn set_burst(&mut self, burst: Option<BurstConfig>, first_due: Micros) {
        self.burst_mode = burst.is_some();
        self.burst_period = burst.map(|b| b.period);
        self.burst_due = burst.map(|_| first_due);
    }

    /// Burst mode driven by the application: `mode` sets the burst bit in replies;
    /// [`Slave::set_burst_due`] says when the next BACK is wanted.
    pub fn set_burst_mode(&mut self, mode: bool) {
        self.burst_mode = mode;
        self.burst_period = None;
        if !mode {
            self.burst_due = None;
        }
    }

    /// When the application wants to publish next (`None`: nothing due). After a BACK
    /// goes out the slave forgets it until told again, unless a period was set with
    /// [`Slave::set_burst`].
    pub fn set_burst_due(&mut self, due: Option<Micros>) {
        self.burst_due = if self.burst_mode { due } else { None };
    }

    /// Changes the reply delay (`None`: HOLD).
    pub fn set_reply_delay(&mut self, delay: Option<Micros>) {
        self.config.reply_delay = delay;
    }

    /// Fault injection for testing conformance testers: when `on`, the slave answers
    /// requests for any polling address and any unique ID (a rule broken on purpose).
    pub fn set_fault_answers_any_address(&mut self, on: bool) {
        self.fault_any_address = on;
    }

    /// Fault injection for testing conformance testers: when `on`, a request whose only
    /// error is its check byte is executed and answered as if it were intact, instead
    /// of with the communication-error summary (a rule broken on purpose).
    pub fn set_fault_executes_bad_check_byte(&mut self, on: bool) {
        self.fault_bad_check = on;
    }

    /// Changes the number of preambles in replies.
    pub fn set_response_preambles(&mut self, n: usize) {
        self.config.response_preambles = n;
    }

    /// Changes the polling address.
    pub fn set_polling_address(&mut self, polling_address: u8) {
        self.config.polling_address = polling_address & 0x3F;
    }

    /// The carrier-detect line changed (optional: stations also work from received
    /// characters alone, but carrier detect lets a reply that starts just before STO
    /// count as started).
    pub fn carrier(&mut self, on: bool) {
        self.line.set_carrier(on);
    }

    /// Feeds a character that finished arriving at `now`.
    pub fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros, handler: &mut impl Handler) {
        let Slave {
            config,
            line,
            tx,
            tx_len,
            tx_to,
            burst_mode,
            stats,
            fault_any_address,
            fault_bad_check,
            ..
        } = self;
        let any = *fault_any_address;
        let bad_check_ok = *fault_bad_check;
        let bursting = *burst_mode;
        let mut ready = false;
        line.receive(byte, flags, now, &mut |e, _| {
            // (address, command, extended, status, data) of the reply to build.
            let mut reply = Reply::default();
            let (address, command, extended, status) = match &e {
                DeframerEvent::Frame(f)
                    if f.frame_type() == FrameType::Stx
                        && (any || is_me(config, &f.address, f.command_byte)) =>
                {
                    stats.requests += 1;
                    if !handler.request(f, &mut reply, now) {
                        return;
                    }
                    (
                        f.address,
                        f.command,
                        f.extended,
                        (reply.response_code, reply.device_status),
                    )
                }
                DeframerEvent::Damaged(d) if d.delimiter.frame_type == FrameType::Stx => {
                    let (Some(a), Some(cmd)) = (d.address, d.command_byte) else {
                        return;
                    };
                    if !(any || is_me(config, &a, cmd)) {
                        return;
                    }
                    stats.requests += 1;
                    // Fault injection: a request damaged only in its check byte is
                    // executed as if it were intact.
                    let only_check = d.errors & 0x7F == hart_proto::tables::comm_error::CHECK_BYTE;
                    if bad_check_ok && only_check {
                        if let Ok(f) = Frame::parse_pdu(d.pdu) {
                            if !handler.request(&f, &mut reply, now) {
                                return;
                            }
                            let spec = FrameSpec {
                                preambles: config.response_preambles,
                                frame_type: FrameType::Ack,
                                address: f.address.with_burst(bursting),
                                expansion: &[],
                                physical_layer: 0,
                                command: f.command,
                                extended: f.extended,
                                status: Some((reply.response_code, reply.device_status)),
                                data: reply.data(),
                            };
                            if let Ok(n) = spec.encode(&mut tx[..]) {
                                *tx_len = n;
                                *tx_to = f.address.master();
                                ready = true;
                            }
                            return;
                        }
                    }
                    stats.comm_error_replies += 1;
                    (
                        a,
                        u16::from(cmd),
                        false,
                        (d.errors, handler.device_status()),
                    )
                }
                _ => return,
            };
            let spec = FrameSpec {
                preambles: config.response_preambles,
                frame_type: FrameType::Ack,
                address: address.with_burst(bursting),
                expansion: &[],
                physical_layer: 0,
                command,
                extended,
                status: Some(status),
                data: reply.data(),
            };
            if let Ok(n) = spec.encode(&mut tx[..]) {
                *tx_len = n;
                *tx_to = address.master();
                ready = true;
            }
        });
        if ready {
            let delay = self.config.reply_delay.unwrap_or(self.line.profile().hold);
            self.state = State::Ready {
                at: now + delay,
                back: false,
            };
        }
    }

    /// When the next burst frame may go out, if burst mode is on and nothing else is
    /// pending.
    fn burst_start(&self) -> Option<Micros> {
        let due = self.burst_due?;
        if !self.burst_mode || self.state != State::Idle {
            return None;
        }
        let p = self.line.profile();
        let (last, e) = self.line.last();
        // The preferred slot after the last frame; otherwise the quiet-line fallback,
        // later than every master's RT1.
        let slot = match last {
            LastFrame::Ack { .. } => Some(e + p.hold),
            LastFrame::Stx { from, to } if !is_me(&self.config, &to, 0) => Some(e + p.rt1(from)),
            LastFrame::Stx { .. } => None,
            // After its own BACK the granted master has RT2 to start; if it does not,
            // the burst device may go on (two characters later, to hear a late start).
            LastFrame::Back { .. } => Some(e + p.rt2 + p.chars(2)),
            _ => None,
        };
        let fallback = e + p.rt1_secondary + p.hold;
        let at = match slot {
            Some(s) if due <= s => s,
            _ => fallback.max(due),
        };
        Some(at.max(self.line.quiet_from()?))
    }

    /// Advances to `now`: returns bytes to transmit when it is time. Call
    /// [`Slave::transmitted`] when they have left.
    pub fn poll(&mut self, now: Micros, handler: &mut impl Handler) -> Option<Transmit<'_>> {
        self.line.poll_gap(now, &mut |_, _| {});
        if let Some(at) = self.burst_start() {
            if now >= at && !self.line.busy(now) {
                let mut reply = Reply::default();
                let command = handler.burst(&mut reply, now);
                let to = self.burst_to;
                let address = Address::Long(hart_proto::frame::LongAddress {
                    master: to,
                    burst: true,
                    id: self.config.unique_id,
                });
                let spec = FrameSpec {
                    preambles: self.config.response_preambles,
                    frame_type: FrameType::Back,
                    address,
                    expansion: &[],
                    physical_layer: 0,
                    command,
                    extended: false,
                    status: Some((reply.response_code, reply.device_status)),
                    data: reply.data(),
                };
                if let Ok(n) = spec.encode(&mut self.tx) {
                    self.tx_len = n;
                    self.tx_to = to;
                    self.state = State::Ready {
                        at: now,
                        back: true,
                    };
                }
            }
        }
        match self.state {
            State::Ready { at, back } if now >= at => {
                self.state = State::Sending {
                    back,
                    to: self.tx_to,
                };
                Some(Transmit {
                    bytes: &self.tx[..self.tx_len],
                    burst: back,
                })
            }
            _ => None,
        }
    }

    /// Records that the last transmission has left at `now`.
    pub fn transmitted(&mut self, now: Micros) {
        if let State::Sending { back, to } = self.state {
            if back {
                self.stats.bursts += 1;
                self.line.sent(LastFrame::Back { to }, now);
                self.burst_to = to.other();
                self.burst_due = match (self.burst_period, self.burst_due) {
                    // Keep the cadence (a BACK waits for a slot, so it is sent a little
                    // after it is due), but never fall more than one period behind.
                    (Some(period), Some(due)) => Some(if due + period <= now {
                        now + period
                    } else {
                        due + period
                    }),
                    _ => None,
                };
            } else {
                self.stats.replies += 1;
                self.line.sent(LastFrame::Ack { to }, now);
            }
            self.state = State::Idle;
        }
    }

    /// The next time [`Slave::poll`] has something to do (absent new characters).
    pub fn next_deadline(&self) -> Option<Micros> {
        let own = match self.state {
            State::Ready { at, .. } => Some(at),
            State::Idle => self.burst_start(),
            State::Sending { .. } => None,
        };
        match (own, self.line.gap_deadline()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }
}

fn is_me(config: &SlaveConfig, a: &Address, command_byte: u8) -> bool {
    match a {
        Address::Short(s) => s.polling_address == config.polling_address,
        Address::Long(l) => {
            l.id == config.unique_id
                || (l.id.is_broadcast() && (command_byte == 11 || command_byte == 21))
        }
    }
}
