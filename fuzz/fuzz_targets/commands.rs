//! Typed command decoders: first two bytes pick the command and direction, the rest is
//! the data. Whatever decodes must re-encode to the bytes it consumed.
#![no_main]
use hart_proto::command::COMMANDS;
use hart_proto::wire::Writer;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if data.len() < 2 {
        return;
    }
    let info = &COMMANDS[usize::from(data[0]) % COMMANDS.len()];
    let body = &data[2..];
    let mut out = [0u8; 512];
    if data[1] & 1 == 0 {
        if let Some(Ok(r)) = hart_proto::decode_request(info.number, body) {
            let mut w = Writer::new(&mut out);
            r.encode(&mut w).unwrap();
            assert_eq!(w.written(), &body[..r.encoded_len()]);
        }
    } else if let Some(Ok(r)) = hart_proto::decode_response(info.number, body) {
        let mut w = Writer::new(&mut out);
        r.encode(&mut w).unwrap();
        assert_eq!(w.written(), &body[..r.encoded_len()]);
    }
});
