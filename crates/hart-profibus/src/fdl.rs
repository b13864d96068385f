//! FDL telegrams (the PROFIBUS data link layer, IEC 61158-4-3 type 3): decoding and
//! encoding, without I/O.
//!
//! | start | layout | what |
//! | --- | --- | --- |
//! | SD1 `0x10` | `SD1 DA SA FC FCS ED` | no data (FDL status request and its reply) |
//! | SD2 `0x68` | `SD2 LE LEr SD2 DA SA FC [DSAP] [SSAP] DU… FCS ED` | variable data, LE = 3 + data bytes (4..=249) |
//! | SD3 `0xA2` | `SD3 DA SA FC DU(8) FCS ED` | exactly 8 data bytes |
//! | SD4 `0xDC` | `SD4 DA SA` | the token, passed between masters |
//! | SC `0xE5` | `SC` | short acknowledgement |
//!
//! FCS is the sum modulo 256 of DA through the last data byte; ED is `0x16`. Bit 7 of
//! DA (and of SA) says that a service access point (DSAP, SSAP) is the first (second)
//! data byte. Each character goes on the line as 11 bits: start, 8 data bits, even
//! parity, stop.

use std::fmt;

/// Start delimiter of a telegram without data.
pub const SD1: u8 = 0x10;
/// Start delimiter of a telegram with variable data.
pub const SD2: u8 = 0x68;
/// Start delimiter of a telegram with 8 data bytes.
pub const SD3: u8 = 0xA2;
/// Start delimiter of the token.
pub const SD4: u8 = 0xDC;
/// The short acknowledgement.
pub const SC: u8 = 0xE5;
/// End delimiter.
pub const ED: u8 = 0x16;
/// The broadcast (global) address.
pub const BROADCAST: u8 = 127;
/// The longest data unit of a telegram (SAPs included): LE is at most 249.
pub const MAX_DATA_UNIT: usize = 246;
/// The longest telegram on the line (an SD2 telegram with 246 data bytes).
pub const MAX_TELEGRAM: usize = MAX_DATA_UNIT + 9;

/// A function code's request kinds (bits 3..0 of FC with bit 6 set).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// Send Data with Acknowledge, low priority (3).
    SdaLow,
    /// Send Data with No acknowledge, low priority (4).
    SdnLow,
    /// Send Data with Acknowledge, high priority (5).
    SdaHigh,
    /// Send Data with No acknowledge, high priority (6).
    SdnHigh,
    /// Request FDL status (9).
    FdlStatus,
    /// Send and Request Data, low priority (12).
    SrdLow,
    /// Send and Request Data, high priority (13).
    SrdHigh,
    /// Request ident (14).
    Ident,
    /// Another request code: not served by a DP slave.
    Other(u8),
}

impl Request {
    fn from_code(code: u8) -> Request {
        match code {
            3 => Request::SdaLow,
            4 => Request::SdnLow,
            5 => Request::SdaHigh,
            6 => Request::SdnHigh,
            9 => Request::FdlStatus,
            12 => Request::SrdLow,
            13 => Request::SrdHigh,
            14 => Request::Ident,
            c => Request::Other(c),
        }
    }

    fn code(self) -> u8 {
        match self {
            Request::SdaLow => 3,
            Request::SdnLow => 4,
            Request::SdaHigh => 5,
            Request::SdnHigh => 6,
            Request::FdlStatus => 9,
            Request::SrdLow => 12,
            Request::SrdHigh => 13,
            Request::Ident => 14,
            Request::Other(c) => c & 0x0F,
        }
    }

    /// Whether the sender waits for an answer (everything but SDN).
    pub fn expects_reply(self) -> bool {
        !matches!(self, Request::SdnLow | Request::SdnHigh)
    }
}

/// A reply's status (bits 3..0 of FC with bit 6 clear).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// OK (0).
    Ok,
    /// UE, user error (1).
    UserError,
    /// RR, no resources (2).
    NoResources,
    /// RS, the service access point is not activated (3).
    SapNotActivated,
    /// DL, data low (8): reply data, no diagnosis waiting.
    DataLow,
    /// NR, no reply data (9).
    NoData,
    /// DH, data high (10): reply data, and new diagnosis for the master to fetch.
    DataHigh,
    /// Another status code.
    Other(u8),
}

impl Status {
    fn from_code(code: u8) -> Status {
        match code {
            0 => Status::Ok,
            1 => Status::UserError,
            2 => Status::NoResources,
            3 => Status::SapNotActivated,
            8 => Status::DataLow,
            9 => Status::NoData,
            10 => Status::DataHigh,
            c => Status::Other(c),
        }
    }

    fn code(self) -> u8 {
        match self {
            Status::Ok => 0,
            Status::UserError => 1,
            Status::NoResources => 2,
            Status::SapNotActivated => 3,
            Status::DataLow => 8,
            Status::NoData => 9,
            Status::DataHigh => 10,
            Status::Other(c) => c & 0x0F,
        }
    }
}

/// The function code byte, decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FunctionCode {
    /// A request (bit 6 set), with its frame count bit and whether that bit is valid.
    Request {
        /// The request.
        request: Request,
        /// FCB, toggled by the master for each new request to a station.
        fcb: bool,
        /// FCV: whether FCB is to be checked (clear on a master's first request).
        fcv: bool,
    },
    /// A reply (bit 6 clear): a slave's station type is 0.
    Reply {
        /// The status.
        status: Status,
        /// The station type (bits 5..4): 0 slave, 1 master not ready, 2 master
        /// ready, 3 master in the ring.
        station_type: u8,
    },
}

impl FunctionCode {
    /// Decodes an FC byte.
    pub fn from_byte(b: u8) -> FunctionCode {
        if b & 0x40 != 0 {
            FunctionCode::Request {
                request: Request::from_code(b & 0x0F),
                fcb: b & 0x20 != 0,
                fcv: b & 0x10 != 0,
            }
        } else {
            FunctionCode::Reply {
                status: Status::from_code(b & 0x0F),
                station_type: (b >> 4) & 0x03,
            }
        }
    }

    /// Encodes the FC byte.
    pub fn to_byte(self) -> u8 {
        match self {
            FunctionCode::Request { request, fcb, fcv } => {
                0x40 | request.code() | (u8::from(fcb) << 5) | (u8::from(fcv) << 4)
            }
            FunctionCode::Reply {
                status,
                station_type,
            } => ((station_type & 0x03) << 4) | status.code(),
        }
    }

    /// A slave's reply with `status`.
    pub fn slave_reply(status: Status) -> FunctionCode {
        FunctionCode::Reply {
            status,
            station_type: 0,
        }
    }
}

/// A telegram with an address header (SD1, SD2, SD3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DataTelegram<'a> {
    /// Destination address (0..=127, 127 the broadcast).
    pub da: u8,
    /// Source address.
    pub sa: u8,
    /// Destination service access point, when DA carries the extension bit.
    pub dsap: Option<u8>,
    /// Source service access point, when SA carries the extension bit.
    pub ssap: Option<u8>,
    /// The function code.
    pub fc: FunctionCode,
    /// The data after the SAPs.
    pub data: &'a [u8],
}

/// A decoded telegram.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Telegram<'a> {
    /// SD1, SD2 or SD3.
    Data(DataTelegram<'a>),
    /// SD4: the token passes from `sa` to `da`.
    Token {
        /// The next master.
        da: u8,
        /// The master that held it.
        sa: u8,
    },
    /// SC: the short acknowledgement.
    ShortAck,
}

/// Why bytes are no telegram.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// The first byte is none of SD1, SD2, SD3, SD4, SC.
    StartDelimiter(u8),
    /// SD2's LE and LEr differ.
    LengthMismatch {
        /// LE.
        le: u8,
        /// LEr.
        ler: u8,
    },
    /// SD2's LE is below 4 or above 249.
    LengthOutOfRange(u8),
    /// SD2's start delimiter is not repeated after LEr.
    RepeatedDelimiter(u8),
    /// The frame check sum is wrong.
    Checksum {
        /// What the telegram carries.
        carried: u8,
        /// The sum of its bytes.
        computed: u8,
    },
    /// The end delimiter is not 0x16.
    EndDelimiter(u8),
    /// DA or SA says a SAP follows, but the data unit is too short to hold it.
    MissingSap,
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::StartDelimiter(b) => write!(
                f,
                "0x{b:02X} is no start delimiter (SD1 0x10, SD2 0x68, SD3 0xA2, SD4 0xDC, SC 0xE5): line noise, a wrong baud rate or parity, or a telegram cut short"
            ),
            DecodeError::LengthMismatch { le, ler } => write!(
                f,
                "SD2 length {le} and its repetition {ler} differ: the telegram was damaged on the line"
            ),
            DecodeError::LengthOutOfRange(le) => {
                write!(f, "SD2 length {le} is outside 4..=249")
            }
            DecodeError::RepeatedDelimiter(b) => write!(
                f,
                "SD2's start delimiter is not repeated (0x{b:02X} instead of 0x68)"
            ),
            DecodeError::Checksum { carried, computed } => write!(
                f,
                "frame check sum 0x{carried:02X} but the bytes sum to 0x{computed:02X}: the telegram was damaged on the line (check wiring, termination and baud rate)"
            ),
            DecodeError::EndDelimiter(b) => write!(
                f,
                "end delimiter 0x{b:02X} instead of 0x16: the telegram was damaged or cut short"
            ),
            DecodeError::MissingSap => write!(
                f,
                "the address says a service access point follows, but the telegram has no byte for it"
            ),
        }
    }
}

impl std::error::Error for DecodeError {}

/// The frame check sum: the sum modulo 256 of `bytes`.
pub fn fcs(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |a, b| a.wrapping_add(*b))
}

/// Decodes the telegram at the start of `buf`: `Ok(None)` while it is incomplete,
/// else the telegram and how many bytes it took.
pub fn decode(buf: &[u8]) -> Result<Option<(Telegram<'_>, usize)>, DecodeError> {
    let Some(&first) = buf.first() else {
        return Ok(None);
    };
    let (body_start, body_len) = match first {
        SC => return Ok(Some((Telegram::ShortAck, 1))),
        SD4 => {
            if buf.len() < 3 {
                return Ok(None);
            }
            return Ok(Some((
                Telegram::Token {
                    da: buf[1] & 0x7F,
                    sa: buf[2] & 0x7F,
                },
                3,
            )));
        }
        SD1 => (1, 3),
        SD3 => (1, 11),
        SD2 => {
            if buf.len() < 4 {
                if buf.len() >= 3 && buf[1] != buf[2] {
                    return Err(DecodeError::LengthMismatch {
                        le: buf[1],
                        ler: buf[2],
                    });
                }
                return Ok(None);
            }
            let (le, ler) = (buf[1], buf[2]);
            if le != ler {
                return Err(DecodeError::LengthMismatch { le, ler });
            }
            if !(4..=249).contains(&le) {
                return Err(DecodeError::LengthOutOfRange(le));
            }
            if buf[3] != SD2 {
                return Err(DecodeError::RepeatedDelimiter(buf[3]));
            }
            (4, usize::from(le))
        }
        other => return Err(DecodeError::StartDelimiter(other)),
    };
    let total = body_start + body_len + 2;
    if buf.len() < total {
        return Ok(None);
    }
    let body = &buf[body_start..body_start + body_len];
    let carried = buf[body_start + body_len];
    let computed = fcs(body);
    if carried != computed {
        return Err(DecodeError::Checksum { carried, computed });
    }
    let end = buf[total - 1];
    if end != ED {
        return Err(DecodeError::EndDelimiter(end));
    }
    let (da_byte, sa_byte, fc) = (body[0], body[1], FunctionCode::from_byte(body[2]));
    let mut data = &body[3..];
    let mut sap = |flag: u8| -> Result<Option<u8>, DecodeError> {
        if flag & 0x80 == 0 {
            return Ok(None);
        }
        let (&s, rest) = data.split_first().ok_or(DecodeError::MissingSap)?;
        data = rest;
        Ok(Some(s))
    };
    let dsap = sap(da_byte)?;
    let ssap = sap(sa_byte)?;
    Ok(Some((
        Telegram::Data(DataTelegram {
            da: da_byte & 0x7F,
            sa: sa_byte & 0x7F,
            dsap,
            ssap,
            fc,
            data,
        }),
        total,
    )))
}

/// Why a telegram cannot be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// Data and SAPs exceed the 246 bytes of a data unit.
    TooLong(usize),
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::TooLong(n) => write!(
                f,
                "{n} bytes of data unit (SAPs included) exceed the 246 a telegram carries"
            ),
        }
    }
}

impl std::error::Error for EncodeError {}

/// Appends `t` to `out`, as SD1 (no data unit), SD3 (exactly 8 bytes of data unit)
/// or SD2 (any other length).
pub fn encode(t: &DataTelegram<'_>, out: &mut Vec<u8>) -> Result<(), EncodeError> {
    let du = usize::from(t.dsap.is_some()) + usize::from(t.ssap.is_some()) + t.data.len();
    if du > MAX_DATA_UNIT {
        return Err(EncodeError::TooLong(du));
    }
    let sd = match du {
        0 => SD1,
        8 => SD3,
        _ => SD2,
    };
    out.push(sd);
    if sd == SD2 {
        let le = (du + 3) as u8;
        out.extend_from_slice(&[le, le, SD2]);
    }
    let start = out.len();
    out.push((t.da & 0x7F) | if t.dsap.is_some() { 0x80 } else { 0 });
    out.push((t.sa & 0x7F) | if t.ssap.is_some() { 0x80 } else { 0 });
    out.push(t.fc.to_byte());
    out.extend(t.dsap);
    out.extend(t.ssap);
    out.extend_from_slice(t.data);
    let sum = fcs(&out[start..]);
    out.push(sum);
    out.push(ED);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_ack_and_token() {
        assert_eq!(decode(&[SC]).unwrap(), Some((Telegram::ShortAck, 1)));
        assert_eq!(decode(&[SD4, 3]).unwrap(), None);
        assert_eq!(
            decode(&[SD4, 3, 2, 0xFF]).unwrap(),
            Some((Telegram::Token { da: 3, sa: 2 }, 3))
        );
    }

    #[test]
    fn function_codes_round_trip() {
        for b in 0..=0x7Fu8 {
            assert_eq!(FunctionCode::from_byte(b).to_byte(), b, "FC 0x{b:02X}");
        }
    }

    #[test]
    fn damaged_telegrams_are_errors() {
        // FDL status request from master 2 to station 5: 10 05 02 49 50 16.
        let good = [SD1, 0x05, 0x02, 0x49, 0x50, ED];
        assert!(decode(&good).unwrap().is_some());
        let mut bad = good;
        bad[4] ^= 1;
        assert!(matches!(decode(&bad), Err(DecodeError::Checksum { .. })));
        let mut bad = good;
        bad[5] = 0x17;
        assert_eq!(decode(&bad), Err(DecodeError::EndDelimiter(0x17)));
        assert_eq!(
            decode(&[SD2, 5, 6, SD2]),
            Err(DecodeError::LengthMismatch { le: 5, ler: 6 })
        );
        assert_eq!(
            decode(&[SD2, 3, 3, SD2]),
            Err(DecodeError::LengthOutOfRange(3))
        );
        assert_eq!(decode(&[0x00]), Err(DecodeError::StartDelimiter(0)));
        // DA says a DSAP follows, but there is no data unit.
        let mut t = vec![SD1, 0x85, 0x02, 0x6D];
        t.push(fcs(&t[1..]));
        t.push(ED);
        assert_eq!(decode(&t), Err(DecodeError::MissingSap));
    }

    #[test]
    fn encode_picks_the_start_delimiter() {
        let mut out = Vec::new();
        let t = DataTelegram {
            da: 2,
            sa: 5,
            dsap: Some(62),
            ssap: Some(60),
            fc: FunctionCode::slave_reply(Status::DataLow),
            data: &[1, 2, 3, 4, 5, 6],
        };
        encode(&t, &mut out).unwrap();
        assert_eq!(out[0], SD3);
        assert_eq!(out.len(), 14);
        let (back, n) = decode(&out).unwrap().unwrap();
        assert_eq!(n, 14);
        assert_eq!(back, Telegram::Data(t));
    }
}
