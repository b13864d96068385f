//! WirelessHART decoders: the first byte picks the layer (802.15.4 + data link, network,
//! transport, a command layout, the capture reader, the stateful decoder); the rest is
//! the input. What parses must re-encode to the same bytes; nothing may panic.
#![no_main]
use hart_wireless::commands::{self, COMMANDS};
use hart_wireless::{capture, decoder, Dlpdu, Npdu, Tpdu};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, rest)) = data.split_first() else {
        return;
    };
    match sel % 6 {
        0 => {
            if let Ok(d) = Dlpdu::parse(rest) {
                assert_eq!(d.encode(), rest);
                let _ = d.verify(&hart_wireless::WELL_KNOWN_KEY, 0);
            }
        }
        1 => {
            if let Ok(n) = Npdu::parse(rest) {
                assert_eq!(n.encode(), rest);
                let _ = n.decrypt(&[0x41; 16], 7);
            }
        }
        2 => {
            if let Ok(t) = Tpdu::parse(rest) {
                assert_eq!(t.encode(), rest);
            }
        }
        3 => {
            let Some((&which, body)) = rest.split_first() else {
                return;
            };
            let info = &COMMANDS[usize::from(which >> 1) % COMMANDS.len()];
            if let Some(Ok(t)) = commands::decode(info.number, which & 1 == 1, body) {
                let again = commands::encode(&t).unwrap();
                assert_eq!(&body[..again.len()], &again[..]);
            }
        }
        4 => {
            let _ = capture::read(rest);
        }
        _ => {
            let mut d = decoder::Decoder::new();
            d.add_join_key([0x41; 16]);
            for (i, f) in rest.split(|&b| b == 0x7E).enumerate() {
                let p = capture::Packet {
                    time_ns: i as u64 * 10_000_000,
                    channel: Some(11),
                    frame: f.to_vec(),
                    fcs_ok: None,
                };
                let r = d.decode(i, &p);
                let _ = (r.to_json(), r.to_line());
            }
        }
    }
});
