//! Property tests: round trips for every typed command and for frames, and the
//! deframer's robustness on arbitrary input.

use hart_proto::command::COMMANDS;
use hart_proto::deframer::{Deframer, DeframerEvent, UartFlags};
use hart_proto::frame::{
    Address, Frame, FrameSpec, FrameType, LongAddress, MasterKind, ShortAddress, UniqueId,
};
use hart_proto::wire::Writer;
use hart_proto::{decode_request, decode_response};
use proptest::prelude::*;

/// For every command in the table and any data of a plausible length: whatever decodes
/// re-encodes to exactly the bytes it consumed, and decoding that again gives the same
/// bytes (floats are compared by bit pattern, so NaN payloads must survive).
#[test]
fn every_command_round_trips() {
    for info in COMMANDS {
        for (max, is_request) in [(info.request_max, true), (info.response_max, false)] {
            // A fresh runner per command: a runner counts its passed cases across runs.
            let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig {
                cases: 256,
                ..ProptestConfig::default()
            });
            let strategy = proptest::collection::vec(any::<u8>(), 0..=max + 4);
            runner
                .run(&strategy, |data| {
                    let mut out = [0u8; 300];
                    if is_request {
                        if let Some(Ok(r)) = decode_request(info.number, &data) {
                            let mut w = Writer::new(&mut out);
                            r.encode(&mut w).unwrap();
                            let n = w.position();
                            prop_assert_eq!(n, r.encoded_len());
                            prop_assert_eq!(
                                &out[..n],
                                &data[..n],
                                "command {} request",
                                info.number
                            );
                            let again = decode_request(info.number, &out[..n]).unwrap().unwrap();
                            let mut out2 = [0u8; 300];
                            let mut w2 = Writer::new(&mut out2);
                            again.encode(&mut w2).unwrap();
                            prop_assert_eq!(w2.written(), &out[..n]);
                        } else {
                            // Only data shorter than the full layout may fail (some layouts have several
                            // valid lengths, e.g. command 107's 1-4 or 9 bytes).
                            prop_assert!(
                                data.len() < info.request_max,
                                "command {} request of {} bytes",
                                info.number,
                                data.len()
                            );
                        }
                    } else if let Some(Ok(r)) = decode_response(info.number, &data) {
                        let mut w = Writer::new(&mut out);
                        r.encode(&mut w).unwrap();
                        let n = w.position();
                        prop_assert_eq!(n, r.encoded_len());
                        prop_assert_eq!(&out[..n], &data[..n], "command {} response", info.number);
                    } else {
                        prop_assert!(
                            data.len() < info.response_max,
                            "command {} response of {} bytes",
                            info.number,
                            data.len()
                        );
                    }
                    Ok(())
                })
                .unwrap_or_else(|e| panic!("command {}: {e}", info.number));
        }
    }
}

/// Data of the full layout length always decodes (no layout rejects its own size).
#[test]
fn full_length_data_always_decodes() {
    for info in COMMANDS {
        let req = vec![0u8; info.request_max];
        let resp = vec![0u8; info.response_max];
        assert!(
            matches!(decode_request(info.number, &req), Some(Ok(_))),
            "command {} request",
            info.number
        );
        assert!(
            matches!(decode_response(info.number, &resp), Some(Ok(_))),
            "command {} response",
            info.number
        );
    }
}

fn address() -> impl Strategy<Value = Address> {
    let master = prop_oneof![Just(MasterKind::Primary), Just(MasterKind::Secondary)];
    prop_oneof![
        (master.clone(), any::<bool>(), 0u8..64).prop_map(|(master, burst, polling_address)| {
            Address::Short(ShortAddress {
                master,
                burst,
                polling_address,
            })
        }),
        (master, any::<bool>(), 0u16..0x4000, 0u32..0x0100_0000).prop_map(
            |(master, burst, t, d)| Address::Long(LongAddress {
                master,
                burst,
                id: UniqueId::new(t, d)
            })
        ),
    ]
}

fn frame_type() -> impl Strategy<Value = FrameType> {
    prop_oneof![
        Just(FrameType::Stx),
        Just(FrameType::Ack),
        Just(FrameType::Back)
    ]
}

proptest! {
    #[test]
    fn frames_round_trip(
        preambles in prop_oneof![Just(0usize), 2usize..25],
        ft in frame_type(),
        address in address(),
        expansion in proptest::collection::vec(any::<u8>(), 0..=3),
        command in any::<u16>(),
        rc in any::<u8>(),
        ds in any::<u8>(),
        data in proptest::collection::vec(any::<u8>(), 0..=251),
        trailing in proptest::collection::vec(any::<u8>(), 0..4),
    ) {
        let spec = FrameSpec { preambles, frame_type: ft, address, expansion: &expansion, physical_layer: 0, command, extended: command == 31, status: Some((rc, ds)), data: &data };
        let mut out = vec![0u8; spec.encoded_len()];
        let n = spec.encode(&mut out).unwrap();
        out.truncate(n);
        out.extend_from_slice(&trailing);
        let f = Frame::parse(&out).unwrap();
        prop_assert_eq!(f.preambles, preambles);
        prop_assert_eq!(f.frame_type(), ft);
        prop_assert_eq!(f.address, address);
        prop_assert_eq!(f.expansion, &expansion[..]);
        prop_assert_eq!(f.command, command);
        prop_assert_eq!(f.data, &data[..]);
        prop_assert_eq!(f.trailing, &trailing[..]);
        prop_assert!(f.checksum_ok());
        if ft != FrameType::Stx {
            prop_assert_eq!(f.response_code, Some(rc));
            prop_assert_eq!(f.device_status, Some(ds));
        }
        // The deframer finds the same frame in the byte stream.
        if preambles >= 2 {
            let mut found = vec![];
            Deframer::default().feed(&out[..n], |e| if let DeframerEvent::Frame(f) = e { found.push(f.pdu.to_vec()) });
            prop_assert_eq!(found, vec![out[preambles..n].to_vec()]);
        }
    }

    #[test]
    fn encode_never_panics_on_any_spec(
        preambles in prop_oneof![0usize..300, Just(usize::MAX), Just(usize::MAX - 3)],
        data_len in prop_oneof![0usize..300, Just(100_000usize)],
        command in any::<u16>(),
        address in address(),
        frame_type in frame_type(),
        extended in any::<bool>(),
    ) {
        let data = vec![0x5Au8; data_len];
        let spec = FrameSpec {
            preambles,
            frame_type,
            extended,
            status: frame_type.has_status().then_some((0, 0)),
            ..FrameSpec::request(address, command, &data)
        };
        let _ = spec.encoded_len();
        let mut out = [0u8; 600];
        if let Ok(n) = spec.encode(&mut out) {
            prop_assert!(n <= out.len());
            prop_assert!(preambles <= hart_proto::frame::MAX_PREAMBLES);
            // The PDU after the preambles is always a frame; with the whole frame, a
            // receiver needs two preambles at least to find it (or none, a PDU).
            prop_assert!(Frame::parse_pdu(&out[preambles..n]).is_ok());
            if preambles != 1 {
                prop_assert!(Frame::parse(&out[..n]).is_ok());
            }
        }
    }

    #[test]
    fn parse_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = Frame::parse(&bytes);
        let _ = Frame::parse_pdu(&bytes);
    }

    #[test]
    fn deframer_never_panics(bytes in proptest::collection::vec((any::<u8>(), 0u8..8), 0..2000), abort_every in 1usize..500) {
        let mut d = Deframer::default();
        let mut events = 0usize;
        for (i, &(b, f)) in bytes.iter().enumerate() {
            let flags = UartFlags { parity: f & 1 != 0 && f > 5, framing: f & 2 != 0 && f > 5, overrun: f & 4 != 0 && f > 6 };
            d.push(b, flags, &mut |_| events += 1);
            if i % abort_every == abort_every - 1 {
                d.abort(&mut |_| events += 1);
            }
        }
        let s = d.stats();
        prop_assert!(s.frames + s.damaged + s.invalid <= bytes.len() as u64);
    }

    /// A good frame after garbage (without 0xFF, which could open a false start that
    /// happens to pass its check byte) is always found once the line goes quiet.
    #[test]
    fn frame_after_garbage_is_found(garbage in proptest::collection::vec(0u8..0xFF, 0..300), poll in 0u8..64) {
        let mut out = [0u8; 64];
        let n = FrameSpec::request(Address::short(poll), 1, &[]).encode(&mut out).unwrap();
        let mut d = Deframer::default();
        let mut found = vec![];
        let mut sink = |e: DeframerEvent<'_>| if let DeframerEvent::Frame(f) = e { found.push(f.pdu.to_vec()) };
        d.feed(&garbage, &mut sink);
        d.feed(&out[..n], &mut sink);
        d.abort(&mut sink);
        prop_assert_eq!(found, vec![out[5..n].to_vec()]);
    }
}

/// Every data length from 0 to past each layout's maximum, with three fill patterns:
/// whatever decodes re-encodes to the bytes it consumed (catches length-dependent forms,
/// e.g. the legacy and HART 7 forms of commands 107 and 108).
#[test]
fn every_length_round_trips() {
    for info in COMMANDS {
        for len in 0..=info.request_max.max(info.response_max) + 4 {
            for fill in [0x00u8, 0xFA, 0xFF] {
                let data = vec![fill; len];
                let mut out = [0u8; 300];
                if let Some(Ok(r)) = decode_request(info.number, &data) {
                    let mut w = Writer::new(&mut out);
                    r.encode(&mut w).unwrap_or_else(|e| {
                        panic!("command {} request of {len} bytes: {e}", info.number)
                    });
                    assert_eq!(
                        w.written(),
                        &data[..r.encoded_len()],
                        "command {} request of {len} bytes",
                        info.number
                    );
                }
                if let Some(Ok(r)) = decode_response(info.number, &data) {
                    let mut w = Writer::new(&mut out);
                    r.encode(&mut w).unwrap_or_else(|e| {
                        panic!("command {} response of {len} bytes: {e}", info.number)
                    });
                    assert_eq!(
                        w.written(),
                        &data[..r.encoded_len()],
                        "command {} response of {len} bytes",
                        info.number
                    );
                }
            }
        }
    }
}
