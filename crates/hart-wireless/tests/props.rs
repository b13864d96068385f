//! Property tests and standard CCM vectors: round trips of every layer and every
//! command layout, AES-CCM against published vectors, wrong keys, arbitrary bytes.

use aes::Aes128;
use ccm::aead::generic_array::GenericArray;
use ccm::aead::{Aead, KeyInit, Payload};
use ccm::consts::{U13, U4, U7, U8};
use hart_wireless::build::{join_npdu, tpdu};
use hart_wireless::commands::{self, COMMANDS};
use hart_wireless::dll::{Ack, DlBody};
use hart_wireless::{crypto, Address, Dlpdu, Npdu, Tpdu};
use proptest::prelude::*;

fn unhex(s: &str) -> Vec<u8> {
    let s: String = s.split_whitespace().collect();
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

/// NIST SP 800-38C, Appendix C, Example 1: CCM with a 4-byte tag (Tlen = 32), the MIC
/// length WirelessHART uses (with a 7-byte nonce there; WirelessHART's is 13 bytes).
#[test]
fn ccm_nist_sp800_38c_example_1() {
    let c = ccm::Ccm::<Aes128, U4, U7>::new(GenericArray::from_slice(&unhex(
        "404142434445464748494a4b4c4d4e4f",
    )));
    let out = c
        .encrypt(
            GenericArray::from_slice(&unhex("10111213141516")),
            Payload {
                msg: &unhex("20212223"),
                aad: &unhex("0001020304050607"),
            },
        )
        .unwrap();
    assert_eq!(out, unhex("7162015b4dac255d"));
}

/// RFC 3610, section 8, Packet Vector #1: a 13-byte nonce as in WirelessHART (M = 8).
#[test]
fn ccm_rfc3610_packet_vector_1() {
    let c = ccm::Ccm::<Aes128, U8, U13>::new(GenericArray::from_slice(&unhex(
        "C0C1C2C3C4C5C6C7C8C9CACBCCCDCECF",
    )));
    let packet = unhex("000102030405060708090A0B0C0D0E0F101112131415161718191A1B1C1D1E");
    let out = c
        .encrypt(
            GenericArray::from_slice(&unhex("00000003020100A0A1A2A3A4A5")),
            Payload {
                msg: &packet[8..],
                aad: &packet[..8],
            },
        )
        .unwrap();
    assert_eq!(
        out,
        unhex("588C979A61C663D2F066D0C2C0F989806D5F6B61DAC38417E8D12CFDF926E0")
    );
}

/// Our M = 4, 13-byte-nonce wrapper agrees with the crate used directly.
#[test]
fn wrapper_is_ccm_with_a_4_byte_tag() {
    let key = [7u8; 16];
    let nonce = [1u8; 13];
    let mut data = b"hello".to_vec();
    let mic = crypto::encrypt(&key, &nonce, b"aad", &mut data);
    let c = ccm::Ccm::<Aes128, U4, U13>::new(GenericArray::from_slice(&key));
    let direct = c
        .encrypt(
            GenericArray::from_slice(&nonce),
            Payload {
                msg: b"hello",
                aad: b"aad",
            },
        )
        .unwrap();
    assert_eq!([&data[..], &mic[..]].concat(), direct);
    assert_eq!(crypto::mic(&key, &nonce, b"aad"), {
        let t = c
            .encrypt(
                GenericArray::from_slice(&nonce),
                Payload {
                    msg: b"",
                    aad: b"aad",
                },
            )
            .unwrap();
        [t[0], t[1], t[2], t[3]]
    });
}

fn addr() -> impl Strategy<Value = Address> {
    prop_oneof![
        any::<u16>().prop_map(Address::Short),
        any::<u64>().prop_map(Address::Long)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_never_panic_and_parsed_frames_re_encode(b in proptest::collection::vec(any::<u8>(), 0..140)) {
        if let Ok(d) = Dlpdu::parse(&b) {
            prop_assert_eq!(d.encode(), b.clone());
        }
        if let Ok(n) = Npdu::parse(&b) {
            prop_assert_eq!(n.encode(), b.clone());
            // Any key: never panics, and (for this test's random data) never opens.
            prop_assert!(n.decrypt(&[0x42; 16], 0).is_none());
        }
        if let Ok(t) = Tpdu::parse(&b) {
            prop_assert_eq!(t.encode(), b.clone());
        }
    }

    #[test]
    fn arbitrary_captures_and_frames_never_panic(
        b in proptest::collection::vec(any::<u8>(), 0..200),
        frames in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..80), 0..6),
    ) {
        let _ = hart_wireless::capture::read(&b);
        let mut pcap = b"\xd4\xc3\xb2\xa1".to_vec();
        pcap.extend_from_slice(&b[..b.len().min(24)]);
        let _ = hart_wireless::capture::read(&pcap);
        let mut d = hart_wireless::decoder::Decoder::new();
        d.add_join_key([0x41; 16]);
        d.add_network_key([0x5A; 16]);
        for (i, f) in frames.iter().enumerate() {
            let p = hart_wireless::capture::Packet { time_ns: i as u64 * 1_000_000, channel: None, frame: f.clone(), fcs_ok: None };
            let r = d.decode(i, &p);
            let _ = (r.to_json(), r.to_line());
        }
    }

    #[test]
    fn every_command_layout_round_trips(b in proptest::collection::vec(any::<u8>(), 0..256), response in any::<bool>()) {
        for c in COMMANDS {
            if let Some(Ok(t)) = commands::decode(c.number, response, &b) {
                let again = commands::encode(&t).unwrap();
                let t2 = commands::decode(c.number, response, &again).unwrap().unwrap();
                // (Compared as bytes: a float field may be NaN, unequal to itself.)
                prop_assert_eq!(commands::encode(&t2).unwrap(), again.clone());
                // What was decoded is a prefix of the data (surplus bytes are ignored).
                prop_assert_eq!(&b[..again.len()], &again[..]);
            }
        }
    }

    #[test]
    fn data_frames_round_trip_and_wrong_keys_fail(
        key in any::<[u8; 16]>(), wrong in any::<[u8; 16]>(), dst in addr(), src in addr(),
        counter in any::<u32>(), asn in 0u64..(1 << 40), seq in any::<u8>(),
        cmds in proptest::collection::vec((any::<u16>(), proptest::collection::vec(any::<u8>(), 0..40)), 0..4),
    ) {
        prop_assume!(key != wrong);
        let list: Vec<(u16, &[u8])> = cmds.iter().map(|(n, d)| (*n, d.as_slice())).collect();
        let t = tpdu(false, seq, &list);
        let plain = t.encode();
        let n = join_npdu(dst, src, counter, &key, &plain);
        prop_assert_eq!(n.decrypt(&key, counter), Some(plain.clone()));
        prop_assert_eq!(n.decrypt(&wrong, counter), None);
        prop_assert_eq!(n.decrypt(&key, counter ^ 1), None);
        prop_assert_eq!(Tpdu::parse(&plain).unwrap(), t);
        let mut d = Dlpdu::new(seq, 0x04CD, Address::Short(1), src, 3, true, DlBody::Data(n));
        d.seal(&key, asn);
        let bytes = d.encode();
        let back = Dlpdu::parse(&bytes).unwrap();
        prop_assert_eq!(&back, &d);
        prop_assert!(back.verify(&key, asn));
        prop_assert!(!back.verify(&wrong, asn));
        prop_assert!(!back.verify(&key, asn ^ 1));
        // The FCS form parses back too.
        let (mac, ok) = hart_wireless::MacFrame::parse_with_fcs(&d.encode_with_fcs()).unwrap();
        prop_assert!(ok);
        prop_assert_eq!(mac.encode(), bytes);
    }

    #[test]
    fn a_flipped_bit_fails_the_mic(bit in 0usize..(8 * 17), asn in 0u64..(1 << 40)) {
        let mut d = Dlpdu::new(5, 0x04CD, Address::Short(1), Address::Short(2), 0, false,
            DlBody::Ack(Ack { response_code: 0, time_adjustment: -3, extra: vec![] }));
        d.seal(&crypto::WELL_KNOWN_KEY, asn);
        let mut bytes = d.encode();
        prop_assume!(bit / 8 < bytes.len());
        bytes[bit / 8] ^= 1 << (bit % 8);
        if let Ok(x) = Dlpdu::parse(&bytes) {
            prop_assert!(!x.verify(&crypto::WELL_KNOWN_KEY, asn));
        }
    }
}

#[test]
fn the_example_exchange_decodes_whole() {
    let keys = hart_wireless::build::ExampleKeys {
        join: [0x41; 16],
        network: [0x5A; 16],
    };
    let frames = hart_wireless::build::example_exchange(&keys, 0x04CD, 5000);
    let refs: Vec<(u64, &[u8])> = frames
        .iter()
        .map(|(a, f)| (a * 10_000_000, f.as_slice()))
        .collect();
    let pcap = hart_wireless::capture::write_pcap(&refs);
    let (reports, stats) =
        hart_wireless::decoder::decode_capture(&pcap, &[keys.join], &[]).unwrap();
    assert_eq!(reports.len(), 6);
    assert!(
        reports.iter().all(|r| r.dl_mic_ok == Some(true)),
        "{reports:#?}"
    );
    assert_eq!(stats.decrypted, 2);
    assert_eq!(stats.commands_typed, 4);
}

/// Every command the issue names is typed, with its response codes.
#[test]
fn every_command_of_the_issue_is_typed() {
    let mut wanted: Vec<u16> = vec![768, 769, 773, 774, 805, 814, 817, 818];
    wanted.extend(777..=780);
    wanted.extend(787..=791);
    wanted.extend(793..=801);
    wanted.extend(832..=845);
    wanted.extend(960..=977);
    for n in wanted {
        let info = commands::info(n).unwrap_or_else(|| panic!("{n} is not typed"));
        assert!(info.codes().iter().any(|(c, _)| *c == 0), "{n}");
        assert_ne!(commands::name(n), "unknown");
    }
    assert_eq!(commands::code_name(963, 67), Some("Session Type Invalid"));
    assert_eq!(commands::name(64533), "vendor");
}

/// 779 takes both forms by its length: HART 7.0's 9 bytes (one-byte MIC failure
/// counters) and the later, longer one the captures carry.
#[test]
fn device_health_both_forms() {
    use commands::{DeviceHealth, Response, Typed};
    let short = unhex("00 0015 0011 03 04 00 02 01");
    let Some(Ok(Typed::Response(0, Some(Response::ReportDeviceHealth(DeviceHealth::V70(h)))))) =
        commands::decode(779, true, &short)
    else {
        panic!("7.0 form not decoded")
    };
    assert_eq!(
        (
            h.generated,
            h.dl_mic_failures,
            h.nl_mic_failures,
            h.crc_errors
        ),
        (21, 3, 4, 2)
    );
    let long = unhex("00 0015 0011 0000 0000 00 04 000000000000ea601026924000000000000000000000");
    let Some(Ok(t @ Typed::Response(0, Some(Response::ReportDeviceHealth(DeviceHealth::Long(h)))))) =
        commands::decode(779, true, &long)
    else {
        panic!("long form not decoded")
    };
    assert_eq!((h.generated, h.terminated, h.crc_errors), (21, 17, 4));
    assert_eq!(commands::encode(&t).unwrap(), long);
}

#[test]
fn source_route_hops_then_the_count_left() {
    use commands::{Response, Typed};
    let data = unhex("00 03 02 0001 0005 07");
    let Some(Ok(Typed::Response(0, Some(Response::WriteSourceRoute(r))))) =
        commands::decode(976, true, &data)
    else {
        panic!()
    };
    assert_eq!(
        (r.route_id, r.hop_count, r.hops.as_slice(), r.remaining),
        (3, 2, &[1u16, 5][..], 7)
    );
}
