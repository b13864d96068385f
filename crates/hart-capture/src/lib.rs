//! # hart-capture
//!
//! Captures of HART traffic that Wireshark and tshark open.
//!
//! **Writing** ([`CaptureWriter`]): each frame seen on a loop becomes one pcapng packet:
//! a HART-IP token-passing PDU message (HART-IP header, then the frame from delimiter to
//! check byte) in a synthetic IPv4/UDP datagram on port 5094, so Wireshark's stock
//! HART-IP dissector decodes the frame field by field. Requests (STX) go from a master's
//! address to the device's as HART-IP requests; replies (ACK) come back as responses
//! with the request's sequence number; burst frames (BACK) are publish messages. The
//! addresses tell who spoke:
//!
//! | Station | IPv4 address | UDP port |
//! |---|---|---|
//! | primary master | 10.0.0.1 | 50001 |
//! | secondary master | 10.0.0.2 | 50002 |
//! | field device, short frame at polling address N | 10.0.1.N | 5094 |
//! | field device, long frame | 10.0.2.(last byte of its device ID) | 5094 |
//!
//! Bytes that are not a valid HART frame (a damaged frame, noise) go on a second
//! interface of link type USER0 (147), which Wireshark shows as raw data, with the link
//! errors in the packet's comment. Every packet's comment also names what the capture
//! knows (the source; UART errors; the gap before the frame). Each block is written
//! whole, so a capture cut short (a full disk, a killed process) is valid up to its
//! last block.
//!
//! **Reading** ([`read_capture`]): pcapng and pcap files, ours or any capture of HART-IP
//! traffic (tcpdump on port 5094: Ethernet, Linux cooked, loopback or raw IP link
//! types; UDP, and TCP segments holding whole HART-IP messages), give back the HART
//! frames with their time stamps. Untrusted files give errors, never panics.

use std::io::Write;

use hart_proto::frame::{Address, Frame, FrameType, MasterKind};
use pcap_parser::ToVec;

/// UDP port of HART-IP (and of the field devices in our captures).
pub const HART_IP_PORT: u16 = 5094;

/// pcapng link type of the first interface: raw IPv4 (`LINKTYPE_RAW`).
pub const LINKTYPE_RAW: u16 = 101;

/// pcapng link type of the second interface: bytes that are not a HART frame
/// (`LINKTYPE_USER0`, shown as data).
pub const LINKTYPE_USER0: u16 = 147;

/// Who sent a frame, as far as the capture knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// A master's request (STX).
    Request(MasterKind),
    /// A field device's reply (ACK) to a master.
    Reply(MasterKind),
    /// A burst frame (BACK).
    Burst,
    /// Not a valid frame: who sent it is not known.
    Unknown,
}

impl Direction {
    /// The direction a frame's delimiter and address give.
    pub fn of(f: &Frame<'_>) -> Direction {
        match f.frame_type() {
            FrameType::Stx => Direction::Request(f.address.master()),
            FrameType::Ack => Direction::Reply(f.address.master()),
            FrameType::Back => Direction::Burst,
        }
    }

    /// A short name for listings and JSON.
    pub fn name(self) -> &'static str {
        match self {
            Direction::Request(MasterKind::Primary) => "primary->device",
            Direction::Request(MasterKind::Secondary) => "secondary->device",
            Direction::Reply(MasterKind::Primary) => "device->primary",
            Direction::Reply(MasterKind::Secondary) => "device->secondary",
            Direction::Burst => "burst",
            Direction::Unknown => "unknown",
        }
    }
}

/// One frame (or run of damaged bytes) to write.
#[derive(Debug, Clone)]
pub struct Record<'a> {
    /// Time the frame's last byte was seen, µs since the Unix epoch.
    pub time_us: u64,
    /// The bytes: a frame from delimiter to check byte, or damaged bytes.
    pub bytes: &'a [u8],
    /// A valid HART frame (`false`: raw data).
    pub valid: bool,
    /// What else the capture knows (source, link errors, gap), as the packet comment.
    pub comment: Option<String>,
}

/// A frame read back from a capture.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Captured {
    /// Time stamp, µs since the Unix epoch.
    pub time_us: u64,
    /// The frame from delimiter to check byte, or the raw bytes of a damaged one.
    pub bytes: Vec<u8>,
    /// Whether it parses as a HART frame.
    pub valid: bool,
    /// Who sent it.
    pub direction: Direction,
    /// The packet's comment, if any.
    pub comment: Option<String>,
}

/// Writes a pcapng capture of HART frames.
pub struct CaptureWriter<W: Write> {
    out: W,
    sequence: u16,
    ip_id: u16,
}

/// Why a capture could not be written or read.
#[derive(Debug)]
pub enum CaptureError {
    /// Writing failed (a full disk, a closed pipe).
    Io(std::io::Error),
    /// The file is not a pcap or pcapng capture, or is damaged.
    Format(String),
}

impl std::fmt::Display for CaptureError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CaptureError::Io(e) => write!(f, "{e}"),
            CaptureError::Format(e) => write!(f, "not a readable pcap or pcapng capture: {e}"),
        }
    }
}

impl std::error::Error for CaptureError {}

impl From<std::io::Error> for CaptureError {
    fn from(e: std::io::Error) -> Self {
        CaptureError::Io(e)
    }
}

fn option(code: u16, value: &[u8]) -> pcap_parser::PcapNGOption<'_> {
    pcap_parser::PcapNGOption {
        code: pcap_parser::OptionCode(code),
        len: value.len() as u16,
        value: std::borrow::Cow::Borrowed(value),
    }
}

impl<W: Write> CaptureWriter<W> {
    /// Starts a capture on `out`: the section header and the two interfaces, written
    /// (and flushed) at once, so a reader sees a valid empty capture.
    pub fn new(mut out: W, application: &str) -> Result<Self, CaptureError> {
        let mut shb = pcap_parser::SectionHeaderBlock {
            block_type: pcap_parser::SHB_MAGIC,
            block_len1: 0,
            bom: pcap_parser::BOM_MAGIC,
            major_version: 1,
            minor_version: 0,
            section_len: -1,
            options: vec![option(4, application.as_bytes())],
            block_len2: 0,
        };
        out.write_all(&to_vec(&mut shb)?)?;
        for (link, name) in [
            (LINKTYPE_RAW, "HART frames as HART-IP"),
            (LINKTYPE_USER0, "bytes that are not HART frames"),
        ] {
            let mut idb = pcap_parser::InterfaceDescriptionBlock {
                block_type: pcap_parser::IDB_MAGIC,
                block_len1: 0,
                linktype: pcap_parser::Linktype(i32::from(link)),
                reserved: 0,
                snaplen: 0,
                options: vec![option(2, name.as_bytes())],
                block_len2: 0,
                if_tsresol: 6,
                if_tsoffset: 0,
            };
            out.write_all(&to_vec(&mut idb)?)?;
        }
        out.flush()?;
        Ok(CaptureWriter {
            out,
            sequence: 0,
            ip_id: 0,
        })
    }

    /// Writes one record as one block, and flushes it (a live capture on a pipe shows
    /// each frame as it comes).
    pub fn write(&mut self, r: &Record<'_>) -> Result<(), CaptureError> {
        let frame = if r.valid {
            Frame::parse_pdu(r.bytes).ok()
        } else {
            None
        };
        let (if_id, data) = match frame {
            Some(f) => (0, self.datagram(&f)),
            None => (1, r.bytes.to_vec()),
        };
        let mut options = vec![];
        if let Some(c) = &r.comment {
            options.push(option(1, c.as_bytes()));
        }
        let mut epb = pcap_parser::EnhancedPacketBlock {
            block_type: pcap_parser::EPB_MAGIC,
            block_len1: 0,
            if_id,
            ts_high: (r.time_us >> 32) as u32,
            ts_low: r.time_us as u32,
            caplen: data.len() as u32,
            origlen: data.len() as u32,
            data: &data,
            options,
            block_len2: 0,
        };
        self.out.write_all(&to_vec(&mut epb)?)?;
        self.out.flush()?;
        Ok(())
    }

    /// The writer back.
    pub fn into_inner(self) -> W {
        self.out
    }

    /// `f` as a HART-IP token-passing PDU message in an IPv4/UDP datagram.
    fn datagram(&mut self, f: &Frame<'_>) -> Vec<u8> {
        let dir = Direction::of(f);
        let (ty, from_master) = match dir {
            Direction::Request(_) => {
                self.sequence = self.sequence.wrapping_add(1);
                (hart_ip::MessageType::Request, true)
            }
            Direction::Reply(_) => (hart_ip::MessageType::Response, false),
            _ => (hart_ip::MessageType::Publish, false),
        };
        let mut message = vec![0u8; hart_ip::HEADER_LEN + f.pdu.len()];
        let _ = hart_ip::encode(
            1,
            ty,
            hart_ip::MessageId::TokenPassingPdu,
            0,
            self.sequence,
            f.pdu,
            &mut message,
        );
        let master = match f.address.master() {
            MasterKind::Primary => ([10, 0, 0, 1], 50001),
            MasterKind::Secondary => ([10, 0, 0, 2], 50002),
        };
        let device = (device_ip(&f.address), HART_IP_PORT);
        let (src, dst) = if from_master {
            (master, device)
        } else {
            (device, master)
        };
        self.ip_id = self.ip_id.wrapping_add(1);
        ipv4_udp(src, dst, self.ip_id, &message)
    }
}

fn to_vec(b: &mut impl ToVec) -> Result<Vec<u8>, CaptureError> {
    b.to_vec()
        .map_err(|e| CaptureError::Format(format!("encoding a block: {e:?}")))
}

/// The synthetic address of the device a frame names.
fn device_ip(a: &Address) -> [u8; 4] {
    match a {
        Address::Short(s) => [10, 0, 1, s.polling_address],
        Address::Long(l) => [10, 0, 2, l.id.to_bytes()[4]],
    }
}

/// An IPv4 header (checksum computed) and a UDP header (checksum 0: none, allowed over
/// IPv4) around `payload`.
fn ipv4_udp(src: ([u8; 4], u16), dst: ([u8; 4], u16), id: u16, payload: &[u8]) -> Vec<u8> {
    let total = 20 + 8 + payload.len();
    let mut p = Vec::with_capacity(total);
    p.extend_from_slice(&[0x45, 0]);
    p.extend_from_slice(&(total as u16).to_be_bytes());
    p.extend_from_slice(&id.to_be_bytes());
    p.extend_from_slice(&[0x40, 0, 64, 17, 0, 0]); // don't fragment, TTL 64, UDP
    p.extend_from_slice(&src.0);
    p.extend_from_slice(&dst.0);
    let sum = checksum(&p[..20]);
    p[10..12].copy_from_slice(&sum.to_be_bytes());
    p.extend_from_slice(&src.1.to_be_bytes());
    p.extend_from_slice(&dst.1.to_be_bytes());
    p.extend_from_slice(&((8 + payload.len()) as u16).to_be_bytes());
    p.extend_from_slice(&[0, 0]);
    p.extend_from_slice(payload);
    p
}

/// The Internet checksum (RFC 1071).
fn checksum(b: &[u8]) -> u16 {
    let mut sum: u32 = b
        .chunks(2)
        .map(|c| u32::from(u16::from_be_bytes([c[0], *c.get(1).unwrap_or(&0)])))
        .sum();
    while sum > 0xFFFF {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    !(sum as u16)
}

mod read;
pub use read::{read_capture, read_capture_ports};

#[cfg(test)]
mod tests {
    use super::*;

    /// A command 0 request from the primary master to polling address 1, the reply, a
    /// burst frame of command 3 and damaged bytes, written and read back.
    #[test]
    fn round_trip() {
        // Frames as hart_proto encodes them (a request, its ACK, a BACK); built here
        // only to have valid check bytes.
        use hart_proto::frame::{FrameBuf, FrameSpec};
        let req = FrameBuf::encode(&FrameSpec::request(Address::short(1), 0, &[])).unwrap();
        let ack = FrameBuf::encode(&FrameSpec {
            frame_type: FrameType::Ack,
            status: Some((0, 0)),
            ..FrameSpec::request(Address::short(1), 0, &[254, 0x26, 0xF1])
        })
        .unwrap();
        let back = FrameBuf::encode(&FrameSpec {
            frame_type: FrameType::Back,
            status: Some((0, 0)),
            ..FrameSpec::request(
                Address::long(hart_proto::frame::UniqueId::new(0x26F2, 3)).with_burst(true),
                3,
                &[0x41, 0x40, 0, 0],
            )
        })
        .unwrap();
        let damaged = [0x06u8, 0x81, 0x00, 0x37];
        let mut w = CaptureWriter::new(Vec::new(), "hartkit test").unwrap();
        let t0 = 1_764_000_000_000_000u64;
        for (i, (bytes, valid)) in [
            (req.as_slice(), true),
            (ack.as_slice(), true),
            (back.as_slice(), true),
            (&damaged[..], false),
        ]
        .into_iter()
        .enumerate()
        {
            w.write(&Record {
                time_us: t0 + i as u64 * 1000,
                bytes,
                valid,
                comment: (!valid).then(|| "parity error".to_string()),
            })
            .unwrap();
        }
        let file = w.into_inner();
        let back_read = read_capture(&file[..]).unwrap();
        assert_eq!(back_read.len(), 4);
        assert_eq!(back_read[0].bytes, req.as_slice());
        assert_eq!(
            back_read[0].direction,
            Direction::Request(MasterKind::Primary)
        );
        assert_eq!(
            back_read[1].direction,
            Direction::Reply(MasterKind::Primary)
        );
        assert_eq!(back_read[2].direction, Direction::Burst);
        assert_eq!(back_read[3].bytes, damaged);
        assert!(!back_read[3].valid);
        assert_eq!(back_read[3].comment.as_deref(), Some("parity error"));
        assert_eq!(back_read[2].time_us, t0 + 2000);
        // Cut anywhere: the whole blocks before the cut, never a panic.
        for cut in 0..file.len() {
            if let Ok(frames) = read_capture(&file[..cut]) {
                assert!(frames.len() <= 4);
            }
        }
    }

    #[test]
    fn not_a_capture() {
        let e = read_capture(&b"RIFF....WAVEfmt "[..]).unwrap_err();
        assert!(e.to_string().contains("pcap"), "{e}");
    }

    #[test]
    fn ip_checksum() {
        // RFC 1071's example words sum to 0xDDF2; the checksum is its complement.
        assert_eq!(
            checksum(&[0x00, 0x01, 0xF2, 0x03, 0xF4, 0xF5, 0xF6, 0xF7]),
            !0xDDF2
        );
    }

    /// The fuzzer's find: an IPv4 header length past the packet (a pcap of raw IP
    /// whose one packet is `4F`).
    #[test]
    fn ip_header_longer_than_the_packet() {
        let mut file = vec![];
        // pcap header: magic, version 2.4, zone, sigfigs, snaplen, link type 101.
        file.extend_from_slice(&0xA1B2_C3D4u32.to_le_bytes());
        file.extend_from_slice(&[2, 0, 4, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        file.extend_from_slice(&65_535u32.to_le_bytes());
        file.extend_from_slice(&101u32.to_le_bytes());
        // One record: time, caplen 1, len 1, the byte 0x4F (IPv4, header 60 bytes).
        file.extend_from_slice(&[0; 8]);
        file.extend_from_slice(&1u32.to_le_bytes());
        file.extend_from_slice(&1u32.to_le_bytes());
        file.push(0x4F);
        assert_eq!(read_capture(&file[..]).unwrap(), vec![]);
    }

    proptest::proptest! {
        /// Any bytes: a list of frames or an error, never a panic.
        #[test]
        fn any_file(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..400)) {
            let _ = read_capture(&bytes[..]);
        }
    }
}
