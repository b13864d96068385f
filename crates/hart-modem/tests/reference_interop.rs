//! The modem against an independent, deliberately simple implementation
//! (`tests/reference`): our modulator decoded by the textbook receiver, the textbook
//! generator decoded by our demodulator, and the reference checked against itself.

mod reference;

use hart_modem::demod::{decode, DemodConfig};
use hart_modem::modulator::{modulate_frames, ModulatorConfig};

fn frames(n: usize, seed: u64) -> Vec<(usize, Vec<u8>)> {
    let mut rng = hart_modem::channel::Rng::new(seed);
    let mut next = move || rng.next_u64();
    (0..n)
        .map(|_| {
            let len = (next() % 26) as usize;
            let mut pdu = vec![0x82];
            pdu.extend((0..6).map(|_| next() as u8));
            pdu.push(len as u8);
            pdu.extend((0..len).map(|_| next() as u8));
            let check = pdu.iter().fold(0, |a, b| a ^ b);
            pdu.push(check);
            (5, pdu)
        })
        .collect()
}

fn good(found: impl Iterator<Item = (Vec<u8>, bool)>) -> Vec<Vec<u8>> {
    found.filter(|f| f.1).map(|f| f.0).collect()
}

/// The reference receiver found exactly the frames sent, each within half a bit.
fn check_reference(got: &[reference::RefFrame], sent: &[(usize, Vec<u8>)], times: &[f64], fs: u32) {
    let want: Vec<_> = sent.iter().map(|f| f.1.clone()).collect();
    assert_eq!(
        good(got.iter().map(|g| (g.pdu.clone(), g.checksum_ok))),
        want,
        "{fs} Hz"
    );
    for (g, t) in got.iter().zip(times) {
        assert!((g.t - t).abs() < 0.5 / 1200.0, "{fs} Hz: {} vs {t}", g.t);
    }
}

#[test]
fn the_reference_decodes_itself() {
    let fr = frames(20, 1);
    for fs in [8000, 44100, 48000] {
        let (s, times) = reference::generate(fs, 0.5, &fr, 0.02);
        check_reference(&reference::receive(fs, &s), &fr, &times, fs);
        // 80 mVpp is below its carrier detect.
        let (quiet, _) = reference::generate(fs, 0.08, &fr, 0.02);
        assert!(reference::receive(fs, &quiet).is_empty());
    }
}

#[test]
fn our_modulator_decodes_with_the_reference_receiver() {
    let fr = frames(40, 2);
    let refs: Vec<(usize, &[u8])> = fr.iter().map(|(p, f)| (*p, f.as_slice())).collect();
    for fs in [8000, 22050, 44100, 48000, 96000] {
        let (s, times) = modulate_frames(ModulatorConfig::new(fs), &refs, 0.02);
        check_reference(&reference::receive(fs, &s), &fr, &times, fs);
    }
}

#[test]
fn the_reference_generator_decodes_with_our_demodulator() {
    let fr = frames(40, 3);
    let want: Vec<_> = fr.iter().map(|f| f.1.clone()).collect();
    // At 8 kHz the reference puts every bit edge on a whole sample, up to 0.15 bit
    // off (our modulator integrates across the sample instead).
    for (fs, speed) in [
        (8000, 1.0),
        (9600, 1.0),
        (11025, 1.0),
        (44100, 1.0),
        (48000, 1.0),
        (48000, 1.01),
        (48000, 0.99),
        (192_000, 1.0),
    ] {
        let (s, times) = reference::generate_speed(fs, 0.5, &fr, 0.02, speed);
        let got = decode(DemodConfig::new(fs), &s);
        assert_eq!(
            good(
                got.iter()
                    .map(|g| (g.pdu.clone(), g.checksum_ok && g.parity_errors == 0))
            ),
            want,
            "{fs} Hz ×{speed}"
        );
        for (g, t) in got.iter().zip(&times) {
            assert!(
                (g.t - t).abs() < 0.1 / 1200.0 / speed,
                "{fs} Hz: {} vs {t}",
                g.t
            );
        }
    }
}
