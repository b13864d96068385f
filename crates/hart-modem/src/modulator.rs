//! Phase-continuous Bell 202 modulator.
//!
//! The instantaneous frequency is integrated exactly across bit boundaries, even when a
//! boundary falls between two samples, so the phase never jumps at any sample rate.
//! The carrier starts and stops with a raised-cosine ramp over one bit of mark (idle)
//! tone: no step, no unmodulated carrier beyond the ramp, no dribble bits.

use crate::{char_bits, BIT_RATE, MARK_HZ, SPACE_HZ};
use core::f64::consts::PI;

/// Settings of a [`Modulator`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModulatorConfig {
    /// Samples per second (8000 and up).
    pub sample_rate: u32,
    /// Signal amplitude in volts peak-to-peak (a master transmits 0.4-0.8 V; a device's
    /// 1 mApp across 250 Ω is 0.5 V).
    pub amplitude_vpp: f64,
    /// Multiplier on both tones (1.01 = tones 1 % high), to model a transmitter's error.
    pub tone_scale: f64,
    /// Multiplier on the bit rate (0.98 = 2 % slow).
    pub rate_scale: f64,
    /// Mark bits sent before the first character; the first of them is the ramp-up.
    pub lead_bits: u32,
    /// Mark bits sent after the last stop bit; the last of them is the ramp-down.
    pub tail_bits: u32,
    /// Carrier phase at the start of a burst, in cycles (0..1).
    pub start_phase: f64,
}

impl ModulatorConfig {
    /// Defaults for a sample rate: 500 mVpp, exact tones, two lead and two tail bits.
    pub fn new(sample_rate: u32) -> Self {
        ModulatorConfig {
            sample_rate,
            amplitude_vpp: 0.5,
            tone_scale: 1.0,
            rate_scale: 1.0,
            lead_bits: 2,
            tail_bits: 2,
            start_phase: 0.0,
        }
    }
}

/// A phase-continuous FSK modulator. Samples are in volts.
#[derive(Debug, Clone)]
pub struct Modulator {
    config: ModulatorConfig,
    /// Fractional sample position carried between calls (time of the next sample
    /// relative to the start of the next burst or silence, in samples).
    carry: f64,
}

impl Modulator {
    /// A modulator with the given settings.
    pub fn new(config: ModulatorConfig) -> Self {
        Modulator { config, carry: 0.0 }
    }

    /// The settings.
    pub fn config(&self) -> &ModulatorConfig {
        &self.config
    }

    /// Changes the settings between bursts.
    pub fn set_config(&mut self, config: ModulatorConfig) {
        self.config = config;
    }

    /// Number of samples [`Modulator::bytes`] produces for `chars` characters.
    pub fn burst_len(&self, chars: usize) -> usize {
        let bits = self.burst_bits(chars);
        let fs = f64::from(self.config.sample_rate);
        let dur = bits as f64 / (BIT_RATE * self.config.rate_scale);
        libm::ceil(dur * fs - self.carry).max(0.0) as usize
    }

    fn burst_bits(&self, chars: usize) -> usize {
        self.config.lead_bits as usize
            + chars * crate::BITS_PER_CHAR
            + self.config.tail_bits as usize
    }

    /// Sends one frame: `preambles` 0xFF characters, then `pdu` (delimiter through check
    /// byte), with the carrier switched on before and off after. Returns the time of
    /// the delimiter's start bit in seconds from the first sample of this burst.
    pub fn frame(&mut self, preambles: usize, pdu: &[u8], out: impl FnMut(f32)) -> f64 {
        let lead = self.config.lead_bits as usize;
        let bytes = core::iter::repeat_n(0xFFu8, preambles).chain(pdu.iter().copied());
        self.bytes(bytes, out);
        let bit = 1.0 / (BIT_RATE * self.config.rate_scale);
        (lead + preambles * crate::BITS_PER_CHAR) as f64 * bit
    }

    /// Sends characters back to back as one carrier burst.
    pub fn bytes(&mut self, bytes: impl Iterator<Item = u8> + Clone, out: impl FnMut(f32)) {
        let lead = self.config.lead_bits as usize;
        let tail = self.config.tail_bits as usize;
        let chars = bytes.clone().count();
        let bits = core::iter::repeat_n(true, lead)
            .chain(bytes.flat_map(char_bits))
            .chain(core::iter::repeat_n(true, tail));
        self.bits(bits, lead + chars * crate::BITS_PER_CHAR + tail, out);
    }

    /// Sends a raw bit sequence (`total` bits) as one burst, ramping the first and
    /// last bit.
    pub fn bits(
        &mut self,
        bits: impl Iterator<Item = bool>,
        total: usize,
        mut out: impl FnMut(f32),
    ) {
        if total == 0 {
            return;
        }
        let c = self.config;
        let fs = f64::from(c.sample_rate);
        let bit_s = 1.0 / (BIT_RATE * c.rate_scale);
        let freq = |b: bool| if b { MARK_HZ } else { SPACE_HZ } * c.tone_scale;
        let peak = c.amplitude_vpp / 2.0;
        let end = total as f64 * bit_s;
        let mut bits = bits;
        let mut cur = bits.next().unwrap_or(true);
        let mut idx = 0usize; // index of `cur`
        let mut cur_end = bit_s;
        let mut phase = c.start_phase; // cycles, at time `t_prev`
        let mut t_prev = 0.0f64;
        let mut n = 0u64;
        // End of the burst in samples; a sample within rounding of it belongs to
        // what comes next.
        let end_samples = end * fs - 1e-9;
        loop {
            let pos = n as f64 + self.carry;
            if pos >= end_samples {
                // The next burst or silence starts this far into the next sample.
                self.carry = (pos - end * fs).max(0.0);
                break;
            }
            let t = pos / fs;
            // Integrate the frequency from t_prev to t across any bit boundaries.
            let mut a = t_prev;
            while t > cur_end && idx + 1 < total {
                phase += freq(cur) * (cur_end - a);
                a = cur_end;
                idx += 1;
                cur = bits.next().unwrap_or(true);
                cur_end = (idx + 1) as f64 * bit_s;
            }
            phase += freq(cur) * (t - a);
            phase -= libm::floor(phase);
            t_prev = t;
            let env = ramp(t / bit_s, end / bit_s);
            out((peak * env * libm::sin(2.0 * PI * phase)) as f32);
            n += 1;
        }
    }

    /// Sends `seconds` of silence (carrier off).
    pub fn silence(&mut self, seconds: f64, mut out: impl FnMut(f32)) {
        let fs = f64::from(self.config.sample_rate);
        let span = seconds * fs - self.carry;
        let n = libm::ceil(span).max(0.0);
        for _ in 0..n as u64 {
            out(0.0);
        }
        self.carry = n - span;
    }
}

/// Raised-cosine envelope over the first and last bit of a burst `len` bits long;
/// `x` is the time in bits.
fn ramp(x: f64, len: f64) -> f64 {
    let edge = x.min(len - x).clamp(0.0, 1.0);
    if edge >= 1.0 {
        1.0
    } else {
        0.5 - 0.5 * libm::cos(PI * edge)
    }
}

/// Modulates whole frames into one buffer: each frame as `(preambles, pdu)`, separated
/// by `gap_s` seconds of silence, with `gap_s` of silence before the first. Returns
/// the samples and, per frame, the time of its delimiter's start bit in seconds.
#[cfg(feature = "alloc")]
pub fn modulate_frames(
    config: ModulatorConfig,
    frames: &[(usize, &[u8])],
    gap_s: f64,
) -> (alloc::vec::Vec<f32>, alloc::vec::Vec<f64>) {
    let mut m = Modulator::new(config);
    let mut out = alloc::vec::Vec::new();
    let mut times = alloc::vec::Vec::new();
    let fs = f64::from(config.sample_rate);
    for (pre, pdu) in frames {
        m.silence(gap_s, |s| out.push(s));
        let start = (out.len() as f64 - m.carry) / fs;
        let t = m.frame(*pre, pdu, |s| out.push(s));
        times.push(start + t);
    }
    m.silence(gap_s, |s| out.push(s));
    (out, times)
}
