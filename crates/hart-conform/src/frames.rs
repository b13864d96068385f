//! Received characters to frames, with their timing: the tester's own receiver,
//! lenient on purpose (it accepts what a device sends so that the test meant for a
//! fault can name it, while the other tests look at the content). Sans-IO: it works on
//! characters already timestamped by the transport.

use hart_proto::frame::{Delimiter, Frame, FrameType, PREAMBLE};

use crate::model::{hex, SeenFrame};

/// A received character: the byte, whether the UART flagged it, when it finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Char {
    /// The byte.
    pub byte: u8,
    /// True when the UART reported a parity, framing or overrun error.
    pub damaged: bool,
    /// When it finished arriving, µs.
    pub at: u64,
}

/// A frame found in received characters.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RxFrame {
    /// The bytes, preambles included.
    pub bytes: Vec<u8>,
    /// Preambles before the delimiter.
    pub preambles: usize,
    /// Start of its first character, µs.
    pub start: u64,
    /// End of its last character, µs.
    pub end: u64,
    /// Longest pause between two characters beyond one character time, µs.
    pub max_gap: u64,
    /// True when every byte its byte count asks for arrived.
    pub complete: bool,
    /// True when a character of it was flagged by the UART.
    pub damaged: bool,
}

impl RxFrame {
    /// The frame from its delimiter on.
    pub fn pdu(&self) -> &[u8] {
        &self.bytes[self.preambles..]
    }

    /// The parsed frame (the check byte is not checked here: see
    /// [`Frame::checksum_ok`]).
    pub fn frame(&self) -> Option<Frame<'_>> {
        if !self.complete {
            return None;
        }
        Frame::parse_pdu(self.pdu()).ok()
    }

    /// The frame type, if the delimiter is valid.
    pub fn frame_type(&self) -> Option<FrameType> {
        Delimiter::from_byte(*self.pdu().first()?).map(|d| d.frame_type)
    }

    /// A short decoding for evidence.
    pub fn summary(&self) -> String {
        if !self.complete {
            return format!("incomplete frame ({} bytes)", self.bytes.len());
        }
        match self.frame() {
            None => "undecodable frame".into(),
            Some(f) => {
                let mut s = format!(
                    "{} {} cmd {}",
                    f.frame_type().name(),
                    address_text(&f.address),
                    f.command
                );
                if let (Some(rc), Some(ds)) = (f.response_code, f.device_status) {
                    s.push_str(&format!(" rc {rc} status 0x{ds:02X}"));
                }
                s.push_str(&format!(" {} data byte(s)", f.data.len()));
                if !f.checksum_ok() {
                    s.push_str(&format!(
                        ", check byte 0x{:02X} (0x{:02X} expected)",
                        f.check_byte, f.expected_check_byte
                    ));
                }
                if self.damaged {
                    s.push_str(", UART errors");
                }
                s
            }
        }
    }

    /// The evidence form, times relative to `t0`.
    pub fn seen(&self, t0: u64) -> SeenFrame {
        SeenFrame {
            hex: hex(&self.bytes),
            preambles: self.preambles,
            start_us: self.start.saturating_sub(t0),
            end_us: self.end.saturating_sub(t0),
            max_gap_us: self.max_gap,
            summary: self.summary(),
        }
    }
}

/// An address as text: `poll N` or `id XXXXXXXXXX`, with the master.
pub fn address_text(a: &hart_proto::frame::Address) -> String {
    use hart_proto::frame::Address;
    let m = match a.master() {
        hart_proto::frame::MasterKind::Primary => "primary",
        hart_proto::frame::MasterKind::Secondary => "secondary",
    };
    match a {
        Address::Short(s) => format!("poll {} ({m})", s.polling_address),
        Address::Long(l) => {
            let b = l.id.to_bytes();
            format!("id {} ({m})", hex(&b).replace(' ', ""))
        }
    }
}

/// How many bytes a frame has from its delimiter on, once `pdu` holds enough of it to
/// tell (`None` until then, or for an invalid delimiter).
pub fn pdu_len(pdu: &[u8]) -> Option<usize> {
    let d = Delimiter::from_byte(*pdu.first()?)?;
    let head = 1 + d.address_len() + usize::from(d.expansion_len) + 1;
    let bc = *pdu.get(head)?;
    Some(head + 1 + usize::from(bc) + 1)
}

/// Splits received characters into frames. `char_time` is one character's duration,
/// µs. A frame starts with at least two preambles and a valid delimiter (the start of
/// message); other bytes are skipped; a frame cut short is kept with `complete` false.
pub fn split(chars: &[Char], char_time: u64) -> Vec<RxFrame> {
    let mut out = vec![];
    let mut i = 0;
    while i < chars.len() {
        // Preambles, then a delimiter.
        let start_i = i;
        while i < chars.len() && chars[i].byte == PREAMBLE {
            i += 1;
        }
        if i >= chars.len() {
            break;
        }
        // Start of message: at least two preambles, then a delimiter (HART ref §2.1).
        if i - start_i < 2 || Delimiter::from_byte(chars[i].byte).is_none() {
            // Not a frame start: skip one byte and look again.
            i = start_i.max(i) + 1;
            continue;
        }
        let preambles = i - start_i;
        let mut bytes: Vec<u8> = chars[start_i..=i].iter().map(|c| c.byte).collect();
        let mut last = i;
        i += 1;
        let mut want = None;
        while i < chars.len() {
            let pdu = &bytes[preambles..];
            if want.is_none() {
                want = pdu_len(pdu);
            }
            if want.is_some_and(|w| pdu.len() >= w) {
                break;
            }
            bytes.push(chars[i].byte);
            last = i;
            i += 1;
        }
        let pdu = &bytes[preambles..];
        let complete = pdu_len(pdu).is_some_and(|w| pdu.len() >= w);
        let span = &chars[start_i..=last];
        let max_gap = span
            .windows(2)
            .map(|w| w[1].at.saturating_sub(w[0].at).saturating_sub(char_time))
            .max()
            .unwrap_or(0);
        out.push(RxFrame {
            bytes,
            preambles,
            start: chars[start_i].at.saturating_sub(char_time),
            end: chars[last].at,
            max_gap,
            complete,
            damaged: span.iter().any(|c| c.damaged),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chars(bytes: &[u8], t0: u64, ct: u64) -> Vec<Char> {
        bytes
            .iter()
            .enumerate()
            .map(|(i, &b)| Char {
                byte: b,
                damaged: false,
                at: t0 + (i as u64 + 1) * ct,
            })
            .collect()
    }

    #[test]
    fn two_frames_with_a_gap_inside_one() {
        // An ACK to poll 0, command 1, status only.
        let ack = [0xFF, 0xFF, 0x06, 0x80, 0x01, 0x02, 0x00, 0x00, 0x85];
        let mut c = chars(&ack, 1000, 100);
        // A gap of 300 µs beyond the character time after the 5th byte.
        for x in &mut c[5..] {
            x.at += 300;
        }
        let back = chars(
            &[0xFF, 0xFF, 0x01, 0x80, 0x01, 0x02, 0x00, 0x00, 0x82],
            5000,
            100,
        );
        c.extend(back);
        let f = split(&c, 100);
        assert_eq!(f.len(), 2);
        assert!(f[0].complete && f[1].complete);
        assert_eq!(f[0].max_gap, 300);
        assert_eq!(f[0].start, 1000);
        assert_eq!(f[0].preambles, 2);
        assert_eq!(f[1].frame_type(), Some(FrameType::Back));
    }

    #[test]
    fn garbage_and_truncation_never_panic() {
        for n in 0..12 {
            let bytes: Vec<u8> = (0..n).map(|i| (i * 37 + 6) as u8).collect();
            let _ = split(&chars(&bytes, 0, 10), 10);
        }
        let f = split(&chars(&[0xFF, 0xFF, 0x86, 0x80], 0, 10), 10);
        assert_eq!(f.len(), 1);
        assert!(!f[0].complete);
        assert!(f[0].frame().is_none());
    }
}
