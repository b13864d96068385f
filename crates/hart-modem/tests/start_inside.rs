//! A demodulator started inside a recording (`Demodulator::starting_at`), as
//! `hartkit modem rx --jobs` starts one per piece of a long file: once settled, it finds
//! the quiet points a demodulator from the start of the recording finds, with the same
//! level bit for bit, and after a quiet point it reports the same frames, bit for bit,
//! however the samples are split into pushes.

use hart_modem::channel::{add_white_noise, Rng};
use hart_modem::demod::{DecodedFrame, DemodConfig, DemodEvent, Demodulator, START_ALIGN};
use hart_modem::modulator::{modulate_frames, ModulatorConfig};

/// Frames of 0 to 24 data bytes with 25 ms gaps, repeated to `seconds`, plus white
/// noise of `sigma` volts.
fn recording(fs: u32, seconds: f64, sigma: f64) -> Vec<f32> {
    let mut frames: Vec<Vec<u8>> = Vec::new();
    for i in 0..25u8 {
        let mut f = vec![0x86, 0xA6, 0x06, 0xBC, 0x61, 0x4E, 0x03, i];
        f.extend((0..i).map(|k| k.wrapping_mul(37) ^ i));
        f.push(f.iter().fold(0, |a, b| a ^ b));
        frames.push(f);
    }
    let refs: Vec<(usize, &[u8])> = frames.iter().map(|f| (5, f.as_slice())).collect();
    let (one, _) = modulate_frames(ModulatorConfig::new(fs), &refs, 0.025);
    let want = (seconds * f64::from(fs)) as usize;
    let mut s: Vec<f32> = one.iter().copied().cycle().take(want).collect();
    add_white_noise(&mut s, sigma, &mut Rng::new(7));
    s
}

/// Pushes `samples` in pieces of `step`, collecting the frames.
fn feed(d: &mut Demodulator, samples: &[f32], step: usize, out: &mut Vec<DecodedFrame>) {
    for piece in samples.chunks(step) {
        d.push(piece, |ev| {
            if let DemodEvent::Frame(f) = ev {
                out.push(f.to_decoded());
            }
        });
    }
}

fn check(fs: u32, sigma: f64, start: u64) {
    let cfg = DemodConfig::new(fs);
    let settled = Demodulator::quiet_from(&cfg, start);
    // A boundary a little after the late demodulator has settled, then more frames.
    let boundary = settled as usize + fs as usize;
    let s = recording(fs, boundary as f64 / f64::from(fs) + 5.0, sigma);
    let start = start as usize;

    let mut whole = Demodulator::new(cfg);
    let mut whole_frames = Vec::new();
    feed(&mut whole, &s[..boundary], 4096, &mut whole_frames);
    let mut late = Demodulator::starting_at(cfg, start as u64);
    assert_eq!(late.samples(), start as u64);
    let mut late_frames = Vec::new();
    feed(&mut late, &s[start..boundary], 777, &mut late_frames);

    // The same level, bit for bit, and the same latest quiet point.
    assert_eq!(
        whole.level_vpp().to_bits(),
        late.level_vpp().to_bits(),
        "{fs} Hz"
    );
    let (q, before_whole) = whole.quiet_point().expect("a quiet point");
    let (q_late, before_late) = late.quiet_point().expect("a quiet point when settled");
    assert_eq!(q, q_late, "{fs} Hz");
    assert!(q >= settled, "{fs} Hz");

    // After it, the same frames.
    feed(&mut whole, &s[boundary..], 1000, &mut whole_frames);
    feed(&mut late, &s[boundary..], 3001, &mut late_frames);
    for (d, out) in [
        (&mut whole, &mut whole_frames),
        (&mut late, &mut late_frames),
    ] {
        d.finish(|ev| {
            if let DemodEvent::Frame(f) = ev {
                out.push(f.to_decoded());
            }
        });
    }
    let after_whole = &whole_frames[before_whole as usize..];
    let after_late = &late_frames[before_late as usize..];
    assert!(
        after_whole.len() >= 10,
        "{fs} Hz: {} frames",
        after_whole.len()
    );
    assert_eq!(after_whole, after_late, "{fs} Hz");
    // (Frames with f64 fields compared with ==: the same bits for anything but NaN.)
    assert_eq!(whole.frames_reported(), whole_frames.len() as u64);
}

#[test]
fn clean_at_48_khz() {
    check(48_000, 0.0, 2 * START_ALIGN);
}

#[test]
fn noisy_at_48_and_44_1_khz() {
    // 14 dB against a 500 mVpp sine, and Eb/N0 of about 10 dB, where frames are lost
    // and damaged ones reported.
    check(48_000, 0.0353, 3 * START_ALIGN);
    check(44_100, 0.2, START_ALIGN);
}

#[test]
fn at_8_and_192_khz() {
    check(8000, 0.02, START_ALIGN);
    check(192_000, 0.05, 5 * START_ALIGN);
}

/// A start that is not a multiple of the alignment is rounded down.
#[test]
fn starts_are_aligned() {
    let cfg = DemodConfig::new(48_000);
    let d = Demodulator::starting_at(cfg, START_ALIGN + 100);
    assert_eq!(d.samples(), START_ALIGN);
    assert_eq!(Demodulator::quiet_from(&cfg, 0), 0);
    assert_eq!(
        Demodulator::quiet_from(&cfg, START_ALIGN + 100),
        Demodulator::quiet_from(&cfg, START_ALIGN)
    );
}
