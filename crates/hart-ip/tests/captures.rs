//! Real HART-IP messages from public captures
//! (crates/hart-proto/tests/vectors/hartip_captures.toml) decode as the captures say,
//! and re-encode byte for byte.

use hart_ip::{encode, Body, Message, MessageId, MessageType};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

#[test]
fn captured_messages_decode_and_reencode() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../hart-proto/tests/vectors/hartip_captures.toml"
    ))
    .unwrap();
    let doc: toml::Value = toml::from_str(&text).unwrap();
    let vectors = doc["vector"].as_array().unwrap();
    assert!(vectors.len() >= 20);
    for v in vectors {
        let name = v["name"].as_str().unwrap();
        let bytes = hex(v["hex"].as_str().unwrap());
        let (m, used) = Message::parse(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(used, bytes.len(), "{name}");
        let e = &v["expect"];
        let int = |k: &str| e.get(k).and_then(|x| x.as_integer());
        assert_eq!(Some(i64::from(m.header.version)), int("version"), "{name}");
        assert_eq!(
            Some(i64::from(m.header.message_type.code())),
            int("message_type"),
            "{name}"
        );
        assert_eq!(
            Some(i64::from(m.header.message_id.code())),
            int("message_id"),
            "{name}"
        );
        assert_eq!(Some(i64::from(m.header.status)), int("status"), "{name}");
        assert_eq!(
            Some(i64::from(m.header.sequence)),
            int("sequence"),
            "{name}"
        );
        assert_eq!(
            Some(i64::from(m.header.byte_count)),
            int("byte_count"),
            "{name}"
        );
        if let Some(pdu) = e.get("pdu").and_then(|p| p.as_str()) {
            let want: Vec<u8> = (0..pdu.len() / 2)
                .map(|i| u8::from_str_radix(&pdu[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            assert_eq!(m.body, &want[..], "{name}");
            match m.body() {
                Ok(Body::TokenPassing(f)) => assert_eq!(f.pdu, &want[..], "{name}"),
                other => panic!("{name}: {other:?}"),
            }
        }
        let mut out = [0u8; 2048];
        let n = encode(
            m.header.version,
            m.header.message_type,
            m.header.message_id,
            m.header.status,
            m.header.sequence,
            m.body,
            &mut out,
        )
        .unwrap();
        assert_eq!(&out[..n], &bytes[..], "{name}: re-encoding");
    }
}

#[test]
fn reference_examples() {
    // hart-reference.md §13 (derived examples; checked against the captures above).
    let si = hex("01 00 00 00 00 01 00 0D 01 00 00 EA 60");
    let (m, _) = Message::parse(&si).unwrap();
    assert_eq!(
        (m.header.message_type, m.header.message_id),
        (MessageType::Request, MessageId::SessionInitiate)
    );
    match m.body().unwrap() {
        Body::SessionInitiate(s) => assert_eq!((s.master_type, s.inactivity_timer_ms), (1, 60_000)),
        b => panic!("{b:?}"),
    }
    let dpdu = hex("02 00 04 00 00 05 00 10 00 00 00 00 00 00 30 00");
    let (m, _) = Message::parse(&dpdu).unwrap();
    let Body::Direct { entries, .. } = m.body().unwrap() else {
        panic!()
    };
    let cmds: Vec<u16> = hart_ip::DirectEntries(entries)
        .map(|e| e.unwrap().command)
        .collect();
    assert_eq!(cmds, vec![0, 48]);
}

#[test]
fn malformed_inputs_are_errors() {
    use hart_ip::Error::*;
    assert_eq!(
        Message::parse(&[1, 0, 2]).unwrap_err(),
        ShortHeader { available: 3 }
    );
    assert_eq!(
        Message::parse(&[1, 0, 2, 0, 0, 1, 0, 4]).unwrap_err(),
        ByteCountTooSmall { byte_count: 4 }
    );
    assert_eq!(
        Message::parse(&[1, 0, 2, 0, 0, 1, 0, 20, 0]).unwrap_err(),
        Truncated {
            byte_count: 20,
            available: 9
        }
    );
    let (m, _) = Message::parse(&[1, 0, 0, 0, 0, 1, 0, 10, 1, 0]).unwrap();
    assert!(matches!(m.body(), Err(BodyTooShort { needed: 5, .. })));
    let (m, _) = Message::parse(&[1, 0, 3, 0, 0, 1, 0, 10, 0x03, 0x80]).unwrap();
    assert!(matches!(m.body(), Err(BadPdu(_))));
    let (m, _) = Message::parse(&[1, 0x30, 2, 0, 0, 1, 0, 8]).unwrap();
    assert_eq!(
        m.header.reserved, 3,
        "reserved bits are reported for the server to act on"
    );
    // Two messages in one buffer (TCP stream, UDP datagram).
    let two = [1u8, 0, 2, 0, 0, 1, 0, 8, 1, 0, 2, 0, 0, 2, 0, 8];
    let (a, n) = Message::parse(&two).unwrap();
    let (b, _) = Message::parse(&two[n..]).unwrap();
    assert_eq!((a.header.sequence, b.header.sequence), (1, 2));
}

proptest::proptest! {
    #[test]
    fn never_panics(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300)) {
        if let Ok((m, n)) = Message::parse(&bytes) {
            proptest::prop_assert!(n <= bytes.len());
            let _ = m.body();
            if let Ok(Body::Direct { entries, .. }) = m.body() {
                for _ in hart_ip::DirectEntries(entries) {}
            }
        }
    }
}
