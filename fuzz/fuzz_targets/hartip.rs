//! HART-IP message decoder: a stream of arbitrary bytes split into messages; every
//! message that parses re-encodes to the same bytes.
#![no_main]
use hart_ip::{encode, Message};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut rest = data;
    while let Ok((m, n)) = Message::parse(rest) {
        let _ = m.body();
        let mut out = vec![0u8; n];
        if m.header.reserved == 0 {
            let k = encode(m.header.version, m.header.message_type, m.header.message_id, m.header.status, m.header.sequence, m.body, &mut out).unwrap();
            assert_eq!(&out[..k], &rest[..n]);
        }
        rest = &rest[n..];
    }
});
