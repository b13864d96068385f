//! `hartkit modem bench`: the software modem's benchmark, and `hartkit loop cable`.
//!
//! Random HART frames (long address, 0-25 data bytes, 5 preambles) are modulated,
//! passed through a channel (white noise at a given Eb/N0, tone and bit-rate error,
//! cable RC, the 4-20 mA analog signal, the receiver noise test's interfering tones),
//! demodulated, and compared byte for byte. Eb/N0 follows the convention of the
//! physical-layer notes: tone peak A, Eb = A²/2·Tb, N0 = 2σ²/fs, so
//! σ = A·sqrt(fs / (4·1200·Eb/N0)), with A the amplitude at the receiver (after the
//! cable RC, averaged over the two tones).

use std::fmt::Write as _;
use std::time::Instant;

use hart_modem::channel::{self, Rng};
use hart_modem::demod::{DemodConfig, DemodEvent, Demodulator};
use hart_modem::modulator::{Modulator, ModulatorConfig};

/// Settings of a benchmark run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Frames per condition.
    pub frames: usize,
    /// Directory for `modem-bench.md` and `modem-bench.csv`.
    pub out: std::path::PathBuf,
    /// Sample rate, Hz.
    pub rate: u32,
    /// Random seed.
    pub seed: u64,
    /// Only conditions with these names (all when empty).
    pub only: Vec<String>,
    /// Also run minimodem on the same signals when it is installed.
    pub minimodem: bool,
}

/// One channel condition.
#[derive(Debug, Clone, PartialEq)]
pub struct Condition {
    /// Short name (used by `--only` and in the report).
    pub name: String,
    /// Group in the report.
    pub group: &'static str,
    /// Eb/N0 in dB; `None` for no noise.
    pub ebn0_db: Option<f64>,
    /// Signal level, volts peak-to-peak.
    pub vpp: f64,
    /// Tone frequency multiplier.
    pub tone_scale: f64,
    /// Bit-rate multiplier.
    pub rate_scale: f64,
    /// Cable RC time constant, seconds.
    pub rc_s: Option<f64>,
    /// 4-20 mA full swing at this frequency (Hz) across 250 Ω.
    pub analog_hz: Option<f64>,
    /// Interfering tones: (Hz, volts peak-to-peak).
    pub tones: Vec<(f64, f64)>,
    /// No signal at all: only the noise (at the σ that `ebn0_db` gives a 500 mVpp signal).
    pub noise_only: bool,
}

impl Condition {
    fn awgn(name: &str, group: &'static str, ebn0: f64) -> Self {
        Condition {
            name: name.to_string(),
            group,
            ebn0_db: Some(ebn0),
            vpp: 0.5,
            tone_scale: 1.0,
            rate_scale: 1.0,
            rc_s: None,
            analog_hz: None,
            tones: Vec::new(),
            noise_only: false,
        }
    }
}

/// The noise test's interfering tones (Hz, Vpp): in-band 1700 Hz and the four
/// out-of-band ones.
pub const NOISE_TEST_TONES: [(f64, f64); 5] = [
    (1700.0, 0.055),
    (250.0, 0.22),
    (125.0, 0.88),
    (63.0, 3.52),
    (29.0, 16.0),
];

/// Every condition of the benchmark.
pub fn conditions() -> Vec<Condition> {
    let mut v = Vec::new();
    for e in [
        8.0, 9.0, 10.0, 10.5, 11.0, 11.5, 12.0, 12.5, 13.0, 14.0, 16.0,
    ] {
        v.push(Condition::awgn(&format!("awgn-{e}"), "awgn", e));
    }
    for e in [11.0, 12.5] {
        for (label, tone, rate) in [
            ("+1%", 1.01, 1.01),
            ("-1%", 0.99, 0.99),
            ("+2%", 1.02, 1.02),
            ("-2%", 0.98, 0.98),
            ("rate+2%", 1.0, 1.02),
            ("rate-2%", 1.0, 0.98),
            ("tones+2%", 1.02, 1.0),
            ("tones-2%", 0.98, 1.0),
        ] {
            let mut c = Condition::awgn(&format!("offset{label}-{e}"), "offset", e);
            c.tone_scale = tone;
            c.rate_scale = rate;
            v.push(c);
        }
        let mut c = Condition::awgn(&format!("rc65us-{e}"), "rc", e);
        c.rc_s = Some(65e-6);
        v.push(c);
    }
    for hz in [10.0, 18.0] {
        let mut c = Condition::awgn(&format!("analog-{hz}hz"), "interference", 20.0);
        c.analog_hz = Some(hz);
        v.push(c);
    }
    for (hz, vpp) in NOISE_TEST_TONES {
        let mut c = Condition::awgn(
            &format!("tone-{hz}hz-{}mvpp", vpp * 1000.0),
            "interference",
            20.0,
        );
        c.tones = vec![(hz, vpp)];
        v.push(c);
    }
    for mvpp in [120.0, 80.0] {
        let mut c = Condition::awgn(&format!("level-{mvpp}mvpp"), "level", 20.0);
        c.vpp = mvpp / 1000.0;
        v.push(c);
    }
    for e in [8.0, 20.0] {
        let mut c = Condition::awgn(&format!("noise-only-{e}"), "level", e);
        c.noise_only = true;
        v.push(c);
    }
    let mut c = Condition::awgn("combined-16", "combined", 16.0);
    c.tone_scale = 1.02;
    c.rate_scale = 1.02;
    c.rc_s = Some(65e-6);
    c.analog_hz = Some(18.0);
    c.tones = NOISE_TEST_TONES.to_vec();
    v.push(c);
    v
}

/// What one condition gave.
#[derive(Debug, Clone, PartialEq)]
pub struct Outcome {
    /// Frames sent.
    pub sent: usize,
    /// Frames received byte-exact with good parity and check byte.
    pub good: usize,
    /// Frames that passed every check but differ from what was sent.
    pub undetected: usize,
    /// Good frames that were never sent (noise-only runs).
    pub false_frames: usize,
    /// Carrier-detect switch-ons beyond one per frame sent.
    pub carrier_false_alarms: usize,
    /// Seconds of signal.
    pub audio_s: f64,
    /// Seconds the demodulator took.
    pub cpu_s: f64,
    /// Frames minimodem got right, when it ran.
    pub minimodem_good: Option<usize>,
}

impl Outcome {
    /// Frame error rate.
    pub fn fer(&self) -> f64 {
        if self.sent == 0 {
            0.0
        } else {
            1.0 - self.good as f64 / self.sent as f64
        }
    }
}

/// Random benchmark frames: long address, command, 0-25 data bytes, check byte.
pub fn random_frames(rng: &mut Rng, n: usize) -> Vec<Vec<u8>> {
    (0..n)
        .map(|_| {
            let len = (rng.next_u64() % 26) as usize;
            let mut pdu = vec![if rng.next_u64() % 2 == 0 { 0x82 } else { 0x86 }];
            pdu.extend((0..6).map(|_| rng.next_u64() as u8));
            pdu.push(len as u8);
            if pdu[0] == 0x86 {
                // A reply: response code and device status come first.
                pdu.extend([0u8, 0]);
                pdu[7] = (len + 2) as u8;
            }
            pdu.extend((0..len).map(|_| rng.next_u64() as u8));
            let check = pdu.iter().fold(0, |a, b| a ^ b);
            pdu.push(check);
            pdu
        })
        .collect()
}

/// Builds the received signal of a condition.
pub fn signal(c: &Condition, frames: &[Vec<u8>], fs: u32, rng: &mut Rng) -> Vec<f32> {
    let mut cfg = ModulatorConfig::new(fs);
    cfg.amplitude_vpp = c.vpp;
    cfg.tone_scale = c.tone_scale;
    cfg.rate_scale = c.rate_scale;
    cfg.lead_bits = 6;
    cfg.tail_bits = 12;
    cfg.start_phase = rng.uniform();
    let mut m = Modulator::new(cfg);
    let mut s = Vec::new();
    for f in frames {
        m.silence(0.030, |x| s.push(x));
        let mut phase = cfg;
        phase.start_phase = rng.uniform();
        m.set_config(phase);
        m.frame(5, f, |x| s.push(x));
    }
    m.silence(0.030, |x| s.push(x));
    if c.noise_only {
        s.iter_mut().for_each(|x| *x = 0.0);
    }
    if let Some(tau) = c.rc_s {
        channel::rc_lowpass(&mut s, fs, tau);
    }
    if let Some(hz) = c.analog_hz {
        // Full swing 4 <-> 20 mA across 250 Ω: 3 V ± 2 V.
        let w = 2.0 * std::f64::consts::PI * hz / f64::from(fs);
        for (i, x) in s.iter_mut().enumerate() {
            *x += (3.0 + 2.0 * (w * i as f64).sin()) as f32;
        }
    }
    for &(hz, vpp) in &c.tones {
        channel::add_tone(&mut s, fs, hz, vpp, rng.uniform());
    }
    if let Some(e) = c.ebn0_db {
        // Eb/N0 at the receiver: the noise follows the level that arrives (500 mVpp
        // for noise-only runs), so the cable's attenuation is not counted twice and
        // its cost is what its distortion does.
        let mut peak = if c.noise_only { 0.25 } else { c.vpp / 2.0 };
        if let Some(tau) = c.rc_s {
            let gain2 = |f: f64| 1.0 / (1.0 + (2.0 * std::f64::consts::PI * f * tau).powi(2));
            peak *= ((gain2(1200.0) + gain2(2200.0)) / 2.0).sqrt();
        }
        let sigma = channel::sigma_for_ebn0(peak, f64::from(fs), e);
        channel::add_white_noise(&mut s, sigma, rng);
    }
    s
}

/// Runs one condition.
pub fn run_condition(
    c: &Condition,
    n: usize,
    fs: u32,
    seed: u64,
) -> (Outcome, Vec<f32>, Vec<Vec<u8>>) {
    let mut rng = Rng::new(seed);
    let frames = if c.noise_only {
        random_frames(&mut rng, n.min(200))
    } else {
        random_frames(&mut rng, n)
    };
    let s = signal(c, &frames, fs, &mut rng);
    let mut d = Demodulator::new(DemodConfig::new(fs));
    let mut got: Vec<(Vec<u8>, bool)> = Vec::new();
    let mut carriers = 0usize;
    let t0 = Instant::now();
    let mut on = |ev: DemodEvent<'_>| match ev {
        DemodEvent::Frame(f) => got.push((
            f.pdu.to_vec(),
            f.checksum_ok && f.parity_errors == 0 && f.framing_errors == 0,
        )),
        DemodEvent::Carrier { on: true, .. } => carriers += 1,
        _ => {}
    };
    for chunk in s.chunks(4800) {
        d.push(chunk, &mut on);
    }
    d.finish(&mut on);
    let cpu_s = t0.elapsed().as_secs_f64();
    let sent = if c.noise_only { 0 } else { frames.len() };
    let (good, undetected, false_frames) = score(&frames[..sent], &got);
    let outcome = Outcome {
        sent,
        good,
        undetected,
        false_frames: if c.noise_only {
            got.iter().filter(|g| g.1).count()
        } else {
            false_frames
        },
        carrier_false_alarms: carriers.saturating_sub(sent),
        audio_s: s.len() as f64 / f64::from(fs),
        cpu_s,
        minimodem_good: None,
    };
    (outcome, s, frames)
}

/// Matches received frames to sent ones in order: (good, undetected wrong, extra).
pub fn score(sent: &[Vec<u8>], got: &[(Vec<u8>, bool)]) -> (usize, usize, usize) {
    let (mut good, mut undetected, mut extra) = (0, 0, 0);
    let mut j = 0;
    for (pdu, ok) in got {
        if !ok {
            continue;
        }
        match sent[j..].iter().position(|s| s == pdu) {
            Some(k) => {
                good += 1;
                j += k + 1;
            }
            None if sent.iter().any(|s| s == pdu) => extra += 1,
            None => undetected += 1,
        }
    }
    (good, undetected, extra)
}

/// Eb/N0 at which the clean curve reaches `fer` (log-linear between measured points).
fn clean_db_for(curve: &[(f64, f64)], fer: f64) -> Option<f64> {
    let lf = |x: f64| x.max(1e-5).ln();
    curve.windows(2).find_map(|w| {
        let ((d0, f0), (d1, f1)) = (w[0], w[1]);
        let (a, b, t) = (lf(f0), lf(f1), lf(fer));
        ((a >= t && t >= b) && a != b).then(|| d0 + (d1 - d0) * (a - t) / (a - b))
    })
}

/// Runs the benchmark and writes `modem-bench.md` and `modem-bench.csv` to `o.out`.
pub fn run(o: &Options) -> Result<String, String> {
    crate::modem::check_rate(o.rate)?;
    let all = conditions();
    for name in &o.only {
        if !all.iter().any(|c| &c.name == name) {
            return Err(format!(
                "no condition {name:?}; the conditions are: {}",
                all.iter()
                    .map(|c| c.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
    }
    let picked: Vec<&Condition> = all
        .iter()
        .filter(|c| o.only.is_empty() || o.only.contains(&c.name))
        .collect();
    let minimodem = o.minimodem && minimodem::available();
    if o.minimodem && !minimodem {
        tracing::warn!(
            "minimodem is not installed; running without it (apt-get install minimodem)"
        );
    }
    let mut rows = Vec::new();
    for (i, c) in picked.iter().enumerate() {
        let (mut out, samples, frames) =
            run_condition(c, o.frames, o.rate, o.seed.wrapping_add(i as u64 * 7919));
        if minimodem && !c.noise_only {
            out.minimodem_good = minimodem::decode_count(&samples, o.rate, &frames).ok();
        }
        eprintln!(
            "{:<24} FER {:.4}  ({} of {})  undetected {}  false {}  CD alarms {}  {:.0}x real time{}",
            c.name,
            out.fer(),
            out.good,
            out.sent,
            out.undetected,
            out.false_frames,
            out.carrier_false_alarms,
            out.audio_s / out.cpu_s.max(1e-9),
            out.minimodem_good.map(|g| format!("  minimodem {g}")).unwrap_or_default()
        );
        rows.push(((*c).clone(), out));
    }
    let report = report(o, &rows);
    std::fs::create_dir_all(&o.out)
        .map_err(|e| format!("cannot create {}: {e}", o.out.display()))?;
    let md = o.out.join("modem-bench.md");
    std::fs::write(&md, &report.0).map_err(|e| format!("cannot write {}: {e}", md.display()))?;
    let csv = o.out.join("modem-bench.csv");
    std::fs::write(&csv, &report.1).map_err(|e| format!("cannot write {}: {e}", csv.display()))?;
    Ok(format!("wrote {} and {}", md.display(), csv.display()))
}

/// The report as Markdown and CSV.
fn report(o: &Options, rows: &[(Condition, Outcome)]) -> (String, String) {
    let curve: Vec<(f64, f64)> = rows
        .iter()
        .filter(|(c, _)| c.group == "awgn")
        .map(|(c, r)| (c.ebn0_db.unwrap_or(0.0), r.fer()))
        .collect();
    let mut md = String::new();
    let _ = writeln!(md, "# Software modem benchmark\n");
    let _ = writeln!(
        md,
        "`hartkit modem bench --frames {} --rate {} --seed {}`: {} random frames per condition (long address, 0-25 data bytes, 5 preambles, 30 ms apart), {} Hz. FER counts frames not received byte-exact with good parity and check byte.\n",
        o.frames, o.rate, o.seed, o.frames, o.rate
    );
    let _ = writeln!(md, "| condition | Eb/N0 dB | level mVpp | FER | good | undetected | false frames | CD false alarms | × real time | cost dB |{}", if rows.iter().any(|r| r.1.minimodem_good.is_some()) { " minimodem FER |" } else { "" });
    let _ = writeln!(
        md,
        "|---|---|---|---|---|---|---|---|---|---|{}",
        if rows.iter().any(|r| r.1.minimodem_good.is_some()) {
            "---|"
        } else {
            ""
        }
    );
    let mut csv = String::from("condition,group,ebn0_db,level_mvpp,sent,good,fer,undetected,false_frames,carrier_false_alarms,x_real_time,minimodem_good\n");
    for (c, r) in rows {
        let speed = r.audio_s / r.cpu_s.max(1e-9);
        let cost = match (c.group, c.ebn0_db) {
            ("offset" | "rc", Some(e)) if r.fer() > 0.0 => {
                clean_db_for(&curve, r.fer()).map(|d| format!("{:+.1}", e - d))
            }
            ("offset" | "rc", Some(_)) => Some("≤ 0".to_string()),
            _ => None,
        }
        .unwrap_or_default();
        let mm = r
            .minimodem_good
            .map(|g| format!(" {:.4} |", 1.0 - g as f64 / r.sent.max(1) as f64));
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.4} | {}/{} | {} | {} | {} | {:.0} | {} |{}",
            c.name,
            c.ebn0_db
                .map(|e| format!("{e}"))
                .unwrap_or_else(|| "-".into()),
            if c.noise_only {
                "-".to_string()
            } else {
                format!("{:.0}", c.vpp * 1000.0)
            },
            r.fer(),
            r.good,
            r.sent,
            r.undetected,
            r.false_frames,
            r.carrier_false_alarms,
            speed,
            cost,
            mm.unwrap_or_default()
        );
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{:.6},{},{},{},{:.1},{}",
            c.name,
            c.group,
            c.ebn0_db.map(|e| e.to_string()).unwrap_or_default(),
            if c.noise_only { 0.0 } else { c.vpp * 1000.0 },
            r.sent,
            r.good,
            r.fer(),
            r.undetected,
            r.false_frames,
            r.carrier_false_alarms,
            speed,
            r.minimodem_good.map(|g| g.to_string()).unwrap_or_default()
        );
    }
    let total_audio: f64 = rows.iter().map(|r| r.1.audio_s).sum();
    let total_cpu: f64 = rows.iter().map(|r| r.1.cpu_s).sum();
    let _ = writeln!(
        md,
        "\nDemodulator speed over all conditions: {:.0}× real time on one core ({:.0} s of signal in {:.1} s).",
        total_audio / total_cpu.max(1e-9),
        total_audio,
        total_cpu
    );
    let _ = writeln!(md, "\n\"cost dB\" is how much more Eb/N0 the clean channel needs for the same FER (interpolated on the awgn rows).");
    let (mean, peak) = fsk_analog_shift(o.rate);
    let _ = writeln!(
        md,
        "\nThe modulator's signal (1 mA peak-to-peak across 250 Ω, frames back to back for 3 s) shifts the 10 Hz analog reading by {mean:.2} µA on average and {peak:.2} µA at most."
    );
    (md, csv)
}

/// How much our modulator's signal shifts a 4-20 mA input's 10 Hz reading (µA, mean
/// and largest): a device sending frames back to back, 1 mA peak-to-peak, 250 Ω.
pub fn fsk_analog_shift(fs: u32) -> (f64, f64) {
    let mut cfg = ModulatorConfig::new(fs);
    cfg.amplitude_vpp = 0.25;
    let mut m = Modulator::new(cfg);
    let mut rng = Rng::new(5);
    let mut s = Vec::new();
    for f in random_frames(&mut rng, 1000) {
        if s.len() >= 3 * fs as usize {
            break;
        }
        m.frame(5, &f, |x| s.push(x));
        m.silence(0.002, |x| s.push(x));
    }
    channel::analog_shift_ua(&s, fs, 250.0)
}

mod minimodem {
    //! Runs minimodem (`--rx 1200 --binary-raw 11`) on a signal and parses its raw bits
    //! as 8O1 HART characters, for a side-by-side comparison.
    use super::score;
    use hart_proto::deframer::{Deframer, DeframerEvent, UartFlags};

    pub fn available() -> bool {
        std::process::Command::new("minimodem")
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    }

    /// Frames minimodem got right.
    pub fn decode_count(samples: &[f32], fs: u32, sent: &[Vec<u8>]) -> Result<usize, String> {
        let dir = std::env::temp_dir().join(format!("hartkit-mm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
        let path = dir.join("bench.wav");
        let peak = samples.iter().fold(0f32, |a, s| a.max(s.abs())).max(1e-9);
        let scaled: Vec<f32> = samples.iter().map(|s| s / peak * 0.9).collect();
        let bytes = hart_modem::wav::write_mono(&scaled, fs, hart_modem::wav::WriteFormat::Pcm16)
            .map_err(|e| e.to_string())?;
        std::fs::write(&path, bytes).map_err(|e| e.to_string())?;
        let out = std::process::Command::new("minimodem")
            .args(["--rx", "1200", "-q", "--binary-raw", "11", "-f"])
            .arg(&path)
            .output()
            .map_err(|e| e.to_string())?;
        let _ = std::fs::remove_dir_all(&dir);
        let text = String::from_utf8_lossy(&out.stdout);
        let bits: Vec<bool> = text
            .chars()
            .filter_map(|c| match c {
                '0' => Some(false),
                '1' => Some(true),
                _ => None,
            })
            .collect();
        // 8O1 UART over the bit stream, then the deframer.
        let mut d = Deframer::default();
        let mut got = Vec::new();
        let mut i = 0;
        while i + 11 <= bits.len() {
            if bits[i] {
                i += 1;
                continue;
            }
            let mut byte = 0u8;
            for k in 0..8 {
                byte |= u8::from(bits[i + 1 + k]) << k;
            }
            let parity_ok = (byte.count_ones() + u32::from(bits[i + 9])) % 2 == 1;
            let flags = UartFlags {
                parity: !parity_ok,
                framing: !bits[i + 10],
                overrun: false,
            };
            d.push(byte, flags, &mut |ev| {
                if let DeframerEvent::Frame(f) = ev {
                    got.push((f.pdu.to_vec(), true));
                }
            });
            i += 11;
        }
        Ok(score(sent, &got).0)
    }
}
