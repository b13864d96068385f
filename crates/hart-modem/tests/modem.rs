//! Modulator and demodulator end to end: every sample rate, timestamps, latency,
//! carrier-detect thresholds, interference, streaming in any chunk size, and garbage.

use hart_modem::demod::{decode, DemodConfig, DemodEvent, Demodulator};
use hart_modem::modulator::{modulate_frames, Modulator, ModulatorConfig};
use hart_modem::{BITS_PER_CHAR, BIT_RATE};
use proptest::prelude::*;

/// A few frames of different kinds, delimiter through check byte.
fn frames() -> Vec<Vec<u8>> {
    let mut v = vec![
        // Command 0 request, short address 0 (STX).
        vec![0x02, 0x80, 0x00, 0x00],
        // Long-address STX, command 1, no data.
        vec![0x82, 0xA6, 0x06, 0xBC, 0x61, 0x4E, 0x01, 0x00],
        // Long-address ACK with 9 data bytes of 0x00 and 0xFF, worst for timing.
        vec![
            0x86, 0x26, 0x4E, 0x00, 0x00, 0x01, 0x03, 0x09, 0x00, 0x00, 0x00, 0xFF, 0x00, 0xFF,
            0x55, 0xAA, 0x0F,
        ],
    ];
    for f in v.iter_mut() {
        let check = f.iter().fold(0, |a, b| a ^ b);
        f.push(check);
    }
    v
}

fn frame_refs(v: &[Vec<u8>]) -> Vec<(usize, &[u8])> {
    v.iter().map(|f| (5usize, f.as_slice())).collect()
}

#[test]
fn every_sample_rate_round_trips_with_exact_timestamps() {
    let fr = frames();
    for fs in [8000, 11025, 16000, 22050, 44100, 48000, 96000, 192_000] {
        let (s, times) = modulate_frames(ModulatorConfig::new(fs), &frame_refs(&fr), 0.03);
        let got = decode(DemodConfig::new(fs), &s);
        assert_eq!(got.len(), fr.len(), "{fs} Hz: {got:?}");
        for ((g, f), t) in got.iter().zip(&fr).zip(&times) {
            assert_eq!(&g.pdu, f, "{fs} Hz");
            assert!(g.checksum_ok && g.parity_errors == 0 && g.framing_errors == 0);
            // The carrier detect and the clock may spend the first one or two
            // preamble characters; HART receivers need only two.
            assert!(
                (3..=5).contains(&g.preambles),
                "{fs} Hz: {} preambles",
                g.preambles
            );
            // Within a tenth of a bit of the delimiter's start bit.
            assert!(
                (g.t - t).abs() < 0.1 / BIT_RATE,
                "{fs} Hz: t {} vs {}",
                g.t,
                t
            );
            assert!(
                (g.level_vpp - 0.5).abs() < 0.05,
                "{fs} Hz: level {}",
                g.level_vpp
            );
        }
    }
}

#[test]
fn a_frame_comes_out_within_two_bit_times_of_its_last_stop_bit() {
    for fs in [8000, 48000, 192_000] {
        let fr = frames();
        let (s, times) = modulate_frames(ModulatorConfig::new(fs), &frame_refs(&fr), 0.03);
        let mut d = Demodulator::new(DemodConfig::new(fs));
        let mut at = Vec::new();
        for (i, x) in s.iter().enumerate() {
            d.push(std::slice::from_ref(x), |ev| {
                if let DemodEvent::Frame(_) = ev {
                    at.push(i as f64 / f64::from(fs));
                }
            });
        }
        assert_eq!(at.len(), fr.len());
        for ((emitted, t), f) in at.iter().zip(&times).zip(&fr) {
            let end = t + (f.len() * BITS_PER_CHAR) as f64 / BIT_RATE;
            let latency_bits = (emitted - end) * BIT_RATE;
            assert!(latency_bits < 2.0, "{fs} Hz: {latency_bits:.2} bit times");
        }
    }
}

fn at_level(vpp: f64) -> usize {
    let fr = frames();
    let mut cfg = ModulatorConfig::new(48000);
    cfg.amplitude_vpp = vpp;
    let (s, _) = modulate_frames(cfg, &frame_refs(&fr), 0.03);
    decode(DemodConfig::new(48000), &s).len()
}

#[test]
fn carrier_detect_takes_120_mvpp_and_ignores_80_mvpp() {
    assert_eq!(at_level(0.120), 3);
    assert_eq!(at_level(0.080), 0);
    // The threshold is in volts: a file recorded at half scale decodes when told so.
    let fr = frames();
    let mut cfg = ModulatorConfig::new(48000);
    cfg.amplitude_vpp = 0.06;
    let (s, _) = modulate_frames(cfg, &frame_refs(&fr), 0.03);
    let mut dc = DemodConfig::new(48000);
    dc.volts_per_unit = 2.0;
    assert_eq!(decode(dc, &s).len(), 3);
}

#[test]
fn the_analog_signal_and_the_noise_test_tones_do_not_disturb_decoding() {
    let fr = frames();
    let fs = 48000;
    let (clean, _) = modulate_frames(ModulatorConfig::new(fs), &frame_refs(&fr), 0.03);
    let tau = 2.0 * std::f64::consts::PI / f64::from(fs);
    type Interferer = Box<dyn Fn(f64) -> f64>;
    let cases: Vec<(&str, Interferer)> = vec![
        (
            "4-20 mA at 18 Hz across 250 ohm",
            Box::new(move |i| 3.0 + 2.0 * (tau * 18.0 * i).sin()),
        ),
        (
            "1700 Hz 55 mVpp",
            Box::new(move |i| 0.0275 * (tau * 1700.0 * i).sin()),
        ),
        (
            "250 Hz 220 mVpp",
            Box::new(move |i| 0.11 * (tau * 250.0 * i).sin()),
        ),
        (
            "125 Hz 880 mVpp",
            Box::new(move |i| 0.44 * (tau * 125.0 * i).sin()),
        ),
        (
            "63 Hz 3.52 Vpp",
            Box::new(move |i| 1.76 * (tau * 63.0 * i).sin()),
        ),
        (
            "29 Hz 16 Vpp",
            Box::new(move |i| 8.0 * (tau * 29.0 * i).sin()),
        ),
    ];
    for (name, f) in cases {
        let s: Vec<f32> = clean
            .iter()
            .enumerate()
            .map(|(i, x)| x + f(i as f64) as f32)
            .collect();
        let got = decode(DemodConfig::new(fs), &s);
        let pdus: Vec<_> = got
            .iter()
            .filter(|g| g.checksum_ok)
            .map(|g| g.pdu.clone())
            .collect();
        assert_eq!(pdus, fr, "{name}");
    }
}

#[test]
fn tone_and_bit_rate_errors_of_two_percent_decode() {
    let fr = frames();
    for (tone, rate) in [
        (1.02, 1.02),
        (0.98, 0.98),
        (1.0, 1.02),
        (1.0, 0.98),
        (1.02, 1.0),
        (0.98, 1.0),
    ] {
        let mut cfg = ModulatorConfig::new(48000);
        cfg.tone_scale = tone;
        cfg.rate_scale = rate;
        let (s, _) = modulate_frames(cfg, &frame_refs(&fr), 0.03);
        let decoded = decode(DemodConfig::new(48000), &s);
        let got: Vec<_> = decoded.iter().map(|g| g.pdu.clone()).collect();
        assert_eq!(got, fr, "tones ×{tone}, bit rate ×{rate}");
        // The errors are measured and reported with each frame (the last, longest
        // frame has had the most transitions to learn from).
        let last = decoded.last().unwrap();
        assert!(
            (last.rate_error - (rate - 1.0)).abs() < 0.004,
            "rate {}",
            last.rate_error
        );
        assert!(
            (last.tone_error - (tone - 1.0)).abs() < 0.004,
            "tone {}",
            last.tone_error
        );
    }
}

#[test]
fn the_modulator_is_phase_continuous_and_starts_and_stops_cleanly() {
    let fs = 48000;
    let mut m = Modulator::new(ModulatorConfig::new(fs));
    let mut s = Vec::new();
    m.frame(5, &frames()[1], |x| s.push(x));
    // No step anywhere: the largest sample-to-sample change is what a 2200 Hz sine of
    // 0.25 V peak can do in one sample.
    let max_step = s
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .fold(0f32, f32::max);
    let bound = 0.25 * 2.0 * std::f32::consts::PI * 2200.0 / fs as f32 * 1.001;
    assert!(max_step <= bound, "{max_step} > {bound}");
    assert!(s[0].abs() < 1e-3 && s[s.len() - 1].abs() < 1e-2);
    // The carrier is on for exactly the bits sent: lead + characters + tail.
    let bits = 2 + (5 + frames()[1].len()) * BITS_PER_CHAR + 2;
    let expected = (bits as f64 / BIT_RATE * f64::from(fs)).ceil() as usize;
    assert_eq!(s.len(), expected);
    // Average zero, as the analog loop needs: the mean is far below a microvolt-scale
    // fraction of the amplitude.
    let mean = s.iter().map(|&x| f64::from(x)).sum::<f64>() / s.len() as f64;
    assert!(mean.abs() < 1e-3, "mean {mean}");
}

#[test]
fn chunk_size_does_not_change_what_is_decoded() {
    let fr = frames();
    let (s, _) = modulate_frames(ModulatorConfig::new(44100), &frame_refs(&fr), 0.02);
    let whole = decode(DemodConfig::new(44100), &s);
    for chunk in [1, 7, 441, 10_000] {
        let mut d = Demodulator::new(DemodConfig::new(44100));
        let mut got = Vec::new();
        for c in s.chunks(chunk) {
            d.push(c, |ev| {
                if let DemodEvent::Frame(f) = ev {
                    got.push((f.pdu.to_vec(), f.t));
                }
            });
        }
        d.finish(|_| {});
        let expect: Vec<_> = whole.iter().map(|g| (g.pdu.clone(), g.t)).collect();
        assert_eq!(got, expect, "chunk {chunk}");
    }
}

#[test]
fn silence_and_a_lone_carrier_give_no_frames() {
    let fs = 48000;
    assert!(decode(DemodConfig::new(fs), &vec![0.0; fs as usize]).is_empty());
    // Unmodulated mark tone (idle line) for a second.
    let mut m = Modulator::new(ModulatorConfig::new(fs));
    let mut s = Vec::new();
    m.bits(std::iter::repeat_n(true, 1200), 1200, |x| s.push(x));
    assert!(decode(DemodConfig::new(fs), &s).is_empty());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn garbage_never_panics(samples in proptest::collection::vec(any::<i16>(), 0..20_000), rate_sel in 0usize..4, gain in 0.0f64..20.0) {
        let fs = [8000, 22050, 48000, 192_000][rate_sel];
        let mut cfg = DemodConfig::new(fs);
        cfg.volts_per_unit = gain;
        let x: Vec<f32> = samples.iter().map(|&v| f32::from(v) / 32768.0).collect();
        let _ = decode(cfg, &x);
    }

    #[test]
    fn random_frames_round_trip(data in proptest::collection::vec(any::<u8>(), 0..25), addr in any::<[u8; 5]>(), cmd in any::<u8>(), phase in 0.0f64..1.0) {
        let mut pdu = vec![0x82];
        pdu.extend(addr);
        pdu.push(cmd);
        pdu.push(data.len() as u8);
        pdu.extend(&data);
        let check = pdu.iter().fold(0, |a, b| a ^ b);
        pdu.push(check);
        let mut cfg = ModulatorConfig::new(48000);
        cfg.start_phase = phase;
        let (s, _) = modulate_frames(cfg, &[(5, pdu.as_slice())], 0.01);
        let got = decode(DemodConfig::new(48000), &s);
        prop_assert_eq!(got.len(), 1);
        prop_assert_eq!(&got[0].pdu, &pdu);
    }
}
