//! Streaming deframer: bytes in (with the UART's per-byte error flags), frames and
//! typed errors out.
//!
//! * A start of message is at least [`DeframerConfig::min_preambles`] consecutive 0xFF
//!   bytes received without error, followed by a valid delimiter received without error.
//! * The byte count decides where the frame ends; bytes that arrive with parity,
//!   framing or overrun errors are kept and reported with the frame as a
//!   communication-error summary (the bits a slave puts in its first status byte).
//! * After anything that is not a good frame, the bytes after the failed start byte are
//!   scanned again, so a real frame hidden behind garbage or behind a cut-off frame is
//!   still found.
//! * Memory is one fixed buffer of [`MAX_PDU_LEN`] bytes plus a replay stack of the same
//!   size; nothing is allocated and no input can make it panic.
//!
//! The deframer has no notion of time: the data-link layer calls
//! [`Deframer::abort`] when it sees an inter-character gap or loses the carrier.

use crate::frame::{Address, Delimiter, Frame, FrameError, MAX_PDU_LEN, PREAMBLE};
use crate::tables::comm_error;

/// Error flags the UART reported for one received character.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct UartFlags {
    /// Vertical (character) parity error.
    pub parity: bool,
    /// Framing error (stop bit not seen).
    pub framing: bool,
    /// Receiver overrun (a character was lost before this one).
    pub overrun: bool,
}

impl UartFlags {
    /// No error.
    pub const OK: UartFlags = UartFlags {
        parity: false,
        framing: false,
        overrun: false,
    };

    /// True when any error flag is set.
    pub fn any(self) -> bool {
        self.parity || self.framing || self.overrun
    }

    /// The flags as communication-error summary bits (bit 7 not included).
    pub fn comm_error_bits(self) -> u8 {
        (if self.parity { comm_error::PARITY } else { 0 })
            | (if self.overrun { comm_error::OVERRUN } else { 0 })
            | (if self.framing { comm_error::FRAMING } else { 0 })
    }

    fn to_bits(self) -> u8 {
        u8::from(self.parity) | u8::from(self.framing) << 1 | u8::from(self.overrun) << 2
    }

    fn from_bits(b: u8) -> Self {
        UartFlags {
            parity: b & 1 != 0,
            framing: b & 2 != 0,
            overrun: b & 4 != 0,
        }
    }
}

/// Settings of a [`Deframer`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeframerConfig {
    /// Preamble bytes needed before a delimiter (HART: 2).
    pub min_preambles: usize,
    /// Largest byte count the receiver accepts; a longer frame is still followed to
    /// its end and reported with the buffer-overflow bit (a device with a small
    /// receive buffer sets this lower than 255).
    pub max_byte_count: u8,
}

impl Default for DeframerConfig {
    fn default() -> Self {
        DeframerConfig {
            min_preambles: crate::frame::MIN_RX_PREAMBLES,
            max_byte_count: 255,
        }
    }
}

/// A frame that arrived complete (by its byte count) but damaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Damaged<'a> {
    /// Communication-error summary as a slave would report it: bit 7 set plus parity
    /// (0x40), overrun (0x20), framing (0x10), check byte (0x08), buffer overflow (0x02).
    pub errors: u8,
    /// The address, when every byte up to and including the address arrived without
    /// a UART error (so a slave may trust it and answer with a communication error).
    pub address: Option<Address>,
    /// The command byte, under the same condition as `address` extended to the command.
    pub command_byte: Option<u8>,
    /// The frame type.
    pub delimiter: Delimiter,
    /// Preambles before the frame.
    pub preambles: usize,
    /// The bytes received (delimiter onwards; truncated at the buffer size on overflow).
    pub pdu: &'a [u8],
}

/// Something the deframer found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeframerEvent<'a> {
    /// A complete frame with a good check byte and no UART errors.
    Frame(Frame<'a>),
    /// A complete frame with errors (see [`Damaged::errors`]).
    Damaged(Damaged<'a>),
    /// A frame that was structurally invalid once complete (e.g. an ACK with byte
    /// count below 2, or command 31 without its extended number).
    Invalid {
        /// The problem.
        error: FrameError,
        /// The bytes (delimiter onwards).
        pdu: &'a [u8],
    },
    /// A frame was cut off by [`Deframer::abort`] (gap or loss of carrier).
    Aborted {
        /// Bytes received of it (delimiter onwards).
        received: usize,
        /// Bytes the frame would have had, if the byte count had arrived.
        expected: Option<usize>,
    },
    /// Bytes that were not part of any frame were skipped (reported before the next
    /// start of message or abort).
    Garbage {
        /// How many bytes.
        bytes: usize,
    },
}

/// Counters kept by the deframer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DeframerStats {
    /// Good frames.
    pub frames: u64,
    /// Damaged frames (UART errors, bad check byte, overflow).
    pub damaged: u64,
    /// Structurally invalid frames.
    pub invalid: u64,
    /// Aborted frames.
    pub aborted: u64,
    /// Bytes skipped as garbage.
    pub garbage_bytes: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Looking for a start of message; `preambles` good 0xFF seen in a row.
    Hunt { preambles: usize },
    /// Inside a frame.
    Frame,
}

const REPLAY_CAP: usize = MAX_PDU_LEN + 1;

/// The streaming deframer. See the [module documentation](self).
#[derive(Clone)]
pub struct Deframer {
    config: DeframerConfig,
    state: State,
    buf: [u8; MAX_PDU_LEN],
    flags: [u8; MAX_PDU_LEN],
    /// Bytes received of the current frame (may exceed `buf` on overflow).
    len: usize,
    /// Total length of the current frame once the byte count is known.
    expected: Option<usize>,
    preambles: usize,
    errors: u8,
    /// Offset of the first byte with a UART error, if any.
    first_error: Option<usize>,
    garbage: usize,
    replay: [(u8, u8); REPLAY_CAP],
    replay_len: usize,
    stats: DeframerStats,
}

impl Default for Deframer {
    fn default() -> Self {
        Self::new(DeframerConfig::default())
    }
}

impl Deframer {
    /// A deframer with the given settings.
    pub fn new(config: DeframerConfig) -> Self {
        Deframer {
            config,
            state: State::Hunt { preambles: 0 },
            buf: [0; MAX_PDU_LEN],
            flags: [0; MAX_PDU_LEN],
            len: 0,
            expected: None,
            preambles: 0,
            errors: 0,
            first_error: None,
            garbage: 0,
            replay: [(0, 0); REPLAY_CAP],
            replay_len: 0,
            stats: DeframerStats::default(),
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> DeframerStats {
        self.stats
    }

    /// True while a frame is being received.
    pub fn in_frame(&self) -> bool {
        self.state == State::Frame
    }

    /// Bytes still to come before the frame being received is complete, once its byte
    /// count has arrived (`None` while hunting or before the byte count). A receiver
    /// uses it to decide the last character of a frame without waiting.
    pub fn remaining(&self) -> Option<usize> {
        match self.state {
            State::Frame => self.expected.map(|e| e.saturating_sub(self.len)),
            State::Hunt { .. } => None,
        }
    }

    /// Feeds bytes received without UART errors.
    pub fn feed(&mut self, bytes: &[u8], mut on_event: impl FnMut(DeframerEvent<'_>)) {
        for &b in bytes {
            self.push(b, UartFlags::OK, &mut on_event);
        }
    }

    /// Feeds one byte with its UART flags.
    pub fn push(
        &mut self,
        byte: u8,
        flags: UartFlags,
        on_event: &mut impl FnMut(DeframerEvent<'_>),
    ) {
        self.step(byte, flags.to_bits(), on_event);
        self.drain_replay(on_event);
    }

    /// Ends the frame being received (inter-character gap, carrier lost). The bytes
    /// received so far are scanned again for a start of message.
    pub fn abort(&mut self, on_event: &mut impl FnMut(DeframerEvent<'_>)) {
        if self.state == State::Frame {
            self.stats.aborted += 1;
            on_event(DeframerEvent::Aborted {
                received: self.len,
                expected: self.expected,
            });
            self.schedule_replay();
            self.drain_replay(on_event);
            // Whatever is left incomplete after the replay is abandoned too, silently.
            if self.state == State::Frame {
                self.garbage += self.len;
                self.reset_frame();
            }
        }
        self.state = State::Hunt { preambles: 0 };
        self.flush_garbage(on_event);
    }

    fn drain_replay(&mut self, on_event: &mut impl FnMut(DeframerEvent<'_>)) {
        while self.replay_len > 0 {
            self.replay_len -= 1;
            let (b, f) = self.replay[self.replay_len];
            self.step(b, f, on_event);
        }
    }

    fn flush_garbage(&mut self, on_event: &mut impl FnMut(DeframerEvent<'_>)) {
        if self.garbage > 0 {
            self.stats.garbage_bytes += self.garbage as u64;
            on_event(DeframerEvent::Garbage {
                bytes: self.garbage,
            });
            self.garbage = 0;
        }
    }

    fn reset_frame(&mut self) {
        self.len = 0;
        self.expected = None;
        self.errors = 0;
        self.first_error = None;
    }

    /// Pushes the current frame's bytes after its delimiter back for rescanning and
    /// returns to hunting. The delimiter itself is counted as garbage.
    fn schedule_replay(&mut self) {
        let stored = self.len.min(MAX_PDU_LEN);
        // Bytes are conserved (each is either here or already in the replay stack), so the
        // stack never holds more than one frame buffer plus the live byte.
        for i in (1..stored).rev() {
            if self.replay_len < REPLAY_CAP {
                self.replay[self.replay_len] = (self.buf[i], self.flags[i]);
                self.replay_len += 1;
            }
        }
        self.garbage += 1 + self.len.saturating_sub(stored);
        self.reset_frame();
        self.state = State::Hunt { preambles: 0 };
    }

    fn step(&mut self, byte: u8, flags: u8, on_event: &mut impl FnMut(DeframerEvent<'_>)) {
        let uart = UartFlags::from_bits(flags);
        match self.state {
            State::Hunt { preambles } => {
                if uart.any() {
                    self.garbage += preambles + 1;
                    self.state = State::Hunt { preambles: 0 };
                } else if byte == PREAMBLE {
                    self.state = State::Hunt {
                        preambles: preambles.saturating_add(1),
                    };
                } else if preambles >= self.config.min_preambles
                    && Delimiter::from_byte(byte).is_some()
                {
                    self.flush_garbage(on_event);
                    self.reset_frame();
                    self.preambles = preambles;
                    self.state = State::Frame;
                    self.store(byte, flags);
                } else {
                    self.garbage += preambles + 1;
                    self.state = State::Hunt { preambles: 0 };
                }
            }
            State::Frame => {
                self.store(byte, flags);
                self.update_expected();
                if self.expected.is_some_and(|e| self.len >= e) {
                    self.finish(on_event);
                }
            }
        }
    }

    fn store(&mut self, byte: u8, flags: u8) {
        let uart = UartFlags::from_bits(flags);
        if uart.any() {
            self.errors |= uart.comm_error_bits();
            self.first_error.get_or_insert(self.len);
        }
        if self.len < MAX_PDU_LEN {
            self.buf[self.len] = byte;
            self.flags[self.len] = flags;
        }
        self.len += 1;
    }

    /// Once the header is in, compute the frame length from the byte count.
    fn update_expected(&mut self) {
        if self.expected.is_some() {
            return;
        }
        let Some(d) = Delimiter::from_byte(self.buf[0]) else {
            return;
        };
        let bc_pos = 1 + d.address_len() + usize::from(d.expansion_len) + 1;
        if self.len > bc_pos {
            let bc = self.buf[bc_pos];
            if bc > self.config.max_byte_count {
                self.errors |= comm_error::BUFFER_OVERFLOW;
            }
            self.expected = Some(bc_pos + 1 + usize::from(bc) + 1);
        }
    }

    fn finish(&mut self, on_event: &mut impl FnMut(DeframerEvent<'_>)) {
        let stored = self.len.min(MAX_PDU_LEN);
        let pdu = &self.buf[..stored];
        let delimiter = Delimiter::from_byte(pdu[0]);
        let mut errors = self.errors;
        let parsed = Frame::parse_pdu(pdu);
        if let Ok(f) = &parsed {
            if !f.checksum_ok() {
                errors |= comm_error::CHECK_BYTE;
            }
        }
        match (parsed, delimiter) {
            (Ok(mut frame), _) if errors == 0 => {
                frame.preambles = self.preambles;
                self.stats.frames += 1;
                on_event(DeframerEvent::Frame(frame));
                self.reset_frame();
                self.state = State::Hunt { preambles: 0 };
            }
            (Err(error), _) if errors == 0 => {
                self.stats.invalid += 1;
                on_event(DeframerEvent::Invalid { error, pdu });
                self.schedule_replay();
            }
            (_, Some(delimiter)) => {
                let addr_end = 1 + delimiter.address_len();
                let cmd_pos = addr_end + usize::from(delimiter.expansion_len);
                let clean_until = self.first_error.unwrap_or(usize::MAX);
                let address = (clean_until >= addr_end && pdu.len() >= addr_end)
                    .then(|| Address::read(delimiter.long_address, &pdu[1..addr_end]));
                let command_byte = (clean_until > cmd_pos)
                    .then(|| pdu.get(cmd_pos).copied())
                    .flatten();
                self.stats.damaged += 1;
                on_event(DeframerEvent::Damaged(Damaged {
                    errors: errors | comm_error::FLAG,
                    address,
                    command_byte,
                    delimiter,
                    preambles: self.preambles,
                    pdu,
                }));
                self.schedule_replay();
            }
            (_, None) => self.schedule_replay(),
        }
    }
}
