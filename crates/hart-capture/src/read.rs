//! Reading HART frames back from pcapng and pcap files.

use hart_proto::frame::Frame;
use pcap_parser::{Block, Linktype, PcapBlockOwned, PcapError};

use crate::{CaptureError, Captured, Direction, HART_IP_PORT, LINKTYPE_USER0};

/// Reads every HART frame of a pcapng or pcap capture from `input` (a file's bytes, as
/// read): token-passing PDUs of HART-IP messages on UDP or TCP port 5094 (whole
/// messages in a segment; segments are not reassembled), and the raw data of link type
/// USER0 that our captures hold for damaged frames. Anything else is passed over. A
/// file cut short gives the frames up to its last whole block.
pub fn read_capture(input: impl std::io::Read + Send) -> Result<Vec<Captured>, CaptureError> {
    read_capture_ports(input, &[HART_IP_PORT])
}

/// [`read_capture`] with HART-IP on these UDP/TCP ports.
pub fn read_capture_ports(
    mut input: impl std::io::Read + Send,
    ports: &[u16],
) -> Result<Vec<Captured>, CaptureError> {
    let mut reader = pcap_parser::create_reader(65_536, &mut input)
        .map_err(|e| CaptureError::Format(describe(&e)))?;
    let mut out = vec![];
    // Per pcapng interface: link type and time resolution (ticks per second).
    let mut interfaces: Vec<(Linktype, u64, i64)> = vec![];
    let mut legacy: (Linktype, bool) = (Linktype::ETHERNET, false);
    loop {
        match reader.next() {
            Ok((used, block)) => {
                match block {
                    PcapBlockOwned::LegacyHeader(h) => {
                        legacy = (h.network, h.is_nanosecond_precision());
                    }
                    PcapBlockOwned::Legacy(b) => {
                        let frac = if legacy.1 {
                            u64::from(b.ts_usec) / 1000
                        } else {
                            u64::from(b.ts_usec)
                        };
                        let t = u64::from(b.ts_sec) * 1_000_000 + frac;
                        let data = &b.data[..(b.caplen as usize).min(b.data.len())];
                        frames_of(legacy.0, data, t, None, ports, &mut out);
                    }
                    PcapBlockOwned::NG(Block::SectionHeader(_)) => interfaces.clear(),
                    PcapBlockOwned::NG(Block::InterfaceDescription(idb)) => {
                        let per_second = idb.ts_resolution().unwrap_or(1_000_000);
                        interfaces.push((idb.linktype, per_second, idb.ts_offset()));
                    }
                    PcapBlockOwned::NG(Block::EnhancedPacket(epb)) => {
                        if let Some(&(link, per_second, offset)) =
                            interfaces.get(epb.if_id as usize)
                        {
                            let ticks = (u64::from(epb.ts_high) << 32) | u64::from(epb.ts_low);
                            let t = ticks_to_us(ticks, per_second, offset);
                            let comment = epb.options.iter().find(|o| o.code.0 == 1).map(|o| {
                                String::from_utf8_lossy(
                                    &o.value[..usize::from(o.len).min(o.value.len())],
                                )
                                .into_owned()
                            });
                            let data = &epb.data[..(epb.caplen as usize).min(epb.data.len())];
                            frames_of(link, data, t, comment, ports, &mut out);
                        }
                    }
                    PcapBlockOwned::NG(Block::SimplePacket(spb)) => {
                        if let Some(&(link, _, _)) = interfaces.first() {
                            frames_of(link, spb.data, 0, None, ports, &mut out);
                        }
                    }
                    _ => {}
                }
                reader.consume(used);
            }
            Err(PcapError::Eof) => break,
            Err(PcapError::Incomplete(_)) => {
                if reader.refill().is_err() {
                    break;
                }
                // No more bytes: a capture cut inside its last block.
                if reader.reader_exhausted() {
                    break;
                }
            }
            Err(e) => return Err(CaptureError::Format(describe(&e))),
        }
    }
    Ok(out)
}

fn describe<I: std::fmt::Debug>(e: &PcapError<I>) -> String {
    match e {
        PcapError::HeaderNotRecognized => {
            "the file does not start with a pcap or pcapng header".into()
        }
        PcapError::Eof => "the file is empty".into(),
        e => format!("{e:?}"),
    }
}

fn ticks_to_us(ticks: u64, per_second: u64, offset_s: i64) -> u64 {
    let us = if per_second == 1_000_000 {
        ticks
    } else if per_second == 0 {
        0
    } else {
        (u128::from(ticks) * 1_000_000 / u128::from(per_second)).min(u128::from(u64::MAX)) as u64
    };
    us.saturating_add_signed(offset_s.saturating_mul(1_000_000))
}

/// The HART frames in one packet of link type `link`.
fn frames_of(
    link: Linktype,
    data: &[u8],
    t: u64,
    comment: Option<String>,
    ports: &[u16],
    out: &mut Vec<Captured>,
) {
    if link == Linktype(i32::from(LINKTYPE_USER0)) {
        let valid = Frame::parse_pdu(data).is_ok_and(|f| f.checksum_ok());
        out.push(Captured {
            time_us: t,
            bytes: data.to_vec(),
            valid,
            direction: Direction::Unknown,
            comment,
        });
        return;
    }
    let Some(ip) = ip_payload(link, data) else {
        return;
    };
    let Some(payload) = transport_payload(ip, ports) else {
        return;
    };
    let mut rest = payload;
    while !rest.is_empty() {
        let Ok((m, used)) = hart_ip::Message::parse(rest) else {
            return;
        };
        rest = &rest[used..];
        if m.header.message_id != hart_ip::MessageId::TokenPassingPdu || m.body.is_empty() {
            continue;
        }
        let (valid, direction) = match Frame::parse_pdu(m.body) {
            Ok(f) => (f.checksum_ok(), Direction::of(&f)),
            Err(_) => (false, Direction::Unknown),
        };
        out.push(Captured {
            time_us: t,
            bytes: m.body.to_vec(),
            valid,
            direction,
            comment: comment.clone(),
        });
    }
}

/// The IP packet inside a link-layer frame.
fn ip_payload(link: Linktype, d: &[u8]) -> Option<&[u8]> {
    match link.0 {
        // Raw IP (12 on some systems, 101 LINKTYPE_RAW, 228 IPv4, 229 IPv6).
        12 | 101 | 228 | 229 => Some(d),
        // Ethernet: skip 802.1Q tags.
        1 => {
            let mut at = 12;
            loop {
                let ty = u16::from_be_bytes([*d.get(at)?, *d.get(at + 1)?]);
                match ty {
                    0x8100 | 0x88A8 => at += 4,
                    0x0800 | 0x86DD => return d.get(at + 2..),
                    _ => return None,
                }
            }
        }
        // BSD loopback / null: a 4-byte family.
        0 | 108 => d.get(4..),
        // Linux cooked capture v1 (16 bytes) and v2 (20 bytes).
        113 => d.get(16..),
        276 => d.get(20..),
        _ => None,
    }
}

/// The UDP or TCP payload of an IPv4 or IPv6 packet to or from one of `ports`.
fn transport_payload<'a>(ip: &'a [u8], ports: &[u16]) -> Option<&'a [u8]> {
    let (proto, rest) = match ip.first()? >> 4 {
        4 => {
            let ihl = usize::from(ip[0] & 0x0F) * 4;
            if !(20..=ip.len()).contains(&ihl) {
                return None;
            }
            let total = usize::from(u16::from_be_bytes([*ip.get(2)?, *ip.get(3)?]));
            let end = total.clamp(ihl, ip.len());
            (*ip.get(9)?, ip.get(ihl..end)?)
        }
        6 => (*ip.get(6)?, ip.get(40..)?),
        _ => return None,
    };
    let port = |b: &[u8], at: usize| Some(u16::from_be_bytes([*b.get(at)?, *b.get(at + 1)?]));
    let (src, dst) = (port(rest, 0)?, port(rest, 2)?);
    if !ports.contains(&src) && !ports.contains(&dst) {
        return None;
    }
    match proto {
        17 => rest.get(8..),
        6 => {
            let off = usize::from(rest.get(12)? >> 4) * 4;
            rest.get(off..)
        }
        _ => None,
    }
}
