//! Modbus RTU framing, sans-IO: bytes and the time they were read go in, whole request
//! frames for our units (or the reason a run of bytes was discarded) and the next
//! deadline come out. The serial port is read and written elsewhere
//! ([`crate::serve_rtu`]).
//!
//! # How a frame is found
//!
//! Modbus over Serial Line (v1.02, §2.5.1.1) delimits frames by silence: a frame ends
//! when the line has been quiet for 3.5 character times (t3.5), and a gap of more than
//! 1.5 character times (t1.5) inside a frame makes it incomplete. Above 19200 bit/s the
//! spec fixes t3.5 at 1.750 ms and t1.5 at 750 µs.
//!
//! A program on a host does not see the line, only the times its reads return: a USB
//! adapter hands characters over in bursts (an FTDI chip every 16 ms by default, or
//! every 62 bytes), the kernel and the scheduler add their own delays, and a
//! pseudo-terminal carries no timing at all. A gap seen between two reads may be no
//! gap on the line, and two frames with a silence between them may arrive in one read.
//! So [`Framer`] decides as follows:
//!
//! * **A frame ends at a silence of t3.5** after the last byte read. What has come since
//!   the previous frame end is then judged whole: a good request for one of our units
//!   (or broadcast) is a [`Frame`]; anything else is [`Event::Discarded`], with the
//!   reason: a bad CRC, another unit's frame (another slave's request or reply on a
//!   multidrop bus), a frame cut short, a reply or exception frame, too long. So a frame
//!   cut short never swallows the next request, and no run of garbage stops anything:
//!   the next silence starts afresh.
//! * **A frame also ends as soon as it is complete by its length and its CRC matches**,
//!   without waiting for the silence: the bytes held since the last frame end are a
//!   request of a function whose length the header tells (functions 1-8, 11, 12, 15-17,
//!   22, 23, 43) for one of our units, whose CRC-16 is good; or another unit's request
//!   or reply of such a function (which then does not hold up what follows it in the
//!   same read). This answers sooner, and it keeps frames apart that an adapter handed
//!   over in one burst. A false match needs the 16-bit CRC to come out right at the one
//!   length the header names: about 1 in 65 536 for random bytes.
//! * **t1.5 is not enforced.** Gaps between reads say nothing reliable about gaps
//!   between characters on the line (a burst boundary of a USB adapter is 16 ms), so a
//!   frame with a gap over t1.5 but under t3.5 is kept whole and judged by its CRC, the
//!   integrity check that does not depend on the host's timing. [`Timing::t15`] is
//!   computed for reference and for the documentation.
//! * **A request at the end of a run of garbage is taken.** When what came between two
//!   silences is no good frame as a whole, but its last bytes are a complete request
//!   for one of our units (not a broadcast) by the length its header gives, with a good
//!   CRC, that request is taken and the bytes before it discarded. A master's silence
//!   between garbage and its request does not always survive the way to us (an adapter's
//!   burst, socat's relay, a busy host); the length and the CRC still tell the request.
//!   Broadcasts are not taken this way: a write to every device is not worth the small
//!   chance that garbage ends like one.
//! * At most 256 bytes (the RTU frame limit) are held: beyond that the oldest are
//!   dropped, and the next silence reports the run as too long (after taking a request
//!   that ends it).
//!
//! A reply must not start before the line has been quiet for t3.5 after the request:
//! [`Frame::end`] is when its last byte was read, and [`Framer::quiet_at`] when the line
//! is quiet enough now.

use std::collections::VecDeque;
use std::fmt;
use std::time::{Duration, Instant};

use tokio_modbus::{ExceptionCode, Request};

/// The longest RTU frame: address, 253 bytes of PDU, CRC.
pub const MAX_FRAME: usize = 256;

/// The silences of a line: t1.5 and t3.5.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Timing {
    /// 1.5 character times: the longest gap allowed inside a frame on the line.
    pub t15: Duration,
    /// 3.5 character times: the silence that ends a frame.
    pub t35: Duration,
}

impl Timing {
    /// The silences at `baud` with characters of `bits_per_char` bits (start, data,
    /// parity, stop: 11 for 8E1, 8O1 and 8N2, 10 for 8N1); above 19200 bit/s the fixed
    /// 750 µs and 1.750 ms of the spec.
    pub fn new(baud: u32, bits_per_char: u32) -> Self {
        if baud > 19_200 {
            return Timing {
                t15: Duration::from_micros(750),
                t35: Duration::from_micros(1750),
            };
        }
        let baud = u64::from(baud.max(1));
        // Half character times, in nanoseconds: 3 of them make t1.5, 7 make t3.5.
        let half = |n: u64| {
            Duration::from_nanos(n * u64::from(bits_per_char) * 1_000_000_000 / (2 * baud))
        };
        Timing {
            t15: half(3),
            t35: half(7),
        }
    }

    /// The silences of a line set up as `line`.
    pub fn for_line(line: &hart_serial::Line) -> Self {
        let parity = u32::from(line.parity != hart_serial::Parity::None);
        Timing::new(line.baud, 1 + 8 + parity + u32::from(line.stop_bits.max(1)))
    }
}

/// A request frame for one of our units, or a broadcast (unit 0), CRC checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// The unit addressed (0: broadcast).
    pub unit: u8,
    /// The PDU: function code and data, without address and CRC.
    pub pdu: Vec<u8>,
    /// When its last byte was read.
    pub end: Instant,
}

/// Why bytes on the line were not taken as a request for us.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Discard {
    /// Fewer than 4 bytes (address, function, CRC) before a silence.
    TooShort {
        /// Bytes held.
        len: usize,
    },
    /// A request for us that stopped short of the length its header gives, then a
    /// silence.
    CutShort {
        /// The unit addressed.
        unit: u8,
        /// Its function code.
        function: u8,
        /// Bytes that came.
        len: usize,
        /// Bytes the request has (at least, when its header did not come whole).
        expected: usize,
    },
    /// The CRC-16 does not match.
    BadCrc {
        /// Bytes held.
        len: usize,
    },
    /// A good frame for a unit that is not ours: another slave's request or reply.
    OtherUnit {
        /// The unit addressed.
        unit: u8,
        /// Its function code.
        function: u8,
        /// Its length.
        len: usize,
    },
    /// A good frame for our unit that is not a request: an exception or a reply (an
    /// adapter's echo of our own), or a length no request of its function has.
    NotARequest {
        /// The unit addressed.
        unit: u8,
        /// Its function code.
        function: u8,
        /// Its length.
        len: usize,
    },
    /// Bytes before a request for us with no silence between them (the request,
    /// found by its length and CRC at the end of the run, is taken).
    BeforeRequest {
        /// Bytes before the request.
        len: usize,
    },
    /// More than [`MAX_FRAME`] bytes without a silence.
    TooLong {
        /// Bytes that came (the first of them dropped, all but the last 256).
        len: usize,
    },
}

impl fmt::Display for Discard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Discard::TooShort { len } => write!(
                f,
                "{len} byte(s) then a silence: too short for a frame (4 bytes at least)"
            ),
            Discard::CutShort {
                unit,
                function,
                len,
                expected,
            } => write!(
                f,
                "a function-{function} request for unit {unit} cut short: {len} of its \
                 {expected} bytes, then a silence"
            ),
            Discard::BadCrc { len } => write!(f, "{len} bytes whose CRC does not match"),
            Discard::OtherUnit {
                unit,
                function,
                len,
            } => write!(
                f,
                "a frame for unit {unit} (function {function}, {len} bytes): not ours, \
                 another slave's"
            ),
            Discard::NotARequest {
                unit,
                function,
                len,
            } => write!(
                f,
                "a frame for unit {unit} with function code {function:#04x} and {len} \
                 bytes is no request (a reply or an exception, an echo?)"
            ),
            Discard::BeforeRequest { len } => write!(
                f,
                "{len} bytes with no silence before a request (which was taken)"
            ),
            Discard::TooLong { len } => write!(
                f,
                "{len} bytes without a silence: longer than an RTU frame ({MAX_FRAME})"
            ),
        }
    }
}

/// What the framer found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A request for us, to answer (unless a broadcast).
    Frame(Frame),
    /// Bytes not taken, and why.
    Discarded(Discard),
}

/// CRC-16/MODBUS (polynomial 0xA001 reflected, initial 0xFFFF) of `bytes`; sent low
/// byte first.
pub fn crc16(bytes: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in bytes {
        crc ^= u16::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// Whether `frame` ends with the CRC of the rest (and is at least 4 bytes).
fn crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 4 && {
        let (body, crc) = frame.split_at(frame.len() - 2);
        crc16(body).to_le_bytes() == [crc[0], crc[1]]
    }
}

/// `unit`, `pdu` and the CRC: a frame to send.
pub fn adu(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(pdu.len() + 3);
    out.push(unit);
    out.extend_from_slice(pdu);
    out.extend_from_slice(&crc16(&out).to_le_bytes());
    out
}

/// The length of a request frame (address to CRC) of the function in `head[1]`, when
/// the bytes in `head` tell it: `None` when more are needed or the function's length is
/// not known from its header.
fn request_len(head: &[u8]) -> Option<usize> {
    let byte = |i: usize| head.get(i).map(|&b| usize::from(b));
    match *head.get(1)? {
        1..=6 | 8 => Some(8),
        7 | 11 | 12 | 17 => Some(4),
        15 | 16 => Some(9 + byte(6)?),
        22 => Some(10),
        23 => Some(13 + byte(10)?),
        43 => Some(7),
        _ => None,
    }
}

/// The length of a request frame of the function in `head[1]` as far as `head` tells
/// it: the whole length, or the least it can be when the header has not come whole.
fn least_request_len(head: &[u8]) -> usize {
    request_len(head).unwrap_or(match head.get(1) {
        Some(23) => 13,
        _ => 9,
    })
}

/// Whether the function's request length is known from its header at all.
fn request_len_known(function: u8) -> bool {
    matches!(function, 1..=8 | 11 | 12 | 15..=17 | 22 | 23 | 43)
}

/// The length of a reply frame of the function in `head[1]` when `head` tells it.
fn reply_len(head: &[u8]) -> Option<usize> {
    let function = *head.get(1)?;
    if function & 0x80 != 0 {
        return Some(5);
    }
    match function {
        1..=4 | 12 | 17 | 23 => Some(5 + usize::from(*head.get(2)?)),
        5 | 6 | 8 | 15 | 16 => Some(8),
        7 => Some(5),
        11 => Some(8),
        22 => Some(10),
        _ => None,
    }
}

/// Finds request frames for our units in the bytes of a serial line, by silence and by
/// length and CRC (see the [module](self) documentation).
#[derive(Debug, Clone)]
pub struct Framer {
    timing: Timing,
    /// Our unit ids, a bit each.
    ours: [u64; 4],
    /// The bytes since the last frame end.
    held: Vec<u8>,
    /// Bytes dropped after [`MAX_FRAME`] since the last frame end.
    dropped: usize,
    /// When the last byte was read.
    last: Option<Instant>,
    out: VecDeque<Event>,
}

impl Framer {
    /// A framer with `timing`, taking requests for `units` (and broadcasts).
    pub fn new(timing: Timing, units: impl IntoIterator<Item = u8>) -> Self {
        let mut f = Framer {
            timing,
            ours: [0; 4],
            held: Vec::with_capacity(MAX_FRAME),
            dropped: 0,
            last: None,
            out: VecDeque::new(),
        };
        f.set_units(units);
        f
    }

    /// The silences it goes by.
    pub fn timing(&self) -> Timing {
        self.timing
    }

    /// Takes requests for `units` from now on (unit 0, broadcast, always).
    pub fn set_units(&mut self, units: impl IntoIterator<Item = u8>) {
        self.ours = [0; 4];
        for u in units {
            self.ours[usize::from(u / 64)] |= 1 << (u % 64);
        }
    }

    fn ours(&self, unit: u8) -> bool {
        unit == 0 || self.ours[usize::from(unit / 64)] & (1 << (unit % 64)) != 0
    }

    /// Takes `bytes`, read at `now`. A silence of t3.5 since the last byte ends what was
    /// held first.
    pub fn push(&mut self, bytes: &[u8], now: Instant) {
        if bytes.is_empty() {
            return;
        }
        self.end_at_silence(now);
        for &b in bytes {
            if self.held.len() >= MAX_FRAME {
                // Keep the last bytes: a request may still end the run (see
                // `end_at_silence`).
                self.held.remove(0);
                self.dropped += 1;
            }
            self.held.push(b);
            self.end_by_length(now);
        }
        self.last = Some(now);
    }

    /// The next frame or discarded run, once it is known at `now`.
    pub fn poll(&mut self, now: Instant) -> Option<Event> {
        if self.out.is_empty() {
            self.end_at_silence(now);
        }
        self.out.pop_front()
    }

    /// When [`Framer::poll`] next has something to say without more bytes: t3.5 after
    /// the last byte, while bytes are held (`None`: nothing held).
    pub fn deadline(&self) -> Option<Instant> {
        if !self.out.is_empty() {
            return self.last;
        }
        if self.held.is_empty() {
            return None;
        }
        self.quiet_at()
    }

    /// When the line will have been quiet for t3.5 (if nothing more comes): the
    /// earliest a reply may start.
    pub fn quiet_at(&self) -> Option<Instant> {
        self.last.map(|t| t + self.timing.t35)
    }

    /// Whether bytes of an unfinished frame are held.
    pub fn holding(&self) -> bool {
        !self.held.is_empty()
    }

    /// Ends what is held when the line has been quiet for t3.5 at `now`.
    fn end_at_silence(&mut self, now: Instant) {
        let Some(last) = self.last else { return };
        if self.held.is_empty() || now.saturating_duration_since(last) < self.timing.t35 {
            return;
        }
        let event = self.judge_whole(last);
        let tail = match event {
            Event::Discarded(_) => self.request_at_the_end(last),
            Event::Frame(_) => None,
        };
        match tail {
            Some((start, frame)) => {
                self.out.push_back(Event::Discarded(Discard::BeforeRequest {
                    len: start + self.dropped,
                }));
                self.out.push_back(Event::Frame(frame));
            }
            None => self.out.push_back(event),
        }
        self.held.clear();
        self.dropped = 0;
    }

    /// A request for one of our units (not a broadcast) that ends the bytes held, by
    /// the length its header gives and a good CRC, after other bytes with no silence
    /// between (a master's request after garbage that an adapter, or socat, handed over
    /// in the same read): where it starts, and the frame.
    fn request_at_the_end(&self, end: Instant) -> Option<(usize, Frame)> {
        let f = &self.held;
        (1..f.len().saturating_sub(3)).find_map(|start| {
            let r = &f[start..];
            (r[0] != 0 && self.ours(r[0]) && request_len(r) == Some(r.len()) && crc_ok(r)).then(
                || {
                    (
                        start,
                        Frame {
                            unit: r[0],
                            pdu: r[1..r.len() - 2].to_vec(),
                            end,
                        },
                    )
                },
            )
        })
    }

    /// What the bytes held make, taken whole at a silence.
    fn judge_whole(&self, end: Instant) -> Event {
        let f = &self.held;
        let len = f.len() + self.dropped;
        if self.dropped > 0 {
            return Event::Discarded(Discard::TooLong { len });
        }
        if len < 4 {
            // A request for us cut short this early still says so.
            return Event::Discarded(match (f.first(), f.get(1)) {
                (Some(&unit), Some(&function))
                    if self.ours(unit) && request_len_known(function) =>
                {
                    Discard::CutShort {
                        unit,
                        function,
                        len,
                        expected: least_request_len(f),
                    }
                }
                _ => Discard::TooShort { len },
            });
        }
        let (unit, function) = (f[0], f[1]);
        let good = crc_ok(f);
        if !self.ours(unit) {
            return Event::Discarded(if good {
                Discard::OtherUnit {
                    unit,
                    function,
                    len,
                }
            } else {
                Discard::BadCrc { len }
            });
        }
        let expected = request_len_known(function).then(|| least_request_len(f));
        match expected {
            Some(expected) if len < expected && !good => Event::Discarded(Discard::CutShort {
                unit,
                function,
                len,
                expected,
            }),
            _ if !good => Event::Discarded(Discard::BadCrc { len }),
            Some(expected) if len != expected => Event::Discarded(Discard::NotARequest {
                unit,
                function,
                len,
            }),
            _ if function & 0x80 != 0 => Event::Discarded(Discard::NotARequest {
                unit,
                function,
                len,
            }),
            _ => Event::Frame(Frame {
                unit,
                pdu: f[1..len - 2].to_vec(),
                end,
            }),
        }
    }

    /// Ends what is held, before any silence, when it is a complete frame by the length
    /// its header gives and its CRC matches.
    fn end_by_length(&mut self, now: Instant) {
        let f = &self.held;
        if f.len() < 4 {
            return;
        }
        let (unit, function) = (f[0], f[1]);
        let event = if self.ours(unit) {
            if request_len(f) != Some(f.len()) || !crc_ok(f) {
                return;
            }
            Event::Frame(Frame {
                unit,
                pdu: f[1..f.len() - 2].to_vec(),
                end: now,
            })
        } else {
            let whole = request_len(f) == Some(f.len()) || reply_len(f) == Some(f.len());
            if !whole || !crc_ok(f) {
                return;
            }
            Event::Discarded(Discard::OtherUnit {
                unit,
                function,
                len: f.len(),
            })
        };
        self.out.push_back(event);
        self.held.clear();
        self.dropped = 0;
    }
}

/// The request in a frame's PDU, or the exception to answer: 0x03 "illegal data value"
/// for a PDU of a known function that does not decode (a quantity outside the
/// protocol's limits, a byte count that disagrees with it). Checks what tokio-modbus's
/// decoder would panic on first, so any bytes are safe.
pub fn decode_request(pdu: &[u8]) -> Result<Request<'static>, ExceptionCode> {
    if pdu.is_empty() || pdu[0] & 0x80 != 0 {
        return Err(ExceptionCode::IllegalFunction);
    }
    crate::pdu::check_request_pdu(pdu).map_err(|_| ExceptionCode::IllegalDataValue)?;
    Request::try_from(tokio_modbus::bytes::Bytes::copy_from_slice(pdu))
        .map_err(|_| ExceptionCode::IllegalDataValue)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: Duration = Duration::from_millis(1);

    fn framer() -> (Framer, Instant) {
        // 19200 bit/s, 8E1: t3.5 = 2.005 ms, t1.5 = 0.859 ms.
        (Framer::new(Timing::new(19_200, 11), 1..=4), Instant::now())
    }

    /// Every event up to `at`.
    fn events(f: &mut Framer, at: Instant) -> Vec<Event> {
        std::iter::from_fn(|| f.poll(at)).collect()
    }

    fn frames(events: &[Event]) -> Vec<(u8, Vec<u8>)> {
        events
            .iter()
            .filter_map(|e| match e {
                Event::Frame(f) => Some((f.unit, f.pdu.clone())),
                _ => None,
            })
            .collect()
    }

    const READ: [u8; 5] = [4, 0, 0, 0, 16];

    #[test]
    fn timing_from_the_baud_rate_and_the_spec_above_19200() {
        let t = Timing::new(19_200, 11);
        assert_eq!(t.t35.as_micros(), 2005);
        assert_eq!(t.t15.as_micros(), 859);
        let t = Timing::new(9600, 11);
        assert_eq!(t.t35.as_micros(), 4010);
        for baud in [38_400, 115_200] {
            let t = Timing::new(baud, 11);
            assert_eq!(t.t35, Duration::from_micros(1750));
            assert_eq!(t.t15, Duration::from_micros(750));
        }
        assert_eq!(
            Timing::for_line(&hart_serial::Line::even(9600)),
            Timing::new(9600, 11)
        );
        assert_eq!(
            Timing::for_line(&hart_serial::Line::none(9600)),
            Timing::new(9600, 10)
        );
    }

    #[test]
    fn crc_of_the_spec_example() {
        // Read holding registers 0x006B, 3, of unit 0x11: CRC 0x8776 (76 87 on the line).
        let f = adu(0x11, &[0x03, 0x00, 0x6B, 0x00, 0x03]);
        assert_eq!(&f[6..], &[0x76, 0x87]);
        assert!(crc_ok(&f));
    }

    #[test]
    fn a_request_split_over_reads_ends_by_length_and_one_with_a_t15_gap_stays_whole() {
        let (mut f, t) = framer();
        let req = adu(1, &READ);
        f.push(&req[..3], t);
        assert_eq!(f.deadline(), Some(t + f.timing().t35));
        assert_eq!(f.poll(t + MS), None);
        // A gap over t1.5 but under t3.5: still one frame (see the module docs).
        f.push(&req[3..], t + Duration::from_micros(1900));
        let e = events(&mut f, t + 2 * MS);
        assert_eq!(frames(&e), vec![(1, READ.to_vec())]);
        assert_eq!(e.len(), 1);
        assert_eq!(f.deadline(), None);
    }

    #[test]
    fn a_gap_of_t35_ends_the_frame() {
        let (mut f, t) = framer();
        let req = adu(1, &READ);
        f.push(&req[..4], t);
        assert_eq!(f.poll(t + 2 * MS), None);
        f.push(&req[4..], t + 3 * MS);
        let e = events(&mut f, t + 10 * MS);
        assert!(
            matches!(e[0], Event::Discarded(Discard::CutShort { len: 4, .. })),
            "{e:?}"
        );
        // The rest alone is no frame either.
        assert_eq!(frames(&e), vec![]);
    }

    #[test]
    fn a_function_16_frame_cut_after_its_byte_count_does_not_take_the_next_request() {
        let (mut f, t) = framer();
        let write = adu(1, &[0x10, 0, 4, 0, 2, 4, 0x40, 0x20, 0, 0]);
        f.push(&write[..7], t);
        let req = adu(1, &READ);
        f.push(&req, t + 400 * MS);
        let e = events(&mut f, t + 401 * MS);
        assert_eq!(
            e[0],
            Event::Discarded(Discard::CutShort {
                unit: 1,
                function: 16,
                len: 7,
                expected: 13
            })
        );
        assert_eq!(frames(&e), vec![(1, READ.to_vec())]);
        let Event::Discarded(why) = &e[0] else {
            unreachable!()
        };
        assert_eq!(
            why.to_string(),
            "a function-16 request for unit 1 cut short: 7 of its 13 bytes, then a silence"
        );
    }

    #[test]
    fn another_slaves_reply_is_ignored_even_in_the_same_read_as_our_request() {
        let (mut f, t) = framer();
        // Unit 5's reply to function 3: 2 registers.
        let reply = adu(5, &[3, 4, 0x12, 0x34, 0x56, 0x78]);
        f.push(&reply, t);
        let e = events(&mut f, t + 10 * MS);
        assert_eq!(
            e,
            vec![Event::Discarded(Discard::OtherUnit {
                unit: 5,
                function: 3,
                len: 9
            })]
        );
        // A reply for unit 5 and our request handed over in one burst.
        let mut burst = reply.clone();
        burst.extend(adu(2, &READ));
        f.push(&burst, t + 20 * MS);
        let e = events(&mut f, t + 20 * MS);
        assert_eq!(frames(&e), vec![(2, READ.to_vec())]);
        // A reply frame of our own unit (an echo) is no request.
        f.push(&adu(1, &[3, 4, 0x12, 0x34, 0x56, 0x78]), t + 40 * MS);
        let e = events(&mut f, t + 50 * MS);
        assert!(
            matches!(
                e[..],
                [Event::Discarded(Discard::NotARequest { unit: 1, .. })]
            ),
            "{e:?}"
        );
        // An exception reply of another slave, and a request to it.
        f.push(&adu(9, &[0x83, 2]), t + 60 * MS);
        f.push(&adu(9, &READ), t + 70 * MS);
        let e = events(&mut f, t + 80 * MS);
        assert!(
            e.iter()
                .all(|e| matches!(e, Event::Discarded(Discard::OtherUnit { unit: 9, .. }))),
            "{e:?}"
        );
        assert_eq!(e.len(), 2);
    }

    #[test]
    fn random_bytes_then_a_good_request_after_a_silence() {
        let (mut f, t) = framer();
        let mut x: u32 = 12345;
        let junk: Vec<u8> = (0..1000)
            .map(|_| {
                x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (x >> 16) as u8
            })
            .collect();
        for (i, c) in junk.chunks(64).enumerate() {
            f.push(c, t + Duration::from_micros(100 * i as u64));
        }
        f.push(&adu(3, &READ), t + 100 * MS);
        let e = events(&mut f, t + 101 * MS);
        assert_eq!(frames(&e).last(), Some(&(3, READ.to_vec())), "{e:?}");
        assert!(
            e.iter()
                .any(|e| matches!(e, Event::Discarded(Discard::TooLong { len: _ }))),
            "{e:?}"
        );
    }

    #[test]
    fn a_request_right_after_garbage_in_one_read_is_taken_at_the_silence() {
        let (mut f, t) = framer();
        for junk_len in [1, 40, 300] {
            let mut burst: Vec<u8> = (0..junk_len).map(|i| (i * 37 + 11) as u8).collect();
            burst.extend(adu(2, &READ));
            f.push(&burst, t);
            assert_eq!(f.poll(t + MS), None, "waits for the silence");
            let e = events(&mut f, t + 3 * MS);
            assert_eq!(
                e,
                vec![
                    Event::Discarded(Discard::BeforeRequest { len: junk_len }),
                    Event::Frame(Frame {
                        unit: 2,
                        pdu: READ.to_vec(),
                        end: t
                    })
                ]
            );
        }
        // Not a broadcast, and not a request cut short.
        let mut burst = vec![0x55; 9];
        burst.extend(adu(0, &[6, 0, 4, 0x40, 0x20]));
        f.push(&burst, t + 10 * MS);
        let cut = adu(1, &READ);
        f.push(&cut[..6], t + 20 * MS);
        let e = events(&mut f, t + 30 * MS);
        assert!(
            matches!(e[0], Event::Discarded(Discard::BadCrc { len: 17 })),
            "{e:?}"
        );
        assert!(
            matches!(e[1], Event::Discarded(Discard::CutShort { .. })),
            "{e:?}"
        );
    }

    #[test]
    fn broadcasts_are_taken_and_a_bad_crc_is_not() {
        let (mut f, t) = framer();
        let write = [6, 0, 4, 0x40, 0x20];
        f.push(&adu(0, &write), t);
        assert_eq!(frames(&events(&mut f, t)), vec![(0, write.to_vec())]);
        let mut bad = adu(1, &READ);
        bad[3] ^= 1;
        f.push(&bad, t + 10 * MS);
        assert_eq!(f.poll(t + 11 * MS), None, "waits for the silence");
        assert_eq!(
            events(&mut f, t + 13 * MS),
            vec![Event::Discarded(Discard::BadCrc { len: 8 })]
        );
        // Too short, and units outside the list.
        f.push(&[1, 3], t + 20 * MS);
        f.push(&[7], t + 30 * MS);
        let e = events(&mut f, t + 40 * MS);
        assert!(
            matches!(e[0], Event::Discarded(Discard::CutShort { .. })),
            "{e:?}"
        );
        assert_eq!(e[1], Event::Discarded(Discard::TooShort { len: 1 }));
        f.set_units([7]);
        f.push(&adu(7, &READ), t + 50 * MS);
        f.push(&adu(1, &READ), t + 60 * MS);
        let e = events(&mut f, t + 70 * MS);
        assert_eq!(frames(&e), vec![(7, READ.to_vec())]);
        assert!(matches!(
            e[1],
            Event::Discarded(Discard::OtherUnit { unit: 1, .. })
        ));
    }

    #[test]
    fn unknown_functions_end_at_the_silence() {
        let (mut f, t) = framer();
        let pdu = [0x41, 1, 2, 3];
        f.push(&adu(1, &pdu), t);
        assert_eq!(f.poll(t + MS), None);
        assert_eq!(frames(&events(&mut f, t + 3 * MS)), vec![(1, pdu.to_vec())]);
    }

    #[test]
    fn requests_decode_and_bad_ones_are_exceptions() {
        assert_eq!(
            decode_request(&READ),
            Ok(Request::ReadInputRegisters(0, 16))
        );
        assert_eq!(
            decode_request(&[0x10, 0xD2, 0xB8, 0xD2, 0x00, 0x00]),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            decode_request(&[3, 0]),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            decode_request(&[0x83, 0]),
            Err(ExceptionCode::IllegalFunction)
        );
    }

    proptest::proptest! {
        /// Any bytes at any times: no panic, every frame taken has a good CRC and is for
        /// one of our units; and a good request after a silence is always found.
        #[test]
        fn any_bytes_then_a_good_request(
            chunks in proptest::collection::vec(
                (proptest::collection::vec(proptest::num::u8::ANY, 0..80), 0u64..5000),
                0..20),
            unit in 1u8..=4,
            start in 0u16..100,
        ) {
            let (mut f, t0) = framer();
            let mut t = t0;
            let mut seen = vec![];
            for (bytes, gap_us) in &chunks {
                t += Duration::from_micros(*gap_us);
                f.push(bytes, t);
                while let Some(e) = f.poll(t) {
                    seen.push(e);
                }
            }
            for e in &seen {
                if let Event::Frame(fr) = e {
                    proptest::prop_assert!(fr.unit <= 4);
                    let _ = decode_request(&fr.pdu);
                }
            }
            let pdu = [3, (start >> 8) as u8, start as u8, 0, 2];
            t += 5 * MS;
            f.push(&adu(unit, &pdu), t);
            let e = events(&mut f, t + 5 * MS);
            proptest::prop_assert_eq!(frames(&e), vec![(unit, pdu.to_vec())]);
        }
    }
}
