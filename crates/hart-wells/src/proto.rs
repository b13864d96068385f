//! Frames, addresses and the data layouts of the network's commands (docs/wells.md).
//!
//! The frames are HART short frames with two preambles: hart-proto encodes and
//! deframes them. This module adds the network's address plan and the layouts of
//! commands 1, 14, 144 and 160, each with an encoder and a decoder that returns a
//! typed error on any input.

use std::fmt;

use hart_proto::deframer::{Deframer, DeframerConfig, DeframerEvent, UartFlags};
use hart_proto::frame::{Address, FrameSpec, FrameType, MasterKind, ShortAddress};

use crate::calibration::{Segment, Sensor};

/// Command 1: read three groups of measured values (sensor bus); on the uplink, the
/// concentrator's latest values.
pub const READ_VALUES: u8 = 1;
/// Command 14: diagnostics (sensor) or status (concentrator).
pub const DIAGNOSTICS: u8 = 14;
/// Command 144: hand over stored data in batches.
pub const TRANSFER: u8 = 144;
/// Command 160: download a calibration table segment by segment.
pub const CALIBRATION: u8 = 160;
/// Command 161: read or change the concentrator's parameters online.
pub const PARAMETERS: u8 = 161;
/// Response code: passed parameter too large.
pub const RC_TOO_LARGE: u8 = 3;

/// The concentrator's parameters (command 161): request data = these 3 bytes (0 and
/// 0xFF leave a value as it is), reply data = the values in force.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Parameters {
    /// Seconds between polls (1-180; 0 in a request: unchanged).
    pub poll_interval_s: u16,
    /// Retries of a sensor request (0-5; 0xFF in a request: unchanged).
    pub retries: u8,
}

impl Parameters {
    /// A request that changes nothing: reads the values in force.
    pub const READ: Parameters = Parameters {
        poll_interval_s: 0,
        retries: 0xFF,
    };

    /// The 3 data bytes.
    pub fn encode(&self) -> Vec<u8> {
        let mut d = self.poll_interval_s.to_be_bytes().to_vec();
        d.push(self.retries);
        d
    }

    /// Decodes 3 data bytes.
    pub fn decode(d: &[u8]) -> Result<Self, DecodeError> {
        if d.len() < 3 {
            return Err(DecodeError::Length {
                what: "command 161",
                expected: 3,
                got: d.len(),
            });
        }
        Ok(Parameters {
            poll_interval_s: u16::from_be_bytes([d[0], d[1]]),
            retries: d[2],
        })
    }
}

/// Preambles the network's stations send.
pub const PREAMBLES: usize = 2;
/// Counts that mark "no value" in a group or record.
pub const NO_VALUE: u32 = 0xFF_FFFF;
/// Records in one command-144 batch at most.
pub const BATCH_RECORDS: usize = 11;
/// Bytes of one command-144 record.
pub const RECORD_LEN: usize = 22;

/// Response code: invalid selection.
pub const RC_INVALID_SELECTION: u8 = 2;
/// Response code: too few data bytes received.
pub const RC_TOO_FEW_BYTES: u8 = 5;
/// Response code: calibration segment out of order.
pub const RC_OUT_OF_ORDER: u8 = 9;
/// Response code: calibration table refused.
pub const RC_TABLE_REFUSED: u8 = 10;
/// Response code: command not implemented.
pub const RC_NOT_IMPLEMENTED: u8 = 64;

/// A station's address byte on the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Station(pub u8);

impl Station {
    /// Sensor `n` (1-15) on a well's bus: `0000 nnnn`.
    pub fn sensor(n: u8) -> Self {
        Station(n & 0x0F)
    }

    /// The concentrator of well `w` (1-15): `1000 wwww`.
    pub fn concentrator(well: u8) -> Self {
        Station(0x80 | (well & 0x0F))
    }

    /// The handheld, for well `w`: `1100 wwww`.
    pub fn handheld(well: u8) -> Self {
        Station(0xC0 | (well & 0x0F))
    }

    /// What kind of station the address names.
    pub fn role(self) -> Role {
        match self.0 & 0xF0 {
            0x00 => Role::Sensor,
            0x80 => Role::Concentrator,
            0xC0 => Role::Handheld,
            _ => Role::Unknown,
        }
    }

    /// The low nibble: the sensor number or the well.
    pub fn number(self) -> u8 {
        self.0 & 0x0F
    }

    /// The address as hart-proto's short address (bit 7 the master bit, bit 6 the
    /// burst bit, bits 0-5 the polling address: the same byte).
    pub fn to_address(self) -> Address {
        Address::Short(ShortAddress {
            master: if self.0 & 0x80 != 0 {
                MasterKind::Primary
            } else {
                MasterKind::Secondary
            },
            burst: self.0 & 0x40 != 0,
            polling_address: self.0 & 0x3F,
        })
    }

    /// The station of a short address; `None` for a long one.
    pub fn from_address(a: &Address) -> Option<Self> {
        match a {
            Address::Short(s) => Some(Station(
                s.master.bits_byte() | if s.burst { 0x40 } else { 0 } | (s.polling_address & 0x3F),
            )),
            Address::Long(_) => None,
        }
    }
}

impl fmt::Display for Station {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.role() {
            Role::Sensor => write!(f, "sensor {} (0x{:02X})", self.number(), self.0),
            Role::Concentrator => write!(
                f,
                "concentrator of well {} (0x{:02X})",
                self.number(),
                self.0
            ),
            Role::Handheld => write!(f, "handheld for well {} (0x{:02X})", self.number(), self.0),
            Role::Unknown => write!(f, "station 0x{:02X}", self.0),
        }
    }
}

/// What an address names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// A sensor on a well's bus.
    Sensor,
    /// A well's data concentrator.
    Concentrator,
    /// The handheld, speaking for a well.
    Handheld,
    /// An address outside the plan.
    Unknown,
}

trait MasterBits {
    fn bits_byte(self) -> u8;
}

impl MasterBits for MasterKind {
    fn bits_byte(self) -> u8 {
        match self {
            MasterKind::Primary => 0x80,
            MasterKind::Secondary => 0,
        }
    }
}

/// A frame of the network, decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Message {
    /// A reply (delimiter 06) rather than a request (02).
    pub reply: bool,
    /// The address byte.
    pub station: Station,
    /// The command.
    pub command: u8,
    /// The two status bytes of a reply.
    pub status: Option<[u8; 2]>,
    /// The data.
    pub data: Vec<u8>,
}

impl Message {
    /// A request.
    pub fn request(station: Station, command: u8, data: Vec<u8>) -> Self {
        Message {
            reply: false,
            station,
            command,
            status: None,
            data,
        }
    }

    /// A reply.
    pub fn reply(station: Station, command: u8, status: [u8; 2], data: Vec<u8>) -> Self {
        Message {
            reply: true,
            station,
            command,
            status: Some(status),
            data,
        }
    }

    /// The frame on the wire: two preambles, delimiter, address, command, byte count,
    /// status (replies), data, check byte. Data beyond 253 bytes is an error of the
    /// caller and is cut.
    pub fn to_bytes(&self) -> Vec<u8> {
        let max = if self.reply { 253 } else { 255 };
        let data = &self.data[..self.data.len().min(max)];
        let spec = FrameSpec {
            preambles: PREAMBLES,
            frame_type: if self.reply {
                FrameType::Ack
            } else {
                FrameType::Stx
            },
            status: self.status.map(|s| (s[0], s[1])),
            ..FrameSpec::request(self.station.to_address(), self.command as u16, data)
        };
        let mut out = vec![0u8; spec.encoded_len()];
        match spec.encode(&mut out) {
            Ok(n) => {
                out.truncate(n);
                out
            }
            Err(_) => Vec::new(),
        }
    }

    /// Response code (first status byte) of a reply.
    pub fn response_code(&self) -> Option<u8> {
        self.status.map(|s| s[0])
    }
}

/// What a receiver found on the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Received {
    /// A frame with a good check byte and no character errors.
    Message(Message),
    /// A frame with errors: the communication-error summary (parity 0x40, overrun
    /// 0x20, framing 0x10, check byte 0x08, buffer overflow 0x02, bit 7 set). The
    /// network does not answer these: the address cannot be trusted.
    Damaged {
        /// The error bits.
        errors: u8,
    },
}

/// Cuts the network's frames out of received characters (hart-proto's deframer with
/// two preambles required).
pub struct Receiver {
    deframer: Deframer,
}

impl Default for Receiver {
    fn default() -> Self {
        Self::new()
    }
}

impl Receiver {
    /// A receiver that needs two preambles before a delimiter.
    pub fn new() -> Self {
        Receiver {
            deframer: Deframer::new(DeframerConfig {
                min_preambles: PREAMBLES,
                max_byte_count: 255,
            }),
        }
    }

    /// Feeds received characters with the UART's flags; returns what completed.
    pub fn push(&mut self, chars: &[(u8, UartFlags)]) -> Vec<Received> {
        let mut out = Vec::new();
        for &(b, flags) in chars {
            self.deframer.push(b, flags, &mut |ev| match ev {
                DeframerEvent::Frame(f) => {
                    let Some(station) = Station::from_address(&f.address) else {
                        return;
                    };
                    if f.extended || !f.expansion.is_empty() {
                        return;
                    }
                    let reply = f.frame_type() == FrameType::Ack;
                    if !reply && f.frame_type() != FrameType::Stx {
                        return;
                    }
                    out.push(Received::Message(Message {
                        reply,
                        station,
                        command: f.command_byte,
                        status: match (f.response_code, f.device_status) {
                            (Some(a), Some(b)) => Some([a, b]),
                            _ => None,
                        },
                        data: f.data.to_vec(),
                    }));
                }
                DeframerEvent::Damaged(d) => out.push(Received::Damaged { errors: d.errors }),
                _ => {}
            });
        }
        out
    }

    /// Feeds clean bytes (no UART flags).
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<Received> {
        let chars: Vec<(u8, UartFlags)> = bytes.iter().map(|&b| (b, UartFlags::OK)).collect();
        self.push(&chars)
    }

    /// Drops a partly received frame (after a gap on the line).
    pub fn reset(&mut self) {
        self.deframer.abort(&mut |_| {});
    }

    /// Whether a frame is partly received.
    pub fn in_frame(&self) -> bool {
        self.deframer.in_frame()
    }
}

/// Why data could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DecodeError {
    /// The data is shorter or longer than the layout.
    Length {
        /// What was decoded.
        what: &'static str,
        /// Bytes expected (or the minimum).
        expected: usize,
        /// Bytes received.
        got: usize,
    },
    /// A field holds a value the layout does not allow.
    Field {
        /// What was decoded.
        what: &'static str,
        /// The problem.
        problem: String,
    },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::Length {
                what,
                expected,
                got,
            } => write!(
                f,
                "{what}: {got} data bytes where the layout has {expected} (see docs/wells.md); \
                 check that both ends run the same version of the network's commands"
            ),
            DecodeError::Field { what, problem } => write!(f, "{what}: {problem}"),
        }
    }
}

impl std::error::Error for DecodeError {}

fn u24(b: &[u8]) -> u32 {
    (b[0] as u32) << 16 | (b[1] as u32) << 8 | b[2] as u32
}

fn put_u24(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.min(NO_VALUE).to_be_bytes()[1..]);
}

fn u32be(b: &[u8]) -> u32 {
    u32::from_be_bytes([b[0], b[1], b[2], b[3]])
}

/// Status of a command-1 reply from a sensor: all groups acquired normally.
pub const STATUS_NORMAL: u16 = 0x0000;
/// Status of a command-1 reply: acquisition abnormal or incomplete.
pub const STATUS_ABNORMAL: u16 = 0xFFFF;

/// A sensor's command-1 reply: three groups, oldest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Groups {
    /// `0x0000` normal, `0xFFFF` abnormal or incomplete.
    pub status: u16,
    /// Values per group: 1 (temperature sensor) or 2 (level sensor: level, then the
    /// sensor's own temperature).
    pub width: usize,
    /// The groups; `NO_VALUE` where the sensor has none, and in the unused second
    /// value of a one-value group.
    pub groups: [[u32; 2]; 3],
}

impl Groups {
    /// The reply's status bytes and data.
    pub fn encode(&self) -> ([u8; 2], Vec<u8>) {
        let mut d = Vec::with_capacity(3 * 3 * self.width);
        for g in &self.groups {
            for &v in g.iter().take(self.width) {
                put_u24(&mut d, v);
            }
        }
        (self.status.to_be_bytes(), d)
    }

    /// Decodes a command-1 reply: 9 data bytes (3 groups of 1 value) or 18 (3 of 2).
    pub fn decode(status: [u8; 2], data: &[u8]) -> Result<Self, DecodeError> {
        let width = match data.len() {
            9 => 1,
            18 => 2,
            n => {
                return Err(DecodeError::Length {
                    what: "command 1 reply (3 groups of 3 or 6 bytes)",
                    expected: 9,
                    got: n,
                })
            }
        };
        let mut groups = [[NO_VALUE; 2]; 3];
        for (i, g) in groups.iter_mut().enumerate() {
            for (j, v) in g.iter_mut().take(width).enumerate() {
                let at = (i * width + j) * 3;
                *v = u24(&data[at..at + 3]);
            }
        }
        Ok(Groups {
            status: u16::from_be_bytes(status),
            width,
            groups,
        })
    }
}

/// A sensor's self-diagnosis (command 14, second status byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Diagnosis {
    /// Healthy.
    Healthy,
    /// Sensing element fault.
    Element,
    /// Analog-to-digital converter fault.
    Adc,
    /// Power supply or watchdog resets.
    Power,
}

impl Diagnosis {
    /// The code in the second status byte.
    pub fn code(self) -> u8 {
        match self {
            Diagnosis::Healthy => 0,
            Diagnosis::Element => 1,
            Diagnosis::Adc => 2,
            Diagnosis::Power => 3,
        }
    }

    /// The diagnosis of a code.
    pub fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0 => Diagnosis::Healthy,
            1 => Diagnosis::Element,
            2 => Diagnosis::Adc,
            3 => Diagnosis::Power,
            _ => return None,
        })
    }

    /// Words for people.
    pub fn describe(self) -> &'static str {
        match self {
            Diagnosis::Healthy => "healthy",
            Diagnosis::Element => "sensing element fault",
            Diagnosis::Adc => "analog-to-digital converter fault",
            Diagnosis::Power => "power supply or watchdog resets",
        }
    }
}

/// One minute of one well, as stored and as carried by command 144.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Record {
    /// The minute (Unix time / 60) the values are the clipped means of.
    pub minute: u32,
    /// Valid values: bit 0 water temperature, bit 1 level, bit 2 level sensor
    /// temperature.
    pub valid: u8,
    /// Water temperature counts (`NO_VALUE` if not valid).
    pub t_raw: u32,
    /// Level counts.
    pub l_raw: u32,
    /// Level sensor temperature counts.
    pub ls_raw: u32,
    /// Water temperature, °C (NaN if not valid).
    pub temperature: f64,
    /// Water level, m (NaN if not valid).
    pub level: f64,
}

/// `Record::valid` bit: water temperature.
pub const VALID_TEMPERATURE: u8 = 1;
/// `Record::valid` bit: level.
pub const VALID_LEVEL: u8 = 2;
/// `Record::valid` bit: level sensor temperature.
pub const VALID_LEVEL_SENSOR_TEMPERATURE: u8 = 4;

impl Record {
    /// A record with no values.
    pub fn empty(minute: u32) -> Self {
        Record {
            minute,
            valid: 0,
            t_raw: NO_VALUE,
            l_raw: NO_VALUE,
            ls_raw: NO_VALUE,
            temperature: f64::NAN,
            level: f64::NAN,
        }
    }

    /// The 22 bytes of the record.
    pub fn encode(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.minute.to_be_bytes());
        out.push(self.valid);
        put_u24(out, self.t_raw);
        put_u24(out, self.l_raw);
        put_u24(out, self.ls_raw);
        out.extend_from_slice(&(self.temperature as f32).to_be_bytes());
        out.extend_from_slice(&(self.level as f32).to_be_bytes());
    }

    /// Reads a record from 22 bytes. The engineering values come back as the f32
    /// the wire carries.
    pub fn decode(b: &[u8]) -> Result<Self, DecodeError> {
        if b.len() < RECORD_LEN {
            return Err(DecodeError::Length {
                what: "command 144 record",
                expected: RECORD_LEN,
                got: b.len(),
            });
        }
        let valid = b[4];
        if valid & !7 != 0 {
            return Err(DecodeError::Field {
                what: "command 144 record",
                problem: format!("valid flags 0x{valid:02X} use bits 3-7, which are reserved"),
            });
        }
        Ok(Record {
            minute: u32be(&b[0..4]),
            valid,
            t_raw: u24(&b[5..8]),
            l_raw: u24(&b[8..11]),
            ls_raw: u24(&b[11..14]),
            temperature: f32::from_be_bytes([b[14], b[15], b[16], b[17]]) as f64,
            level: f32::from_be_bytes([b[18], b[19], b[20], b[21]]) as f64,
        })
    }

    /// The record as the wire carries it (engineering values rounded to f32).
    pub fn wire_rounded(&self) -> Self {
        Record {
            temperature: self.temperature as f32 as f64,
            level: self.level as f32 as f64,
            ..*self
        }
    }
}

/// A command-144 reply: one batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Batch {
    /// Records remaining after this batch.
    pub remaining: u32,
    /// The records, oldest first (at most [`BATCH_RECORDS`]).
    pub records: Vec<Record>,
}

impl Batch {
    /// Whether more records remain after this batch.
    pub fn more(&self) -> bool {
        self.remaining > 0
    }

    /// The reply data.
    pub fn encode(&self) -> Vec<u8> {
        let n = self.records.len().min(BATCH_RECORDS);
        let mut d = Vec::with_capacity(6 + n * RECORD_LEN);
        d.push(self.more() as u8);
        d.extend_from_slice(&self.remaining.to_be_bytes());
        d.push(n as u8);
        for r in &self.records[..n] {
            r.encode(&mut d);
        }
        d
    }

    /// Decodes the reply data.
    pub fn decode(d: &[u8]) -> Result<Self, DecodeError> {
        const WHAT: &str = "command 144 reply";
        if d.len() < 6 {
            return Err(DecodeError::Length {
                what: WHAT,
                expected: 6,
                got: d.len(),
            });
        }
        let more = d[0] & 1 != 0;
        let remaining = u32be(&d[1..5]);
        let n = d[5] as usize;
        if n > BATCH_RECORDS {
            return Err(DecodeError::Field {
                what: WHAT,
                problem: format!("{n} records in one batch; at most {BATCH_RECORDS} fit"),
            });
        }
        if d.len() != 6 + n * RECORD_LEN {
            return Err(DecodeError::Length {
                what: WHAT,
                expected: 6 + n * RECORD_LEN,
                got: d.len(),
            });
        }
        if more != (remaining > 0) {
            return Err(DecodeError::Field {
                what: WHAT,
                problem: format!(
                    "the more-flag says {more} but {remaining} records remain after the batch"
                ),
            });
        }
        let mut records = Vec::with_capacity(n);
        let mut last = None;
        for i in 0..n {
            let r = Record::decode(&d[6 + i * RECORD_LEN..6 + (i + 1) * RECORD_LEN])?;
            if last.is_some_and(|l| r.minute <= l) {
                return Err(DecodeError::Field {
                    what: WHAT,
                    problem: format!(
                        "record {} (minute {}) is not after the one before it",
                        i + 1,
                        r.minute
                    ),
                });
            }
            last = Some(r.minute);
            records.push(r);
        }
        Ok(Batch { remaining, records })
    }
}

/// A command-144 request: the last minute the requester has stored from the station.
pub fn transfer_request(ack: u32) -> Vec<u8> {
    ack.to_be_bytes().to_vec()
}

/// Decodes a command-144 request.
pub fn decode_transfer_request(d: &[u8]) -> Result<u32, DecodeError> {
    if d.len() < 4 {
        return Err(DecodeError::Length {
            what: "command 144 request",
            expected: 4,
            got: d.len(),
        });
    }
    Ok(u32be(&d[..4]))
}

/// A command-160 request: one calibration segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentRequest {
    /// The sensor the table is for.
    pub sensor: Sensor,
    /// Segment number, 1-10.
    pub number: u8,
    /// The segment.
    pub segment: Segment,
}

/// Bytes of a command-160 request.
pub const SEGMENT_REQUEST_LEN: usize = 35;

impl SegmentRequest {
    /// The request data.
    pub fn encode(&self) -> Vec<u8> {
        let mut d = Vec::with_capacity(SEGMENT_REQUEST_LEN);
        d.push(self.sensor.code());
        d.push(self.number);
        put_u24(&mut d, self.segment.raw_from);
        put_u24(&mut d, self.segment.raw_to);
        for a in [self.segment.a0, self.segment.a1, self.segment.a2] {
            d.extend_from_slice(&a.to_be_bytes());
        }
        d.extend_from_slice(&[0, 0, 0]);
        d
    }

    /// Decodes the request data; the response code to answer on error.
    pub fn decode(d: &[u8]) -> Result<Self, (u8, DecodeError)> {
        const WHAT: &str = "command 160 request";
        if d.len() < SEGMENT_REQUEST_LEN {
            return Err((
                RC_TOO_FEW_BYTES,
                DecodeError::Length {
                    what: WHAT,
                    expected: SEGMENT_REQUEST_LEN,
                    got: d.len(),
                },
            ));
        }
        let Some(sensor) = Sensor::from_code(d[0]) else {
            return Err((
                RC_INVALID_SELECTION,
                DecodeError::Field {
                    what: WHAT,
                    problem: format!("sensor code {} (0 temperature, 1 level)", d[0]),
                },
            ));
        };
        let number = d[1];
        if !(1..=10).contains(&number) {
            return Err((
                RC_INVALID_SELECTION,
                DecodeError::Field {
                    what: WHAT,
                    problem: format!("segment {number} (1-10)"),
                },
            ));
        }
        let f = |at: usize| {
            f64::from_be_bytes([
                d[at],
                d[at + 1],
                d[at + 2],
                d[at + 3],
                d[at + 4],
                d[at + 5],
                d[at + 6],
                d[at + 7],
            ])
        };
        Ok(SegmentRequest {
            sensor,
            number,
            segment: Segment {
                raw_from: u24(&d[2..5]),
                raw_to: u24(&d[5..8]),
                a0: f(8),
                a1: f(16),
                a2: f(24),
            },
        })
    }
}

/// Command-160 reply state: the segment was taken.
pub const SEGMENT_TAKEN: u8 = 0;
/// Command-160 reply state: the table is complete and in force.
pub const TABLE_IN_FORCE: u8 = 1;

/// A command-160 reply: the segment's sensor and number echoed, and what the station
/// did with it ([`SEGMENT_TAKEN`] or [`TABLE_IN_FORCE`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SegmentReply {
    /// The sensor the table is for.
    pub sensor: Sensor,
    /// Segment number, 1-10.
    pub number: u8,
    /// [`SEGMENT_TAKEN`] or [`TABLE_IN_FORCE`].
    pub state: u8,
}

/// Bytes of a command-160 reply.
pub const SEGMENT_REPLY_LEN: usize = 3;

impl SegmentReply {
    /// The reply to `request`, with `state`.
    pub fn to(request: &SegmentRequest, state: u8) -> Self {
        SegmentReply {
            sensor: request.sensor,
            number: request.number,
            state,
        }
    }

    /// The reply data.
    pub fn encode(&self) -> Vec<u8> {
        vec![self.sensor.code(), self.number, self.state]
    }

    /// Decodes the reply data.
    pub fn decode(d: &[u8]) -> Result<Self, DecodeError> {
        const WHAT: &str = "command 160 reply";
        let [code, number, state, ..] = *d else {
            return Err(DecodeError::Length {
                what: WHAT,
                expected: SEGMENT_REPLY_LEN,
                got: d.len(),
            });
        };
        let sensor = Sensor::from_code(code).ok_or_else(|| DecodeError::Field {
            what: WHAT,
            problem: format!("sensor code {code} (0 temperature, 1 level)"),
        })?;
        Ok(SegmentReply {
            sensor,
            number,
            state,
        })
    }
}

/// Puts a table together from command-160 segments: segment 1 starts a table, each
/// next segment must follow, a repeated segment (its reply was lost) is taken again,
/// and the tenth makes the table if it checks out.
#[derive(Debug, Clone, Default)]
pub struct TableAssembler {
    pending: Option<(Sensor, Vec<Segment>)>,
    /// The segment that completed the last table (its reply may have been lost).
    completed: Option<(Sensor, Segment)>,
}

/// What a segment did.
#[derive(Debug, Clone, PartialEq)]
pub enum Assembled {
    /// Taken; more to come.
    Taken,
    /// The table is complete and checks out.
    Table(Sensor, Box<crate::calibration::Table>),
    /// The segment that completed the last table, again (its reply was lost): the
    /// table is already in force.
    AlreadyInForce,
    /// Refused: the response code and why.
    Refused(u8, String),
}

impl TableAssembler {
    /// The table made from the last segment was kept: a repeat of that segment
    /// (its reply lost) is answered *in force*.
    pub fn confirm(&mut self, sensor: Sensor, last: Segment) {
        self.completed = Some((sensor, last));
    }

    /// Takes one segment.
    pub fn take(&mut self, seg: SegmentRequest) -> Assembled {
        if self.pending.is_none()
            && seg.number as usize == crate::calibration::SEGMENTS
            && self.completed == Some((seg.sensor, seg.segment))
        {
            return Assembled::AlreadyInForce;
        }
        if seg.number == 1 {
            self.pending = Some((seg.sensor, vec![]));
            self.completed = None;
        }
        let Some((sensor, segs)) = self.pending.as_mut() else {
            return Assembled::Refused(
                RC_OUT_OF_ORDER,
                format!("segment {} before segment 1", seg.number),
            );
        };
        if *sensor == seg.sensor && segs.len() == seg.number as usize {
            segs.pop();
        }
        if *sensor != seg.sensor || segs.len() + 1 != seg.number as usize {
            return Assembled::Refused(
                RC_OUT_OF_ORDER,
                format!(
                    "segment {} of the {} table where segment {} of the {} table was next",
                    seg.number,
                    seg.sensor.name(),
                    segs.len() + 1,
                    sensor.name()
                ),
            );
        }
        segs.push(seg.segment);
        if segs.len() < crate::calibration::SEGMENTS {
            return Assembled::Taken;
        }
        let Some((sensor, segs)) = self.pending.take() else {
            return Assembled::Taken;
        };
        match crate::calibration::Table::new(segs) {
            Ok(t) => Assembled::Table(sensor, Box::new(t)),
            Err(e) => Assembled::Refused(RC_TABLE_REFUSED, e.to_string()),
        }
    }
}

/// One sensor's line in a concentrator's status (uplink command 14).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorStatus {
    /// Its address on the bus.
    pub address: u8,
    /// What it measures.
    pub kind: Sensor,
    /// Its state: the command-14 code, or [`STATE_NOT_ANSWERING`].
    pub state: u8,
    /// The minute of its last good value (0 never).
    pub last_good: u32,
}

impl SensorStatus {
    /// As JSON, states in words (the PC's report and its status log).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "address": self.address,
            "kind": self.kind.name(),
            "state": state_name(self.state),
            "last_good_minute": self.last_good,
        })
    }
}

/// Sensor state: it does not answer.
pub const STATE_NOT_ANSWERING: u8 = 0x10;

/// A concentrator's status (uplink command 14).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StationStatus {
    /// Summary: 0 all well, 1 a sensor faulty or not answering, 2 the store dropped
    /// minutes not handed over.
    pub summary: u8,
    /// The concentrator's clock, Unix time / 60.
    pub clock: u32,
    /// Minutes stored.
    pub stored: u32,
    /// Minutes not handed over.
    pub unsent: u32,
    /// Store fill, per mille of capacity.
    pub fill_permille: u16,
    /// Minutes dropped before they were handed over.
    pub dropped_unsent: u32,
    /// The sensors.
    pub sensors: Vec<SensorStatus>,
}

impl StationStatus {
    /// The reply's status bytes and data.
    pub fn encode(&self) -> ([u8; 2], Vec<u8>) {
        let mut d = Vec::with_capacity(19 + 7 * self.sensors.len());
        d.extend_from_slice(&self.clock.to_be_bytes());
        d.extend_from_slice(&self.stored.to_be_bytes());
        d.extend_from_slice(&self.unsent.to_be_bytes());
        d.extend_from_slice(&self.fill_permille.to_be_bytes());
        d.extend_from_slice(&self.dropped_unsent.to_be_bytes());
        let k = self.sensors.len().min(15);
        d.push(k as u8);
        for s in &self.sensors[..k] {
            d.push(s.address);
            d.push(s.kind.code());
            d.push(s.state);
            d.extend_from_slice(&s.last_good.to_be_bytes());
        }
        ([DIAGNOSTICS, self.summary], d)
    }

    /// Decodes the reply.
    pub fn decode(status: [u8; 2], d: &[u8]) -> Result<Self, DecodeError> {
        const WHAT: &str = "concentrator status (command 14)";
        if d.len() < 19 {
            return Err(DecodeError::Length {
                what: WHAT,
                expected: 19,
                got: d.len(),
            });
        }
        let k = d[18] as usize;
        if d.len() != 19 + 7 * k {
            return Err(DecodeError::Length {
                what: WHAT,
                expected: 19 + 7 * k,
                got: d.len(),
            });
        }
        let mut sensors = Vec::with_capacity(k);
        for i in 0..k {
            let s = &d[19 + 7 * i..26 + 7 * i];
            let Some(kind) = Sensor::from_code(s[1]) else {
                return Err(DecodeError::Field {
                    what: WHAT,
                    problem: format!("sensor kind {} (0 temperature, 1 level)", s[1]),
                });
            };
            sensors.push(SensorStatus {
                address: s[0],
                kind,
                state: s[2],
                last_good: u32be(&s[3..7]),
            });
        }
        Ok(StationStatus {
            summary: status[1],
            clock: u32be(&d[0..4]),
            stored: u32be(&d[4..8]),
            unsent: u32be(&d[8..12]),
            fill_permille: u16::from_be_bytes([d[12], d[13]]),
            dropped_unsent: u32be(&d[14..18]),
            sensors,
        })
    }
}

/// Words for a sensor state code.
pub fn state_name(state: u8) -> &'static str {
    if state == STATE_NOT_ANSWERING {
        return "not answering";
    }
    Diagnosis::from_code(state).map_or("unknown state", Diagnosis::describe)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    /// The published design's example: the concentrator asks the temperature sensor
    /// at address 1 for data.
    #[test]
    fn published_request() {
        let m = Message::request(Station::sensor(1), READ_VALUES, vec![]);
        assert_eq!(m.to_bytes(), hex("FF FF 02 01 01 00 02"));
        let got = Receiver::new().feed(&hex("FF FF 02 01 01 00 02"));
        assert_eq!(got, vec![Received::Message(m)]);
    }

    /// The published reply shapes: byte count 0x0B for the temperature sensor, 0x14 for
    /// the level sensor at address 2.
    #[test]
    fn published_reply_shapes() {
        let t = Groups {
            status: 0,
            width: 1,
            groups: [
                [0x7AE148, NO_VALUE],
                [0x7AE14B, NO_VALUE],
                [0x7AE14D, NO_VALUE],
            ],
        };
        let (s, d) = t.encode();
        let bytes = Message::reply(Station::sensor(1), 1, s, d).to_bytes();
        assert_eq!(&bytes[..8], &hex("FF FF 06 01 01 0B 00 00")[..]);
        assert_eq!(bytes.len(), 8 + 9 + 1);
        let l = Groups {
            status: 0,
            width: 2,
            groups: [[1, 2], [3, 4], [5, 6]],
        };
        let (s, d) = l.encode();
        let bytes = Message::reply(Station::sensor(2), 1, s, d).to_bytes();
        assert_eq!(&bytes[..8], &hex("FF FF 06 02 01 14 00 00")[..]);
        let Received::Message(m) = Receiver::new().feed(&bytes).remove(0) else {
            panic!()
        };
        assert_eq!(Groups::decode(m.status.unwrap(), &m.data).unwrap(), l);
    }

    /// The example reply in docs/wells.md, decoded: 15.200, 15.201, 15.201 °C.
    #[test]
    fn the_documented_reply_decodes() {
        let bytes = hex("FF FF 06 01 01 0B 00 00 82 0C A9 82 0D B5 82 0D 2F B0");
        let Received::Message(m) = Receiver::new().feed(&bytes).remove(0) else {
            panic!("the example does not parse")
        };
        let g = Groups::decode(m.status.unwrap(), &m.data).unwrap();
        let t = crate::calibration::Table::builtin(Sensor::Temperature);
        let c: Vec<f64> = g.groups.iter().map(|v| t.eval(v[0])).collect();
        for (got, want) in c.iter().zip([15.2003, 15.2011, 15.2007]) {
            assert!((got - want).abs() < 1e-5, "{c:?}");
        }
    }

    /// The tenth segment again after its reply was lost: in force, but only once the
    /// table was kept.
    #[test]
    fn segment_ten_repeated() {
        use crate::calibration::Table;
        let t = Table::builtin(Sensor::Level);
        let mut a = TableAssembler::default();
        let seg = |i: usize| SegmentRequest {
            sensor: Sensor::Level,
            number: i as u8 + 1,
            segment: t.segments()[i],
        };
        for i in 0..9 {
            assert_eq!(a.take(seg(i)), Assembled::Taken);
        }
        assert!(matches!(a.take(seg(9)), Assembled::Table(Sensor::Level, _)));
        // Not kept (the store failed): a repeat is out of order, not "in force".
        assert!(matches!(
            a.take(seg(9)),
            Assembled::Refused(RC_OUT_OF_ORDER, _)
        ));
        for i in 0..9 {
            a.take(seg(i));
        }
        assert!(matches!(a.take(seg(9)), Assembled::Table(..)));
        a.confirm(Sensor::Level, t.segments()[9]);
        assert_eq!(a.take(seg(9)), Assembled::AlreadyInForce);
    }

    /// A frame with a wrong check byte or a parity error is reported damaged (and so
    /// never answered: its address cannot be trusted).
    #[test]
    fn damaged_frames_are_reported_not_delivered() {
        let mut bytes = hex("FF FF 02 01 01 00 02");
        bytes[6] ^= 0x10;
        let got = Receiver::new().feed(&bytes);
        assert!(
            matches!(got[..], [Received::Damaged { errors }] if errors & 0x08 != 0),
            "{got:?}"
        );
        let chars: Vec<(u8, UartFlags)> = hex("FF FF 02 01 01 00 02")
            .into_iter()
            .enumerate()
            .map(|(i, b)| {
                let mut f = UartFlags::OK;
                f.parity = i == 4;
                (b, f)
            })
            .collect();
        let got = Receiver::new().push(&chars);
        assert!(
            matches!(got[..], [Received::Damaged { errors }] if errors & 0x40 != 0),
            "{got:?}"
        );
    }

    #[test]
    fn addresses_round_trip_through_hart_proto() {
        for b in 0..=255u8 {
            let s = Station(b);
            assert_eq!(Station::from_address(&s.to_address()), Some(s));
        }
        assert_eq!(Station::concentrator(3).0, 0x83);
        assert_eq!(Station::handheld(3).0, 0xC3);
        assert_eq!(Station::handheld(3).role(), Role::Handheld);
    }

    #[test]
    fn batch_round_trip_and_limits() {
        let recs: Vec<Record> = (0..11)
            .map(|i| Record {
                minute: 29_000_000 + i,
                valid: 7,
                t_raw: 8_000_000 + i,
                l_raw: 4_000_000,
                ls_raw: 3_000_000,
                temperature: 15.25,
                level: 10.5,
            })
            .collect();
        let b = Batch {
            remaining: 4,
            records: recs,
        };
        let d = b.encode();
        assert_eq!(d.len(), 6 + 11 * 22);
        assert!(d.len() <= 253);
        assert_eq!(Batch::decode(&d).unwrap(), b);
        // Truncated, too many, out of order: typed errors.
        assert!(Batch::decode(&d[..d.len() - 1]).is_err());
        let mut bad = d.clone();
        bad[5] = 12;
        assert!(Batch::decode(&bad).is_err());
        let mut bad = d.clone();
        bad[6..10].copy_from_slice(&u32::MAX.to_be_bytes());
        assert!(Batch::decode(&bad).is_err());
    }

    #[test]
    fn decoders_never_panic_on_short_input() {
        for n in 0..40 {
            let d = vec![0xA5; n];
            let _ = Batch::decode(&d);
            let _ = Groups::decode([0, 0], &d);
            let _ = SegmentRequest::decode(&d);
            let _ = StationStatus::decode([14, 0], &d);
            let _ = decode_transfer_request(&d);
            let _ = Record::decode(&d);
        }
    }

    proptest::proptest! {
        #[test]
        fn receiver_and_decoders_take_any_bytes(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..600)) {
            for r in Receiver::new().feed(&bytes) {
                if let Received::Message(m) = r {
                    let _ = Batch::decode(&m.data);
                    let _ = Groups::decode(m.status.unwrap_or([0, 0]), &m.data);
                    let _ = SegmentRequest::decode(&m.data);
                    let _ = StationStatus::decode([14, 0], &m.data);
                }
            }
        }
    }
}
