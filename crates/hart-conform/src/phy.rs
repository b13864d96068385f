//! Physical-layer tests on a recording of the device's signal (a WAV file): carrier
//! amplitude, tone frequencies, bit rate, phase continuity, carrier start and stop,
//! signal-to-noise. The modem's demodulator finds the frames and estimates level,
//! tone and rate errors; the envelope, the phase steps and the noise are measured here
//! from the samples.

use hart_modem::demod::{DemodConfig, DemodEvent, Demodulator};

use crate::catalog::{PhyTest, Test, TESTS};
use crate::model::{hex, Evidence, Group, Report, SeenFrame, TestResult, Verdict};

/// Limits of the physical-layer tests (see docs/conform.md for where each comes from).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Lowest carrier amplitude, V peak-to-peak (receivers must receive at 120 mVpp).
    pub min_vpp: f64,
    /// Highest carrier amplitude, V peak-to-peak (1.5 mA into 500 Ω).
    pub max_vpp: f64,
    /// Largest tone frequency error, fraction (0.01 = 1 %).
    pub tone_error: f64,
    /// Largest bit-rate error, fraction.
    pub rate_error: f64,
    /// Longest carrier before the first and after the last character, s.
    pub carrier_lead_lag_s: f64,
    /// Lowest signal-to-noise ratio, dB.
    pub min_snr_db: f64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            min_vpp: 0.12,
            max_vpp: 0.75,
            tone_error: 0.01,
            rate_error: 0.01,
            carrier_lead_lag_s: 0.005,
            min_snr_db: 20.0,
        }
    }
}

/// What was measured of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameMeasure {
    /// Start of its first character (first preamble), s from the start of the file.
    pub start_s: f64,
    /// Where the carrier comes on (the envelope passes half the level), s.
    pub carrier_on_s: Option<f64>,
    /// Where it goes off, s.
    pub carrier_off_s: Option<f64>,
    /// End of its last character, s.
    pub end_s: f64,
    /// Bytes from the delimiter through the check byte.
    pub pdu: Vec<u8>,
    /// Level, V peak-to-peak.
    pub level_vpp: f64,
    /// Tone error (+0.01: both tones 1 % high).
    pub tone_error: f64,
    /// Bit-rate error (+0.01: 1 % fast).
    pub rate_error: f64,
    /// Check byte right and no parity or framing error.
    pub clean: bool,
    /// Carrier before the first character, s (from the envelope).
    pub lead_s: Option<f64>,
    /// Carrier after the last character, s.
    pub lag_s: Option<f64>,
    /// Largest sample-to-sample step inside the frame, V.
    pub max_step_v: f64,
    /// The largest step a phase-continuous 2200 Hz tone of this level makes, V.
    pub tone_step_v: f64,
}

/// Reads `wav` and runs the physical-layer tests. A file that cannot be read gives
/// could-not-run verdicts saying why; nothing in the file makes this panic.
pub fn run(wav: &[u8], name: &str, limits: &Limits) -> Report {
    let defs: Vec<_> = TESTS.iter().filter(|d| d.group == Group::Phy).collect();
    let mut warnings = vec![];
    let all = |verdict: Verdict, why: String, evidence: Vec<Evidence>| -> Vec<TestResult> {
        defs.iter()
            .map(|d| TestResult::of(d, verdict, why.clone(), evidence.clone(), 0))
            .collect()
    };
    let report = |results: Vec<TestResult>, warnings: Vec<String>, dur: f64| Report {
        target: name.to_string(),
        transport: "recording".into(),
        device: None,
        warnings,
        results,
        duration_us: (dur * 1e6) as u64,
        line_time_us: 0,
    };
    let parsed = match hart_modem::wav::Wav::parse(wav) {
        Ok(w) => w,
        Err(e) => {
            return report(
                all(
                    Verdict::CouldNotRun,
                    format!("{name} is no readable WAV file: {e}"),
                    vec![],
                ),
                warnings,
                0.0,
            )
        }
    };
    if parsed.truncated() {
        warnings.push(format!(
            "{name} is truncated: its header announces more samples than it holds; what is there was measured"
        ));
    }
    let fs = parsed.sample_rate();
    let samples = match parsed.channel(0) {
        Ok(s) => s,
        Err(e) => {
            return report(
                all(Verdict::CouldNotRun, format!("{name}: {e}"), vec![]),
                warnings,
                0.0,
            )
        }
    };
    if !(8_000..=192_000).contains(&fs) {
        return report(
            all(
                Verdict::CouldNotRun,
                format!("{name}: sample rate {fs} Hz; the demodulator takes 8000-192000 Hz"),
                vec![],
            ),
            warnings,
            0.0,
        );
    }
    let dur = samples.len() as f64 / f64::from(fs);
    let frames = measure(&samples, fs);
    if frames.is_empty() {
        // A carrier that carries no decodable frame: the signal is not a clean
        // phase-continuous FSK transmission (phase jumps, distortion).
        let env = envelope(&samples, fs);
        let char_n = (f64::from(fs) * 11.0 * BIT_S) as usize;
        let mut run_len = 0usize;
        let mut longest = 0usize;
        // Only carriers that end well inside the recording count: one cut off by its
        // end (a truncated file) says nothing about the signal.
        let inside = env.len().saturating_sub(char_n);
        for e in &env[..inside] {
            if *e > 0.03 {
                run_len += 1;
            } else {
                longest = longest.max(run_len);
                run_len = 0;
            }
        }
        if longest >= 4 * char_n {
            let why = format!(
                "a carrier of {:.0} ms was heard in {name} but no frame decodes from it",
                longest as f64 / f64::from(fs) * 1000.0
            );
            let results = defs
                .iter()
                .map(|d| {
                    let (verdict, detail) = if d.test == Test::Phy(PhyTest::PhaseContinuity) {
                        (
                            Verdict::Fail,
                            format!("{why}: phase jumps or distortion break the FSK signal"),
                        )
                    } else {
                        (Verdict::CouldNotRun, why.clone())
                    };
                    TestResult::of(d, verdict, detail, vec![], 0)
                })
                .collect();
            return report(results, warnings, dur);
        }
        return report(
            all(
                Verdict::CouldNotRun,
                format!(
                    "no HART frame found in {name} ({:.2} s at {fs} Hz): check it records the loop signal of a transmission",
                    dur
                ),
                vec![],
            ),
            warnings,
            dur,
        );
    }
    let evidence: Vec<Evidence> = frames
        .iter()
        .map(|f| Evidence {
            what: format!("frame at {:.3} s", f.start_s),
            sent_hex: String::new(),
            sent_start_us: 0,
            sent_end_us: 0,
            received: vec![SeenFrame {
                hex: hex(&f.pdu),
                preambles: 0,
                start_us: (f.start_s * 1e6) as u64,
                end_us: (f.end_s * 1e6) as u64,
                max_gap_us: 0,
                summary: format!(
                    "level {:.0} mVpp, tones {:+.2} %, bit rate {:+.2} %, carrier lead {} lag {}, largest step {:.0} mV ({:.0} mV for a continuous tone){}",
                    f.level_vpp * 1000.0,
                    f.tone_error * 100.0,
                    f.rate_error * 100.0,
                    f.lead_s.map_or("?".into(), |s| format!("{:.1} ms", s * 1000.0)),
                    f.lag_s.map_or("?".into(), |s| format!("{:.1} ms", s * 1000.0)),
                    f.max_step_v * 1000.0,
                    f.tone_step_v * 1000.0,
                    if f.clean { "" } else { ", decoded with errors" }
                ),
            }],
            reply_delay_us: None,
            error: None,
        })
        .collect();
    let noise = noise_rms(&samples, fs, &frames);
    let snr = noise.map(|n| {
        let level = frames.iter().map(|f| f.level_vpp).sum::<f64>() / frames.len() as f64;
        20.0 * (level / (2.0 * std::f64::consts::SQRT_2) / n.max(1e-9)).log10()
    });
    let results = defs
        .iter()
        .map(|d| {
            let (verdict, detail) = judge(d.test, &frames, snr, noise.unwrap_or(0.0), limits);
            TestResult::of(d, verdict, detail, evidence.clone(), 0)
        })
        .collect();
    report(results, warnings, dur)
}

fn judge(
    test: Test,
    frames: &[FrameMeasure],
    snr: Option<f64>,
    noise_rms: f64,
    l: &Limits,
) -> (Verdict, String) {
    let worst = |f: &dyn Fn(&FrameMeasure) -> f64| {
        frames
            .iter()
            .map(f)
            .fold(0.0f64, |a, b| if b.abs() > a.abs() { b } else { a })
    };
    let ok = |b: bool, s: String| (if b { Verdict::Pass } else { Verdict::Fail }, s);
    let Test::Phy(test) = test else {
        return (
            Verdict::CouldNotRun,
            format!("{}: not a physical-layer test", test.id()),
        );
    };
    match test {
        PhyTest::Amplitude => {
            let lo = frames.iter().map(|f| f.level_vpp).fold(f64::MAX, f64::min);
            let hi = frames.iter().map(|f| f.level_vpp).fold(0.0, f64::max);
            ok(
                lo >= l.min_vpp && hi <= l.max_vpp,
                format!(
                    "level {:.0}-{:.0} mVpp (limits {:.0}-{:.0})",
                    lo * 1000.0,
                    hi * 1000.0,
                    l.min_vpp * 1000.0,
                    l.max_vpp * 1000.0
                ),
            )
        }
        PhyTest::Frequencies => {
            let e = worst(&|f| f.tone_error);
            ok(
                e.abs() <= l.tone_error,
                format!(
                    "tones {:+.2} % off: mark {:.0} Hz, space {:.0} Hz (limit ±{:.1} %)",
                    e * 100.0,
                    1200.0 * (1.0 + e),
                    2200.0 * (1.0 + e),
                    l.tone_error * 100.0
                ),
            )
        }
        PhyTest::BitRate => {
            let e = worst(&|f| f.rate_error);
            ok(
                e.abs() <= l.rate_error,
                format!(
                    "bit rate {:.1} bit/s ({:+.2} %, limit ±{:.1} %)",
                    1200.0 * (1.0 + e),
                    e * 100.0,
                    l.rate_error * 100.0
                ),
            )
        }
        PhyTest::PhaseContinuity => {
            let unclean = frames.iter().filter(|f| !f.clean).count();
            // A phase-continuous tone moves at most `tone_step_v` between samples;
            // noise adds up to about 5·√2·σ; a phase jump steps up to the full
            // peak-to-peak level.
            let allow =
                |f: &FrameMeasure| 1.3 * f.tone_step_v + 5.0 * std::f64::consts::SQRT_2 * noise_rms;
            let jumps = frames.iter().filter(|f| f.max_step_v > allow(f)).count();
            let worst = frames
                .iter()
                .map(|f| f.max_step_v / allow(f).max(1e-9))
                .fold(0.0, f64::max);
            ok(
                unclean == 0 && jumps == 0,
                format!(
                    "{unclean} of {} frame(s) decoded with errors, {jumps} with a phase jump (largest step {:.2} of what a continuous tone and the noise allow)",
                    frames.len(),
                    worst
                ),
            )
        }
        PhyTest::CarrierTiming => {
            let lead = frames.iter().filter_map(|f| f.lead_s).fold(0.0, f64::max);
            let lag = frames.iter().filter_map(|f| f.lag_s).fold(0.0, f64::max);
            if frames
                .iter()
                .all(|f| f.lead_s.is_none() && f.lag_s.is_none())
            {
                return (
                    Verdict::CouldNotRun,
                    "no silence around the frames to see the carrier start and stop".into(),
                );
            }
            ok(
                lead <= l.carrier_lead_lag_s && lag <= l.carrier_lead_lag_s,
                format!(
                    "carrier up to {:.1} ms before the first character and {:.1} ms after the last (limit {:.1} ms)",
                    lead * 1000.0,
                    lag * 1000.0,
                    l.carrier_lead_lag_s * 1000.0
                ),
            )
        }
        PhyTest::SignalToNoise => match snr {
            None => (
                Verdict::CouldNotRun,
                "no quiet stretch of 20 ms in the recording to measure the noise".into(),
            ),
            Some(db) => ok(
                db >= l.min_snr_db,
                format!("signal-to-noise {db:.1} dB (limit {:.0} dB)", l.min_snr_db),
            ),
        },
    }
}

/// One bit at 1200 bit/s, s.
const BIT_S: f64 = 1.0 / 1200.0;

/// The envelope: RMS over one bit, as volts peak-to-peak of a sine, per sample.
fn envelope(samples: &[f32], fs: u32) -> Vec<f64> {
    let w = ((f64::from(fs) * BIT_S) as usize).max(1);
    let mut out = vec![0.0; samples.len()];
    let mut acc = 0.0f64;
    for i in 0..samples.len() {
        acc += f64::from(samples[i]).powi(2);
        if i >= w {
            acc -= f64::from(samples[i - w]).powi(2);
        }
        let n = (i + 1).min(w) as f64;
        // Centre the window on the sample.
        let c = i.saturating_sub(w / 2);
        out[c] = (acc.max(0.0) / n).sqrt() * 2.0 * std::f64::consts::SQRT_2;
    }
    out
}

/// Power of the tone `hz` over `n` samples from `at`.
fn tone_power(samples: &[f32], fs: f64, at: usize, n: usize, hz: f64) -> f64 {
    let w = 2.0 * std::f64::consts::PI * hz / fs;
    let (mut re, mut im) = (0.0f64, 0.0f64);
    for (k, s) in samples[at..(at + n).min(samples.len())].iter().enumerate() {
        let x = f64::from(*s);
        re += x * (w * k as f64).cos();
        im += x * (w * k as f64).sin();
    }
    re * re + im * im
}

/// Finds and measures the frames. The demodulator is set to hear down to 30 mVpp (a
/// tester measures levels a receiver would ignore).
pub fn measure(samples: &[f32], fs: u32) -> Vec<FrameMeasure> {
    let mut cfg = DemodConfig::new(fs);
    cfg.carrier_on_vpp = 0.03;
    cfg.carrier_off_vpp = 0.025;
    let mut demod = Demodulator::new(cfg);
    let mut found: Vec<(f64, Vec<u8>, f64, f64, f64, bool)> = vec![];
    let mut on_event = |e: DemodEvent<'_>| {
        if let DemodEvent::Frame(f) = e {
            found.push((
                f.t,
                f.pdu.to_vec(),
                f.level_vpp,
                f.tone_error,
                f.rate_error,
                f.checksum_ok && f.parity_errors == 0 && f.framing_errors == 0,
            ))
        }
    };
    for piece in samples.chunks(4096) {
        demod.push(piece, &mut on_event);
    }
    demod.finish(&mut on_event);
    let env = envelope(samples, fs);
    let fsf = f64::from(fs);
    let char_s = 11.0 * BIT_S;
    let bit_n = ((fsf * BIT_S) as usize).max(1);
    let mut out = vec![];
    for (t, pdu, level, tone, rate, clean) in found {
        // Characters last as long as the measured bit rate makes them.
        let end_s = t + pdu.len() as f64 * char_s / (1.0 + rate).max(0.5);
        let half = level / 2.0;
        let delim = ((t * fsf) as usize).min(env.len());
        let last = ((end_s * fsf) as usize).min(env.len().saturating_sub(1));
        // Carrier on: where the envelope rises past half the level, back from the
        // delimiter; off: where it falls below after the last character.
        let on = (0..delim).rev().find(|&i| env[i] < half).map(|i| i + 1);
        let off = (last..env.len()).find(|&i| env[i] < half);
        // The first character: the first space (2200 Hz) bit after the carrier comes
        // on (the carrier before it is mark; each preamble starts with a space bit).
        let first = on.and_then(|on| {
            let step = (bit_n / 8).max(1);
            let mut i = on;
            while i + bit_n <= delim + bit_n && i + bit_n <= samples.len() {
                let space = tone_power(samples, fsf, i, bit_n, 2200.0);
                let mark = tone_power(samples, fsf, i, bit_n, 1200.0);
                if space > mark {
                    // The window that sees most of the bit starts about at its edge.
                    return Some(i);
                }
                i += step;
            }
            None
        });
        let start_s = first.map_or(t, |i| i as f64 / fsf);
        let lead_s = match (on, first) {
            (Some(on), Some(first)) if on > 0 => Some(first.saturating_sub(on) as f64 / fsf),
            _ => None,
        };
        let lag_s = off.map(|i| (i.saturating_sub(last)) as f64 / fsf);
        // Phase continuity: the largest step between samples inside the frame against
        // the steepest a 2200 Hz tone of this level can make.
        let peak = level / 2.0;
        let max_step = 2.0 * std::f64::consts::PI * 2200.0 * 1.02 / fsf * peak;
        let a = ((start_s + 2.0 * BIT_S) * fsf) as usize;
        let b = (((end_s - 2.0 * BIT_S) * fsf) as usize).min(samples.len());
        let max_step_v = if a + 1 < b {
            samples[a..b]
                .windows(2)
                .map(|w| f64::from((w[1] - w[0]).abs()))
                .fold(0.0, f64::max)
        } else {
            0.0
        };
        out.push(FrameMeasure {
            start_s,
            end_s,
            carrier_on_s: on.map(|i| i as f64 / fsf),
            carrier_off_s: off.map(|i| i as f64 / fsf),
            pdu,
            level_vpp: level,
            tone_error: tone,
            rate_error: rate,
            clean,
            lead_s,
            lag_s,
            max_step_v,
            tone_step_v: max_step,
        });
    }
    out
}

/// The noise: RMS of the samples at least 10 ms away from any frame's carrier (`None`
/// when there are less than 20 ms of those).
fn noise_rms(samples: &[f32], fs: u32, frames: &[FrameMeasure]) -> Option<f64> {
    let fsf = f64::from(fs);
    let guard = 0.010;
    let mut sum = 0.0f64;
    let mut n = 0usize;
    for (i, s) in samples.iter().enumerate() {
        let t = i as f64 / fsf;
        if frames.iter().all(|f| {
            t < f.carrier_on_s.unwrap_or(f.start_s) - guard
                || t > f.carrier_off_s.unwrap_or(f.end_s) + guard
        }) {
            sum += f64::from(*s).powi(2);
            n += 1;
        }
    }
    if (n as f64) < 0.020 * fsf {
        return None;
    }
    Some((sum / n as f64).sqrt())
}

/// A recording for tests and examples: `frames` (delimiter through check byte) with 5
/// preambles each, modulated with `config`, 30 ms of silence around each, as a 16-bit
/// WAV file. `phase_jump` inverts the signal in the middle of each frame (two
/// 180-degree phase jumps); `noise_vpp` adds white noise of that peak-to-peak level
/// (approximately: σ = vpp / 6).
pub fn make_wav(
    frames: &[&[u8]],
    config: hart_modem::modulator::ModulatorConfig,
    phase_jump: bool,
    noise_vpp: f64,
) -> Vec<u8> {
    use hart_modem::modulator::Modulator;
    let fs = config.sample_rate;
    let mut m = Modulator::new(config);
    let mut out: Vec<f32> = vec![];
    m.silence(0.03, |s| out.push(s));
    for pdu in frames {
        let from = out.len();
        m.frame(5, pdu, |s| out.push(s));
        if phase_jump {
            let len = out.len() - from;
            for s in &mut out[from + len * 2 / 5..from + len * 3 / 5] {
                *s = -*s;
            }
        }
        m.silence(0.03, |s| out.push(s));
    }
    if noise_vpp > 0.0 {
        let mut rng = hart_modem::channel::Rng::new(7);
        hart_modem::channel::add_white_noise(&mut out, noise_vpp / 6.0, &mut rng);
    }
    hart_modem::wav::write_mono(&out, fs, hart_modem::wav::WriteFormat::Pcm16).unwrap_or_default()
}
