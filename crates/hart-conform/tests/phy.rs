//! The physical-layer tests on recordings the modem makes with known impairments: each
//! limit is found where it should be, bad input ends in a clear verdict.

use hart_conform::phy::{make_wav, run, Limits};
use hart_conform::Verdict;
use hart_modem::modulator::ModulatorConfig;

/// An ACK to command 1 (status and 5 data bytes) and a command 0 request.
const ACK: &[u8] = &[
    0x86, 0xA6, 0xF1, 0x01, 0x00, 0x01, 0x01, 0x07, 0x00, 0x00, 0x0C, 0x42, 0xF0, 0x00, 0x00, 0x00,
];

fn fixed(mut pdu: Vec<u8>) -> Vec<u8> {
    let n = pdu.len() - 1;
    pdu[n] = hart_proto::frame::checksum(&pdu[..n]);
    pdu
}

fn verdicts(cfg: ModulatorConfig, jump: bool, noise: f64) -> Vec<(&'static str, Verdict, String)> {
    let pdu = fixed(ACK.to_vec());
    let wav = make_wav(&[&pdu, &pdu], cfg, jump, noise);
    let r = run(&wav, "test.wav", &Limits::default());
    r.results
        .iter()
        .map(|t| (t.id, t.verdict, t.detail.clone()))
        .collect()
}

fn failing(v: &[(&'static str, Verdict, String)]) -> Vec<&'static str> {
    v.iter()
        .filter(|x| x.1 == Verdict::Fail)
        .map(|x| x.0)
        .collect()
}

fn base() -> ModulatorConfig {
    ModulatorConfig::new(48_000)
}

#[test]
fn a_clean_recording_passes_everything() {
    let v = verdicts(base(), false, 0.0);
    assert!(
        v.iter().all(|x| x.1 == Verdict::Pass || x.0 == "PHY-006"),
        "{v:#?}"
    );
    // Noise a little below the floor still passes; no noise at all too.
    let v = verdicts(base(), false, 0.01);
    assert!(v.iter().all(|x| x.1 == Verdict::Pass), "{v:#?}");
}

#[test]
fn each_impairment_fails_its_test() {
    let cases: Vec<(&str, ModulatorConfig, bool, f64, &[&str])> = vec![
        (
            "level 80 mVpp",
            ModulatorConfig {
                amplitude_vpp: 0.08,
                ..base()
            },
            false,
            0.0,
            &["PHY-001"],
        ),
        (
            "level 1 Vpp",
            ModulatorConfig {
                amplitude_vpp: 1.0,
                ..base()
            },
            false,
            0.0,
            &["PHY-001"],
        ),
        (
            "level 450 mVpp",
            ModulatorConfig {
                amplitude_vpp: 0.45,
                ..base()
            },
            false,
            0.0,
            &[],
        ),
        (
            "tones 2.5 % high",
            ModulatorConfig {
                tone_scale: 1.025,
                ..base()
            },
            false,
            0.0,
            &["PHY-002"],
        ),
        (
            "tones 0.5 % low",
            ModulatorConfig {
                tone_scale: 0.995,
                ..base()
            },
            false,
            0.0,
            &[],
        ),
        (
            "bit rate 2.5 % slow",
            ModulatorConfig {
                rate_scale: 0.975,
                ..base()
            },
            false,
            0.0,
            &["PHY-003"],
        ),
        (
            "bit rate 0.5 % fast",
            ModulatorConfig {
                rate_scale: 1.005,
                ..base()
            },
            false,
            0.0,
            &[],
        ),
        ("phase jumps", base(), true, 0.0, &["PHY-004"]),
        (
            "carrier 12 bits early and late",
            ModulatorConfig {
                lead_bits: 12,
                tail_bits: 12,
                ..base()
            },
            false,
            0.0,
            &["PHY-005"],
        ),
        ("noise 150 mVpp", base(), false, 0.15, &["PHY-006"]),
    ];
    for (what, cfg, jump, noise, want) in cases {
        let v = verdicts(cfg, jump, noise);
        assert_eq!(failing(&v), want.to_vec(), "{what}: {v:#?}");
    }
}

#[test]
fn bad_input_is_a_clear_verdict() {
    let pdu = fixed(ACK.to_vec());
    let wav = make_wav(&[&pdu], base(), false, 0.0);
    for (what, bytes) in [
        ("empty", vec![]),
        ("header only", wav[..20].to_vec()),
        ("truncated", wav[..wav.len() / 3].to_vec()),
        ("not a wav", b"hello, this is text not audio".to_vec()),
    ] {
        let r = run(&bytes, what, &Limits::default());
        assert!(
            r.results.iter().all(|t| t.verdict != Verdict::Fail),
            "{what}: {:#?}",
            r.results
        );
        assert!(!r.results.is_empty());
        assert!(!r.results[0].detail.is_empty());
    }
}
