//! Demodulator: any samples (here 16-bit values from arbitrary bytes, at a sample rate
//! taken from the first byte) must be consumed without a panic, and every frame it
//! reports must be a slice it can describe.
#![no_main]
use hart_modem::demod::{DemodConfig, DemodEvent, Demodulator};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, rest)) = data.split_first() else {
        return;
    };
    let rate = [8000, 11025, 22050, 44100, 48000, 96000, 192000][usize::from(sel) % 7];
    let mut cfg = DemodConfig::new(rate);
    // Loud input so the carrier detect opens and the detector runs.
    cfg.volts_per_unit = f64::from(sel >> 3) * 0.5;
    let samples: Vec<f32> = rest
        .chunks_exact(2)
        .map(|c| f32::from(i16::from_le_bytes([c[0], c[1]])) / 32768.0)
        .collect();
    let mut d = Demodulator::new(cfg);
    let mut check = |ev: DemodEvent<'_>| {
        if let DemodEvent::Frame(f) = ev {
            assert!(!f.pdu.is_empty());
            assert!(f.t.is_finite() && f.level_vpp.is_finite());
        }
    };
    // Fed in two pieces so state carried between calls is exercised too.
    let half = samples.len() / 2;
    d.push(&samples[..half], &mut check);
    d.push(&samples[half..], &mut check);
    d.finish(&mut check);
});
