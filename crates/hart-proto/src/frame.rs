//! The HART token-passing frame (PDU).
//!
//! ```text
//! [FF × n] delimiter address(1|5) expansion(0..3) command byte_count
//!          [response_code device_status]   (ACK/BACK only, counted in byte_count)
//!          [extended command, 2 bytes]      (command byte 31 only, counted in byte_count)
//!          data check_byte [trailing...]
//! ```
//!
//! [`Frame::parse`] is a zero-copy view over received bytes; [`FrameSpec::encode`] builds
//! frames into a caller-provided buffer. Neither allocates or panics.

use core::fmt;

use crate::tables::comm_error;
use crate::wire::EncodeError;

/// Longest frame without preambles: delimiter, 5 address bytes, 3 expansion bytes,
/// command, byte count, 255 bytes, check byte.
pub const MAX_PDU_LEN: usize = 1 + 5 + 3 + 1 + 1 + 255 + 1;

/// Most preambles [`FrameSpec::encode`] writes: far more than any device needs (HART
/// asks 5 to 20), few enough that a frame always fits a small buffer.
pub const MAX_PREAMBLES: usize = 255;

/// Preamble byte.
pub const PREAMBLE: u8 = 0xFF;

/// Preambles a sender uses unless told otherwise.
pub const DEFAULT_PREAMBLES: usize = 5;

/// Fewest preambles a receiver needs to recognise a start of message on a serial line.
pub const MIN_RX_PREAMBLES: usize = 2;

/// The command byte that announces a 16-bit extended command number.
pub const EXTENDED_COMMAND: u8 = 31;

/// Frame type, delimiter bits 2–0.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameType {
    /// Master to slave request (2).
    Stx,
    /// Slave to master reply (6).
    Ack,
    /// Burst frame, unsolicited slave publication (1).
    Back,
}

impl FrameType {
    /// The delimiter bits 2–0.
    pub fn bits(self) -> u8 {
        match self {
            FrameType::Back => 1,
            FrameType::Stx => 2,
            FrameType::Ack => 6,
        }
    }

    /// From delimiter bits 2–0.
    pub fn from_bits(b: u8) -> Option<Self> {
        match b & 7 {
            1 => Some(FrameType::Back),
            2 => Some(FrameType::Stx),
            6 => Some(FrameType::Ack),
            _ => None,
        }
    }

    /// `"STX"`, `"ACK"` or `"BACK"`.
    pub fn name(self) -> &'static str {
        match self {
            FrameType::Stx => "STX",
            FrameType::Ack => "ACK",
            FrameType::Back => "BACK",
        }
    }

    /// True for ACK and BACK, which carry the two status bytes.
    pub fn has_status(self) -> bool {
        self != FrameType::Stx
    }
}

/// The delimiter (start byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Delimiter {
    /// Frame type (bits 2–0).
    pub frame_type: FrameType,
    /// Long (unique, 5-byte) address when set (bit 7).
    pub long_address: bool,
    /// Number of expansion bytes, 0..=3 (bits 6–5).
    pub expansion_len: u8,
    /// Physical layer type (bits 4–3): 0 asynchronous (FSK, RS-485), 1 synchronous (PSK).
    pub physical_layer: u8,
}

impl Delimiter {
    /// Decodes a delimiter byte; `None` when the frame type bits are not 1, 2 or 6.
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(Delimiter {
            frame_type: FrameType::from_bits(b)?,
            long_address: b & 0x80 != 0,
            expansion_len: (b >> 5) & 3,
            physical_layer: (b >> 3) & 3,
        })
    }

    /// Encodes the delimiter byte.
    pub fn to_byte(self) -> u8 {
        (u8::from(self.long_address) << 7)
            | ((self.expansion_len & 3) << 5)
            | ((self.physical_layer & 3) << 3)
            | self.frame_type.bits()
    }

    /// Length of the address field (1 or 5).
    pub fn address_len(self) -> usize {
        if self.long_address {
            5
        } else {
            1
        }
    }
}

/// Which master a frame comes from or is addressed to (address bit 7).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum MasterKind {
    /// Primary master (bit set), e.g. the control system.
    #[default]
    Primary,
    /// Secondary master (bit clear), e.g. a handheld.
    Secondary,
}

impl MasterKind {
    /// `"primary"` or `"secondary"`.
    pub fn name(self) -> &'static str {
        match self {
            MasterKind::Primary => "primary",
            MasterKind::Secondary => "secondary",
        }
    }

    /// The other master.
    pub fn other(self) -> Self {
        match self {
            MasterKind::Primary => MasterKind::Secondary,
            MasterKind::Secondary => MasterKind::Primary,
        }
    }

    fn bit(self) -> u8 {
        match self {
            MasterKind::Primary => 0x80,
            MasterKind::Secondary => 0,
        }
    }

    fn from_byte(b: u8) -> Self {
        if b & 0x80 != 0 {
            MasterKind::Primary
        } else {
            MasterKind::Secondary
        }
    }
}

/// Short (polling) address: one byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct ShortAddress {
    /// Master bit.
    pub master: MasterKind,
    /// Burst-mode bit (set by a slave in burst mode).
    pub burst: bool,
    /// Polling address, 0..=63 (HART 5: 0..=15).
    pub polling_address: u8,
}

/// The 38-bit unique identifier of a long address: 14-bit (expanded) device type and
/// 24-bit device ID.
///
/// For HART 5/6 devices the device-type field is the manufacturer ID (6 bits kept) and
/// the manufacturer's device type; for HART 7 it is the expanded device type masked to
/// 14 bits. Both read the same bits, see [`UniqueId::manufacturer_id`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct UniqueId {
    /// Expanded device type, 14 bits.
    pub expanded_device_type: u16,
    /// Device ID, 24 bits.
    pub device_id: u32,
}

impl UniqueId {
    /// The broadcast identifier (all 38 bits zero).
    pub const BROADCAST: UniqueId = UniqueId {
        expanded_device_type: 0,
        device_id: 0,
    };

    /// Builds an identifier; extra high bits are masked off (14 and 24 bits kept).
    pub fn new(expanded_device_type: u16, device_id: u32) -> Self {
        UniqueId {
            expanded_device_type: expanded_device_type & 0x3FFF,
            device_id: device_id & 0x00FF_FFFF,
        }
    }

    /// From HART 5/6 identity fields: manufacturer ID (low 6 bits used) and device type.
    pub fn from_manufacturer(manufacturer_id: u8, device_type: u8, device_id: u32) -> Self {
        Self::new(
            u16::from(manufacturer_id & 0x3F) << 8 | u16::from(device_type),
            device_id,
        )
    }

    /// From the 5 address bytes; the master and burst bits of the first byte are ignored.
    pub fn from_bytes(b: [u8; 5]) -> Self {
        UniqueId {
            expanded_device_type: u16::from(b[0] & 0x3F) << 8 | u16::from(b[1]),
            device_id: u32::from_be_bytes([0, b[2], b[3], b[4]]),
        }
    }

    /// The 5 address bytes with master and burst bits clear.
    pub fn to_bytes(self) -> [u8; 5] {
        let d = self.device_id.to_be_bytes();
        [
            (self.expanded_device_type >> 8) as u8 & 0x3F,
            self.expanded_device_type as u8,
            d[1],
            d[2],
            d[3],
        ]
    }

    /// The low 6 bits of the manufacturer ID (HART 5/6 reading of the first byte).
    pub fn manufacturer_id(self) -> u8 {
        (self.expanded_device_type >> 8) as u8 & 0x3F
    }

    /// The manufacturer's device type (HART 5/6 reading of the second byte).
    pub fn device_type(self) -> u8 {
        self.expanded_device_type as u8
    }

    /// True for the broadcast address.
    pub fn is_broadcast(self) -> bool {
        self == Self::BROADCAST
    }

    /// Parses 10 hex digits (spaces, colons allowed), e.g. `"264E0000D2"`.
    pub fn parse_hex(s: &str) -> Result<Self, &'static str> {
        let mut b = [0u8; 5];
        let mut n = 0;
        let mut hi: Option<u8> = None;
        for c in s.chars() {
            if c == ' ' || c == ':' || c == '-' {
                continue;
            }
            let v = c
                .to_digit(16)
                .ok_or("unique ID must be 10 hexadecimal digits")? as u8;
            match hi.take() {
                None => hi = Some(v),
                Some(h) => {
                    if n == 5 {
                        return Err("unique ID must be 10 hexadecimal digits (got more)");
                    }
                    b[n] = h << 4 | v;
                    n += 1;
                }
            }
        }
        if n != 5 || hi.is_some() {
            return Err("unique ID must be 10 hexadecimal digits");
        }
        if b[0] & 0xC0 != 0 {
            return Err("unique ID has only 38 bits: the first byte must be 00..3F");
        }
        Ok(Self::from_bytes(b))
    }
}

impl fmt::Display for UniqueId {
    /// 10 upper-case hex digits.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for b in self.to_bytes() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// Long (unique) address: five bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct LongAddress {
    /// Master bit.
    pub master: MasterKind,
    /// Burst-mode bit.
    pub burst: bool,
    /// The 38-bit identifier.
    pub id: UniqueId,
}

/// A frame address.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Address {
    /// One-byte polling address.
    Short(ShortAddress),
    /// Five-byte unique address.
    Long(LongAddress),
}

impl Address {
    /// Short address `polling_address` from the primary master.
    pub fn short(polling_address: u8) -> Self {
        Address::Short(ShortAddress {
            master: MasterKind::Primary,
            burst: false,
            polling_address: polling_address & 0x3F,
        })
    }

    /// Long address of `id` from the primary master.
    pub fn long(id: UniqueId) -> Self {
        Address::Long(LongAddress {
            master: MasterKind::Primary,
            burst: false,
            id,
        })
    }

    /// The master bit.
    pub fn master(&self) -> MasterKind {
        match self {
            Address::Short(a) => a.master,
            Address::Long(a) => a.master,
        }
    }

    /// The burst-mode bit.
    pub fn burst(&self) -> bool {
        match self {
            Address::Short(a) => a.burst,
            Address::Long(a) => a.burst,
        }
    }

    /// Returns the address with the master bit replaced.
    pub fn with_master(mut self, m: MasterKind) -> Self {
        match &mut self {
            Address::Short(a) => a.master = m,
            Address::Long(a) => a.master = m,
        }
        self
    }

    /// Returns the address with the burst bit replaced.
    pub fn with_burst(mut self, burst: bool) -> Self {
        match &mut self {
            Address::Short(a) => a.burst = burst,
            Address::Long(a) => a.burst = burst,
        }
        self
    }

    /// True for the long broadcast address.
    pub fn is_broadcast(&self) -> bool {
        matches!(self, Address::Long(a) if a.id.is_broadcast())
    }

    /// Length on the wire.
    pub fn len(&self) -> usize {
        match self {
            Address::Short(_) => 1,
            Address::Long(_) => 5,
        }
    }

    /// Never true; present for API symmetry with `len`.
    pub fn is_empty(&self) -> bool {
        false
    }

    fn write(&self, out: &mut [u8]) -> usize {
        match self {
            Address::Short(a) => {
                out[0] = a.master.bit() | (u8::from(a.burst) << 6) | (a.polling_address & 0x3F);
                1
            }
            Address::Long(a) => {
                let mut b = a.id.to_bytes();
                b[0] |= a.master.bit() | (u8::from(a.burst) << 6);
                out[..5].copy_from_slice(&b);
                5
            }
        }
    }

    /// Reads an address from `b` (at least 1 or 5 bytes, as `long` says).
    pub(crate) fn read(long: bool, b: &[u8]) -> Self {
        let master = MasterKind::from_byte(b[0]);
        let burst = b[0] & 0x40 != 0;
        if long {
            Address::Long(LongAddress {
                master,
                burst,
                id: UniqueId::from_bytes([b[0], b[1], b[2], b[3], b[4]]),
            })
        } else {
            Address::Short(ShortAddress {
                master,
                burst,
                polling_address: b[0] & 0x3F,
            })
        }
    }
}

impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Address::Short(a) => write!(f, "polling address {}", a.polling_address)?,
            Address::Long(a) if a.id.is_broadcast() => f.write_str("broadcast")?,
            Address::Long(a) => write!(f, "unique ID {}", a.id)?,
        }
        write!(
            f,
            " ({} master{})",
            self.master().name(),
            if self.burst() { ", burst" } else { "" }
        )
    }
}

/// Why bytes are not a frame. Offsets count from the first byte given to the parser
/// (preambles included).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// Nothing to parse.
    Empty,
    /// Only preamble bytes.
    NoDelimiter {
        /// Number of preamble bytes seen.
        preambles: usize,
    },
    /// Exactly one preamble byte: a serial receiver needs at least two, a bare PDU none.
    TooFewPreambles {
        /// Offset of the delimiter.
        offset: usize,
    },
    /// The delimiter's frame-type bits are not STX (2), ACK (6) or BACK (1).
    InvalidDelimiter {
        /// Offset of the delimiter.
        offset: usize,
        /// The byte found.
        value: u8,
    },
    /// The bytes end before the frame does.
    Truncated {
        /// Offset where the missing field starts.
        offset: usize,
        /// The field that is incomplete.
        field: &'static str,
        /// Bytes the frame needs from `offset`.
        expected: usize,
        /// Bytes present from `offset`.
        available: usize,
    },
    /// The byte count is too small for the frame type or command.
    ByteCountTooSmall {
        /// Offset of the byte count.
        offset: usize,
        /// The byte count.
        byte_count: u8,
        /// The smallest acceptable byte count.
        minimum: u8,
        /// Why it must be that large.
        reason: &'static str,
    },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FrameError::Empty => f.write_str("no bytes to decode"),
            FrameError::NoDelimiter { preambles } => {
                write!(f, "truncated: {preambles} preamble byte(s) but no delimiter")
            }
            FrameError::TooFewPreambles { offset } => write!(
                f,
                "preamble at byte 0: only 1 preamble byte before the delimiter at byte {offset}; a receiver needs at least 2 (or none for a bare PDU)"
            ),
            FrameError::InvalidDelimiter { offset, value } => write!(
                f,
                "delimiter at byte {offset}: 0x{value:02X} is not a valid start byte (frame type bits {} must be 2 STX, 6 ACK or 1 BACK)",
                value & 7
            ),
            FrameError::Truncated { offset, field, expected, available } => write!(
                f,
                "truncated: {field} at byte {offset} needs {expected} byte(s), only {available} present"
            ),
            FrameError::ByteCountTooSmall { offset, byte_count, minimum, reason } => write!(
                f,
                "byte count at byte {offset}: {byte_count} is less than {minimum} ({reason})"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for FrameError {}

/// A parsed frame: a view over the received bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Number of preamble bytes before the delimiter.
    pub preambles: usize,
    /// The delimiter byte as received.
    pub delimiter_byte: u8,
    /// The decoded delimiter.
    pub delimiter: Delimiter,
    /// The address.
    pub address: Address,
    /// Expansion bytes (usually none).
    pub expansion: &'a [u8],
    /// The command byte as sent (31 for extended commands).
    pub command_byte: u8,
    /// The command number: the command byte, or for command byte 31 the 16-bit number
    /// from the first two data bytes.
    pub command: u16,
    /// True when the command number came from a command-31 expansion.
    pub extended: bool,
    /// The byte count as received.
    pub byte_count: u8,
    /// Response code (first status byte), ACK/BACK only.
    pub response_code: Option<u8>,
    /// Field device status (second status byte), ACK/BACK only.
    pub device_status: Option<u8>,
    /// Data after the status bytes and after any extended command number.
    pub data: &'a [u8],
    /// The check byte as received.
    pub check_byte: u8,
    /// The check byte the frame should have (XOR of delimiter through last data byte).
    pub expected_check_byte: u8,
    /// The frame from the delimiter through the check byte (no preambles, no trailing).
    pub pdu: &'a [u8],
    /// Bytes after the check byte.
    pub trailing: &'a [u8],
}

/// XOR of `bytes`: the HART longitudinal parity.
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |a, b| a ^ b)
}

impl<'a> Frame<'a> {
    /// Parses one frame from `bytes`: any number of preambles except exactly one (zero is
    /// a bare PDU as carried by HART-IP), then the frame; bytes after the check byte are
    /// kept in [`Frame::trailing`]. A wrong check byte is reported by
    /// [`Frame::checksum_ok`], not as an error, so damaged frames can still be shown.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, FrameError> {
        if bytes.is_empty() {
            return Err(FrameError::Empty);
        }
        let preambles = bytes.iter().take_while(|&&b| b == PREAMBLE).count();
        if preambles == bytes.len() {
            return Err(FrameError::NoDelimiter { preambles });
        }
        if preambles == 1 {
            return Err(FrameError::TooFewPreambles { offset: 1 });
        }
        let mut f = Self::parse_pdu(&bytes[preambles..]).map_err(|e| e.shifted(preambles))?;
        f.preambles = preambles;
        Ok(f)
    }

    /// Parses a frame that starts at the delimiter (no preambles).
    pub fn parse_pdu(bytes: &'a [u8]) -> Result<Self, FrameError> {
        let need = |offset: usize, field: &'static str, expected: usize| {
            let available = bytes.len().saturating_sub(offset);
            if available < expected {
                Err(FrameError::Truncated {
                    offset,
                    field,
                    expected,
                    available,
                })
            } else {
                Ok(())
            }
        };
        need(0, "delimiter", 1)?;
        let delimiter_byte = bytes[0];
        let delimiter =
            Delimiter::from_byte(delimiter_byte).ok_or(FrameError::InvalidDelimiter {
                offset: 0,
                value: delimiter_byte,
            })?;
        let alen = delimiter.address_len();
        need(1, "address", alen)?;
        let address = Address::read(delimiter.long_address, &bytes[1..1 + alen]);
        let mut pos = 1 + alen;
        let elen = usize::from(delimiter.expansion_len);
        need(pos, "expansion bytes", elen)?;
        let expansion = &bytes[pos..pos + elen];
        pos += elen;
        need(pos, "command", 1)?;
        let command_byte = bytes[pos];
        pos += 1;
        need(pos, "byte count", 1)?;
        let bc_offset = pos;
        let byte_count = bytes[pos];
        pos += 1;
        let body_len = usize::from(byte_count);
        need(pos, "data (byte count)", body_len)?;
        let body = &bytes[pos..pos + body_len];
        need(pos + body_len, "check byte", 1)?;
        let check_byte = bytes[pos + body_len];
        let pdu = &bytes[..pos + body_len + 1];
        let trailing = &bytes[pos + body_len + 1..];

        let (response_code, device_status, rest) = if delimiter.frame_type.has_status() {
            if body.len() < 2 {
                return Err(FrameError::ByteCountTooSmall {
                    offset: bc_offset,
                    byte_count,
                    minimum: 2,
                    reason: "an ACK or BACK carries the response code and device status",
                });
            }
            (Some(body[0]), Some(body[1]), &body[2..])
        } else {
            (None, None, body)
        };

        let (command, extended, data) = if command_byte == EXTENDED_COMMAND {
            match rest.len() {
                n if n >= 2 => (u16::from_be_bytes([rest[0], rest[1]]), true, &rest[2..]),
                // A reply to a command-31 request that was too short to carry the number
                // (response code 5) or a communication-error reply: status only.
                0 if delimiter.frame_type.has_status() => (31, false, rest),
                _ => {
                    let minimum = if delimiter.frame_type.has_status() {
                        4
                    } else {
                        2
                    };
                    return Err(FrameError::ByteCountTooSmall {
                        offset: bc_offset,
                        byte_count,
                        minimum,
                        reason: "command 31 carries a 16-bit extended command number",
                    });
                }
            }
        } else {
            (u16::from(command_byte), false, rest)
        };

        Ok(Frame {
            preambles: 0,
            delimiter_byte,
            delimiter,
            address,
            expansion,
            command_byte,
            command,
            extended,
            byte_count,
            response_code,
            device_status,
            data,
            check_byte,
            expected_check_byte: checksum(&pdu[..pdu.len() - 1]),
            pdu,
            trailing,
        })
    }

    /// The frame type.
    pub fn frame_type(&self) -> FrameType {
        self.delimiter.frame_type
    }

    /// True when the check byte matches.
    pub fn checksum_ok(&self) -> bool {
        self.check_byte == self.expected_check_byte
    }

    /// True for an ACK/BACK whose first status byte is a communication-error summary.
    pub fn is_communication_error(&self) -> bool {
        self.response_code
            .is_some_and(|rc| rc & comm_error::FLAG != 0)
    }

    /// Offset of the data within [`Frame::pdu`].
    pub fn data_offset(&self) -> usize {
        self.pdu.len() - 1 - self.data.len()
    }
}

impl FrameError {
    fn shifted(self, by: usize) -> Self {
        match self {
            FrameError::TooFewPreambles { offset } => FrameError::TooFewPreambles {
                offset: offset + by,
            },
            FrameError::InvalidDelimiter { offset, value } => FrameError::InvalidDelimiter {
                offset: offset + by,
                value,
            },
            FrameError::Truncated {
                offset,
                field,
                expected,
                available,
            } => FrameError::Truncated {
                offset: offset + by,
                field,
                expected,
                available,
            },
            FrameError::ByteCountTooSmall {
                offset,
                byte_count,
                minimum,
                reason,
            } => FrameError::ByteCountTooSmall {
                offset: offset + by,
                byte_count,
                minimum,
                reason,
            },
            e => e,
        }
    }
}

/// Everything needed to build a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSpec<'a> {
    /// Number of preamble bytes (default 5; 0 for a bare PDU).
    pub preambles: usize,
    /// Frame type.
    pub frame_type: FrameType,
    /// Address (its length selects the delimiter's address type).
    pub address: Address,
    /// Expansion bytes, at most 3.
    pub expansion: &'a [u8],
    /// Physical layer bits of the delimiter (0 asynchronous).
    pub physical_layer: u8,
    /// Command number. Numbers above 255 are sent as command 31 with the number in the
    /// first two data bytes; so is any number when `extended` is set.
    pub command: u16,
    /// Force the command-31 expansion for a number below 256.
    pub extended: bool,
    /// Response code and device status for ACK/BACK (ignored for STX; `(0, 0)` if `None`).
    pub status: Option<(u8, u8)>,
    /// Data bytes (after the status bytes and any extended command number).
    pub data: &'a [u8],
}

impl<'a> FrameSpec<'a> {
    /// A request (STX) with default preambles.
    pub fn request(address: Address, command: u16, data: &'a [u8]) -> Self {
        FrameSpec {
            preambles: DEFAULT_PREAMBLES,
            frame_type: FrameType::Stx,
            address,
            expansion: &[],
            physical_layer: 0,
            command,
            extended: false,
            status: None,
            data,
        }
    }

    /// A reply (ACK) with default preambles.
    pub fn reply(
        address: Address,
        command: u16,
        response_code: u8,
        device_status: u8,
        data: &'a [u8],
    ) -> Self {
        FrameSpec {
            frame_type: FrameType::Ack,
            status: Some((response_code, device_status)),
            ..Self::request(address, command, data)
        }
    }

    /// Bytes [`FrameSpec::encode`] writes.
    pub fn encoded_len(&self) -> usize {
        // Saturating: a caller's absurd preamble count gives a length no buffer has
        // (encode then refuses it), never an overflow.
        self.preambles
            .saturating_add(1 + self.address.len() + 2 + 1)
            .saturating_add(self.expansion.len())
            .saturating_add(self.body_len())
    }

    fn is_extended(&self) -> bool {
        self.extended || self.command > 255
    }

    fn body_len(&self) -> usize {
        (usize::from(self.frame_type.has_status()) * 2 + usize::from(self.is_extended()) * 2)
            .saturating_add(self.data.len())
    }

    /// Writes the frame into `out`, returning its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        if self.preambles > MAX_PREAMBLES {
            return Err(EncodeError::Invalid("at most 255 preambles"));
        }
        if self.expansion.len() > 3 {
            return Err(EncodeError::Invalid("at most 3 expansion bytes"));
        }
        let body_len = self.body_len();
        let byte_count = u8::try_from(body_len).map_err(|_| {
            EncodeError::Invalid(
                "data too long: the byte count (status, extended command and data) is at most 255",
            )
        })?;
        if let Address::Short(a) = self.address {
            if a.polling_address > 63 {
                return Err(EncodeError::Invalid("polling address must be 0..=63"));
            }
        }
        let total = self.encoded_len();
        if out.len() < total {
            return Err(EncodeError::BufferTooSmall {
                needed: total,
                capacity: out.len(),
            });
        }
        out[..self.preambles].fill(PREAMBLE);
        let start = self.preambles;
        let mut p = start;
        let delimiter = Delimiter {
            frame_type: self.frame_type,
            long_address: matches!(self.address, Address::Long(_)),
            expansion_len: self.expansion.len() as u8,
            physical_layer: self.physical_layer & 3,
        };
        out[p] = delimiter.to_byte();
        p += 1;
        p += self.address.write(&mut out[p..]);
        out[p..p + self.expansion.len()].copy_from_slice(self.expansion);
        p += self.expansion.len();
        out[p] = if self.is_extended() {
            EXTENDED_COMMAND
        } else {
            self.command as u8
        };
        out[p + 1] = byte_count;
        p += 2;
        if self.frame_type.has_status() {
            let (rc, ds) = self.status.unwrap_or((0, 0));
            out[p] = rc;
            out[p + 1] = ds;
            p += 2;
        }
        if self.is_extended() {
            out[p..p + 2].copy_from_slice(&self.command.to_be_bytes());
            p += 2;
        }
        out[p..p + self.data.len()].copy_from_slice(self.data);
        p += self.data.len();
        out[p] = checksum(&out[start..p]);
        Ok(p + 1)
    }
}

/// An owned frame buffer (preambles excluded) that needs no allocator.
#[derive(Clone)]
pub struct FrameBuf {
    buf: [u8; MAX_PDU_LEN],
    len: usize,
}

impl FrameBuf {
    /// Encodes `spec` without its preambles.
    pub fn encode(spec: &FrameSpec<'_>) -> Result<Self, EncodeError> {
        let mut fb = FrameBuf {
            buf: [0; MAX_PDU_LEN],
            len: 0,
        };
        fb.len = FrameSpec {
            preambles: 0,
            ..*spec
        }
        .encode(&mut fb.buf)?;
        Ok(fb)
    }

    /// Copies a PDU (delimiter through check byte).
    pub fn from_pdu(pdu: &[u8]) -> Option<Self> {
        let mut fb = FrameBuf {
            buf: [0; MAX_PDU_LEN],
            len: pdu.len(),
        };
        fb.buf.get_mut(..pdu.len())?.copy_from_slice(pdu);
        Some(fb)
    }

    /// The PDU bytes.
    pub fn as_slice(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    /// Parses the stored PDU.
    pub fn frame(&self) -> Result<Frame<'_>, FrameError> {
        Frame::parse_pdu(self.as_slice())
    }

    /// The PDU bytes, copied.
    #[cfg(feature = "std")]
    pub fn to_vec(&self) -> std::vec::Vec<u8> {
        self.as_slice().to_vec()
    }
}

impl fmt::Debug for FrameBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for b in self.as_slice() {
            write!(f, "{b:02X} ")?;
        }
        Ok(())
    }
}
