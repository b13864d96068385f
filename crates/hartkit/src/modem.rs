//! `hartkit modem`: HART frames to and from sound (WAV files, raw samples on standard
//! input), through the software Bell 202 modem in `hart-modem`.

use std::io::{Read, Write};

use hart_modem::demod::{DecodedFrame, DemodConfig, DemodEvent, Demodulator, RxFrame, START_ALIGN};
use hart_modem::modulator::{Modulator, ModulatorConfig};
use hart_modem::wav::{self, Wav, WriteFormat};
use hart_proto::frame::Frame;
use serde_json::json;

use crate::{annotate, hex};

/// Lowest and highest sample rates the modem accepts.
pub const RATES: std::ops::RangeInclusive<u32> = 8000..=192_000;

/// Settings of `hartkit modem tx`.
#[derive(Debug, Clone)]
pub struct TxOptions {
    /// Output WAV file.
    pub out: std::path::PathBuf,
    /// Sample rate, Hz.
    pub rate: u32,
    /// Signal level, millivolts peak-to-peak.
    pub amplitude_mvpp: f64,
    /// Preamble characters before each frame.
    pub preambles: usize,
    /// Silence before, between and after frames, milliseconds.
    pub gap_ms: f64,
    /// Volts represented by a full-scale sample (1.0).
    pub volts_per_fs: f64,
    /// Write 32-bit float samples instead of 16-bit PCM.
    pub float: bool,
    /// White noise over the whole recording (silence included), this many dB below a
    /// sine of the signal's level (`None`: none), as `modem channel --snr-db`.
    pub snr_db: Option<f64>,
    /// Seed of the noise.
    pub seed: u64,
}

/// Checks a sample rate against [`RATES`].
pub fn check_rate(rate: u32) -> Result<(), String> {
    if RATES.contains(&rate) {
        Ok(())
    } else {
        Err(format!(
            "sample rate {rate} Hz is outside 8000-192000 Hz; resample the file (e.g. `sox in.wav -r 48000 out.wav`)"
        ))
    }
}

/// Parses frames given as hex, one per argument or one per line of a file; each runs
/// from the delimiter to the check byte (leading 0xFF preambles are dropped, since the
/// modulator adds its own).
pub fn parse_frames(
    args: &[String],
    file: Option<&std::path::Path>,
) -> Result<Vec<Vec<u8>>, String> {
    let mut lines: Vec<String> = args.to_vec();
    if let Some(path) = file {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        lines.extend(
            text.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(String::from),
        );
    }
    if lines.is_empty() {
        return Err(
            "no frames given: pass hex frames as arguments or --in FILE with one per line".into(),
        );
    }
    lines
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let mut bytes = hex::parse(&[l]).map_err(|e| format!("frame {}: {e}", i + 1))?;
            let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
            bytes.drain(..pre);
            if bytes.is_empty() {
                return Err(format!("frame {}: only preambles, no delimiter", i + 1));
            }
            let frame = Frame::parse(&bytes).map_err(|e| {
                format!("frame {}: {e} (give each frame from the delimiter through the check byte)", i + 1)
            })?;
            if !frame.checksum_ok() || !frame.trailing.is_empty() {
                return Err(format!(
                    "frame {}: the check byte should be {:02X} and end the frame (the frame is {} bytes by its byte count)",
                    i + 1,
                    frame.expected_check_byte,
                    frame.pdu.len()
                ));
            }
            Ok(bytes)
        })
        .collect()
}

/// `hartkit modem tx`: writes the frames as a WAV file and describes what it wrote.
pub fn tx(frames: &[Vec<u8>], o: &TxOptions) -> Result<String, String> {
    check_rate(o.rate)?;
    if !o.volts_per_fs.is_finite() || o.volts_per_fs <= 0.0 {
        return Err("--volts-per-fs must be positive".into());
    }
    let mut cfg = ModulatorConfig::new(o.rate);
    cfg.amplitude_vpp = o.amplitude_mvpp / 1000.0;
    let mut m = Modulator::new(cfg);
    let mut samples = Vec::new();
    let gap = o.gap_ms / 1000.0;
    let scale = (1.0 / o.volts_per_fs) as f32;
    let mut push = |s: f32| samples.push(s * scale);
    for f in frames {
        m.silence(gap, &mut push);
        m.frame(o.preambles, f, &mut push);
    }
    m.silence(gap, &mut push);
    if let Some(snr) = o.snr_db {
        if !snr.is_finite() {
            return Err(format!("--snr-db {snr}: give a number of dB"));
        }
        let sigma =
            hart_modem::channel::StreamChannel::sigma_for_snr(o.amplitude_mvpp / 1000.0, snr)
                / o.volts_per_fs;
        let mut rng = hart_modem::channel::Rng::new(o.seed);
        hart_modem::channel::add_white_noise(&mut samples, sigma, &mut rng);
    }
    let peak = samples.iter().fold(0f32, |a, s| a.max(s.abs()));
    if peak > 1.0 && !o.float {
        return Err(format!(
            "the signal peaks at {peak:.2} of full scale and would clip in 16-bit PCM; lower --amplitude-mvpp, raise --volts-per-fs or use --float"
        ));
    }
    if o.out.as_os_str() == "-" {
        // A pipe: raw signed 16-bit little-endian samples, for `modem channel` and
        // `modem rx --raw s16le --rate R -`.
        let raw: Vec<u8> = samples
            .iter()
            .flat_map(|&s| to_s16(s).to_le_bytes())
            .collect();
        let mut out = std::io::stdout().lock();
        return match out.write_all(&raw).and_then(|_| out.flush()) {
            Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
                Err(format!("writing samples: {e}"))
            }
            _ => Ok(String::new()),
        };
    }
    let format = if o.float {
        WriteFormat::Float32
    } else {
        WriteFormat::Pcm16
    };
    let bytes = wav::write_mono(&samples, o.rate, format).map_err(|e| e.to_string())?;
    std::fs::write(&o.out, bytes).map_err(|e| format!("cannot write {}: {e}", o.out.display()))?;
    Ok(format!(
        "wrote {} frame(s), {:.3} s at {} Hz, {} mVpp, to {}",
        frames.len(),
        samples.len() as f64 / f64::from(o.rate),
        o.rate,
        o.amplitude_mvpp,
        o.out.display()
    ))
}

/// Where `hartkit modem rx` reads samples from.
#[derive(Debug, Clone)]
pub enum RxInput {
    /// A WAV file.
    Wav(std::path::PathBuf),
    /// Raw signed 16-bit little-endian mono samples at this rate, from a file or
    /// (path `-`) standard input.
    RawS16le {
        /// File, or `-` for standard input.
        path: std::path::PathBuf,
        /// Sample rate, Hz.
        rate: u32,
    },
    /// A sound card's input (`default` or a name as `--list-sound-cards` prints it),
    /// first channel, at its own rate; needs the `sound-card` feature.
    SoundCard(String),
}

/// The live view of `modem rx --live`: one status line on standard error, redrawn at
/// most ten times a second: carrier, level, frames so far, the last frame.
#[derive(Debug)]
pub struct LiveView {
    carrier: bool,
    level_vpp: f64,
    frames: usize,
    damaged: usize,
    last: String,
    last_draw: Option<std::time::Instant>,
    /// Seconds of signal seen.
    seconds: f64,
}

impl Default for LiveView {
    fn default() -> Self {
        Self::new()
    }
}

impl LiveView {
    /// Nothing seen yet.
    pub fn new() -> Self {
        LiveView {
            carrier: false,
            level_vpp: 0.0,
            frames: 0,
            damaged: 0,
            last: String::new(),
            last_draw: None,
            seconds: 0.0,
        }
    }

    /// A frame was decoded.
    pub fn frame(&mut self, f: &RxFrame<'_>) {
        self.frames += 1;
        if !(f.checksum_ok && f.parity_errors == 0 && f.framing_errors == 0) {
            self.damaged += 1;
        }
        let mut hex = hex::compact(f.pdu);
        if hex.len() > 24 {
            hex.truncate(24);
            hex.push('…');
        }
        self.last = format!("{hex} at {:.0} mVpp", f.level_vpp * 1000.0);
    }

    /// The demodulator's state after a block; `seconds` of signal so far.
    pub fn update(&mut self, carrier: bool, level_vpp: f64, seconds: f64) {
        self.carrier = carrier;
        self.level_vpp = level_vpp;
        self.seconds = seconds;
    }

    /// The status line: `  12.3 s  carrier ON   482 mVpp [#########-----------]  frames 12 (0 damaged)  last 82A606…`.
    pub fn render(&self) -> String {
        // A bar to 1 Vpp, 20 steps of 50 mV; the carrier threshold sits at step 2.
        let steps = ((self.level_vpp / 0.05).round() as usize).min(20);
        format!(
            "{:>8.1} s  carrier {:<3} {:>4.0} mVpp [{}{}]  frames {} ({} damaged){}",
            self.seconds,
            if self.carrier { "ON" } else { "off" },
            self.level_vpp * 1000.0,
            "#".repeat(steps),
            "-".repeat(20 - steps),
            self.frames,
            self.damaged,
            if self.last.is_empty() {
                String::new()
            } else {
                format!("  last {}", self.last)
            }
        )
    }

    /// Redraws the line on standard error if a tenth of a second has passed (or
    /// `force`).
    pub fn draw(&mut self, force: bool) {
        let now = std::time::Instant::now();
        if !force
            && self
                .last_draw
                .is_some_and(|t| now.duration_since(t).as_millis() < 100)
        {
            return;
        }
        self.last_draw = Some(now);
        eprint!("\r\x1b[2K{}", self.render());
    }

    /// Clears the line (before a frame's listing is written to the same terminal).
    pub fn clear(&self) {
        if self.last_draw.is_some() {
            eprint!("\r\x1b[2K");
        }
    }
}

/// One decoded frame as the JSON line `hartkit modem rx --json` prints.
pub fn frame_json(f: &RxFrame<'_>) -> serde_json::Value {
    json!({
        "t": (f.t * 1e6).round() / 1e6,
        "hex": hex::compact(f.pdu),
        "preambles": f.preambles,
        "checksum_ok": f.checksum_ok,
        "parity_errors": f.parity_errors,
        "level_mvpp": (f.level_vpp * 1e4).round() / 10.0,
    })
}

/// One decoded frame as a readable listing: a summary line, then the frame decoded
/// field by field when it is intact.
pub fn frame_text(f: &RxFrame<'_>) -> String {
    let mut flags = Vec::new();
    if !f.checksum_ok {
        flags.push("CHECK BYTE WRONG".to_string());
    }
    if f.parity_errors > 0 {
        flags.push(format!("{} PARITY ERROR(S)", f.parity_errors));
    }
    if f.framing_errors > 0 {
        flags.push(format!("{} FRAMING ERROR(S)", f.framing_errors));
    }
    let mut out = format!(
        "t={:.6} s  {} preambles  {:.0} mVpp  bit rate {:+.1} %  tones {:+.1} %  {}{}\n",
        f.t,
        f.preambles,
        f.level_vpp * 1000.0,
        f.rate_error * 100.0,
        f.tone_error * 100.0,
        hex::spaced(f.pdu),
        if flags.is_empty() {
            String::new()
        } else {
            format!("  [{}]", flags.join(", "))
        }
    );
    if flags.is_empty() {
        if let Ok(mut frame) = Frame::parse(f.pdu) {
            frame.preambles = f.preambles;
            for line in annotate::frame(&frame).lines() {
                out.push_str("    ");
                out.push_str(line);
                out.push('\n');
            }
        }
    }
    out
}

/// Settings of `hartkit modem rx`.
#[derive(Debug, Clone)]
pub struct RxOptions {
    /// Volts represented by a full-scale sample.
    pub volts_per_fs: f64,
    /// One JSON object per line and frame instead of the listing.
    pub json: bool,
    /// The live status line on standard error (decodes on one core).
    pub live: bool,
    /// Cores a long file is decoded on; the output is the same whatever the number.
    pub jobs: usize,
    /// Samples per piece of a file decoded on its own (`None`: the file split evenly
    /// between the jobs, pieces of 2^21 to 2^25 samples); for tests.
    pub chunk_samples: Option<u64>,
}

impl RxOptions {
    /// Defaults: 1 V full scale, the listing, one core.
    pub fn new() -> Self {
        RxOptions {
            volts_per_fs: 1.0,
            json: false,
            live: false,
            jobs: 1,
            chunk_samples: None,
        }
    }
}

impl Default for RxOptions {
    fn default() -> Self {
        Self::new()
    }
}

/// `hartkit modem rx`: decodes every frame and prints each as soon as it is found
/// (one JSON object per line with `json`). Returns the number of frames.
///
/// With `live`, a status line on standard error shows the carrier, the level and the
/// frames as they come. A long file (WAV, or raw samples in a file) is decoded on
/// `jobs` cores, in pieces (see [`decode_file`]), with the same output.
pub fn rx(
    input: &RxInput,
    o: &RxOptions,
    out: &mut dyn std::io::Write,
    mut capture: Option<&mut crate::host::Capture>,
) -> Result<usize, String> {
    let (volts_per_fs, as_json, live) = (o.volts_per_fs, o.json, o.live);
    let jobs = if live { 1 } else { o.jobs.max(1) };
    let view = std::cell::RefCell::new(live.then(LiveView::new));
    let mut count = 0usize;
    let error: std::cell::RefCell<Option<std::io::Error>> = std::cell::RefCell::new(None);
    let capture_error: std::cell::RefCell<Option<String>> = std::cell::RefCell::new(None);
    // Capture time stamps: a file's modification time, or now for standard input,
    // plus the frame's time in the recording.
    let start_us = recording_start_us(input);
    let mut emit = |ev: DemodEvent<'_>| {
        if let DemodEvent::Frame(f) = ev {
            count += 1;
            if let Some(v) = view.borrow_mut().as_mut() {
                v.frame(&f);
                v.clear();
            }
            if let Some(c) = capture.as_deref_mut() {
                let valid = f.checksum_ok && f.parity_errors == 0 && f.framing_errors == 0;
                let note = format!(
                    "level {:.0} mVpp, {} preambles, {} parity and {} framing errors{}",
                    f.level_vpp * 1000.0,
                    f.preambles,
                    f.parity_errors,
                    f.framing_errors,
                    if f.checksum_ok {
                        ""
                    } else {
                        ", check byte wrong"
                    }
                );
                if let Err((e, _)) = c.record(start_us + (f.t * 1e6) as u64, f.pdu, valid, &note) {
                    capture_error.borrow_mut().get_or_insert(e);
                }
            }
            let text = if as_json {
                frame_json(&f).to_string() + "\n"
            } else {
                frame_text(&f)
            };
            if let Err(e) = out.write_all(text.as_bytes()) {
                error.borrow_mut().get_or_insert(e);
            }
            let _ = out.flush();
        }
    };
    // After each block: the live view, if any.
    let tick = |d: &Demodulator, samples_seen: u64| {
        if let Some(v) = view.borrow_mut().as_mut() {
            let fs = f64::from(d.config().sample_rate);
            v.update(d.carrier(), d.level_vpp(), samples_seen as f64 / fs);
            v.draw(false);
        }
    };
    match input {
        RxInput::Wav(path) => {
            let file = SampleFile::wav(path)?;
            decode_file(
                &file,
                config(file.rate, volts_per_fs),
                jobs,
                o.chunk_samples,
                &mut emit,
                &tick,
                &|| error.borrow().is_some(),
            )?;
        }
        RxInput::RawS16le { path, rate } if jobs > 1 && path.as_os_str() != "-" => {
            check_rate(*rate)?;
            let file = SampleFile::raw_s16le(path, *rate)?;
            decode_file(
                &file,
                config(*rate, volts_per_fs),
                jobs,
                o.chunk_samples,
                &mut emit,
                &tick,
                &|| error.borrow().is_some(),
            )?;
        }
        RxInput::RawS16le { path, rate } => {
            check_rate(*rate)?;
            let mut reader: Box<dyn Read> = if path.as_os_str() == "-" {
                Box::new(std::io::stdin().lock())
            } else {
                Box::new(
                    std::fs::File::open(path)
                        .map_err(|e| format!("cannot open {}: {e}", path.display()))?,
                )
            };
            let mut d = Demodulator::new(config(*rate, volts_per_fs));
            let mut buf = vec![0u8; 8192];
            let mut s16 = S16Decoder::default();
            let mut samples = Vec::with_capacity(4096);
            let mut seen = 0u64;
            while s16.read(&mut reader, &mut buf, &mut samples)? {
                d.push(&samples, &mut emit);
                seen += samples.len() as u64;
                tick(&d, seen);
                if error.borrow().is_some() {
                    break;
                }
            }
            d.finish(&mut emit);
        }
        RxInput::SoundCard(name) => {
            let card = crate::sound::SoundCard::open(name)?;
            eprintln!(
                "listening to {} at {} samples/s (Ctrl-C to stop)",
                card.name(),
                card.rate()
            );
            check_rate(card.rate())?;
            let mut d = Demodulator::new(config(card.rate(), volts_per_fs));
            let mut seen = 0u64;
            let mut reported = 0;
            while let Some(samples) = card.next_block()? {
                d.push(&samples, &mut emit);
                seen += samples.len() as u64;
                tick(&d, seen);
                if error.borrow().is_some() {
                    break;
                }
                if card.dropped() > reported {
                    reported = card.dropped();
                    tracing::warn!(
                        "{reported} block(s) of samples lost so far: the decoder fell behind the card (a busy machine?); frames across a gap are lost"
                    );
                }
            }
            d.finish(&mut emit);
        }
    }
    if let Some(v) = view.borrow_mut().as_mut() {
        v.draw(true);
        eprintln!();
    }
    if let Some(e) = capture_error.into_inner() {
        return Err(e);
    }
    match error.into_inner() {
        // A closed pipe (`| head`) ends the run quietly.
        Some(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(format!("writing output: {e}"))
        }
        _ => Ok(count),
    }
}

/// When the recording began, µs since the Unix epoch: the file's modification time, or
/// now for standard input.
fn recording_start_us(input: &RxInput) -> u64 {
    let path = match input {
        RxInput::Wav(p) => Some(p),
        RxInput::RawS16le { path, .. } if path.as_os_str() != "-" => Some(path),
        RxInput::RawS16le { .. } | RxInput::SoundCard(_) => None,
    };
    path.and_then(|p| std::fs::metadata(p).ok())
        .and_then(|m| m.modified().ok())
        .unwrap_or_else(std::time::SystemTime::now)
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// Raw signed 16-bit little-endian samples read in pieces: a byte left over at the end
/// of one piece starts the next sample.
#[derive(Debug, Default)]
struct S16Decoder {
    carry: Option<u8>,
}

impl S16Decoder {
    /// Reads what `r` has (at most `buf`'s size) and puts its samples in `out`;
    /// `false` at the end of the input.
    fn read(
        &mut self,
        r: &mut impl Read,
        buf: &mut [u8],
        out: &mut Vec<f32>,
    ) -> Result<bool, String> {
        let n = loop {
            match r.read(buf) {
                Ok(n) => break n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(format!("reading samples: {e}")),
            }
        };
        out.clear();
        self.decode(&buf[..n], out);
        Ok(n > 0)
    }

    /// Appends the samples of `bytes` (full scale ±1) to `out`.
    fn decode(&mut self, bytes: &[u8], out: &mut Vec<f32>) {
        let mut it = self.carry.take().into_iter().chain(bytes.iter().copied());
        loop {
            match (it.next(), it.next()) {
                (Some(lo), Some(hi)) => out.push(f32::from(i16::from_le_bytes([lo, hi])) / 32768.0),
                (Some(lo), None) => {
                    self.carry = Some(lo);
                    break;
                }
                _ => break,
            }
        }
    }
}

/// A sample (full scale ±1) as signed 16-bit PCM, clipped.
fn to_s16(s: f32) -> i16 {
    (s * 32768.0).round().clamp(-32768.0, 32767.0) as i16
}

/// Settings of `hartkit modem channel`.
#[derive(Debug, Clone)]
pub struct ChannelOptions {
    /// Sample rate, Hz.
    pub rate: u32,
    /// Signal-to-noise ratio against a sine of `signal_mvpp`, dB (`None`: no noise).
    pub snr_db: Option<f64>,
    /// The signal level the SNR refers to, mV peak to peak.
    pub signal_mvpp: f64,
    /// Cable low-pass time constant, µs (0: none).
    pub rc_us: f64,
    /// Hum frequency, Hz (0: none).
    pub hum_hz: f64,
    /// Hum level, mV peak to peak.
    pub hum_mvpp: f64,
    /// A constant 4-20 mA current, mA.
    pub analog_ma: Option<f64>,
    /// A 4 ↔ 20 mA sweep at this rate, Hz.
    pub analog_sweep_hz: Option<f64>,
    /// Sense resistor of the analog current, Ω.
    pub loop_ohm: f64,
    /// Volts a full-scale sample stands for.
    pub volts_per_fs: f64,
    /// Noise seed.
    pub seed: u64,
}

/// `hartkit modem channel`: raw s16le samples from standard input to standard output
/// through a simulated line (cable low-pass, the 4-20 mA current, hum, noise), block by
/// block, so `modem tx --out - | modem channel ... | modem rx --raw s16le --rate R -` is
/// a modem link. Samples beyond full scale are clipped and counted on standard error.
pub fn channel(o: &ChannelOptions) -> Result<String, String> {
    check_rate(o.rate)?;
    if !(o.volts_per_fs.is_finite() && o.volts_per_fs > 0.0) {
        return Err("--volts-per-fs must be positive".into());
    }
    let v = o.volts_per_fs;
    let sigma = o.snr_db.map_or(0.0, |snr| {
        hart_modem::channel::StreamChannel::sigma_for_snr(o.signal_mvpp / 1000.0, snr)
    }) / v;
    let mut ch = hart_modem::channel::StreamChannel::new(
        o.rate,
        sigma,
        o.rc_us * 1e-6,
        o.hum_hz,
        o.hum_mvpp / 1000.0 / v,
        o.seed,
    );
    use hart_modem::channel::AnalogProfile;
    let analog = match (o.analog_ma, o.analog_sweep_hz) {
        (Some(ma), _) if !(ma.is_finite() && (0.0..=25.0).contains(&ma)) => {
            return Err(format!("--analog-ma {ma}: give 0 to 25 mA"))
        }
        (_, Some(hz)) if !(hz.is_finite() && hz > 0.0 && hz <= 1000.0) => {
            return Err(format!("--analog-sweep-hz {hz}: give 0 to 1000 Hz"))
        }
        (Some(ma), _) => Some(AnalogProfile::Constant(ma)),
        (None, Some(hz)) => Some(AnalogProfile::Sweep {
            low_ma: 4.0,
            high_ma: 20.0,
            hz,
        }),
        (None, None) => None,
    };
    if let Some(profile) = analog {
        if !(o.loop_ohm.is_finite() && o.loop_ohm > 0.0) {
            return Err(format!("--loop-ohm {}: must be positive", o.loop_ohm));
        }
        // In full-scale units, like the rest of the stream.
        ch = ch.with_analog(profile, o.loop_ohm / v);
    }
    let mut clipped = 0u64;
    let mut input = std::io::stdin().lock();
    let mut out = std::io::stdout().lock();
    let mut buf = vec![0u8; 16_384];
    let mut s16 = S16Decoder::default();
    let mut samples: Vec<f32> = Vec::with_capacity(8_192);
    let mut raw: Vec<u8> = Vec::with_capacity(16_384);
    while s16.read(&mut input, &mut buf, &mut samples)? {
        ch.process(&mut samples);
        clipped += samples.iter().filter(|s| s.abs() >= 1.0).count() as u64;
        raw.clear();
        raw.extend(samples.iter().flat_map(|&s| to_s16(s).to_le_bytes()));
        match out.write_all(&raw) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(String::new()),
            Err(e) => return Err(format!("writing samples: {e}")),
        }
    }
    let _ = out.flush();
    if clipped > 0 {
        tracing::warn!(
            "{clipped} sample(s) beyond full scale were clipped: raise --volts-per-fs \
             (it is {v} V; the analog current alone puts up to 25 mA × --loop-ohm on the line)"
        );
    }
    Ok(String::new())
}

/// Bytes of a WAV file read at a time: memory stays a few megabytes whatever the
/// file's length.
pub const WAV_BLOCK: usize = 1 << 20;

/// The samples of a file: where they are and how they are stored.
#[derive(Debug, Clone)]
pub struct SampleFile {
    path: std::path::PathBuf,
    format: wav::SampleFormat,
    channels: u16,
    /// Sample rate, Hz.
    pub rate: u32,
    /// Where the samples begin, bytes.
    offset: u64,
    /// Sample frames (one sample per channel) in the file.
    pub frames: u64,
}

impl SampleFile {
    /// A WAV file: its header, parsed from a prefix read larger until the data chunk
    /// begins in it. Notes on standard error: more than one channel (the first is
    /// decoded), a file cut short (what is there is decoded).
    pub fn wav(path: &std::path::Path) -> Result<Self, String> {
        let name = path.display();
        let mut file = std::fs::File::open(path).map_err(|e| format!("cannot read {name}: {e}"))?;
        let len = file.metadata().map(|m| m.len()).unwrap_or(u64::MAX);
        let mut prefix = Vec::new();
        let header = loop {
            let want = (prefix.len() * 2).max(65_536);
            let mut more = vec![0u8; want - prefix.len()];
            let n =
                read_full(&mut file, &mut more).map_err(|e| format!("cannot read {name}: {e}"))?;
            prefix.extend_from_slice(&more[..n]);
            let eof = n < more.len();
            match Wav::parse(&prefix) {
                Ok(w) => {
                    let offset = w.data().as_ptr() as usize - prefix.as_ptr() as usize;
                    break (
                        w.format(),
                        w.channels(),
                        w.sample_rate(),
                        offset as u64,
                        w.declared_data_len(),
                    );
                }
                Err(_) if !eof && prefix.len() < (16 << 20) => continue,
                Err(e) => return Err(format!("{name}: {e}")),
            }
        };
        let (format, channels, rate, offset, declared) = header;
        check_rate(rate)?;
        if channels != 1 {
            tracing::warn!("{name} has {channels} channels; decoding the first");
        }
        let available = len.saturating_sub(offset);
        let data_len = declared.map_or(available, |d| d.min(available));
        if declared.is_some_and(|d| d > available) {
            tracing::warn!("{name} is cut short (the header promises more samples than the file holds); decoding what is there");
        }
        let frame = (u64::from(channels) * format.bytes() as u64).max(1);
        Ok(SampleFile {
            path: path.to_path_buf(),
            format,
            channels,
            rate,
            offset,
            frames: data_len / frame,
        })
    }

    /// A file of raw signed 16-bit little-endian mono samples at `rate`.
    pub fn raw_s16le(path: &std::path::Path, rate: u32) -> Result<Self, String> {
        let len = std::fs::metadata(path)
            .map_err(|e| format!("cannot open {}: {e}", path.display()))?
            .len();
        Ok(SampleFile {
            path: path.to_path_buf(),
            format: wav::SampleFormat::I16,
            channels: 1,
            rate,
            offset: 0,
            frames: len / 2,
        })
    }

    /// Bytes of one sample frame.
    fn frame_bytes(&self) -> u64 {
        (u64::from(self.channels) * self.format.bytes() as u64).max(1)
    }

    /// Reads the first channel's samples `from..to` in blocks of [`WAV_BLOCK`] bytes
    /// and hands each block to `push`, until `to`, the end of the file, or `push`
    /// returns `false`.
    pub fn read(
        &self,
        from: u64,
        to: u64,
        mut push: impl FnMut(&[f32]) -> bool,
    ) -> Result<(), String> {
        use std::io::{Seek, SeekFrom};
        let to = to.min(self.frames);
        if from >= to {
            return Ok(());
        }
        let name = self.path.display();
        let frame = self.frame_bytes();
        let mut file =
            std::fs::File::open(&self.path).map_err(|e| format!("cannot read {name}: {e}"))?;
        file.seek(SeekFrom::Start(self.offset + from * frame))
            .map_err(|e| format!("cannot read {name}: {e}"))?;
        let block = (WAV_BLOCK as u64 / frame).max(1) * frame;
        let mut buf = vec![0u8; block.min((to - from) * frame) as usize];
        let mut samples = Vec::with_capacity(buf.len());
        let mut left = (to - from) * frame;
        while left > 0 {
            let want = left.min(block) as usize;
            let n = read_full(&mut file, &mut buf[..want])
                .map_err(|e| format!("cannot read {name}: {e}"))?;
            let whole = n - n % frame as usize;
            samples.clear();
            wav::extend_samples(self.format, self.channels, 0, &buf[..whole], &mut samples)
                .map_err(|e| format!("{name}: {e}"))?;
            if !push(&samples) || n < want {
                break;
            }
            left -= n as u64;
        }
        Ok(())
    }
}

/// Pieces decoded on their own are at least this many samples (43 s at 48 kHz) unless
/// asked otherwise: each one's demodulator first settles on some 6-8 s before it.
const MIN_CHUNK: u64 = 1 << 21;
/// ... and at most this many (11.7 minutes at 48 kHz): the frames of pieces decoded
/// ahead of the output wait in memory.
const MAX_CHUNK: u64 = 1 << 25;
/// Samples before a piece's start in which its demodulator looks for a quiet point,
/// beyond those it needs to settle.
const QUIET_SEARCH: u64 = 65_536;

/// Decodes a file of samples, on `jobs` threads when it is long enough, and hands the
/// frames to `emit` in order; `tick` after each block when on one thread; `stop` says
/// when to give up (output closed).
///
/// On several threads the file is cut into pieces, each decoded by a demodulator
/// started some 300 000 samples before the piece
/// ([`Demodulator::starting_at`]) so it has settled by then. Its part of the output
/// begins at the last quiet point (the carrier detect quiet for two updates in a row,
/// nothing being received) at or before the piece's start, and ends at the last one at
/// or before the next piece's start: after a quiet point every settled demodulator
/// reports what one demodulator from the start of the file reports, frame by frame
/// and bit by bit, so the pieces' outputs joined are that output. Each frame is thus
/// reported by the piece its start falls in, with the pieces' boundaries moved back to
/// the last quiet point. Where there is none in the stretch before a boundary (a
/// carrier that never stops), the piece before runs on to the next boundary instead.
pub fn decode_file(
    file: &SampleFile,
    cfg: DemodConfig,
    jobs: usize,
    chunk_samples: Option<u64>,
    emit: &mut dyn FnMut(DemodEvent<'_>),
    tick: &dyn Fn(&Demodulator, u64),
    stop: &dyn Fn() -> bool,
) -> Result<(), String> {
    let n = file.frames;
    let chunk = chunk_samples
        .unwrap_or_else(|| n.div_ceil(jobs.max(1) as u64).clamp(MIN_CHUNK, MAX_CHUNK))
        .max(1);
    if jobs <= 1 || n <= chunk {
        let mut d = Demodulator::new(cfg);
        let mut seen = 0u64;
        file.read(0, n, |samples| {
            d.push(samples, &mut *emit);
            seen += samples.len() as u64;
            tick(&d, seen);
            !stop()
        })?;
        d.finish(&mut *emit);
        return Ok(());
    }
    let pieces = n.div_ceil(chunk) as usize;
    let bounds: Vec<u64> = (0..=pieces as u64).map(|k| (k * chunk).min(n)).collect();
    // Where each piece's demodulator starts: settled, with room to find a quiet
    // point, before the piece.
    let settle = Demodulator::quiet_from(&cfg, START_ALIGN) - START_ALIGN;
    let starts: Vec<u64> = bounds
        .iter()
        .map(|&b| {
            let s = b.saturating_sub(settle + QUIET_SEARCH);
            s - s % START_ALIGN
        })
        .collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    let abort = std::sync::atomic::AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::scope(|scope| {
        for _ in 0..jobs.min(pieces) {
            let tx = tx.clone();
            let (next, abort, bounds, starts) = (&next, &abort, &bounds, &starts);
            scope.spawn(move || loop {
                let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if k >= pieces || abort.load(std::sync::atomic::Ordering::Relaxed) {
                    break;
                }
                let r = decode_piece(file, cfg, bounds, starts, k, abort);
                if tx.send((k, r)).is_err() {
                    break;
                }
            });
        }
        drop(tx);
        // Out in order, each piece as soon as it and those before it are done.
        let mut done: Vec<Option<Result<Option<Vec<DecodedFrame>>, String>>> =
            (0..pieces).map(|_| None).collect();
        let mut out = 0;
        let mut result = Ok(());
        for (k, r) in rx {
            done[k] = Some(r);
            while out < pieces {
                let Some(r) = done[out].take() else { break };
                out += 1;
                match r {
                    Ok(frames) => {
                        for f in frames.iter().flatten() {
                            emit(DemodEvent::Frame(f.as_rx()));
                        }
                    }
                    Err(e) => {
                        result = Err(e);
                        out = pieces;
                    }
                }
                if result.is_err() || stop() {
                    abort.store(true, std::sync::atomic::Ordering::Relaxed);
                    out = pieces;
                }
            }
        }
        result
    })
}

/// Piece `k` of [`decode_file`]: its frames, or `None` when there is no quiet point
/// before its start (the piece before covers it).
fn decode_piece(
    file: &SampleFile,
    cfg: DemodConfig,
    bounds: &[u64],
    starts: &[u64],
    k: usize,
    abort: &std::sync::atomic::AtomicBool,
) -> Result<Option<Vec<DecodedFrame>>, String> {
    let go = || !abort.load(std::sync::atomic::Ordering::Relaxed);
    let start = if k == 0 { 0 } else { starts[k] };
    let mut d = Demodulator::starting_at(cfg, start);
    let mut frames: Vec<DecodedFrame> = Vec::new();
    let feed = |d: &mut Demodulator, frames: &mut Vec<DecodedFrame>, from, to| {
        file.read(from, to, |samples| {
            d.push(samples, |ev| {
                if let DemodEvent::Frame(f) = ev {
                    frames.push(f.to_decoded());
                }
            });
            go()
        })
    };
    let first = if k == 0 {
        0
    } else {
        feed(&mut d, &mut frames, start, bounds[k])?;
        match d.quiet_point() {
            Some((q, before)) => {
                tracing::debug!("piece {k} starts at the quiet point at sample {q}");
                before as usize
            }
            None => {
                tracing::debug!(
                    "piece {k}: no quiet point before sample {}; the piece before covers it",
                    bounds[k]
                );
                return Ok(None);
            }
        }
    };
    let last = bounds.len() - 1;
    let mut j = k + 1;
    let end = loop {
        feed(&mut d, &mut frames, bounds[j - 1], bounds[j])?;
        if j == last {
            d.finish(|ev| {
                if let DemodEvent::Frame(f) = ev {
                    frames.push(f.to_decoded());
                }
            });
            break frames.len();
        }
        // The boundary holds when the piece after finds the same quiet point: the
        // latest before it, if that piece's demodulator has settled by then.
        if let Some((q, before)) = d.quiet_point() {
            if q >= Demodulator::quiet_from(&cfg, starts[j]) {
                break before as usize;
            }
        }
        j += 1;
    };
    frames.truncate(end);
    frames.drain(..first.min(end));
    tracing::debug!(
        "piece {k}: {} frame(s), up to piece {j}'s boundary",
        frames.len()
    );
    Ok(Some(frames))
}

/// Reads until `buf` is full or the input ends; the bytes read.
fn read_full(r: &mut impl Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

fn config(rate: u32, volts_per_fs: f64) -> DemodConfig {
    let mut c = DemodConfig::new(rate);
    c.volts_per_unit = volts_per_fs;
    c
}

#[cfg(test)]
mod s16_tests {
    use super::S16Decoder;

    /// Samples split across reads at an odd byte come out whole and in order.
    #[test]
    fn odd_splits() {
        let bytes: Vec<u8> = [0i16, 16384, -16384, 32767, -32768]
            .iter()
            .flat_map(|s| s.to_le_bytes())
            .collect();
        let mut d = S16Decoder::default();
        let mut out = vec![];
        for piece in bytes.chunks(3) {
            d.decode(piece, &mut out);
        }
        assert_eq!(out, [0.0, 0.5, -0.5, 32767.0 / 32768.0, -1.0]);
    }
}
