//! Streaming deframer: bytes with UART flags and gaps. Every good frame it reports must
//! parse again with a good check byte.
#![no_main]
use hart_proto::deframer::{Deframer, DeframerEvent, UartFlags};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut d = Deframer::default();
    let mut check = |e: DeframerEvent<'_>| {
        if let DeframerEvent::Frame(f) = e {
            let again = hart_proto::Frame::parse_pdu(f.pdu).expect("reported frames parse");
            assert!(again.checksum_ok());
        }
    };
    // Each input byte pair is (control, value): control selects UART flags or a gap.
    for pair in data.chunks(2) {
        let (ctl, b) = (pair[0], *pair.get(1).unwrap_or(&0xFF));
        if ctl == 0xA5 {
            d.abort(&mut check);
            continue;
        }
        let flags = if ctl & 0xF0 == 0xE0 {
            UartFlags { parity: ctl & 1 != 0, framing: ctl & 2 != 0, overrun: ctl & 4 != 0 }
        } else {
            UartFlags::OK
        };
        d.push(b, flags, &mut check);
    }
    d.abort(&mut check);
});
