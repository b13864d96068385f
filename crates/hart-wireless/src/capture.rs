//! A small pcap and pcapng reader and a pcap writer for IEEE 802.15.4 captures: link
//! types 195 (802.15.4 with FCS), 230 (802.15.4 without FCS) and 283 (IEEE 802.15.4
//! TAP, whose TLVs give the FCS length and the channel).

use alloc::string::String;
use alloc::vec::Vec;
use core::fmt;

/// Link type 195: IEEE 802.15.4 frames ending with their FCS.
pub const LINKTYPE_IEEE802_15_4_WITHFCS: u32 = 195;
/// Link type 230: IEEE 802.15.4 frames without FCS.
pub const LINKTYPE_IEEE802_15_4_NOFCS: u32 = 230;
/// Link type 283: IEEE 802.15.4 TAP (a TLV header, then the frame).
pub const LINKTYPE_IEEE802_15_4_TAP: u32 = 283;

/// One captured 802.15.4 frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Packet {
    /// Capture time in nanoseconds since the Unix epoch.
    pub time_ns: u64,
    /// The radio channel (11-26), when the capture says.
    pub channel: Option<u8>,
    /// The frame from frame control to the end of the payload (FCS removed).
    pub frame: Vec<u8>,
    /// Whether the FCS was good; `None` when the capture holds no FCS.
    pub fcs_ok: Option<bool>,
}

/// Why a capture file could not be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CaptureError {
    /// Neither the pcap nor the pcapng magic number.
    NotACapture,
    /// The file ends inside a header or block.
    Truncated {
        /// Byte offset of the incomplete header or block.
        offset: usize,
    },
    /// A link type this reader does not take.
    LinkType(u32),
    /// A pcapng block that contradicts itself.
    BadBlock {
        /// Byte offset of the block.
        offset: usize,
        /// What was wrong.
        reason: &'static str,
    },
}

impl fmt::Display for CaptureError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CaptureError::NotACapture => f.write_str(
                "not a pcap or pcapng file (unknown magic number); save the capture as pcap or pcapng",
            ),
            CaptureError::Truncated { offset } => write!(
                f,
                "the capture ends inside a header at byte {offset}; was the file cut short?"
            ),
            CaptureError::LinkType(t) => write!(
                f,
                "link type {t} is not IEEE 802.15.4; hartkit reads link types 195 (with FCS), 230 (without FCS) and 283 (TAP)"
            ),
            CaptureError::BadBlock { offset, reason } => {
                write!(f, "pcapng block at byte {offset}: {reason}")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for CaptureError {}

/// Reads every frame of a pcap or pcapng file.
pub fn read(data: &[u8]) -> Result<Vec<Packet>, CaptureError> {
    if data.len() < 4 {
        return Err(CaptureError::NotACapture);
    }
    match &data[..4] {
        [0x0A, 0x0D, 0x0D, 0x0A] => read_pcapng(data),
        _ => read_pcap(data),
    }
}

fn rd16(b: &[u8], le: bool) -> u16 {
    let a = [b[0], b[1]];
    if le {
        u16::from_le_bytes(a)
    } else {
        u16::from_be_bytes(a)
    }
}

fn rd32(b: &[u8], le: bool) -> u32 {
    let a = [b[0], b[1], b[2], b[3]];
    if le {
        u32::from_le_bytes(a)
    } else {
        u32::from_be_bytes(a)
    }
}

fn read_pcap(d: &[u8]) -> Result<Vec<Packet>, CaptureError> {
    let (le, nano) = match rd32(d, true) {
        0xA1B2_C3D4 => (true, false),
        0xA1B2_3C4D => (true, true),
        _ => match rd32(d, false) {
            0xA1B2_C3D4 => (false, false),
            0xA1B2_3C4D => (false, true),
            _ => return Err(CaptureError::NotACapture),
        },
    };
    if d.len() < 24 {
        return Err(CaptureError::Truncated { offset: 0 });
    }
    let link = rd32(&d[20..], le) & 0x0FFF_FFFF;
    check_link(link)?;
    let mut out = Vec::new();
    let mut p = 24;
    while p < d.len() {
        if d.len() - p < 16 {
            return Err(CaptureError::Truncated { offset: p });
        }
        let sec = rd32(&d[p..], le) as u64;
        let frac = rd32(&d[p + 4..], le) as u64;
        let incl = rd32(&d[p + 8..], le) as usize;
        let start = p + 16;
        if d.len() - start < incl {
            return Err(CaptureError::Truncated { offset: p });
        }
        let time_ns = sec * 1_000_000_000 + if nano { frac } else { frac * 1000 };
        out.push(packet(link, time_ns, &d[start..start + incl]));
        p = start + incl;
    }
    Ok(out)
}

fn check_link(link: u32) -> Result<(), CaptureError> {
    match link {
        LINKTYPE_IEEE802_15_4_WITHFCS | LINKTYPE_IEEE802_15_4_NOFCS | LINKTYPE_IEEE802_15_4_TAP => {
            Ok(())
        }
        t => Err(CaptureError::LinkType(t)),
    }
}

fn read_pcapng(d: &[u8]) -> Result<Vec<Packet>, CaptureError> {
    let mut out = Vec::new();
    let mut le = true;
    // (link type, time units per second) of each interface of the current section.
    let mut ifaces: Vec<(u32, u64)> = Vec::new();
    let mut p = 0;
    while p < d.len() {
        if d.len() - p < 12 {
            return Err(CaptureError::Truncated { offset: p });
        }
        let btype_raw = &d[p..p + 4];
        if btype_raw == [0x0A, 0x0D, 0x0D, 0x0A] {
            le = match &d[p + 8..p + 12] {
                [0x4D, 0x3C, 0x2B, 0x1A] => true,
                [0x1A, 0x2B, 0x3C, 0x4D] => false,
                _ => {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "unknown byte-order magic",
                    })
                }
            };
            ifaces.clear();
        }
        let btype = rd32(btype_raw, le);
        let blen = rd32(&d[p + 4..], le) as usize;
        if blen < 12 || blen % 4 != 0 {
            return Err(CaptureError::BadBlock {
                offset: p,
                reason: "block length is not a multiple of 4 of at least 12",
            });
        }
        if d.len() - p < blen {
            return Err(CaptureError::Truncated { offset: p });
        }
        let body = &d[p + 8..p + blen - 4];
        match btype {
            1 => {
                if body.len() < 8 {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "interface description block too short",
                    });
                }
                let link = rd16(body, le) as u32;
                let mut units = 1_000_000u64;
                let mut o = 8;
                while o + 4 <= body.len() {
                    let code = rd16(&body[o..], le);
                    let len = rd16(&body[o + 2..], le) as usize;
                    if code == 0 || body.len() - o - 4 < len {
                        break;
                    }
                    if code == 9 && len >= 1 {
                        let r = body[o + 4];
                        let (base, exp) = if r & 0x80 != 0 {
                            (2u64, r & 0x7F)
                        } else {
                            (10, r)
                        };
                        units = base.checked_pow(exp as u32).unwrap_or(1_000_000);
                    }
                    o += 4 + len.div_ceil(4) * 4;
                }
                ifaces.push((link, units.max(1)));
            }
            6 => {
                if body.len() < 20 {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "enhanced packet block too short",
                    });
                }
                let iface = rd32(body, le) as usize;
                let ts = (rd32(&body[4..], le) as u64) << 32 | rd32(&body[8..], le) as u64;
                let caplen = rd32(&body[12..], le) as usize;
                if body.len() - 20 < caplen {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "captured length runs past the block",
                    });
                }
                let Some(&(link, units)) = ifaces.get(iface) else {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "packet names an interface that was not described",
                    });
                };
                check_link(link)?;
                let time_ns = (ts / units)
                    .saturating_mul(1_000_000_000)
                    .saturating_add((ts % units) * 1_000_000_000 / units);
                out.push(packet(link, time_ns, &body[20..20 + caplen]));
            }
            3 => {
                let Some(&(link, _)) = ifaces.first() else {
                    return Err(CaptureError::BadBlock {
                        offset: p,
                        reason: "simple packet block before any interface",
                    });
                };
                check_link(link)?;
                if body.len() >= 4 {
                    let olen = (rd32(body, le) as usize).min(body.len() - 4);
                    out.push(packet(link, 0, &body[4..4 + olen]));
                }
            }
            _ => {}
        }
        p += blen;
    }
    Ok(out)
}

fn packet(link: u32, time_ns: u64, raw: &[u8]) -> Packet {
    let mut channel = None;
    let (frame, fcs_len) = match link {
        LINKTYPE_IEEE802_15_4_TAP => {
            let mut fcs_len = 2;
            let hlen = if raw.len() >= 4 {
                (u16::from_le_bytes([raw[2], raw[3]]) as usize).clamp(4, raw.len())
            } else {
                raw.len()
            };
            let mut o = 4;
            while hlen >= o + 4 {
                let t = u16::from_le_bytes([raw[o], raw[o + 1]]);
                let l = u16::from_le_bytes([raw[o + 2], raw[o + 3]]) as usize;
                let v = &raw[o + 4..hlen.min(o + 4 + l)];
                match (t, v) {
                    (0, [f, ..]) => {
                        fcs_len = match f {
                            0 => 0,
                            2 => 4,
                            _ => 2,
                        }
                    }
                    (3, [lo, hi, ..]) => {
                        channel = u8::try_from(u16::from_le_bytes([*lo, *hi])).ok()
                    }
                    _ => {}
                }
                o += 4 + l.div_ceil(4) * 4;
            }
            (&raw[hlen..], fcs_len)
        }
        LINKTYPE_IEEE802_15_4_NOFCS => (raw, 0),
        _ => (raw, 2),
    };
    if fcs_len == 0 || frame.len() < fcs_len {
        return Packet {
            time_ns,
            channel,
            frame: frame.to_vec(),
            fcs_ok: None,
        };
    }
    let (body, f) = frame.split_at(frame.len() - fcs_len);
    let ok = if fcs_len == 2 {
        crate::mac::fcs(body) == u16::from_le_bytes([f[0], f[1]])
    } else {
        // A 32-bit FCS: not used by WirelessHART; not checked.
        true
    };
    Packet {
        time_ns,
        channel,
        frame: body.to_vec(),
        fcs_ok: Some(ok),
    }
}

/// Writes frames (each without FCS; it is computed here) as a pcap file of link type
/// 195, the form Wireshark's `wpan` dissector reads with an FCS check.
pub fn write_pcap(frames: &[(u64, &[u8])]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&0xA1B2_C3D4u32.to_le_bytes());
    v.extend_from_slice(&2u16.to_le_bytes());
    v.extend_from_slice(&4u16.to_le_bytes());
    v.extend_from_slice(&[0; 8]);
    v.extend_from_slice(&65535u32.to_le_bytes());
    v.extend_from_slice(&LINKTYPE_IEEE802_15_4_WITHFCS.to_le_bytes());
    for (t, f) in frames {
        let n = (f.len() + 2) as u32;
        v.extend_from_slice(&((t / 1_000_000_000) as u32).to_le_bytes());
        v.extend_from_slice(&((t % 1_000_000_000 / 1000) as u32).to_le_bytes());
        v.extend_from_slice(&n.to_le_bytes());
        v.extend_from_slice(&n.to_le_bytes());
        v.extend_from_slice(f);
        v.extend_from_slice(&crate::mac::fcs(f).to_le_bytes());
    }
    v
}

/// Lowercase hex of `b`.
pub fn hex(b: &[u8]) -> String {
    use core::fmt::Write;
    let mut s = String::with_capacity(b.len() * 2);
    for x in b {
        let _ = write!(s, "{x:02x}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn block(t: u32, body: &[u8]) -> Vec<u8> {
        let len = (12 + body.len()) as u32;
        let mut v = t.to_le_bytes().to_vec();
        v.extend_from_slice(&len.to_le_bytes());
        v.extend_from_slice(body);
        v.extend_from_slice(&len.to_le_bytes());
        v
    }

    #[test]
    fn pcapng_option_padding_past_the_block_is_no_panic() {
        let mut shb = 0x1A2B_3C4Du32.to_le_bytes().to_vec();
        shb.extend_from_slice(&[1, 0, 0, 0]);
        shb.extend_from_slice(&[0xFF; 8]);
        let mut f = block(0x0A0D_0D0A, &shb);
        // An interface whose last option (1 byte of if_tsresol) is not padded.
        let mut idb = 195u16.to_le_bytes().to_vec();
        idb.extend_from_slice(&[0, 0, 0, 0, 0, 0]);
        idb.extend_from_slice(&[9, 0, 1, 0, 6]);
        idb.extend_from_slice(&[0, 0, 0]);
        f.extend_from_slice(&block(1, &idb));
        let frame = [0x41, 0x88, 1, 0xCD, 0x04, 1, 0, 2, 0, 0x3A, 1, 2, 3, 4];
        let mut epb = vec![0u8; 12];
        epb.extend_from_slice(&((frame.len() + 2) as u32).to_le_bytes());
        epb.extend_from_slice(&((frame.len() + 2) as u32).to_le_bytes());
        epb.extend_from_slice(&frame);
        epb.extend_from_slice(&crate::mac::fcs(&frame).to_le_bytes());
        epb.resize(epb.len().div_ceil(4) * 4, 0);
        f.extend_from_slice(&block(6, &epb));
        let p = read(&f).unwrap();
        assert_eq!(p.len(), 1);
        assert_eq!(p[0].fcs_ok, Some(true));
        assert_eq!(p[0].frame, frame);
        // Cut anywhere: an error, never a panic.
        for n in 0..f.len() {
            let _ = read(&f[..n]);
        }
    }

    #[test]
    fn tap_header_channel_and_fcs() {
        let frame = [0x41, 0x88, 1, 0xCD, 0x04, 1, 0, 2, 0, 0x3A, 1, 2, 3, 4];
        // TAP: version, reserved, length 16; TLV 0 (FCS type 1), TLV 3 (channel 15, page 0).
        let mut raw = vec![0, 0, 20, 0, 0, 0, 1, 0, 1, 0, 0, 0, 3, 0, 3, 0, 15, 0, 0, 0];
        raw.extend_from_slice(&frame);
        raw.extend_from_slice(&crate::mac::fcs(&frame).to_le_bytes());
        let p = packet(LINKTYPE_IEEE802_15_4_TAP, 0, &raw);
        assert_eq!((p.channel, p.fcs_ok), (Some(15), Some(true)));
        assert_eq!(p.frame, frame);
        for n in 0..raw.len() {
            let _ = packet(LINKTYPE_IEEE802_15_4_TAP, 0, &raw[..n]);
        }
    }
}
