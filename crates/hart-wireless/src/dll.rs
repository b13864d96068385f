//! The WirelessHART data-link PDU inside the 802.15.4 frame: the specifier byte
//! (priority, key, packet type), the payload of each packet type, and the data-link MIC
//! (AES-CCM* with a 4-byte MIC and nothing encrypted).

use alloc::vec::Vec;
use core::fmt;

use crate::crypto::{self, Key};
use crate::mac::{Address, MacError, MacFrame};
use crate::nl::{NlError, Npdu};

/// Packet type (bits 2-0 of the specifier).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PduType {
    /// 0: acknowledgement.
    Ack,
    /// 1: advertisement.
    Advertise,
    /// 2: keep-alive.
    KeepAlive,
    /// 3: disconnect.
    Disconnect,
    /// 7: data.
    Data,
    /// 4-6: reserved.
    Reserved(u8),
}

impl PduType {
    /// From the 3-bit code.
    pub fn from_code(c: u8) -> Self {
        match c & 7 {
            0 => PduType::Ack,
            1 => PduType::Advertise,
            2 => PduType::KeepAlive,
            3 => PduType::Disconnect,
            7 => PduType::Data,
            n => PduType::Reserved(n),
        }
    }
    /// The 3-bit code.
    pub fn code(self) -> u8 {
        match self {
            PduType::Ack => 0,
            PduType::Advertise => 1,
            PduType::KeepAlive => 2,
            PduType::Disconnect => 3,
            PduType::Data => 7,
            PduType::Reserved(n) => n & 7,
        }
    }
    /// The name used in the JSON view: `"ack"`, `"advertise"`, `"keep-alive"`,
    /// `"disconnect"`, `"data"` (`"reserved"` otherwise).
    pub fn name(self) -> &'static str {
        match self {
            PduType::Ack => "ack",
            PduType::Advertise => "advertise",
            PduType::KeepAlive => "keep-alive",
            PduType::Disconnect => "disconnect",
            PduType::Data => "data",
            PduType::Reserved(_) => "reserved",
        }
    }
}

/// Why a data-link PDU could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DlError {
    /// The 802.15.4 frame around it is wrong.
    Mac(MacError),
    /// No room for the specifier and the 4-byte MIC.
    TooShort {
        /// MAC payload bytes present.
        available: usize,
    },
    /// A packet type's payload is shorter than its layout.
    Payload {
        /// The packet type.
        pdu: &'static str,
        /// What was missing.
        reason: &'static str,
    },
    /// The network PDU of a data frame is wrong.
    Network(NlError),
}

impl fmt::Display for DlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DlError::Mac(e) => e.fmt(f),
            DlError::TooShort { available } => write!(
                f,
                "data-link PDU too short: {available} byte(s) after the 802.15.4 header, \
                 at least 5 needed (specifier and 4-byte MIC)"
            ),
            DlError::Payload { pdu, reason } => write!(f, "{pdu} payload: {reason}"),
            DlError::Network(e) => write!(f, "network PDU: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DlError {}

/// A link of an advertised superframe.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AdvLink {
    /// Slot number within the superframe.
    pub slot: u16,
    /// Bit 7 reserved, bit 6 transmit allowed, bits 5-0 channel offset.
    pub flags: u8,
}

impl AdvLink {
    /// Bits 5-0: the channel offset.
    pub fn channel_offset(&self) -> u8 {
        self.flags & 0x3F
    }
    /// Bit 6: a device may transmit (join request) in this link.
    pub fn transmit(&self) -> bool {
        self.flags & 0x40 != 0
    }
}

/// An advertised superframe and its join links.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdvSuperframe {
    /// Superframe ID.
    pub id: u8,
    /// Number of slots.
    pub slots: u16,
    /// The links.
    pub links: Vec<AdvLink>,
}

/// The advertisement payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Advertise {
    /// Absolute slot number (5 bytes).
    pub asn: u64,
    /// Join control: bits 7-4 security level supported, bits 3-0 join priority.
    pub join_control: u8,
    /// Number of channels in the map.
    pub channel_count: u8,
    /// Channel map (bit 0 = channel 11), little-endian on air.
    pub channel_map: u16,
    /// Graph ID.
    pub graph_id: u16,
    /// The superframes.
    pub superframes: Vec<AdvSuperframe>,
    /// Bytes after the superframes (none in the captures).
    pub extra: Vec<u8>,
}

/// The acknowledgement payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ack {
    /// Response code: 0 success, 61 no buffers, 62 no alarm/event buffers, 63 priority too low.
    pub response_code: u8,
    /// Time adjustment, µs (the receiver's view of the sender's clock error).
    pub time_adjustment: i16,
    /// Bytes after the time adjustment (none in the captures).
    pub extra: Vec<u8>,
}

/// Name of an ACK response code.
pub fn ack_code_name(code: u8) -> &'static str {
    match code {
        0 => "success",
        61 => "no buffers available",
        62 => "no alarm/event buffers available",
        63 => "priority too low",
        _ => "reserved",
    }
}

/// The payload of a data-link PDU, by packet type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DlBody {
    /// An acknowledgement.
    Ack(Ack),
    /// An advertisement.
    Advertise(Advertise),
    /// A keep-alive (empty payload; any bytes are kept).
    KeepAlive(Vec<u8>),
    /// A disconnect (empty payload; any bytes are kept).
    Disconnect(Vec<u8>),
    /// A data PDU carrying a network PDU.
    Data(Npdu),
    /// A reserved packet type: the payload as is.
    Reserved(Vec<u8>),
}

/// A data-link PDU with its 802.15.4 header fields.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Dlpdu {
    /// 802.15.4 frame control flags (see [`MacFrame::flags`]).
    pub mac_flags: u16,
    /// Sequence number (ASN & 0xFF).
    pub seq: u8,
    /// Network ID (the PAN ID).
    pub network_id: u16,
    /// Source PAN ID, when present.
    pub src_pan: Option<u16>,
    /// Destination.
    pub dst: Address,
    /// Source.
    pub src: Address,
    /// Specifier bits 7-6 (reserved).
    pub reserved: u8,
    /// Specifier bits 5-4: priority (0 alarm, 1 normal, 2 process data, 3 command).
    pub priority: u8,
    /// Specifier bit 3: authenticated with the network key (else the well-known key).
    pub network_key: bool,
    /// Packet type.
    pub pdu_type: PduType,
    /// The payload.
    pub body: DlBody,
    /// The data-link MIC.
    pub mic: [u8; 4],
}

fn short(pdu: &'static str, reason: &'static str) -> DlError {
    DlError::Payload { pdu, reason }
}

impl Advertise {
    /// Parses an advertisement payload.
    pub fn parse(b: &[u8]) -> Result<Self, DlError> {
        let e = |r| short("advertise", r);
        if b.len() < 12 {
            return Err(e(
                "needs 12 bytes: ASN, join control, channels, map, graph, superframe count",
            ));
        }
        let mut asn = [0u8; 8];
        asn[3..].copy_from_slice(&b[..5]);
        let n = b[11] as usize;
        let mut p = 12;
        let mut superframes = Vec::with_capacity(n);
        for _ in 0..n {
            if b.len() - p < 4 {
                return Err(e("a superframe is cut short"));
            }
            let (id, slots, nl) = (b[p], u16::from_be_bytes([b[p + 1], b[p + 2]]), b[p + 3]);
            p += 4;
            if b.len() - p < 3 * nl as usize {
                return Err(e("a superframe's links are cut short"));
            }
            let links = (0..nl as usize)
                .map(|i| AdvLink {
                    slot: u16::from_be_bytes([b[p + 3 * i], b[p + 3 * i + 1]]),
                    flags: b[p + 3 * i + 2],
                })
                .collect();
            p += 3 * nl as usize;
            superframes.push(AdvSuperframe { id, slots, links });
        }
        Ok(Advertise {
            asn: u64::from_be_bytes(asn),
            join_control: b[5],
            channel_count: b[6],
            channel_map: u16::from_le_bytes([b[7], b[8]]),
            graph_id: u16::from_be_bytes([b[9], b[10]]),
            superframes,
            extra: b[p..].to_vec(),
        })
    }

    /// Encodes the payload.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = Vec::with_capacity(32);
        v.extend_from_slice(&self.asn.to_be_bytes()[3..]);
        v.push(self.join_control);
        v.push(self.channel_count);
        v.extend_from_slice(&self.channel_map.to_le_bytes());
        v.extend_from_slice(&self.graph_id.to_be_bytes());
        v.push(self.superframes.len() as u8);
        for s in &self.superframes {
            v.push(s.id);
            v.extend_from_slice(&s.slots.to_be_bytes());
            v.push(s.links.len() as u8);
            for l in &s.links {
                v.extend_from_slice(&l.slot.to_be_bytes());
                v.push(l.flags);
            }
        }
        v.extend_from_slice(&self.extra);
        v
    }
}

impl Ack {
    /// Parses an ACK payload.
    pub fn parse(b: &[u8]) -> Result<Self, DlError> {
        if b.len() < 3 {
            return Err(short(
                "ack",
                "needs 3 bytes: response code and time adjustment",
            ));
        }
        Ok(Ack {
            response_code: b[0],
            time_adjustment: i16::from_be_bytes([b[1], b[2]]),
            extra: b[3..].to_vec(),
        })
    }
    /// Encodes the payload.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = alloc::vec![self.response_code];
        v.extend_from_slice(&self.time_adjustment.to_be_bytes());
        v.extend_from_slice(&self.extra);
        v
    }
}

impl DlBody {
    fn encode(&self) -> Vec<u8> {
        match self {
            DlBody::Ack(a) => a.encode(),
            DlBody::Advertise(a) => a.encode(),
            DlBody::Data(n) => n.encode(),
            DlBody::KeepAlive(b) | DlBody::Disconnect(b) | DlBody::Reserved(b) => b.clone(),
        }
    }
}

impl Dlpdu {
    /// Parses the data-link PDU of an 802.15.4 frame given without its FCS.
    pub fn parse(frame: &[u8]) -> Result<Self, DlError> {
        let mac = MacFrame::parse(frame).map_err(DlError::Mac)?;
        Self::from_mac(mac)
    }

    /// The data-link PDU of a parsed 802.15.4 frame.
    pub fn from_mac(mac: MacFrame) -> Result<Self, DlError> {
        let p = &mac.payload;
        if p.len() < 5 {
            return Err(DlError::TooShort { available: p.len() });
        }
        let spec = p[0];
        let (payload, m) = p[1..].split_at(p.len() - 5);
        let pdu_type = PduType::from_code(spec);
        let body = match pdu_type {
            PduType::Ack => DlBody::Ack(Ack::parse(payload)?),
            PduType::Advertise => DlBody::Advertise(Advertise::parse(payload)?),
            PduType::KeepAlive => DlBody::KeepAlive(payload.to_vec()),
            PduType::Disconnect => DlBody::Disconnect(payload.to_vec()),
            PduType::Data => DlBody::Data(Npdu::parse(payload).map_err(DlError::Network)?),
            PduType::Reserved(_) => DlBody::Reserved(payload.to_vec()),
        };
        Ok(Dlpdu {
            mac_flags: mac.flags,
            seq: mac.seq,
            network_id: mac.pan,
            src_pan: mac.src_pan,
            dst: mac.dst,
            src: mac.src,
            reserved: spec >> 6,
            priority: (spec >> 4) & 3,
            network_key: spec & 8 != 0,
            pdu_type,
            body,
            mic: [m[0], m[1], m[2], m[3]],
        })
    }

    /// A data-link PDU with the usual 802.15.4 flags (PAN ID compression) and a zero
    /// MIC; set the MIC with [`Dlpdu::seal`].
    pub fn new(
        seq: u8,
        network_id: u16,
        dst: Address,
        src: Address,
        priority: u8,
        network_key: bool,
        body: DlBody,
    ) -> Self {
        let pdu_type = match &body {
            DlBody::Ack(_) => PduType::Ack,
            DlBody::Advertise(_) => PduType::Advertise,
            DlBody::KeepAlive(_) => PduType::KeepAlive,
            DlBody::Disconnect(_) => PduType::Disconnect,
            DlBody::Data(_) => PduType::Data,
            DlBody::Reserved(_) => PduType::Reserved(4),
        };
        Dlpdu {
            mac_flags: crate::mac::FC_PAN_COMPRESSION,
            seq,
            network_id,
            src_pan: None,
            dst,
            src,
            reserved: 0,
            priority: priority & 3,
            network_key,
            pdu_type,
            body,
            mic: [0; 4],
        }
    }

    /// The specifier byte.
    pub fn specifier(&self) -> u8 {
        (self.reserved & 3) << 6
            | (self.priority & 3) << 4
            | (self.network_key as u8) << 3
            | self.pdu_type.code()
    }

    /// The frame without MIC and FCS: what the MIC authenticates.
    pub fn authenticated(&self) -> Vec<u8> {
        let mut payload = alloc::vec![self.specifier()];
        payload.extend_from_slice(&self.body.encode());
        let mac = MacFrame {
            flags: self.mac_flags,
            seq: self.seq,
            pan: self.network_id,
            src_pan: self.src_pan,
            dst: self.dst,
            src: self.src,
            payload,
        };
        mac.encode()
    }

    /// The frame without FCS.
    pub fn encode(&self) -> Vec<u8> {
        let mut v = self.authenticated();
        v.extend_from_slice(&self.mic);
        v
    }

    /// The frame with its FCS, as on air.
    pub fn encode_with_fcs(&self) -> Vec<u8> {
        let mut v = self.encode();
        let f = crate::mac::fcs(&v);
        v.extend_from_slice(&f.to_le_bytes());
        v
    }

    /// The nonce of the data-link MIC: ASN (5 bytes, big-endian) then the source
    /// address as 8 bytes (big-endian, a nickname zero-padded).
    pub fn nonce(&self, asn: u64) -> [u8; 13] {
        let mut n = [0u8; 13];
        n[..5].copy_from_slice(&asn.to_be_bytes()[3..]);
        n[5..].copy_from_slice(&self.src.nonce_bytes());
        n
    }

    /// The MIC this frame should carry under `key` at `asn`.
    pub fn compute_mic(&self, key: &Key, asn: u64) -> [u8; 4] {
        crypto::mic(key, &self.nonce(asn), &self.authenticated())
    }

    /// True when the frame's MIC verifies under `key` at `asn`.
    pub fn verify(&self, key: &Key, asn: u64) -> bool {
        self.compute_mic(key, asn) == self.mic
    }

    /// Sets the MIC for `key` at `asn`.
    pub fn seal(&mut self, key: &Key, asn: u64) {
        self.mic = self.compute_mic(key, asn);
    }
}
