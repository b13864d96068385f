//! Frame codec tests: one table of field-commented frames, each checked in both
//! directions (parse the bytes and compare the fields; build from the fields and compare
//! the bytes).
//!
//! Source of the frames: the worked examples of hart-reference.md §13 (check bytes
//! verified there by an independent implementation, `crates/hartkit/tests/oracle`);
//! frames captured from real devices live in `tests/vectors/public.toml`.

use hart_proto::frame::*;

struct Case {
    name: &'static str,
    bytes: &'static [u8],
    preambles: usize,
    frame_type: FrameType,
    address: Address,
    command: u16,
    status: Option<(u8, u8)>,
    data: &'static [u8],
}

const DEV: UniqueId = UniqueId {
    expanded_device_type: 0x2606,
    device_id: 0x123456,
};

fn long(master: MasterKind, burst: bool) -> Address {
    Address::Long(LongAddress {
        master,
        burst,
        id: DEV,
    })
}

fn short(master: MasterKind, p: u8) -> Address {
    Address::Short(ShortAddress {
        master,
        burst: false,
        polling_address: p,
    })
}

use MasterKind::{Primary, Secondary};

fn cases() -> Vec<Case> {
    vec![
        Case {
            name: "cmd 0 request, short, poll 0, primary",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, // preamble
                0x02, // delimiter: STX, short address
                0x80, // address: primary master, polling address 0
                0x00, // command 0
                0x00, // byte count 0
                0x82, // check byte
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: short(Primary, 0),
            command: 0,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 0 request, short, poll 0, secondary",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, /* secondary, poll 0 */ 0x00, 0x00, 0x00,
                0x02,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: short(Secondary, 0),
            command: 0,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 0 request, short, poll 5",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, /* primary, poll 5 */ 0x85, 0x00, 0x00,
                0x87,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: short(Primary, 5),
            command: 0,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 0 request, short, poll 63 (HART 6/7 range)",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, /* primary, poll 63 */ 0xBF, 0x00, 0x00,
                0xBD,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: short(Primary, 63),
            command: 0,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 0 reply, HART 7 (22 data bytes)",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, // preamble
                0x06, // ACK, short
                0x80, // primary, poll 0
                0x00, // command 0
                0x18, // byte count 24 = 2 status + 22 data
                0x00, 0x00, // RC 0, device status 0
                0xFE, 0x26, 0x06, 0x05, 0x07, 0x01, 0x02, 0x18, 0x00, 0x12, 0x34,
                0x56, // HART 5 part
                0x05, 0x04, 0x00, 0x01, 0x00, // HART 6 part
                0x00, 0x26, 0x00, 0x26, 0x01, // HART 7 part
                0x28, // check byte
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: short(Primary, 0),
            command: 0,
            status: Some((0, 0)),
            data: &[
                0xFE, 0x26, 0x06, 0x05, 0x07, 0x01, 0x02, 0x18, 0x00, 0x12, 0x34, 0x56, 0x05, 0x04,
                0x00, 0x01, 0x00, 0x00, 0x26, 0x00, 0x26, 0x01,
            ],
        },
        Case {
            name: "cmd 1 request, long, primary",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x82, /* address */ 0xA6, 0x06, 0x12, 0x34,
                0x56, 0x01, 0x00, 0x53,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: long(Primary, false),
            command: 1,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 1 reply 12.5 psi",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x01, //
                0x07, // byte count: 2 status + 5 data
                0x00, 0x00, // status
                0x06, // psi
                0x41, 0x48, 0x00, 0x00, // 12.5
                0x5F,
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: long(Primary, false),
            command: 1,
            status: Some((0, 0)),
            data: &[0x06, 0x41, 0x48, 0x00, 0x00],
        },
        Case {
            name: "cmd 11 broadcast with tag PT-101",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x82, //
                0x80, 0x00, 0x00, 0x00, 0x00, // broadcast from the primary master
                0x0B, 0x06, //
                0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20, // "PT-101  " packed
                0x8F,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: Address::Long(LongAddress {
                master: Primary,
                burst: false,
                id: UniqueId::BROADCAST,
            }),
            command: 11,
            status: None,
            data: &[0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20],
        },
        Case {
            name: "cmd 35 error reply RC 9, configuration changed",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x23, 0x02,
                /* RC */ 0x09, /* status */ 0x40, 0x3E,
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: long(Primary, false),
            command: 35,
            status: Some((9, 0x40)),
            data: &[],
        },
        Case {
            name: "communication error reply (check byte error)",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x01, 0x02,
                /* comm error + LRC */ 0x88, 0x00, 0xDD,
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: long(Primary, false),
            command: 1,
            status: Some((0x88, 0)),
            data: &[],
        },
        Case {
            name: "cmd 31 request: extended command 0x0400",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x82, 0xA6, 0x06, 0x12, 0x34, 0x56,
                /* 31 */ 0x1F, 0x02, /* 1024 */ 0x04, 0x00, 0x4B,
            ],
            preambles: 5,
            frame_type: FrameType::Stx,
            address: long(Primary, false),
            command: 0x0400,
            status: None,
            data: &[],
        },
        Case {
            name: "cmd 31 reply with one data byte",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x1F, //
                0x05, // 2 status + 2 command + 1 data
                0x00, 0x00, 0x04, 0x00, 0xAA, 0xE2,
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: long(Primary, false),
            command: 0x0400,
            status: Some((0, 0)),
            data: &[0xAA],
        },
        Case {
            name: "cmd 31 RC 64 reply keeps the command number",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x1F, 0x04, 0x40,
                0x00, 0x04, 0x00, 0x09,
            ],
            preambles: 5,
            frame_type: FrameType::Ack,
            address: long(Primary, false),
            command: 0x0400,
            status: Some((64, 0)),
            data: &[],
        },
        Case {
            name: "BACK cmd 1 to the secondary master, burst bit set",
            bytes: &[
                0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x81, //
                0x66, 0x06, 0x12, 0x34, 0x56, // secondary (bit 7 clear), burst (bit 6 set)
                0x01, 0x07, 0x00, 0x00, 0x06, 0x41, 0x48, 0x00, 0x00, 0x98,
            ],
            preambles: 5,
            frame_type: FrameType::Back,
            address: long(Secondary, true),
            command: 1,
            status: Some((0, 0)),
            data: &[0x06, 0x41, 0x48, 0x00, 0x00],
        },
        Case {
            name: "bare PDU (as inside HART-IP): no preamble",
            bytes: &[0x02, 0x80, 0x00, 0x00, 0x82],
            preambles: 0,
            frame_type: FrameType::Stx,
            address: short(Primary, 0),
            command: 0,
            status: None,
            data: &[],
        },
        Case {
            name: "two preambles are enough",
            bytes: &[0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x82],
            preambles: 2,
            frame_type: FrameType::Stx,
            address: short(Primary, 0),
            command: 0,
            status: None,
            data: &[],
        },
    ]
}

#[test]
fn parse_every_case() {
    for c in cases() {
        let f = Frame::parse(c.bytes).unwrap_or_else(|e| panic!("{}: {e}", c.name));
        assert_eq!(f.preambles, c.preambles, "{}", c.name);
        assert_eq!(f.frame_type(), c.frame_type, "{}", c.name);
        assert_eq!(f.address, c.address, "{}", c.name);
        assert_eq!(f.command, c.command, "{}", c.name);
        assert_eq!(f.response_code.zip(f.device_status), c.status, "{}", c.name);
        assert_eq!(f.data, c.data, "{}", c.name);
        assert!(f.checksum_ok(), "{}", c.name);
        assert!(f.trailing.is_empty(), "{}", c.name);
    }
}

#[test]
fn encode_every_case() {
    for c in cases() {
        let spec = FrameSpec {
            preambles: c.preambles,
            frame_type: c.frame_type,
            address: c.address,
            expansion: &[],
            physical_layer: 0,
            command: c.command,
            extended: false,
            status: c.status,
            data: c.data,
        };
        let mut out = [0u8; 300];
        let n = spec
            .encode(&mut out)
            .unwrap_or_else(|e| panic!("{}: {e}", c.name));
        assert_eq!(&out[..n], c.bytes, "{}", c.name);
        assert_eq!(n, spec.encoded_len(), "{}", c.name);
    }
}

#[test]
fn four_preambles_and_trailing_garbage() {
    // Real HART 5 devices answer with 4 preambles; bytes after the check byte stay apart.
    let bytes = [
        0xFF, 0xFF, 0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x01, 0x07, 0x00, 0x00, 0x06,
        0x41, 0x48, 0x00, 0x00, 0x5F, 0x00, 0xFF, 0x13,
    ];
    let f = Frame::parse(&bytes).unwrap();
    assert_eq!(f.preambles, 4);
    assert!(f.checksum_ok());
    assert_eq!(f.trailing, &[0x00, 0xFF, 0x13]);
    assert_eq!(f.pdu.len(), 16);
}

#[test]
fn long_address_fields() {
    // Manufacturer 0x1A, device type 0x1A, device ID 0xAD188C: the first address byte
    // carries the master bit and the manufacturer ID masked to 6 bits.
    let id = UniqueId::from_manufacturer(0x1A, 0x1A, 0xAD188C);
    let a = Address::Long(LongAddress {
        master: Primary,
        burst: false,
        id,
    });
    let mut out = [0u8; 16];
    let n = FrameSpec::request(a, 1, &[]).encode(&mut out).unwrap();
    assert_eq!(&out[5..11], &[0x82, 0x9A, 0x1A, 0xAD, 0x18, 0x8C]);
    let f = Frame::parse(&out[..n]).unwrap();
    let Address::Long(l) = f.address else {
        panic!()
    };
    assert_eq!(l.id.manufacturer_id(), 0x1A);
    assert_eq!(l.id.device_type(), 0x1A);
    assert_eq!(l.id.to_string(), "1A1AAD188C");
    // A manufacturer ID above 63 keeps only its low 6 bits, as every HART master does.
    assert_eq!(
        UniqueId::from_manufacturer(0x66, 0x06, 1).manufacturer_id(),
        0x26
    );
    assert_eq!(
        UniqueId::parse_hex("26 4E 00 00 D2").unwrap(),
        UniqueId::new(0x264E, 0xD2)
    );
    assert!(UniqueId::parse_hex("E64E0000D2").is_err());
    assert!(UniqueId::parse_hex("264E0000").is_err());
}

#[test]
fn status_only_replies() {
    // A busy reply to command 3: status bytes, no data.
    let b = [
        0xFF, 0xFF, 0x86, 0xA6, 0x06, 0x12, 0x34, 0x56, 0x03, 0x02, 0x20, 0x00,
    ];
    let mut v = b.to_vec();
    v.push(hart_proto::frame::checksum(&b[2..]));
    let f = Frame::parse(&v).unwrap();
    assert_eq!(f.response_code, Some(32));
    assert!(f.data.is_empty());
    assert!(f.checksum_ok());
    // Command-31 reply to a request too short to carry the number (RC 5): status only.
    let b = [0x06, 0x80, 0x1F, 0x02, 0x05, 0x00];
    let mut v = b.to_vec();
    v.push(hart_proto::frame::checksum(&b));
    let f = Frame::parse(&v).unwrap();
    assert_eq!(
        (f.command, f.extended, f.response_code),
        (31, false, Some(5))
    );
}

#[test]
fn negative_cases() {
    use FrameError::*;
    let err = |b: &[u8]| Frame::parse(b).unwrap_err();
    assert_eq!(err(&[]), Empty);
    assert_eq!(err(&[0xFF, 0xFF, 0xFF]), NoDelimiter { preambles: 3 });
    assert_eq!(
        err(&[0xFF, 0x02, 0x80, 0x00, 0x00, 0x82]),
        TooFewPreambles { offset: 1 }
    );
    assert_eq!(
        err(&[0xFF, 0xFF, 0x03, 0x80, 0x00, 0x00, 0x82]),
        InvalidDelimiter {
            offset: 2,
            value: 3
        }
    );
    // Truncated in the address, the header, the data (byte count past the end), the check byte.
    assert!(matches!(
        err(&[0xFF, 0xFF, 0x82, 0xA6, 0x06]),
        Truncated {
            field: "address",
            offset: 3,
            ..
        }
    ));
    assert!(matches!(
        err(&[0xFF, 0xFF, 0x02, 0x80, 0x00]),
        Truncated {
            field: "byte count",
            offset: 5,
            ..
        }
    ));
    assert!(matches!(
        err(&[0xFF, 0xFF, 0x02, 0x80, 0x00, 0x05, 0x01]),
        Truncated {
            field: "data (byte count)",
            offset: 6,
            expected: 5,
            available: 1
        }
    ));
    assert!(matches!(
        err(&[0x02, 0x80, 0x00, 0x00]),
        Truncated {
            field: "check byte",
            ..
        }
    ));
    // ACK with byte count 1 cannot hold the two status bytes.
    assert!(matches!(
        err(&[0x06, 0x80, 0x00, 0x01, 0x00, 0x87]),
        ByteCountTooSmall { minimum: 2, .. }
    ));
    // Command 31 with fewer than 2 bytes.
    assert!(matches!(
        err(&[0x02, 0x80, 0x1F, 0x01, 0x04, 0x9A]),
        ByteCountTooSmall {
            byte_count: 1,
            minimum: 2,
            ..
        }
    ));
    assert!(matches!(
        err(&[0x06, 0x80, 0x1F, 0x03, 0x00, 0x00, 0x04, 0x9E]),
        ByteCountTooSmall { minimum: 4, .. }
    ));
    // Bad checksum is reported, not an error.
    let f = Frame::parse(&[0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x83]).unwrap();
    assert!(!f.checksum_ok());
    assert_eq!(f.expected_check_byte, 0x82);
    // Every error explains itself with the byte offset.
    let msg = err(&[0xFF, 0xFF, 0x02, 0x80, 0x00, 0x05, 0x01]).to_string();
    assert!(msg.contains("truncated") && msg.contains("byte 6"), "{msg}");
}

#[test]
fn encoder_limits() {
    let mut out = [0u8; 400];
    let data = [0u8; 256];
    assert!(FrameSpec::request(Address::short(0), 1, &data[..255])
        .encode(&mut out)
        .is_ok());
    assert!(FrameSpec::request(Address::short(0), 1, &data)
        .encode(&mut out)
        .is_err());
    // ACK: 2 status bytes count too.
    assert!(FrameSpec::reply(Address::short(0), 1, 0, 0, &data[..254])
        .encode(&mut out)
        .is_err());
    let mut small = [0u8; 4];
    assert!(FrameSpec::request(Address::short(0), 1, &[])
        .encode(&mut small)
        .is_err());
    // Commands above 255 go through command 31 automatically.
    let n = FrameSpec {
        preambles: 0,
        ..FrameSpec::request(Address::short(1), 1024, &[])
    }
    .encode(&mut out)
    .unwrap();
    assert_eq!(&out[..n], &[0x02, 0x81, 0x1F, 0x02, 0x04, 0x00, 0x9A]);
}

/// Optional fields end a layout: a 13-byte command 105 reply holds everything up to the
/// maximum number of burst messages, and its 13th byte (too short for the command
/// number) is surplus, not a trigger mode.
#[test]
fn bytes_after_an_absent_optional_field_are_surplus() {
    let mut data = [0u8; 13];
    data[12] = 4;
    let Some(Ok(hart_proto::Response::ReadBurstConfiguration(c))) =
        hart_proto::decode_response(105, &data)
    else {
        panic!("command 105 reply did not decode");
    };
    assert_eq!(c.max_burst_messages, Some(0));
    assert_eq!(c.command_number, None);
    assert_eq!(c.trigger_mode, None);
}
