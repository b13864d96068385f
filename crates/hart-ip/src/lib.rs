//! # hart-ip
//!
//! The HART-IP message codec: an 8-byte header (version, message type, message ID,
//! status, sequence number, byte count including the header) and the bodies of session
//! initiate, session close, keep-alive, token-passing PDU, direct PDU and read audit
//! log. `no_std`, no allocation, and no panic on any input: every decoder returns a
//! typed [`Error`].
//!
//! TCP carries a stream of messages split by the header's byte count
//! ([`Message::parse`] returns how many bytes it used); a UDP datagram may hold
//! several.
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]

use core::fmt;

/// The HART-IP port (UDP and TCP).
pub const PORT: u16 = 5094;
/// Header length.
pub const HEADER_LEN: usize = 8;

/// Message type (header byte 1, bits 3-0).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageType {
    /// 0: request.
    Request,
    /// 1: response.
    Response,
    /// 2: publish (notification, e.g. burst messages).
    Publish,
    /// 15: negative acknowledge.
    Nak,
    /// Any other value.
    Other(u8),
}

impl MessageType {
    /// From the 4-bit code.
    pub fn from_code(c: u8) -> Self {
        match c {
            0 => MessageType::Request,
            1 => MessageType::Response,
            2 => MessageType::Publish,
            15 => MessageType::Nak,
            x => MessageType::Other(x),
        }
    }

    /// The 4-bit code.
    pub fn code(self) -> u8 {
        match self {
            MessageType::Request => 0,
            MessageType::Response => 1,
            MessageType::Publish => 2,
            MessageType::Nak => 15,
            MessageType::Other(x) => x & 0x0F,
        }
    }
}

/// Message ID (header byte 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageId {
    /// 0: session initiate.
    SessionInitiate,
    /// 1: session close.
    SessionClose,
    /// 2: keep-alive.
    KeepAlive,
    /// 3: token-passing PDU (a HART frame without preambles).
    TokenPassingPdu,
    /// 4: direct PDU (commands to the HART-IP device itself).
    DirectPdu,
    /// 5: read audit log.
    ReadAuditLog,
    /// Any other value.
    Other(u8),
}

impl MessageId {
    /// From the byte.
    pub fn from_code(c: u8) -> Self {
        match c {
            0 => MessageId::SessionInitiate,
            1 => MessageId::SessionClose,
            2 => MessageId::KeepAlive,
            3 => MessageId::TokenPassingPdu,
            4 => MessageId::DirectPdu,
            5 => MessageId::ReadAuditLog,
            x => MessageId::Other(x),
        }
    }

    /// The byte.
    pub fn code(self) -> u8 {
        match self {
            MessageId::SessionInitiate => 0,
            MessageId::SessionClose => 1,
            MessageId::KeepAlive => 2,
            MessageId::TokenPassingPdu => 3,
            MessageId::DirectPdu => 4,
            MessageId::ReadAuditLog => 5,
            MessageId::Other(x) => x,
        }
    }

    /// Name for people.
    pub fn name(self) -> &'static str {
        match self {
            MessageId::SessionInitiate => "session initiate",
            MessageId::SessionClose => "session close",
            MessageId::KeepAlive => "keep-alive",
            MessageId::TokenPassingPdu => "token-passing PDU",
            MessageId::DirectPdu => "direct PDU",
            MessageId::ReadAuditLog => "read audit log",
            MessageId::Other(_) => "unknown message ID",
        }
    }
}

/// Session status codes (header byte 3 of responses).
pub mod status {
    /// Success.
    pub const SUCCESS: u8 = 0;
    /// Invalid selection (e.g. invalid master type).
    pub const INVALID_SELECTION: u8 = 2;
    /// Too few data bytes.
    pub const TOO_FEW_DATA_BYTES: u8 = 5;
    /// Device-specific error.
    pub const DEVICE_SPECIFIC: u8 = 6;
    /// Warning: set to nearest possible value (inactivity timer adjusted).
    pub const SET_TO_NEAREST: u8 = 8;
    /// Security not initialized.
    pub const SECURITY_NOT_INITIALIZED: u8 = 9;
    /// Warning: protocol version not supported (the server answers with its version).
    pub const VERSION_NOT_SUPPORTED: u8 = 14;
    /// All available sessions in use.
    pub const ALL_SESSIONS_IN_USE: u8 = 15;
    /// Access restricted.
    pub const ACCESS_RESTRICTED: u8 = 16;
    /// Warning: insecure session already exists.
    pub const INSECURE_SESSION_EXISTS: u8 = 30;

    /// Meaning of a session status code.
    pub fn name(code: u8) -> &'static str {
        match code {
            SUCCESS => "success",
            INVALID_SELECTION => "invalid selection (master type)",
            TOO_FEW_DATA_BYTES => "too few data bytes",
            DEVICE_SPECIFIC => "device-specific error",
            SET_TO_NEAREST => "set to nearest possible value (inactivity timer adjusted)",
            SECURITY_NOT_INITIALIZED => "security not initialized",
            VERSION_NOT_SUPPORTED => "protocol version not supported",
            ALL_SESSIONS_IN_USE => "all available sessions in use",
            ACCESS_RESTRICTED => "access restricted",
            INSECURE_SESSION_EXISTS => "insecure session already exists",
            _ => "undefined status code",
        }
    }
}

/// The 8-byte header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Protocol version: 1 (plain), 2 (secured).
    pub version: u8,
    /// Message type.
    pub message_type: MessageType,
    /// Reserved bits 7-4 of byte 1 (must be 0).
    pub reserved: u8,
    /// Message ID.
    pub message_id: MessageId,
    /// Status: 0 in requests; a session status code in responses.
    pub status: u8,
    /// Sequence number.
    pub sequence: u16,
    /// Whole message length, header included.
    pub byte_count: u16,
}

/// Why bytes are not a HART-IP message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Error {
    /// Fewer than 8 bytes: no complete header (a stream needs more bytes).
    ShortHeader {
        /// Bytes present.
        available: usize,
    },
    /// The byte count is below the header length.
    ByteCountTooSmall {
        /// The byte count.
        byte_count: u16,
    },
    /// The byte count says more than the bytes present (a stream needs more bytes).
    Truncated {
        /// The byte count.
        byte_count: u16,
        /// Bytes present.
        available: usize,
    },
    /// A body too short for its message ID.
    BodyTooShort {
        /// Message ID.
        message_id: MessageId,
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        available: usize,
    },
    /// A token-passing PDU that is not a HART frame.
    BadPdu(hart_proto::FrameError),
    /// The output buffer is too small.
    BufferTooSmall,
    /// The message would be longer than 65535 bytes.
    TooLong,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::ShortHeader { available } => {
                write!(f, "HART-IP header needs 8 bytes, got {available}")
            }
            Error::ByteCountTooSmall { byte_count } => write!(
                f,
                "HART-IP byte count {byte_count} is less than the 8-byte header"
            ),
            Error::Truncated {
                byte_count,
                available,
            } => write!(
                f,
                "truncated HART-IP message: byte count {byte_count}, {available} byte(s) present"
            ),
            Error::BodyTooShort {
                message_id,
                needed,
                available,
            } => write!(
                f,
                "{} body needs {needed} byte(s), got {available}",
                message_id.name()
            ),
            Error::BadPdu(e) => write!(f, "token-passing PDU: {e}"),
            Error::BufferTooSmall => f.write_str("output buffer too small"),
            Error::TooLong => f.write_str("HART-IP message longer than 65535 bytes"),
        }
    }
}

impl Header {
    /// Parses the first 8 bytes.
    pub fn parse(b: &[u8]) -> Result<Self, Error> {
        if b.len() < HEADER_LEN {
            return Err(Error::ShortHeader { available: b.len() });
        }
        let byte_count = u16::from_be_bytes([b[6], b[7]]);
        if usize::from(byte_count) < HEADER_LEN {
            return Err(Error::ByteCountTooSmall { byte_count });
        }
        Ok(Header {
            version: b[0],
            message_type: MessageType::from_code(b[1] & 0x0F),
            reserved: b[1] >> 4,
            message_id: MessageId::from_code(b[2]),
            status: b[3],
            sequence: u16::from_be_bytes([b[4], b[5]]),
            byte_count,
        })
    }

    /// Writes the 8 header bytes.
    pub fn write(&self, out: &mut [u8]) -> Result<(), Error> {
        let o = out.get_mut(..HEADER_LEN).ok_or(Error::BufferTooSmall)?;
        o[0] = self.version;
        o[1] = (self.reserved << 4) | self.message_type.code();
        o[2] = self.message_id.code();
        o[3] = self.status;
        o[4..6].copy_from_slice(&self.sequence.to_be_bytes());
        o[6..8].copy_from_slice(&self.byte_count.to_be_bytes());
        Ok(())
    }
}

/// A message: header and body (a view over received bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Message<'a> {
    /// The header.
    pub header: Header,
    /// The body (byte count − 8 bytes).
    pub body: &'a [u8],
}

impl<'a> Message<'a> {
    /// Parses one message from the start of `b`; returns it and the bytes it used.
    pub fn parse(b: &'a [u8]) -> Result<(Self, usize), Error> {
        let header = Header::parse(b)?;
        let n = usize::from(header.byte_count);
        if b.len() < n {
            return Err(Error::Truncated {
                byte_count: header.byte_count,
                available: b.len(),
            });
        }
        Ok((
            Message {
                header,
                body: &b[HEADER_LEN..n],
            },
            n,
        ))
    }

    /// The body as a typed value.
    pub fn body(&self) -> Result<Body<'a>, Error> {
        Body::parse(self.header.message_id, self.header.message_type, self.body)
    }
}

/// Session initiate body (5 bytes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SessionInitiate {
    /// 1 primary master, 0 secondary.
    pub master_type: u8,
    /// Inactivity close timer, ms.
    pub inactivity_timer_ms: u32,
}

/// A typed body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Body<'a> {
    /// Session initiate request or response.
    SessionInitiate(SessionInitiate),
    /// Session close, keep-alive, or an empty error response.
    Empty,
    /// A HART frame from the delimiter through the check byte.
    TokenPassing(hart_proto::Frame<'a>),
    /// Direct PDU: device status, extended status, then command entries.
    Direct {
        /// Device status.
        device_status: u8,
        /// Extended device status.
        extended_status: u8,
        /// The command entries ([`DirectEntries`] iterates them).
        entries: &'a [u8],
    },
    /// Read audit log request: start record and count.
    AuditLogRequest {
        /// First record.
        start: u8,
        /// Number of records.
        count: u8,
    },
    /// Anything else, raw.
    Raw(&'a [u8]),
}

impl<'a> Body<'a> {
    /// Parses a body by message ID.
    pub fn parse(id: MessageId, ty: MessageType, b: &'a [u8]) -> Result<Self, Error> {
        let need = |n: usize| {
            if b.len() < n {
                Err(Error::BodyTooShort {
                    message_id: id,
                    needed: n,
                    available: b.len(),
                })
            } else {
                Ok(())
            }
        };
        match id {
            MessageId::SessionInitiate if b.is_empty() && ty != MessageType::Request => {
                Ok(Body::Empty)
            }
            MessageId::SessionInitiate => {
                need(5)?;
                Ok(Body::SessionInitiate(SessionInitiate {
                    master_type: b[0],
                    inactivity_timer_ms: u32::from_be_bytes([b[1], b[2], b[3], b[4]]),
                }))
            }
            MessageId::SessionClose | MessageId::KeepAlive if b.is_empty() => Ok(Body::Empty),
            MessageId::TokenPassingPdu if b.is_empty() => Ok(Body::Empty),
            MessageId::TokenPassingPdu => hart_proto::Frame::parse_pdu(b)
                .map(Body::TokenPassing)
                .map_err(Error::BadPdu),
            MessageId::DirectPdu if b.is_empty() => Ok(Body::Empty),
            MessageId::DirectPdu => {
                need(2)?;
                Ok(Body::Direct {
                    device_status: b[0],
                    extended_status: b[1],
                    entries: &b[2..],
                })
            }
            MessageId::ReadAuditLog if ty == MessageType::Request => {
                need(2)?;
                Ok(Body::AuditLogRequest {
                    start: b[0],
                    count: b[1],
                })
            }
            _ => Ok(Body::Raw(b)),
        }
    }
}

/// One command entry of a direct PDU: command, and request data or (for responses) the
/// response code followed by the data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DirectEntry<'a> {
    /// Command number.
    pub command: u16,
    /// The entry's data (after the byte count).
    pub data: &'a [u8],
}

/// Iterates the command entries of a direct PDU; stops at a truncated entry.
pub struct DirectEntries<'a>(pub &'a [u8]);

impl<'a> Iterator for DirectEntries<'a> {
    type Item = Result<DirectEntry<'a>, Error>;
    fn next(&mut self) -> Option<Self::Item> {
        let b = self.0;
        if b.is_empty() {
            return None;
        }
        if b.len() < 3 {
            self.0 = &[];
            return Some(Err(Error::BodyTooShort {
                message_id: MessageId::DirectPdu,
                needed: 3,
                available: b.len(),
            }));
        }
        let n = usize::from(b[2]);
        if b.len() < 3 + n {
            self.0 = &[];
            return Some(Err(Error::BodyTooShort {
                message_id: MessageId::DirectPdu,
                needed: 3 + n,
                available: b.len(),
            }));
        }
        self.0 = &b[3 + n..];
        Some(Ok(DirectEntry {
            command: u16::from_be_bytes([b[0], b[1]]),
            data: &b[3..3 + n],
        }))
    }
}

/// Builds a message into `out`; returns its length.
pub fn encode(
    version: u8,
    ty: MessageType,
    id: MessageId,
    status: u8,
    sequence: u16,
    body: &[u8],
    out: &mut [u8],
) -> Result<usize, Error> {
    let n = HEADER_LEN + body.len();
    let byte_count = u16::try_from(n).map_err(|_| Error::TooLong)?;
    let dst = out.get_mut(..n).ok_or(Error::BufferTooSmall)?;
    Header {
        version,
        message_type: ty,
        reserved: 0,
        message_id: id,
        status,
        sequence,
        byte_count,
    }
    .write(dst)?;
    dst[HEADER_LEN..].copy_from_slice(body);
    Ok(n)
}

/// Session initiate body bytes.
pub fn session_initiate_body(master_type: u8, inactivity_timer_ms: u32) -> [u8; 5] {
    let t = inactivity_timer_ms.to_be_bytes();
    [master_type, t[0], t[1], t[2], t[3]]
}
