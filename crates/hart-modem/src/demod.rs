//! Streaming Bell 202 demodulator (API placeholder; being written).

use hart_proto::deframer::UartFlags;

/// Settings of a [`Demodulator`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DemodConfig {
    /// Samples per second (8000 to 192000).
    pub sample_rate: u32,
    /// Volts represented by a sample value of 1.0.
    pub volts_per_unit: f64,
    /// Carrier detect switches on at this level (volts peak-to-peak).
    pub carrier_on_vpp: f64,
    /// Carrier detect switches off below this level.
    pub carrier_off_vpp: f64,
}

impl DemodConfig {
    /// Defaults for a sample rate: 1 V per unit, carrier on at 100 mVpp, off at 85 mVpp.
    pub fn new(sample_rate: u32) -> Self {
        DemodConfig {
            sample_rate,
            volts_per_unit: 1.0,
            carrier_on_vpp: 0.1,
            carrier_off_vpp: 0.085,
        }
    }
}

/// A received character.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RxChar {
    /// The data byte.
    pub byte: u8,
    /// Parity and framing errors.
    pub flags: UartFlags,
    /// Time of the start bit's leading edge, seconds since the first sample.
    pub t: f64,
}

/// A received frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RxFrame<'a> {
    /// Time of the delimiter's start bit, seconds since the first sample.
    pub t: f64,
    /// Delimiter through check byte.
    pub pdu: &'a [u8],
    /// Preamble characters before the delimiter.
    pub preambles: usize,
    /// True when the check byte matches.
    pub checksum_ok: bool,
    /// Characters of the frame (delimiter through check byte) with a parity error.
    pub parity_errors: usize,
    /// Characters of the frame with a framing error.
    pub framing_errors: usize,
    /// Estimated signal level, volts peak-to-peak.
    pub level_vpp: f64,
}

/// Something the demodulator found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DemodEvent<'a> {
    /// Carrier detect changed; `t` in seconds since the first sample.
    Carrier {
        /// New state.
        on: bool,
        /// When.
        t: f64,
        /// Level at that moment, volts peak-to-peak.
        level_vpp: f64,
    },
    /// A character.
    Char(RxChar),
    /// A complete frame (good or damaged).
    Frame(RxFrame<'a>),
}

/// The streaming demodulator.
#[derive(Debug, Clone)]
pub struct Demodulator {
    config: DemodConfig,
}

impl Demodulator {
    /// A demodulator with the given settings.
    pub fn new(config: DemodConfig) -> Self {
        Demodulator { config }
    }

    /// The settings.
    pub fn config(&self) -> &DemodConfig {
        &self.config
    }

    /// Feeds samples; events are reported as they are found.
    pub fn push(&mut self, samples: &[f32], mut on_event: impl FnMut(DemodEvent<'_>)) {
        let _ = (samples, &mut on_event);
    }

    /// Ends the input: anything still being received is decided and reported.
    pub fn finish(&mut self, mut on_event: impl FnMut(DemodEvent<'_>)) {
        let _ = &mut on_event;
    }
}

/// A frame found by [`decode`], owned.
#[cfg(feature = "alloc")]
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedFrame {
    /// Time of the delimiter's start bit, seconds from the first sample.
    pub t: f64,
    /// Delimiter through check byte.
    pub pdu: alloc::vec::Vec<u8>,
    /// Preamble characters before the delimiter.
    pub preambles: usize,
    /// True when the check byte matches.
    pub checksum_ok: bool,
    /// Characters with a parity error.
    pub parity_errors: usize,
    /// Characters with a framing error.
    pub framing_errors: usize,
    /// Estimated level, volts peak-to-peak.
    pub level_vpp: f64,
}

/// Decodes every frame in a buffer of samples.
#[cfg(feature = "alloc")]
pub fn decode(config: DemodConfig, samples: &[f32]) -> alloc::vec::Vec<DecodedFrame> {
    let mut d = Demodulator::new(config);
    let mut out = alloc::vec::Vec::new();
    let mut take = |ev: DemodEvent<'_>| {
        if let DemodEvent::Frame(f) = ev {
            out.push(DecodedFrame {
                t: f.t,
                pdu: f.pdu.to_vec(),
                preambles: f.preambles,
                checksum_ok: f.checksum_ok,
                parity_errors: f.parity_errors,
                framing_errors: f.framing_errors,
                level_vpp: f.level_vpp,
            });
        }
    };
    d.push(samples, &mut take);
    d.finish(&mut take);
    out
}
