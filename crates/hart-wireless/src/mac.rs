//! The IEEE 802.15.4 frame as WirelessHART uses it: frame control, sequence number
//! (the low byte of the ASN), PAN ID (the network ID), 2-byte nicknames or 8-byte
//! EUI-64 addresses (little-endian on air) and the FCS (CRC-16 ITU-T, "kermit").

use alloc::vec::Vec;
use core::fmt;

/// A data-link address: a 2-byte nickname or an 8-byte EUI-64.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Address {
    /// No address (addressing mode 0).
    None,
    /// A nickname.
    Short(u16),
    /// An EUI-64 (most significant byte first as a number).
    Long(u64),
}

impl Address {
    /// The address as 8 bytes, most significant first, a nickname zero-padded (how
    /// nonces carry it).
    pub fn nonce_bytes(&self) -> [u8; 8] {
        match *self {
            Address::None => [0; 8],
            Address::Short(s) => (s as u64).to_be_bytes(),
            Address::Long(l) => l.to_be_bytes(),
        }
    }

    /// 802.15.4 addressing mode: 0 none, 2 short, 3 long.
    pub fn mode(&self) -> u8 {
        match self {
            Address::None => 0,
            Address::Short(_) => 2,
            Address::Long(_) => 3,
        }
    }

    /// Bytes the address occupies.
    pub fn len(&self) -> usize {
        match self {
            Address::None => 0,
            Address::Short(_) => 2,
            Address::Long(_) => 8,
        }
    }

    /// True for [`Address::None`].
    pub fn is_empty(&self) -> bool {
        matches!(self, Address::None)
    }
}

/// Lowercase hex, most significant byte first: 4 digits for a nickname, 16 for an
/// EUI-64, `-` for none.
impl fmt::Display for Address {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Address::None => f.write_str("-"),
            Address::Short(s) => write!(f, "{s:04x}"),
            Address::Long(l) => write!(f, "{l:016x}"),
        }
    }
}

/// Why a frame could not be parsed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MacError {
    /// Fewer bytes than the header (and FCS) need.
    TooShort {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        available: usize,
    },
    /// Not an 802.15.4 data frame (WirelessHART sends only data frames).
    NotData {
        /// The frame type field (bits 2-0 of frame control).
        frame_type: u8,
    },
    /// An addressing mode WirelessHART does not use (1 is reserved).
    BadAddressMode {
        /// The mode.
        mode: u8,
    },
    /// 802.15.4 security (WirelessHART secures at its own data-link layer).
    Secured,
}

impl fmt::Display for MacError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MacError::TooShort { needed, available } => write!(
                f,
                "802.15.4 frame too short: needs {needed} bytes, has {available} (a cut capture?)"
            ),
            MacError::NotData { frame_type } => write!(
                f,
                "802.15.4 frame type {frame_type} is not a data frame (WirelessHART uses data frames only)"
            ),
            MacError::BadAddressMode { mode } => {
                write!(f, "802.15.4 addressing mode {mode} is reserved")
            }
            MacError::Secured => f.write_str(
                "802.15.4-level security is set; WirelessHART secures frames at its data-link layer",
            ),
        }
    }
}

/// The CRC-16 of 802.15.4 (ITU-T polynomial 0x1021 reflected, initial 0, "kermit");
/// sent little-endian after the frame.
pub fn fcs(data: &[u8]) -> u16 {
    let mut crc: u16 = 0;
    for &b in data {
        crc ^= b as u16;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0x8408
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// An 802.15.4 data frame: the header fields and the MAC payload (the data-link
/// specifier, payload and MIC of WirelessHART), without the FCS.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MacFrame {
    /// Frame control bits other than frame type and addressing modes: bit 3 security,
    /// 4 frame pending, 5 ACK request, 6 PAN ID compression, 12-13 frame version.
    pub flags: u16,
    /// Sequence number (ASN & 0xFF in WirelessHART).
    pub seq: u8,
    /// Destination PAN ID: the WirelessHART network ID.
    pub pan: u16,
    /// Source PAN ID, when the frame carries one (PAN ID compression off).
    pub src_pan: Option<u16>,
    /// Destination address.
    pub dst: Address,
    /// Source address.
    pub src: Address,
    /// The MAC payload.
    pub payload: Vec<u8>,
}

const FC_SECURITY: u16 = 1 << 3;
/// PAN ID compression: one PAN ID for both addresses.
pub const FC_PAN_COMPRESSION: u16 = 1 << 6;

impl MacFrame {
    /// A WirelessHART data frame (frame control 0x8841 with nicknames).
    pub fn new(seq: u8, pan: u16, dst: Address, src: Address, payload: Vec<u8>) -> Self {
        MacFrame {
            flags: FC_PAN_COMPRESSION,
            seq,
            pan,
            src_pan: None,
            dst,
            src,
            payload,
        }
    }

    /// Parses a frame without its FCS.
    pub fn parse(b: &[u8]) -> Result<Self, MacError> {
        let short = |needed: usize| MacError::TooShort {
            needed,
            available: b.len(),
        };
        if b.len() < 3 {
            return Err(short(3));
        }
        let fc = u16::from_le_bytes([b[0], b[1]]);
        let frame_type = (fc & 7) as u8;
        if frame_type != 1 {
            return Err(MacError::NotData { frame_type });
        }
        if fc & FC_SECURITY != 0 {
            return Err(MacError::Secured);
        }
        let dmode = ((fc >> 10) & 3) as u8;
        let smode = ((fc >> 14) & 3) as u8;
        for m in [dmode, smode] {
            if m == 1 {
                return Err(MacError::BadAddressMode { mode: m });
            }
        }
        let alen = |m: u8| match m {
            2 => 2,
            3 => 8,
            _ => 0,
        };
        let compressed = fc & FC_PAN_COMPRESSION != 0;
        let has_dpan = dmode != 0 || (smode != 0 && compressed);
        let has_span = smode != 0 && !compressed;
        let hdr = 3
            + if has_dpan { 2 } else { 0 }
            + alen(dmode)
            + if has_span { 2 } else { 0 }
            + alen(smode);
        if b.len() < hdr {
            return Err(short(hdr));
        }
        let mut p = 3;
        let u16le = |p: &mut usize| {
            let v = u16::from_le_bytes([b[*p], b[*p + 1]]);
            *p += 2;
            v
        };
        let pan = if has_dpan { u16le(&mut p) } else { 0 };
        let read_addr = |m: u8, p: &mut usize| -> Address {
            match m {
                2 => {
                    let v = u16::from_le_bytes([b[*p], b[*p + 1]]);
                    *p += 2;
                    Address::Short(v)
                }
                3 => {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(&b[*p..*p + 8]);
                    *p += 8;
                    Address::Long(u64::from_le_bytes(a))
                }
                _ => Address::None,
            }
        };
        let dst = read_addr(dmode, &mut p);
        let src_pan = if has_span {
            let v = u16::from_le_bytes([b[p], b[p + 1]]);
            p += 2;
            Some(v)
        } else {
            None
        };
        let src = read_addr(smode, &mut p);
        Ok(MacFrame {
            flags: fc & !(7 | (3 << 10) | (3 << 14)),
            seq: b[2],
            pan,
            src_pan,
            dst,
            src,
            payload: b[p..].to_vec(),
        })
    }

    /// Parses a frame that ends with its FCS; also says whether the FCS is good.
    pub fn parse_with_fcs(b: &[u8]) -> Result<(Self, bool), MacError> {
        if b.len() < 5 {
            return Err(MacError::TooShort {
                needed: 5,
                available: b.len(),
            });
        }
        let (body, f) = b.split_at(b.len() - 2);
        let ok = fcs(body) == u16::from_le_bytes([f[0], f[1]]);
        Ok((Self::parse(body)?, ok))
    }

    /// The header bytes (frame control to source address).
    pub fn header(&self) -> Vec<u8> {
        let fc = self.flags | 1 | (self.dst.mode() as u16) << 10 | (self.src.mode() as u16) << 14;
        let mut v = Vec::with_capacity(23);
        v.extend_from_slice(&fc.to_le_bytes());
        v.push(self.seq);
        let compressed = self.flags & FC_PAN_COMPRESSION != 0;
        if !self.dst.is_empty() || (!self.src.is_empty() && compressed) {
            v.extend_from_slice(&self.pan.to_le_bytes());
        }
        put_addr(&mut v, self.dst);
        if !self.src.is_empty() && !compressed {
            v.extend_from_slice(&self.src_pan.unwrap_or(self.pan).to_le_bytes());
        }
        put_addr(&mut v, self.src);
        v
    }

    /// The frame without FCS.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = self.header();
        v.extend_from_slice(&self.payload);
        v
    }

    /// The frame with its FCS, as sent on air.
    pub fn encode_with_fcs(&self) -> Vec<u8> {
        let mut v = self.encode();
        let f = fcs(&v);
        v.extend_from_slice(&f.to_le_bytes());
        v
    }
}

fn put_addr(v: &mut Vec<u8>, a: Address) {
    match a {
        Address::None => {}
        Address::Short(s) => v.extend_from_slice(&s.to_le_bytes()),
        Address::Long(l) => v.extend_from_slice(&l.to_le_bytes()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fcs_check_value() {
        // CRC-16/KERMIT check value of "123456789".
        assert_eq!(fcs(b"123456789"), 0x2189);
    }
}
