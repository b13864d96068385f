//! Properties of the codec and the slave, checked on generated input; telegrams the
//! slave sends are also decoded by profirust's independent decoder.

use std::time::Duration;

use hart_profibus::fdl::{self, DataTelegram, FunctionCode, Request, Telegram};
use hart_profibus::{Slave, SlaveConfig};
use proptest::prelude::*;

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        Just(Request::SdaLow),
        Just(Request::SdnLow),
        Just(Request::SdaHigh),
        Just(Request::SdnHigh),
        Just(Request::FdlStatus),
        Just(Request::SrdLow),
        Just(Request::SrdHigh),
        Just(Request::Ident),
    ]
}

type Parts = (u8, u8, Option<u8>, Option<u8>, Request, bool, bool, Vec<u8>);

fn parts() -> impl Strategy<Value = Parts> {
    (
        0u8..128,
        0u8..128,
        proptest::option::of(0u8..64),
        proptest::option::of(0u8..64),
        request(),
        any::<bool>(),
        any::<bool>(),
        proptest::collection::vec(any::<u8>(), 0..=244),
    )
}

fn telegram(p: &Parts) -> DataTelegram<'_> {
    DataTelegram {
        da: p.0,
        sa: p.1,
        dsap: p.2,
        ssap: p.3,
        fc: FunctionCode::Request {
            request: p.4,
            fcb: p.5,
            fcv: p.6,
        },
        data: &p.7,
    }
}

proptest! {
    #[test]
    fn encode_then_decode_is_the_same_telegram(p in parts()) {
        let t = telegram(&p);
        let mut out = Vec::new();
        fdl::encode(&t, &mut out).unwrap();
        let (back, n) = fdl::decode(&out).unwrap().unwrap();
        prop_assert_eq!(n, out.len());
        prop_assert_eq!(back, Telegram::Data(t.clone()));
        // profirust reads the same bytes as a telegram of the same length.
        let theirs = profirust::fdl::Telegram::deserialize(&out);
        prop_assert!(matches!(theirs, Some(Ok((_, m))) if m == out.len()));
        // Every prefix is incomplete, not an error.
        for k in 0..out.len() {
            prop_assert_eq!(fdl::decode(&out[..k]), Ok(None));
        }
    }

    #[test]
    fn a_flipped_bit_is_always_detected(p in parts(), at in any::<prop::sample::Index>(), bit in 0u8..8) {
        let mut out = Vec::new();
        fdl::encode(&telegram(&p), &mut out).unwrap();
        let i = at.index(out.len());
        out[i] ^= 1 << bit;
        prop_assert!(fdl::decode(&out).is_err(), "flip at {} bit {} of {:02X?}", i, bit, out);
    }

    #[test]
    fn decode_takes_any_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        if let Ok(Some((_, n))) = fdl::decode(&bytes) {
            prop_assert!(n <= bytes.len() && n > 0);
        }
    }

    /// Any bytes at any times: no panic, and everything the slave sends is one whole
    /// telegram that both decoders read.
    #[test]
    fn the_slave_takes_any_line(chunks in proptest::collection::vec(
        (0u64..5_000, proptest::collection::vec(any::<u8>(), 0..40)), 0..40),
        valid in proptest::collection::vec((parts(), 0u64..5_000), 0..10),
    ) {
        let mut slave = Slave::new(SlaveConfig {
            address: 5,
            ident_number: 0x4854,
            cfg: vec![0xA1, 0x90],
            baud: 19_200,
            max_tsdr_bits: 60,
            user_prm_len: 0,
        }).unwrap();
        let mut now = Duration::ZERO;
        let mut feed: Vec<(u64, Vec<u8>)> = chunks;
        for (mut p, gap) in valid {
            p.0 = if p.0 % 2 == 0 { 5 } else { 127 };
            p.2 = p.2.map(|s| 55 + s % 8);
            let mut out = Vec::new();
            fdl::encode(&telegram(&p), &mut out).unwrap();
            feed.push((gap, out));
        }
        for (gap, bytes) in feed {
            now += Duration::from_micros(gap);
            slave.receive(now, &bytes);
            while let Some(d) = slave.deadline() {
                if d > now + Duration::from_millis(1) { break; }
                now = now.max(d);
                if let Some(reply) = slave.poll_transmit(now) {
                    let (_, n) = fdl::decode(&reply).unwrap().unwrap();
                    prop_assert_eq!(n, reply.len());
                    let theirs = profirust::fdl::Telegram::deserialize(&reply);
                    prop_assert!(matches!(theirs, Some(Ok((_, m))) if m == reply.len()));
                } else {
                    break;
                }
            }
        }
    }
}
