//! Streaming Bell 202 demodulator.
//!
//! Samples go in; carrier changes, timestamped characters with parity and framing
//! flags, and frames (through `hart-proto`'s deframer) come out. The stages:
//!
//! 1. **Front end**, per sample: a linear-phase high-pass removes the 4-20 mA analog
//!    signal and low-frequency interference without delaying one tone more than the
//!    other (see `LinearHighPass`); the signal is mixed with free-running
//!    1200 Hz and 2200 Hz oscillators and integrated into running sums, so the
//!    correlation with either tone over any interval costs two look-ups.
//! 2. **Carrier detect**, per 1/8 bit: the level of the stronger tone over the last bit,
//!    in volts peak-to-peak, smoothed over one bit, with hysteresis (on at
//!    [`DemodConfig::carrier_on_vpp`], off below [`DemodConfig::carrier_off_vpp`]),
//!    plus a check that one tone dominates, as in FSK and not in noise. A jump of the
//!    level while the carrier is on (a burst after noise) starts afresh.
//! 3. **Clock recovery**: the first transition is where the tones' energy balance over a
//!    sliding one-bit window crosses zero; after that, each transition the detector
//!    decides is timed by the carrier phase step across it (a window that starts δ late
//!    sees ±2π·1000 Hz·δ), measured on the grid the clock predicts now over up to three
//!    bits of each tone. Transitions are numbered by the detector's bit windows. While
//!    the clock is acquired (the preamble), the bit length is a robust fit through the
//!    transitions (outliers dropped, a new segment after a gap too long to count) and
//!    the grid sits on it; after that, two weighted line fits of transition time
//!    against bit number give the bit grid and the bit length. They hold at ±4 % of
//!    bit rate.
//! 4. **Detection** with the memory of continuous-phase FSK: per bit, the complex
//!    correlations with both tones, referred to the start of the bit, feed a Viterbi
//!    search over the last three bits in which every survivor carries its own
//!    estimate of the carrier phase, built from its own past decisions (per-survivor
//!    processing). The phase advance between windows is modelled over their actual
//!    spacing with a measured tone error. With a good estimate this is coherent
//!    maximum-likelihood sequence detection; at the start of a burst, with no estimate
//!    yet, it falls back to the non-coherent metric by itself.
//! 5. **Characters** (8O1) are read from the best survivor four bits behind the newest
//!    bit, re-aligned on preamble characters between frames; the last character of a
//!    frame, known from its byte count, is read as soon as its stop bit is in, so a
//!    frame comes out about 1.5 bit times after its last stop bit.

use hart_proto::deframer::{Deframer, DeframerEvent, UartFlags};
use hart_proto::frame::checksum;
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

/// A received frame; `P` holds its bytes: borrowed in [`DemodEvent::Frame`]
/// ([`RxFrame`]), owned from `decode` (`DecodedFrame`, with the `alloc` feature).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReceivedFrame<P> {
    /// Time of the delimiter's start bit, seconds since the first sample.
    pub t: f64,
    /// Delimiter through check byte.
    pub pdu: P,
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
    /// Estimated bit rate error when the frame ended (+0.01 = 1 % fast).
    pub rate_error: f64,
    /// Estimated tone frequency error when the frame ended (+0.01 = 1 % high).
    pub tone_error: f64,
}

/// A received frame as the demodulator reports it, its bytes borrowed.
pub type RxFrame<'a> = ReceivedFrame<&'a [u8]>;

/// A received frame with its bytes owned, as [`decode`] returns it.
#[cfg(feature = "alloc")]
pub type DecodedFrame = ReceivedFrame<alloc::vec::Vec<u8>>;

#[cfg(feature = "alloc")]
impl DecodedFrame {
    /// The same frame with its bytes borrowed, as the demodulator reports it.
    pub fn as_rx(&self) -> RxFrame<'_> {
        ReceivedFrame {
            t: self.t,
            pdu: &self.pdu,
            preambles: self.preambles,
            checksum_ok: self.checksum_ok,
            parity_errors: self.parity_errors,
            framing_errors: self.framing_errors,
            level_vpp: self.level_vpp,
            rate_error: self.rate_error,
            tone_error: self.tone_error,
        }
    }
}

impl RxFrame<'_> {
    /// The same frame with its bytes copied.
    #[cfg(feature = "alloc")]
    pub fn to_decoded(&self) -> DecodedFrame {
        ReceivedFrame {
            t: self.t,
            pdu: self.pdu.to_vec(),
            preambles: self.preambles,
            checksum_ok: self.checksum_ok,
            parity_errors: self.parity_errors,
            framing_errors: self.framing_errors,
            level_vpp: self.level_vpp,
            rate_error: self.rate_error,
            tone_error: self.tone_error,
        }
    }
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

/// Samples of history the detector may read back in the running sums (6 bits at
/// 192 kHz).
const RING: usize = 1024;
/// Length of the rings of running sums: the history plus the samples the front end runs
/// ahead of the detector (at most [`PIECE`]), a power of two.
const RING_LEN: usize = 2 * RING;
/// The front end (high-pass, mixers, running sums) runs over pieces of at most this many
/// samples, aligned on multiples of it, before the carrier detect, the clock recovery and
/// the detector catch up with the events in the piece: tight loops instead of a check of
/// every stage at every sample. Divides [`REBASE`].
const PIECE: usize = 512;
/// The running sums are rebased and the oscillators re-derived every this many samples.
const REBASE: u64 = 4096;
/// The high-pass filter's sums are re-added from scratch every this many samples.
const HP_READD: usize = 65536;
/// Samples per epoch of the level and tone-dominance averages (see
/// [`Demodulator::starting_at`]): 3276 updates at 48 kHz and 819 at 192 kHz, after
/// which an average started from zero differs from one that has run for ever by less
/// than 1e-20 of its value.
const LEVEL_EPOCH: u64 = 16384;
/// A demodulator started inside a recording ([`Demodulator::starting_at`]) starts at
/// a multiple of this many samples, so that every periodic reset falls where it falls
/// for a demodulator started at sample 0.
pub const START_ALIGN: u64 = HP_READD as u64;
/// Survivors: the last `STATE_BITS` bits.
const STATE_BITS: u32 = 3;
const STATES: usize = 1 << STATE_BITS;
/// Bits the last character of a frame may wait beyond its stop bit when, read at
/// once, it does not complete a good frame.
const LAST_CHAR_WAIT: usize = 2;
/// Bits a character waits for before it is read from the best survivor.
const DECISION_DELAY: usize = 4;
/// Characters remembered for frame timestamps.
const CHAR_RING: usize = 512;
/// Bit start times remembered.
const BIT_RING: usize = 128;

#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct C64 {
    re: f64,
    im: f64,
}

impl C64 {
    fn new(re: f64, im: f64) -> Self {
        C64 { re, im }
    }
    /// e^{j2π·cycles}, to about 3e-7 (polynomials on an eighth of a turn; a few
    /// times faster than `sin` and `cos`, which matters at one call per bit per tone).
    fn expj(cycles: f64) -> Self {
        let x = cycles - round_fast(cycles);
        let q = round_fast(x * 4.0);
        let t = 2.0 * core::f64::consts::PI * (x - q * 0.25);
        let t2 = t * t;
        let sin = t * (1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0)));
        let cos = 1.0 - t2 / 2.0 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0)));
        match q as i64 & 3 {
            0 => C64::new(cos, sin),
            1 => C64::new(-sin, cos),
            2 => C64::new(-cos, -sin),
            _ => C64::new(sin, -cos),
        }
    }
    fn mul(self, o: C64) -> C64 {
        C64::new(
            self.re * o.re - self.im * o.im,
            self.re * o.im + self.im * o.re,
        )
    }
    fn scale(self, k: f64) -> C64 {
        C64::new(self.re * k, self.im * k)
    }
    fn add(self, o: C64) -> C64 {
        C64::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: C64) -> C64 {
        C64::new(self.re - o.re, self.im - o.im)
    }
    fn norm2(self) -> f64 {
        self.re * self.re + self.im * self.im
    }
}

/// The running sums of both tones at one sample, lane 0 mark, lane 1 space: the
/// front end updates both with the same packed operations.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Lanes {
    re: [f64; 2],
    im: [f64; 2],
}

impl Lanes {
    const ZERO: Lanes = Lanes {
        re: [0.0; 2],
        im: [0.0; 2],
    };
    fn lane(self, l: usize) -> C64 {
        C64::new(self.re[l], self.im[l])
    }
    fn sub(self, o: Lanes) -> Lanes {
        Lanes {
            re: [self.re[0] - o.re[0], self.re[1] - o.re[1]],
            im: [self.im[0] - o.im[0], self.im[1] - o.im[1]],
        }
    }
}

/// Linear-phase high-pass: the input delayed by the group delay of a cascade of three
/// moving averages, each about one mark cycle long, minus the cascade's output. The
/// averages have nulls at 1200 Hz and 2400 Hz and pass only -60 dB at 2200 Hz, so both
/// tones come through with unit gain and the same delay (no dispersion between mark
/// and space, which would smear every transition), while DC is removed exactly and
/// 29 Hz comes out 51 dB down, 63 Hz 37 dB, 125 Hz 25 dB.
#[derive(Clone)]
struct LinearHighPass {
    len: [usize; 3],
    inv_len: [f64; 3],
    /// Delay of the cascade, samples.
    delay: usize,
    sums: [f64; 3],
    /// Inputs of each stage, oldest first, up to `pos` (stage 0 holds raw samples, used
    /// for the delayed path too); at least [`HP_HIST`] of them.
    hist: [[f64; HP_BUF]; 3],
    /// Where the next input goes in `hist`.
    pos: usize,
    /// Samples filtered.
    n: usize,
}

/// Inputs each stage of the high-pass needs from before a piece: at least the longest
/// average (161 samples at 192 kHz) and the delay (239 samples).
const HP_HIST: usize = 256;
/// Length of the high-pass filter's input buffers: the newest [`HP_HIST`] inputs are
/// moved back to the start when a piece no longer fits, at most once every [`PIECE`]
/// samples however small the pieces (the analog loop pushes 16 at a time).
const HP_BUF: usize = HP_HIST + 2 * PIECE;

impl LinearHighPass {
    fn new(fs: f64) -> Self {
        let m = libm::round(fs / crate::MARK_HZ).max(2.0) as usize;
        // Odd total delay would need half samples: make the three lengths sum to an
        // odd number so (L1 + L2 + L3 - 3) is even.
        let len = if (3 * m) % 2 == 1 {
            [m, m, m]
        } else {
            [m, m + 1, m]
        };
        let delay = (len[0] + len[1] + len[2] - 3) / 2;
        debug_assert!(delay <= HP_HIST && len.iter().all(|&l| l <= HP_HIST));
        LinearHighPass {
            len,
            inv_len: len.map(|l| 1.0 / l as f64),
            delay,
            sums: [0.0; 3],
            hist: [[0.0; HP_BUF]; 3],
            pos: HP_HIST,
            n: 0,
        }
    }

    /// Filters a piece of at most [`PIECE`] samples (that does not cross a multiple of
    /// [`HP_READD`]), scaled by `vpu`, and hands each output to `sink` in order.
    #[inline(always)]
    fn run_piece(&mut self, piece: &[f32], vpu: f64, mut sink: impl FnMut(f64)) {
        const H: usize = HP_HIST;
        let p = piece.len();
        if self.pos + p > HP_BUF {
            // Keep the newest inputs, at the start.
            for h in self.hist.iter_mut() {
                h.copy_within(self.pos - H..self.pos, 0);
            }
            self.pos = H;
        }
        let at = self.pos;
        let [l0, l1, l2] = self.len;
        let [i0, i1, i2] = self.inv_len;
        let d = self.delay;
        assert!(
            p <= PIECE && at >= H && at + p <= HP_BUF && l0 <= H && l1 <= H && l2 <= H && d <= H
        );
        let (b0, b1, b2, bd) = (at - l0, at - l1, at - l2, at - d);
        let [mut s0, mut s1, mut s2] = self.sums;
        let [h0, h1, h2] = &mut self.hist;
        for (o, &x) in h0[at..at + p].iter_mut().zip(piece) {
            let x = f64::from(x) * vpu;
            // Untrusted input: NaN and infinities become silence.
            *o = if x.is_finite() { x } else { 0.0 };
        }
        let h0 = &h0[..];
        // Stages 1 and 2 read their inputs `len` samples back while writing the newest:
        // cells let both views of the one buffer go through the loop together.
        let h1 = core::cell::Cell::from_mut(&mut h1[..]).as_slice_of_cells();
        let h2 = core::cell::Cell::from_mut(&mut h2[..]).as_slice_of_cells();
        let stage0 = h0[at..at + p].iter().zip(&h0[b0..b0 + p]);
        let stage1 = h1[at..at + p].iter().zip(&h1[b1..b1 + p]);
        let stage2 = h2[at..at + p].iter().zip(&h2[b2..b2 + p]);
        let delayed = &h0[bd..bd + p];
        for ((((&x, &old0), (in1, old1)), (in2, old2)), &d) in
            stage0.zip(stage1).zip(stage2).zip(delayed)
        {
            s0 += x - old0;
            let v0 = s0 * i0;
            in1.set(v0);
            s1 += v0 - old1.get();
            let v1 = s1 * i1;
            in2.set(v1);
            s2 += v1 - old2.get();
            let v2 = s2 * i2;
            sink(d - v2);
        }
        self.sums = [s0, s1, s2];
        self.pos = at + p;
        self.n = self.n.wrapping_add(p);
        if self.n % HP_READD == 0 {
            // Re-add the windows from scratch so rounding cannot accumulate (newest
            // first).
            for st in 0..3 {
                let end = self.pos;
                self.sums[st] = self.hist[st][end - self.len[st]..end].iter().rev().sum();
            }
        }
    }
}

/// The Viterbi survivors, one per state, field by field (the trellis step then runs
/// as loops over the states that the compiler can pack).
#[derive(Debug, Clone, Copy)]
struct Survivors {
    /// Path metric; minus infinity for a state no path reaches.
    metric: [f64; STATES],
    /// Carrier phase estimate (complex, decision-directed along this path).
    r_re: [f64; STATES],
    r_im: [f64; STATES],
    /// Undoes the phase turn of this path's bits so far: each space turns the phase
    /// at the next bit start by -60° (2200 Hz over 1/1200 s is 1 5/6 cycles), each
    /// mark by 0°, plus the measured extra turn per bit when the tones and the bit
    /// rate are off by different amounts.
    rot_re: [f64; STATES],
    rot_im: [f64; STATES],
    /// Bits of this path, newest in bit 0.
    hist: [u64; STATES],
}

impl Survivors {
    /// No path at all.
    const DEAD: Survivors = Survivors {
        metric: [f64::NEG_INFINITY; STATES],
        r_re: [0.0; STATES],
        r_im: [0.0; STATES],
        rot_re: [1.0; STATES],
        rot_im: [0.0; STATES],
        hist: [0; STATES],
    };

    /// One path, in state `i`: metric 0, no phase estimate, all ones so far.
    fn start(i: usize) -> Self {
        let mut s = Survivors::DEAD;
        s.metric[i] = 0.0;
        s.hist[i] = u64::MAX;
        s
    }
}

/// One detected bit window and its correlations (referred to its start).
#[derive(Debug, Clone, Copy, Default)]
struct BitRec {
    start: f64,
    ym: C64,
    ys: C64,
}

#[derive(Debug, Clone, Copy, Default)]
struct CharRec {
    byte: u8,
    flags: UartFlags,
    t: f64,
    level: f64,
}

/// The streaming demodulator. See the [module documentation](self).
#[derive(Clone)]
pub struct Demodulator {
    config: DemodConfig,
    fs: f64,
    /// Nominal samples per bit.
    spb: f64,
    /// Samples between carrier-detect and clock-recovery updates (1/8 bit or less).
    block: u32,
    hp: LinearHighPass,
    /// Delay of the front end, samples (subtracted from every timestamp).
    hp_delay: f64,
    lo_m: C64,
    lo_s: C64,
    rot_m: C64,
    rot_s: C64,
    /// Running sums of x·LO for both tones; `sums[i & (RING_LEN-1)]` is the sum over
    /// samples before sample i (since the last rebase).
    sums: [Lanes; RING_LEN],
    /// The detector's clock: the sample count its events are at (between pieces, the
    /// samples seen, counted from the start of the recording).
    n: u64,
    /// Sample count of the next carrier-detect update.
    next_block: u64,
    // Carrier detect.
    /// Level of the stronger tone and tone dominance, smoothed over about a bit: each
    /// an exponential average restarted from zero at the first update of every
    /// [`LEVEL_EPOCH`] samples, one epoch after a younger twin started: the twin's
    /// value then takes over. What the average forgets in an epoch is far below a
    /// rounding error, so this is the plain average for every purpose, yet it depends
    /// on the last two epochs of signal only: a demodulator started later in a
    /// recording computes the same value (see [`Demodulator::starting_at`]).
    level: f64,
    contrast: f64,
    /// The younger twins of `level` and `contrast`.
    young_level: f64,
    young_contrast: f64,
    /// The epoch (sample count / [`LEVEL_EPOCH`]) of the latest update.
    level_epoch: u64,
    /// Level averaged over about eight bits: a jump above it is a new burst (reset when
    /// the carrier comes on, so what it holds while the carrier is off never counts).
    slow_level: f64,
    carrier: bool,
    /// The level was below both carrier thresholds at the latest update.
    was_quiet: bool,
    /// Sample count from which quiet points are recorded: the demodulator computes the
    /// level a demodulator started at sample 0 computes for the update before (0 for
    /// one that did).
    quiet_from: u64,
    /// The latest quiet point (see [`Demodulator::quiet_point`]): sample count and
    /// frames reported before it.
    quiet: Option<(u64, u64)>,
    /// Frames reported so far.
    frames_out: core::cell::Cell<u64>,
    // Clock recovery.
    /// Start of the next bit window not yet detected, in samples (fractional).
    next_bit: f64,
    /// Current bit length estimate, samples.
    period: f64,
    side: i8,
    last_zero: Option<f64>,
    prev_v: f64,
    prev_t: f64,
    /// Line fit of transition times against bit numbers, origin at the newest.
    fit: TimingFit,
    /// The fitted bit boundary at the newest transition, samples, and its bit window.
    grid_origin: f64,
    grid_j: i64,
    /// Transitions accepted by the fit since the carrier came on.
    locked: u32,
    /// Measured relative tone error (both tones come from one clock in every modem):
    /// the phase advance between two bit windows `Δ` samples apart is
    /// 2π·f·(1 + ε)·Δ/fs for a tone f. The windows' own spacing is known exactly, so
    /// a bit-rate error needs no estimate here.
    eps: f64,
    /// Same-tone bit pairs measured since the carrier came on.
    pairs: u32,

    // Detection.
    surv: Survivors,
    /// Index of the best survivor (the first with the highest metric).
    best_idx: usize,
    /// Bits detected since the carrier came on.
    k: usize,
    bits: [BitRec; BIT_RING],
    // Characters.
    /// Next bit to examine for a start bit.
    pos: usize,
    char_start: Option<usize>,
    chars: [CharRec; CHAR_RING],
    char_n: usize,
    /// XOR of the characters of the frame being received.
    frame_xor: u8,
    deframer: Deframer,
}

impl core::fmt::Debug for Demodulator {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Demodulator")
            .field("config", &self.config)
            .field("samples", &self.n)
            .field("carrier", &self.carrier)
            .field("level_vpp", &self.level)
            .finish_non_exhaustive()
    }
}

/// Clock recovery: each transition's weight decays by this factor per newer
/// transition (memory of about ten transitions, a few characters).
const FIT_FORGET: f64 = 0.9;
/// The same for the bit length (memory of about fifty transitions).
const FIT_FORGET_LONG: f64 = 0.98;
/// Strength of the clock recovery's prior on the nominal bit rate, in bits² per
/// transition of weight.
const SLOPE_PRIOR: f64 = 2.0;
/// The same while the clock is being acquired.
const SLOPE_PRIOR_ACQUIRE: f64 = 50.0;
/// Forgetting factor while the clock is still being acquired: the phase references
/// built from badly placed windows must not last.
const LAMBDA_ACQUIRE: f64 = 0.4;
/// Transitions after which the clock counts as settled.
const SETTLED_TRANSITIONS: u32 = 16;
/// Transitions after which the phase references get the longer memory of [`LAMBDA`]:
/// a reference is only as good as the bit grid it was built on (a window δ off a
/// transition turns its phase by 2π·1000 Hz·δ), and the grid is still rough for a few
/// characters after the clock has settled.
const LAMBDA_SETTLED: u32 = 24;
/// Transitions found from the tone balance alone before the clock recovery switches
/// to the detector's decisions: one. The tone balance is rough at low signal-to-noise
/// (a tenth of a bit, and worse on the carrier's ramp); the phase step at a decided
/// transition is not, even when the grid is still a third of a bit off.
const ACQUIRE_TRANSITIONS: u32 = 1;
/// Longest window, in bits, on either side of a transition for measuring its timing.
const STEP_BITS: usize = 3;
/// Bits the decision-directed clock recovery waits for the detector's decisions.
const TIMING_DELAY: usize = 3;
/// A transition is measured again on the current grid when its windows lie more than
/// this (in bits) off it.
const REMEASURE: f64 = 0.1;
/// Gain of the tone-error estimate once settled (memory of a few hundred bit pairs).
const EPS_GAIN: f64 = 0.004;
/// Pairs of weight the zero starting value of the tone error counts for.
const EPS_PRIOR_PAIRS: u32 = 2;
/// Phase steps larger than this (radians) are not used to measure the tone error.
const EPS_OUTLIER: f64 = 0.8;
/// A level this many times the eight-bit average starts a new burst.
const RESTART_RATIO: f64 = 2.0;

/// Weighted sums of a least-squares line fit through (bit number, transition time),
/// with the origin at the newest transition.
#[derive(Debug, Clone, Copy, Default)]
struct LineSums {
    s0: f64,
    s1: f64,
    s2: f64,
    sz: f64,
    snz: f64,
}

impl LineSums {
    /// Moves the origin to (dn, dz), forgets by `forget` and adds the new origin point.
    fn shift_add(&mut self, dn: f64, dz: f64, forget: f64) {
        self.shift_add_weighted(dn, dz, forget, 1.0);
    }

    /// [`Self::shift_add`] with the new point weighing `w`.
    fn shift_add_weighted(&mut self, dn: f64, dz: f64, forget: f64, w: f64) {
        let (s0, s1, sz) = (self.s0, self.s1, self.sz);
        self.snz = self.snz - dn * sz - dz * s1 + dn * dz * s0;
        self.s2 = self.s2 - 2.0 * dn * s1 + dn * dn * s0;
        self.s1 = s1 - dn * s0;
        self.sz = sz - dz * s0;
        self.s0 = self.s0 * forget + w;
        self.s1 *= forget;
        self.s2 *= forget;
        self.sz *= forget;
        self.snz *= forget;
    }

    /// Slope, pulled towards `nominal` by a prior of `prior` bits² per unit weight.
    fn slope(&self, nominal: f64, prior: f64) -> f64 {
        let det = self.s0 * self.s2 - self.s1 * self.s1;
        (self.s0 * self.snz - self.s1 * self.sz + prior * self.s0 * nominal)
            / (det + prior * self.s0)
    }

    /// Fitted time of bit 0 (the origin) for a given slope, relative to the origin.
    fn intercept(&self, slope: f64) -> f64 {
        (self.sz - slope * self.s1) / self.s0
    }
}

/// Clock recovery by line fits of transition times against bit numbers. The bit length
/// comes from a long memory (several frames' worth of characters), the position of
/// the bit grid from a short one, so a steady bit-rate error is learnt exactly while
/// the grid still follows the newest transitions. Every transition weighs alike
/// however far apart they are, which a loop filter fed with phase errors cannot do
/// (a preamble has one transition pair per character, data one per bit or two).
#[derive(Debug, Clone, Copy, Default)]
struct TimingFit {
    long: LineSums,
    short: LineSums,
    /// Transitions seen while the clock is acquired: the bit length is fitted from
    /// them robustly, so the rough transitions of the carrier's ramp and the noise
    /// before it cannot bend it.
    acq: [AcqPoint; ACQ_POINTS],
    /// Entries of `acq` in use.
    acq_len: usize,
    /// Bit window of the first transition of the fit.
    first_j: i64,
    /// Bit window at which the newest transition was decided.
    last_j: i64,
    /// Time of the newest transition (the origin), samples.
    last: f64,
    /// Transitions rejected in a row.
    rejected: u32,
    started: bool,
}

impl TimingFit {
    fn start(z: f64, j: i64) -> Self {
        let one = LineSums {
            s0: 1.0,
            ..LineSums::default()
        };
        let mut acq = [AcqPoint::default(); ACQ_POINTS];
        acq[0] = AcqPoint { n: 0.0, z, seg: 0 };
        TimingFit {
            long: one,
            short: one,
            acq,
            acq_len: 1,
            first_j: j,
            last_j: j,
            last: z,
            rejected: 0,
            started: true,
        }
    }

    /// Adds a transition at `z` samples; returns the fitted newest boundary and bit
    /// length, or `None` when the transition is rejected as an outlier.
    fn add(&mut self, z: f64, j: i64, period: f64, nominal: f64, prior: f64) -> Option<(f64, f64)> {
        if !self.started {
            *self = TimingFit::start(z, j);
            return Some((z, period));
        }
        let dz = z - self.last;
        // Which bit this transition is on: the detector's own count of bit windows
        // since the previous one. Rounding the time between them by a bit length
        // numbers a ten-bit gap wrong as soon as the signal is 2 % slow and the newer
        // transition is measured a third of a bit late, and a gap numbered wrong
        // bends the fitted bit length in a way that confirms itself.
        let dn = (j - self.last_j) as f64;
        if dn < 1.0 {
            // Two transitions within one bit: the newer one is noise.
            return None;
        }
        // Residual against the current fit.
        let pred = self.short.intercept(period) + dn * period;
        let resid = dz - pred;
        // Outliers are only recognised once the clock has settled: before that the
        // grid itself may be a third of a bit off, and the transitions that would pull
        // it back must not be thrown away.
        if prior <= SLOPE_PRIOR && libm::fabs(resid) > 0.35 * period {
            self.rejected += 1;
            if self.rejected < 3 {
                return None;
            }
            // The grid itself is off: restart the short fit from this transition,
            // keeping what the long one knows of the bit length.
            self.rejected = 0;
            self.last_j = j;
            self.long.shift_add(dn, dz, FIT_FORGET_LONG);
            self.short = LineSums {
                s0: 1.0,
                ..LineSums::default()
            };
            self.last = z;
            let slope = self
                .long
                .slope(nominal, prior)
                .clamp(nominal * 0.96, nominal * 1.04);
            return Some((z, slope));
        }
        self.rejected = 0;
        self.long.shift_add(dn, dz, FIT_FORGET_LONG);
        self.short.shift_add(dn, dz, FIT_FORGET);
        self.last = z;
        self.last_j = j;
        let acquiring = prior > SLOPE_PRIOR;
        let slope = if acquiring && self.acq_len > 0 && self.acq_len < ACQ_POINTS {
            let mut seg = self.acq[self.acq_len - 1].seg;
            if dn > ACQ_MAX_GAP {
                // Bits lost in a long gap (a start bit missed in the preamble) cannot
                // be counted while the bit length is unknown: at 2 % a twenty-bit gap
                // is 20.4 bits. The fit gives the points after it their own
                // intercept, and the grid restarts from this transition.
                seg += 1;
                self.short = LineSums {
                    s0: 1.0,
                    ..LineSums::default()
                };
            }
            self.acq[self.acq_len] = AcqPoint {
                n: self.n_abs(),
                z,
                seg,
            };
            self.acq_len += 1;
            let (slope, _, fitted) = robust_slope(&self.acq[..self.acq_len], nominal, prior);
            if let Some(f) = fitted {
                // The grid follows the robust line, not every rough transition: one
                // transition measured a third of a bit off would otherwise move the
                // windows so far that the next gap is counted a bit too long.
                self.short = LineSums {
                    s0: 1.0,
                    sz: f - z,
                    ..LineSums::default()
                };
            }
            slope
        } else {
            if self.acq_len > 0 {
                // The clock has settled: carry on from the inliers alone.
                self.rebuild_long(nominal, prior);
            }
            self.long.slope(nominal, prior)
        };
        let slope = slope.clamp(nominal * 0.96, nominal * 1.04);
        Some((z + self.short.intercept(slope), slope))
    }

    /// Bit number of the newest transition since the fit started.
    fn n_abs(&self) -> f64 {
        (self.last_j - self.first_j) as f64
    }

    /// Rebuilds the long fit from the acquisition's inliers and ends the acquisition.
    /// Gaps between segments are numbered with the fitted bit length.
    fn rebuild_long(&mut self, nominal: f64, prior: f64) {
        let pts = &self.acq[..self.acq_len];
        let (slope, inliers, _) = robust_slope(pts, nominal, prior);
        let mut long = LineSums::default();
        let mut prev = pts[0];
        for (i, p) in pts.iter().enumerate() {
            let w = if inliers >> i & 1 == 1 { 1.0 } else { 0.0 };
            let dz = p.z - prev.z;
            let dn = if p.seg == prev.seg {
                p.n - prev.n
            } else {
                libm::round(dz / slope)
            };
            long.shift_add_weighted(dn, dz, FIT_FORGET_LONG, w);
            prev = *p;
        }
        // Points since the last one kept in `acq` (none when it was full only now).
        if prev.n != self.n_abs() {
            long.shift_add_weighted(
                self.n_abs() - prev.n,
                self.last - prev.z,
                FIT_FORGET_LONG,
                1.0,
            );
        }
        self.long = long;
        self.acq_len = 0;
    }
}

/// Transitions kept for the robust fit while the clock is acquired.
const ACQ_POINTS: usize = 32;
/// Residuals (in bits) beyond which the robust fit drops a transition, pass by pass.
const ROBUST_LIMITS: [f64; 3] = [0.5, 0.3, 0.2];

/// Longest gap, in bits, counted across while the bit length is still unknown.
const ACQ_MAX_GAP: f64 = 12.0;

/// A transition seen while the clock is acquired.
#[derive(Debug, Clone, Copy, Default)]
struct AcqPoint {
    /// Bit number (counted from the first transition; across segments only roughly).
    n: f64,
    /// Time, samples.
    z: f64,
    /// Segment: the bit numbers of two segments are not comparable.
    seg: u32,
}

/// Bit length from the acquisition's transitions: least-squares lines with one slope
/// and an intercept per segment, the slope pulled towards `nominal` by `prior`,
/// refitted three times without the points that lie too far from the previous fit.
/// Returns the slope, the inliers as a bit mask and the fitted time of the newest
/// point (`None` when its segment has no inlier but the newest point itself).
fn robust_slope(pts: &[AcqPoint], nominal: f64, prior: f64) -> (f64, u32, Option<f64>) {
    let mut mask: u32 = if pts.len() >= 32 {
        u32::MAX
    } else {
        (1u32 << pts.len()) - 1
    };
    let last = pts[pts.len() - 1];
    let (n0, z0) = (last.n, last.z);
    // Per segment (points are in order, so segments are runs): (count, mean n, mean z).
    let mut means = [(0.0f64, 0.0f64, 0.0f64); ACQ_POINTS];
    let fit = |mask: u32, means: &mut [(f64, f64, f64); ACQ_POINTS]| {
        let (mut sxx, mut sxy) = (0.0, 0.0);
        let mut i = 0;
        while i < pts.len() {
            let seg = pts[i].seg;
            let mut l = LineSums::default();
            let start = i;
            while i < pts.len() && pts[i].seg == seg {
                if mask >> i & 1 == 1 {
                    let (dn, dz) = (pts[i].n - n0, pts[i].z - z0);
                    l.s0 += 1.0;
                    l.s1 += dn;
                    l.s2 += dn * dn;
                    l.sz += dz;
                    l.snz += dn * dz;
                }
                i += 1;
            }
            let m = if l.s0 > 0.0 {
                sxx += l.s2 - l.s1 * l.s1 / l.s0;
                sxy += l.snz - l.s1 * l.sz / l.s0;
                (l.s0, l.s1 / l.s0, l.sz / l.s0)
            } else {
                (0.0, 0.0, 0.0)
            };
            means[start..i].iter_mut().for_each(|x| *x = m);
        }
        (sxy + prior * nominal) / (sxx + prior)
    };
    let mut slope = fit(mask, &mut means);
    for limit in ROBUST_LIMITS {
        let mut keep = 0u32;
        for (i, p) in pts.iter().enumerate() {
            let (_, mn, mz) = means[i];
            let r = (p.z - z0) - (mz + slope * (p.n - n0 - mn));
            if libm::fabs(r) <= limit * nominal {
                keep |= 1 << i;
            }
        }
        // Too few left to say anything about the bit length: keep the last fit.
        if keep.count_ones() < 3 {
            break;
        }
        mask = keep;
        slope = fit(mask, &mut means);
    }
    let (count, mn, mz) = means[pts.len() - 1];
    let fitted = if count >= 2.0 {
        Some(z0 + mz - slope * mn)
    } else {
        None
    };
    (slope, mask, fitted)
}

/// Forgetting factor of the per-survivor phase estimate (memory about 1/(1-λ) bits).
/// Longer memories average more noise out of the reference but also keep the phase
/// errors that the bit grid's jitter puts into it at every transition: 0.6 measured
/// best (0.85 gave five times the frame errors at 11 dB).
const LAMBDA: f64 = 0.6;
/// Tone dominance (|E_m - E_s| / (E_m + E_s), smoothed over two bits) needed to switch
/// the carrier on: about 0.93 for a clean FSK signal, 0.5 on average for noise.
const CONTRAST_ON: f64 = 0.7;
/// Hysteresis of the transition detector on the tone balance.
const HYST: f64 = 0.7;

impl Demodulator {
    /// A demodulator with the given settings. Sample rates outside 8000..=192000 are
    /// clamped into that range (the caller should reject them first).
    pub fn new(config: DemodConfig) -> Self {
        let fs = f64::from(config.sample_rate.clamp(8000, 192_000));
        let spb = fs / crate::BIT_RATE;
        let hp = LinearHighPass::new(fs);
        let block = ((fs / 9600.0) as u32).max(1);
        Demodulator {
            config,
            fs,
            spb,
            block,
            hp_delay: hp.delay as f64,
            hp,
            lo_m: C64::new(1.0, 0.0),
            lo_s: C64::new(1.0, 0.0),
            rot_m: C64::expj(-crate::MARK_HZ / fs),
            rot_s: C64::expj(-crate::SPACE_HZ / fs),
            sums: [Lanes::ZERO; RING_LEN],
            n: 0,
            next_block: u64::from(block),
            level: 0.0,
            contrast: 0.0,
            young_level: 0.0,
            young_contrast: 0.0,
            level_epoch: 0,
            slow_level: 0.0,
            carrier: false,
            was_quiet: false,
            quiet_from: 0,
            quiet: None,
            frames_out: core::cell::Cell::new(0),
            next_bit: 0.0,
            period: spb,
            side: 0,
            last_zero: None,
            prev_v: 0.0,
            prev_t: 0.0,
            fit: TimingFit::default(),
            grid_origin: 0.0,
            grid_j: 0,
            locked: 0,
            eps: 0.0,
            pairs: 0,
            surv: Survivors::DEAD,
            best_idx: 0,
            k: 0,
            bits: [BitRec::default(); BIT_RING],
            pos: 0,
            char_start: None,
            chars: [CharRec::default(); CHAR_RING],
            char_n: 0,
            frame_xor: 0,
            deframer: Deframer::default(),
        }
    }

    /// A demodulator for the samples of a recording from sample `start` on (a
    /// multiple of [`START_ALIGN`]; others are rounded down, and the first sample
    /// pushed must be sample [`Self::samples`]), to decode a long recording in pieces
    /// on several cores with the same result as one demodulator from the start.
    /// `Demodulator::new(config)` is `starting_at(config, 0)`.
    ///
    /// Everything the demodulator computes depends on a bounded stretch of signal
    /// before it, or is started afresh when the carrier comes on: the high-pass
    /// filter's sums are re-added every 65536 samples, the running sums rebased and the
    /// oscillators re-derived every 4096, the level and tone dominance averages
    /// restarted every [`LEVEL_EPOCH`] (all at multiples of these sample counts); the
    /// clock, the detector and the deframer start afresh with every burst. So from
    /// sample [`Self::quiet_from`] on this demodulator's level is the one a
    /// demodulator started at sample 0 has, bit for bit, and after a *quiet point*
    /// (see [`Self::quiet_point`]) everything it reports is what that one reports.
    pub fn starting_at(config: DemodConfig, start: u64) -> Self {
        let start = start - start % START_ALIGN;
        let mut d = Demodulator::new(config);
        if start == 0 {
            return d;
        }
        let rate = d.config.sample_rate;
        d.n = start;
        d.hp.n = start as usize;
        d.lo_m = lo_at(crate::MARK_HZ as u64, start, rate);
        d.lo_s = lo_at(crate::SPACE_HZ as u64, start, rate);
        let block = u64::from(d.block);
        d.next_block = (start / block + 1) * block;
        d.level_epoch = start / LEVEL_EPOCH;
        d.quiet_from = Self::quiet_from(&config, start);
        d
    }

    /// The sample count from which a demodulator [started](Self::starting_at) at
    /// sample `start` computes the level of one started at sample 0, for the update at
    /// that sample count and the one before, and so records the same quiet points:
    /// the high-pass filter's output is exact after three re-adds of its cascade
    /// (196608 samples), the running sums a ring's length later, the level two epochs
    /// after that (229376 samples in all), plus one carrier-detect update.
    pub fn quiet_from(config: &DemodConfig, start: u64) -> u64 {
        let start = start - start % START_ALIGN;
        if start == 0 {
            return 0;
        }
        let fs = f64::from(config.sample_rate.clamp(8000, 192_000));
        let block = ((fs / 9600.0) as u64).max(1);
        start + 3 * HP_READD as u64 + 2 * LEVEL_EPOCH + block
    }

    /// Samples pushed so far, counted from the start of the recording (for a
    /// demodulator [started](Self::starting_at) inside one, from there).
    pub fn samples(&self) -> u64 {
        self.n
    }

    /// Frames reported so far.
    pub fn frames_reported(&self) -> u64 {
        self.frames_out.get()
    }

    /// The latest quiet point: the sample count of a carrier-detect update at which
    /// the level had been below both carrier thresholds for two updates in a row (from
    /// [`Self::quiet_from`] on), and the number of frames reported before it. At a
    /// quiet point the carrier is off and nothing is being received, and every part
    /// of the state that decides what is reported later (the filters and sums, the
    /// level, the deframer's hunt) is what any other settled demodulator fed the same
    /// recording has: two such demodulators report the same frames, bit for bit,
    /// after a quiet point both have seen.
    pub fn quiet_point(&self) -> Option<(u64, u64)> {
        self.quiet
    }

    /// The settings.
    pub fn config(&self) -> &DemodConfig {
        &self.config
    }

    /// True while the carrier is detected.
    pub fn carrier(&self) -> bool {
        self.carrier
    }

    /// The current level estimate, volts peak-to-peak.
    pub fn level_vpp(&self) -> f64 {
        self.level
    }

    /// Estimated bit rate error of the signal being received (+0.01 = 1 % fast).
    pub fn rate_error(&self) -> f64 {
        self.spb / self.period - 1.0
    }

    /// Estimated tone frequency error of the signal being received (+0.01 = both
    /// tones 1 % high).
    pub fn tone_error(&self) -> f64 {
        self.eps
    }

    /// Feeds samples; events are reported as they are found.
    pub fn push(&mut self, samples: &[f32], mut on_event: impl FnMut(DemodEvent<'_>)) {
        let mut rest = samples;
        while !rest.is_empty() {
            // A piece up to the next multiple of PIECE: the front end over all of it,
            // then the events in it, each at its own sample count as if the samples had
            // come one by one.
            let room = PIECE - (self.n % PIECE as u64) as usize;
            let (piece, tail) = rest.split_at(room.min(rest.len()));
            rest = tail;
            self.front_end(piece);
            let end = self.n + piece.len() as u64;
            if end % REBASE == 0 {
                self.run_events(end - 1, &mut on_event);
                self.n = end;
                // Re-derive the oscillators from the sample count so rounding cannot
                // accumulate, and keep the running sums small.
                self.lo_m = lo_at(crate::MARK_HZ as u64, end, self.config.sample_rate);
                self.lo_s = lo_at(crate::SPACE_HZ as u64, end, self.config.sample_rate);
                self.rebase();
            }
            self.run_events(end, &mut on_event);
            self.n = end;
        }
    }

    /// The front end over a piece (within one multiple of [`PIECE`]) starting at sample
    /// `self.n`: high-pass, mixers, running sums. Writes the sums up to sample
    /// `self.n + piece.len()`; `self.n` is left for the detector's clock.
    fn front_end(&mut self, piece: &[f32]) {
        const M: usize = RING_LEN - 1;
        let mut i = self.n as usize;
        let last = self.sums[i & M];
        let (mut am, mut as_) = (last.lane(0), last.lane(1));
        let (mut lm, mut ls) = (self.lo_m, self.lo_s);
        let (rm, rs) = (self.rot_m, self.rot_s);
        let sums = &mut self.sums;
        self.hp.run_piece(piece, self.config.volts_per_unit, |v| {
            am = am.add(lm.scale(v));
            as_ = as_.add(ls.scale(v));
            i = i.wrapping_add(1);
            sums[i & M] = Lanes {
                re: [am.re, as_.re],
                im: [am.im, as_.im],
            };
            lm = lm.mul(rm);
            ls = ls.mul(rs);
        });
        self.lo_m = lm;
        self.lo_s = ls;
    }

    /// The carrier detect, clock recovery and detection events up to sample count
    /// `upto`, in order, each with the detector's clock at its sample count: the
    /// carrier-detect update every `block` samples, then the bits that are due.
    fn run_events(&mut self, upto: u64, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        loop {
            let bit_due = if self.carrier {
                // The first sample count n with n >= next_bit + period + 1.
                ceil_count(self.next_bit + self.period + 1.0)
            } else {
                u64::MAX
            };
            let at = self.next_block.min(bit_due).max(self.n);
            if at > upto {
                return;
            }
            self.n = at;
            if at == self.next_block {
                self.next_block += u64::from(self.block);
                self.on_block(on_event);
            }
            if self.carrier {
                while self.now() >= self.next_bit + self.period + 1.0 {
                    self.detect_bit(on_event);
                }
            }
        }
    }

    /// Ends the input: anything still being received is decided and reported.
    pub fn finish(&mut self, mut on_event: impl FnMut(DemodEvent<'_>)) {
        if self.carrier {
            self.carrier_off(&mut on_event);
        }
    }

    /// Keeps the running sums small: subtract the newest value from the ring
    /// (differences are unchanged); only the last [`RING`] sums are ever read again.
    fn rebase(&mut self) {
        const M: usize = RING_LEN - 1;
        let n = self.n as usize;
        let base = self.sums[n & M];
        for k in 0..RING {
            let i = n.wrapping_sub(k) & M;
            self.sums[i] = self.sums[i].sub(base);
        }
    }

    /// Running sum at a fractional sample position (linear between samples). The
    /// position must lie within the ring.
    #[inline]
    fn prefix(&self, t: f64) -> Lanes {
        let (i, fl) = floor_parts(t);
        let f = t - fl;
        let a = self.sums[i & (RING_LEN - 1)];
        if f == 0.0 {
            // What the line below gives for f = 0 (the sums are finite and never -0).
            return a;
        }
        let b = self.sums[(i + 1) & (RING_LEN - 1)];
        let mut out = a;
        for l in 0..2 {
            out.re[l] = a.re[l] + (b.re[l] - a.re[l]) * f;
            out.im[l] = a.im[l] + (b.im[l] - a.im[l]) * f;
        }
        out
    }

    /// [`Self::prefix`] for one tone (lane 0 mark, 1 space).
    #[inline]
    fn prefix_lane(&self, t: f64, l: usize) -> C64 {
        let (i, fl) = floor_parts(t);
        let f = t - fl;
        let a = self.sums[i & (RING_LEN - 1)].lane(l);
        if f == 0.0 {
            return a;
        }
        let b = self.sums[(i + 1) & (RING_LEN - 1)].lane(l);
        a.add(b.sub(a).scale(f))
    }

    /// Correlations with both tones over [a, b) (samples), global oscillator phase.
    #[inline(always)]
    fn corr(&self, a: f64, b: f64) -> (C64, C64) {
        let d = self.prefix(b).sub(self.prefix(a));
        (d.lane(0), d.lane(1))
    }

    /// The detector's clock as a float (a signed conversion: cheaper than an unsigned
    /// one, and the same value below 2^53).
    #[inline]
    fn now(&self) -> f64 {
        self.n as i64 as f64
    }

    fn t_of(&self, samples: f64) -> f64 {
        (samples - self.hp_delay).max(0.0) / self.fs
    }

    fn on_block(&mut self, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        let now = self.now();
        if now < self.spb + 2.0 {
            return;
        }
        let (cm, cs) = self.corr(now - self.spb, now);
        let (em, es) = (cm.norm2(), cs.norm2());
        // Volts peak-to-peak of the stronger tone: a tone of peak A correlates to
        // A/2 per sample.
        let vpp = 4.0 * libm::sqrt(em.max(es)) / self.spb;
        let v = if em + es > 0.0 {
            (em - es) / (em + es)
        } else {
            0.0
        };
        let epoch = self.n / LEVEL_EPOCH;
        if epoch != self.level_epoch {
            self.level_epoch = epoch;
            self.level = self.young_level;
            self.contrast = self.young_contrast;
            self.young_level = 0.0;
            self.young_contrast = 0.0;
        }
        let alpha = f64::from(self.block) / self.spb;
        self.level += alpha * (vpp - self.level);
        self.contrast += alpha / 2.0 * (libm::fabs(v) - self.contrast);
        self.young_level += alpha * (vpp - self.young_level);
        self.young_contrast += alpha / 2.0 * (libm::fabs(v) - self.young_contrast);
        let quiet =
            self.level < self.config.carrier_off_vpp && self.level < self.config.carrier_on_vpp;
        if quiet && self.was_quiet && self.n >= self.quiet_from && !self.carrier {
            // Two updates in a row below both thresholds: the first switched the
            // carrier off if it was on, so nothing is being received now.
            self.quiet = Some((self.n, self.frames_out.get()));
        }
        self.was_quiet = quiet;
        if !self.carrier {
            if self.level >= self.config.carrier_on_vpp && self.contrast >= CONTRAST_ON {
                self.carrier_on(now, on_event);
            }
        } else if self.level < self.config.carrier_off_vpp {
            self.carrier_off(on_event);
            return;
        } else if self.level > RESTART_RATIO * self.slow_level {
            // A burst starting while the carrier detect was already on (noise, or
            // another transmitter right after): the clock and the phase references
            // belong to what came before, so start afresh.
            self.carrier_off(on_event);
            self.carrier_on(now, on_event);
        }
        // The floor falls with the level within a bit and rises over eight bits, so a
        // burst after noise stands out against the noise, not against its own start.
        let rate = if self.level < self.slow_level {
            alpha
        } else {
            alpha / 8.0
        };
        self.slow_level += rate * (self.level - self.slow_level);
        if self.carrier && self.locked < ACQUIRE_TRANSITIONS {
            self.track_transition(v, now - self.spb / 2.0);
        }
        self.prev_v = v;
        self.prev_t = now - self.spb / 2.0;
    }

    /// Clock recovery: `v` is the tone balance of the one-bit window centred at `t`.
    fn track_transition(&mut self, v: f64, t: f64) {
        if (v >= 0.0) != (self.prev_v >= 0.0) {
            let d = self.prev_v - v;
            let f = if d != 0.0 { self.prev_v / d } else { 0.5 };
            self.last_zero = Some(self.prev_t + f * (t - self.prev_t));
        }
        let new_side = if v > HYST {
            1
        } else if v < -HYST {
            -1
        } else {
            self.side
        };
        if new_side != self.side {
            let was = self.side;
            self.side = new_side;
            if was != 0 {
                if let Some(z) = self.last_zero.take() {
                    // The bit window this transition falls at.
                    let j = self.k as i64 + libm::round((z - self.next_bit) / self.period) as i64;
                    self.on_transition(z, j);
                }
            }
        }
    }

    /// A transition at `z` samples, at the start of bit window `j`.
    fn on_transition(&mut self, z: f64, j: i64) {
        // The bit length is held near nominal until the clock has settled: the first
        // transitions (noise before the burst, the sparse preamble) are too few and
        // too rough to measure it.
        let prior = if self.locked >= SETTLED_TRANSITIONS {
            SLOPE_PRIOR
        } else {
            SLOPE_PRIOR_ACQUIRE
        };
        let r = self.fit.add(z, j, self.period, self.spb, prior);
        let Some((origin, period)) = r else {
            return;
        };
        self.locked += 1;
        self.period = period;
        self.grid_origin = origin;
        self.grid_j = j;
        // Move the next window onto the fitted grid of bit boundaries.
        let target = origin + libm::round((self.next_bit - origin) / period) * period;
        self.next_bit = target;
    }

    fn carrier_on(&mut self, now: f64, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        self.carrier = true;
        self.slow_level = self.level;
        self.fit = TimingFit::default();
        self.locked = 0;
        self.eps = 0.0;
        self.pairs = 0;
        self.side = 0;
        self.last_zero = None;
        self.period = self.spb;
        // Start detecting from four bits back (within the ring even at 192 kHz): the
        // carrier detect needs about two bits to rise, and the first preamble
        // character must not be lost.
        self.next_bit = (now - 4.0 * self.spb).max(0.0);
        self.surv = Survivors::start(STATES - 1);
        self.best_idx = STATES - 1;
        self.k = 0;
        self.pos = 0;
        self.char_start = None;
        on_event(DemodEvent::Carrier {
            on: true,
            t: self.t_of(now),
            level_vpp: self.level,
        });
    }

    fn carrier_off(&mut self, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        // Decide everything still pending from the best path.
        self.run_uart(0, true, on_event);
        let mut forward = |ev: DeframerEvent<'_>, this: &FrameCtx<'_>| this.forward(ev, on_event);
        let ctx = FrameCtx {
            chars: &self.chars,
            frames_out: &self.frames_out,
            char_n: self.char_n,
            rate_error: self.spb / self.period - 1.0,
            tone_error: self.eps,
        };
        self.deframer.abort(&mut |ev| forward(ev, &ctx));
        self.carrier = false;
        on_event(DemodEvent::Carrier {
            on: false,
            t: self.t_of(self.now()),
            level_vpp: self.level,
        });
    }

    /// Correlations with both tones over `[a, a + len)`, referred to the window's start
    /// (C' = C·e^{+j2πf·a/fs}) and scaled to the tone's amplitude.
    #[inline]
    fn bit_corr(&self, a: f64, len: f64) -> (C64, C64) {
        let (cm, cs) = self.corr(a, a + len);
        let norm = 2.0 / len;
        let ym = cm
            .mul(lo_frac(crate::MARK_HZ as u64, a, self.config.sample_rate))
            .scale(norm);
        let ys = cs
            .mul(lo_frac(crate::SPACE_HZ as u64, a, self.config.sample_rate))
            .scale(norm);
        (ym, ys)
    }

    /// [`Self::bit_corr`] for one tone (mark when `mark`).
    #[inline]
    fn tone_corr(&self, a: f64, len: f64, mark: bool) -> C64 {
        let (l, f) = if mark {
            (0, crate::MARK_HZ as u64)
        } else {
            (1, crate::SPACE_HZ as u64)
        };
        self.prefix_lane(a + len, l)
            .sub(self.prefix_lane(a, l))
            .mul(lo_frac(f, a, self.config.sample_rate))
            .scale(2.0 / len)
    }

    fn detect_bit(&mut self, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        let a = self.next_bit;
        let b = a + self.period;
        let (ym, ys) = self.bit_corr(a, self.period);
        let spacing = if self.k == 0 {
            self.period
        } else {
            a - self.bits[(self.k - 1) % BIT_RING].start
        };
        let lambda = if self.locked >= LAMBDA_SETTLED {
            LAMBDA
        } else {
            LAMBDA_ACQUIRE
        };
        self.viterbi(ym, ys, spacing, lambda);
        self.bits[self.k % BIT_RING] = BitRec { start: a, ym, ys };
        self.k += 1;
        self.next_bit = b;
        if self.locked >= ACQUIRE_TRANSITIONS && self.k > TIMING_DELAY {
            self.decided_transition(self.k - TIMING_DELAY);
        }
        let delay = if self.deframer.remaining() == Some(1) {
            0
        } else {
            DECISION_DELAY
        };
        self.run_uart(delay, false, on_event);
    }

    /// Decision-directed clock recovery. Where the best path changes tone at the start
    /// of bit `j`, a window that starts `δ` late sees the new tone's phase advanced by
    /// 2π·f·δ for each tone, so the carrier phase jumps by ±2π·1000 Hz·δ across the
    /// transition (after undoing the path's own -60° per space). That jump measures
    /// the timing error from two whole-bit correlations: unbiased by the neighbouring
    /// bits, and only at real transitions.
    fn decided_transition(&mut self, j: usize) {
        if j == 0 || self.k - j + 1 >= BIT_RING {
            return;
        }
        let (prev, cur) = (self.bit_at(j - 1), self.bit_at(j));
        let mut bp = self.bits[(j - 1) % BIT_RING];
        let mut bc = self.bits[j % BIT_RING];
        if prev != cur && self.locked > 0 {
            // Measure at the boundary the clock now predicts, not where the windows
            // were placed bits ago (before the latest transitions moved the grid): a
            // window a third of a bit off holds a third of the other tone, and the
            // phase step across it is then a poor measure. Where a tone lasts longer
            // than a bit, its window covers up to `STEP_BITS` of it: the phase step's
            // noise falls with the windows' lengths (by 0.7 when both sides have two
            // bits; by 0.8 across a preamble's start bit, one bit against several).
            let g = self.grid_origin + (j as i64 - self.grid_j) as f64 * self.period;
            let oldest = self.now() - (RING - 2) as f64;
            let mut lp = 1;
            while lp < STEP_BITS
                && j > lp
                && self.bit_at(j - 1 - lp) == prev
                && g - (lp + 1) as f64 * self.period > oldest
            {
                lp += 1;
            }
            let mut lc = 1;
            while lc < STEP_BITS
                && j + lc < self.k
                && self.bit_at(j + lc) == cur
                && g + (lc + 1) as f64 * self.period <= self.now()
            {
                lc += 1;
            }
            let moved = libm::fabs(g - bc.start) > REMEASURE * self.period
                || libm::fabs(bc.start - bp.start - self.period) > REMEASURE * self.period;
            if (moved || lp > 1 || lc > 1)
                && g - lp as f64 * self.period > oldest
                && g + lc as f64 * self.period <= self.now()
            {
                let (lpf, lcf) = (lp as f64 * self.period, lc as f64 * self.period);
                // Only the tone each side holds is needed.
                let yp = self.tone_corr(g - lpf, lpf, prev);
                let yc = self.tone_corr(g, lcf, cur);
                bp = BitRec {
                    start: g - lpf,
                    ym: yp,
                    ys: yp,
                };
                bc = BitRec {
                    start: g,
                    ym: yc,
                    ys: yc,
                };
            }
        }
        let yp = if prev { bp.ym } else { bp.ys };
        let yc = if cur { bc.ym } else { bc.ys };
        // Undo the previous tone's phase advance over the windows' actual spacing.
        let f_prev = if prev {
            crate::MARK_HZ
        } else {
            crate::SPACE_HZ
        };
        let cycles = f_prev * (bc.start - bp.start) / self.fs;
        let rel = yc
            .mul(C64::new(yp.re, -yp.im))
            .mul(C64::expj(-cycles * (1.0 + self.eps)));
        if rel.norm2() == 0.0 {
            return;
        }
        let dphi = libm::atan2(rel.im, rel.re);
        if prev == cur {
            // Two bits of one tone: what is left of the phase advance is the tone
            // error times the cycles in between. Averaged over the pairs seen, starting
            // as if some pairs had measured zero so the first noisy ones cannot swing it.
            if libm::fabs(dphi) > EPS_OUTLIER {
                // A wrong decision or a noise spike, not a drift.
                return;
            }
            let residual = dphi / (2.0 * core::f64::consts::PI * cycles);
            self.pairs += 1;
            let gain = (1.0 / f64::from(self.pairs + EPS_PRIOR_PAIRS)).max(EPS_GAIN);
            self.eps = (self.eps + gain * residual).clamp(-0.045, 0.045);
            return;
        }
        // Mark to space: the new tone is 1000 Hz higher.
        let df = if prev {
            crate::SPACE_HZ - crate::MARK_HZ
        } else {
            crate::MARK_HZ - crate::SPACE_HZ
        };
        let late = dphi / (2.0 * core::f64::consts::PI * df) * self.fs;
        let late = late.clamp(-self.period / 2.0, self.period / 2.0);
        self.on_transition(bc.start - late, j as i64);
    }

    /// One trellis step; `spacing` is the distance from the previous bit window's start
    /// to this one's, in samples.
    fn viterbi(&mut self, ym: C64, ys: C64, spacing: f64, lambda: f64) {
        // Phase advance of each tone across that spacing, undone.
        let f = 1.0 + self.eps;
        let step = [
            C64::expj(-crate::SPACE_HZ * f * spacing / self.fs),
            C64::expj(-crate::MARK_HZ * f * spacing / self.fs),
        ];
        // Per predecessor (each feeds two branches): the path's rotation brought up to
        // this bit's start (the previous bit's tone ran across the spacing), its
        // forgotten reference λR and the λ|R| its metric gives back. A state no path
        // reaches has metric minus infinity, and so have its branches.
        let sv = &self.surv;
        let mut p_re = [0.0; STATES];
        let mut p_im = [0.0; STATES];
        let mut lr_re = [0.0; STATES];
        let mut lr_im = [0.0; STATES];
        let mut lr_abs = [0.0; STATES];
        for p in 0..STATES {
            let st = step[(sv.hist[p] & 1) as usize];
            p_re[p] = sv.rot_re[p] * st.re - sv.rot_im[p] * st.im;
            p_im[p] = sv.rot_re[p] * st.im + sv.rot_im[p] * st.re;
            lr_re[p] = sv.r_re[p] * lambda;
            lr_im[p] = sv.r_im[p] * lambda;
            lr_abs[p] = lambda * libm::sqrt(sv.r_re[p] * sv.r_re[p] + sv.r_im[p] * sv.r_im[p]);
        }
        // Every branch: from predecessor p with bit b (0: space, 1: mark), the
        // correlation turned by the path's rotation, added to its reference.
        let mut rr_re = [[0.0; STATES]; 2];
        let mut rr_im = [[0.0; STATES]; 2];
        let mut m = [[0.0; STATES]; 2];
        for (b, y0) in [ys, ym].into_iter().enumerate() {
            for p in 0..STATES {
                let re = lr_re[p] + (y0.re * p_re[p] - y0.im * p_im[p]);
                let im = lr_im[p] + (y0.re * p_im[p] + y0.im * p_re[p]);
                rr_re[b][p] = re;
                rr_im[b][p] = im;
                m[b][p] = sv.metric[p] + libm::sqrt(re * re + im * im) - lr_abs[p];
            }
        }
        // State ns is reached from ns >> 1 (oldest bit 0) and ns >> 1 | 4 (oldest bit
        // 1) with bit ns & 1; the first wins ties, and a state neither reaches stays
        // dead.
        let mut next = Survivors::DEAD;
        for ns in 0..STATES {
            let b = ns & 1;
            let p0 = ns >> 1;
            let p1 = p0 | (1 << (STATE_BITS - 1));
            let take0 = m[b][p0] > f64::NEG_INFINITY;
            let to_beat = if take0 { m[b][p0] } else { f64::NEG_INFINITY };
            let p = if m[b][p1] > to_beat {
                p1
            } else if take0 {
                p0
            } else {
                continue;
            };
            next.metric[ns] = m[b][p];
            next.r_re[ns] = rr_re[b][p];
            next.r_im[ns] = rr_im[b][p];
            next.rot_re[ns] = p_re[p];
            next.rot_im[ns] = p_im[p];
            next.hist[ns] = sv.hist[p] << 1 | b as u64;
        }
        // Keep the rotations on the unit circle and the metrics small.
        if self.k % 64 == 0 {
            for ns in 0..STATES {
                let (re, im) = (next.rot_re[ns], next.rot_im[ns]);
                let a = libm::sqrt(re * re + im * im);
                if a > 0.0 {
                    let k = 1.0 / a;
                    next.rot_re[ns] = re * k;
                    next.rot_im[ns] = im * k;
                }
            }
        }
        let best = next
            .metric
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        self.best_idx = next.metric.iter().position(|&m| m == best).unwrap_or(0);
        for m in next.metric.iter_mut() {
            *m -= best;
        }
        self.surv = next;
    }

    fn best_hist(&self) -> u64 {
        self.surv.hist[self.best_idx]
    }

    /// Bit `idx` (counted since the carrier came on) on the best path.
    fn bit_at(&self, idx: usize) -> bool {
        let age = self.k - 1 - idx;
        age >= 64 || self.best_hist() >> age & 1 == 1
    }

    /// True when the best path holds a 0xFF character (0 then ten 1s) from bit `p`.
    fn is_preamble_at(&self, p: usize) -> bool {
        p + crate::BITS_PER_CHAR <= self.k
            && !self.bit_at(p)
            && (p + 1..p + crate::BITS_PER_CHAR).all(|i| self.bit_at(i))
    }

    /// Reads characters from the best path, deciding bits `delay` bits behind the newest.
    /// `flush`: the carrier is gone; decide everything, and drop a character cut off.
    fn run_uart(&mut self, delay: usize, flush: bool, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        loop {
            if let Some(s) = self.char_start {
                // The last character of a frame is read as soon as its stop bit is in,
                // so the frame is out within the front end's delay (1.5 bits) after
                // the end of the stop bit.
                let delay = if self.deframer.remaining() == Some(1) {
                    0
                } else {
                    delay
                };
                if self.k < s + crate::BITS_PER_CHAR + delay {
                    if flush && self.k > s {
                        // Carrier lost inside a character: it is cut off.
                        self.char_start = None;
                        self.pos = self.k;
                    }
                    return;
                }
                if !self.deframer.in_frame() {
                    // Between frames, noise (or the tail of a cut-off frame) can leave the
                    // character framing off by a few bits, and back-to-back characters
                    // would keep it off. A preamble character, 0xFF, is the only place
                    // where a 0 is followed by ten 1s: re-align on it.
                    let decided = self.k.saturating_sub(delay);
                    let from = s
                        .saturating_sub(crate::BITS_PER_CHAR - 1)
                        .max(self.k.saturating_sub(60));
                    let to = decided.saturating_sub(crate::BITS_PER_CHAR - 1);
                    if !self.is_preamble_at(s) {
                        if let Some(p) = (from..to).find(|&p| p != s && self.is_preamble_at(p)) {
                            self.char_start = Some(p);
                            continue;
                        }
                    }
                }
                let mut byte = 0u8;
                for i in 0..8 {
                    byte |= u8::from(self.bit_at(s + 1 + i)) << i;
                }
                let parity = self.bit_at(s + 9);
                let stop = self.bit_at(s + 10);
                let flags = UartFlags {
                    parity: (byte.count_ones() + u32::from(parity)) % 2 == 0,
                    framing: !stop,
                    overrun: false,
                };
                let last = self.deframer.remaining() == Some(1);
                if last
                    && !flush
                    && self.k < s + crate::BITS_PER_CHAR + LAST_CHAR_WAIT
                    && (flags.any() || self.frame_xor ^ byte != 0)
                {
                    // Read this early, the last character does not complete a good
                    // frame: give the detector another bit or two before deciding.
                    return;
                }
                let t = self.t_of(self.bits[s % BIT_RING].start);
                self.char_start = None;
                self.pos = s + crate::BITS_PER_CHAR;
                self.push_char(
                    CharRec {
                        byte,
                        flags,
                        t,
                        level: self.level,
                    },
                    on_event,
                );
            } else {
                if self.k < self.pos + 1 + delay || self.pos >= self.k {
                    return;
                }
                if self.bit_at(self.pos) {
                    self.pos += 1;
                } else {
                    self.char_start = Some(self.pos);
                }
            }
        }
    }

    fn push_char(&mut self, c: CharRec, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        on_event(DemodEvent::Char(RxChar {
            byte: c.byte,
            flags: c.flags,
            t: c.t,
        }));
        self.chars[self.char_n % CHAR_RING] = c;
        self.char_n += 1;
        let ctx = FrameCtx {
            chars: &self.chars,
            frames_out: &self.frames_out,
            char_n: self.char_n,
            rate_error: self.spb / self.period - 1.0,
            tone_error: self.eps,
        };
        self.deframer
            .push(c.byte, c.flags, &mut |ev| ctx.forward(ev, on_event));
        // Check byte so far of the frame being received (XOR of delimiter onwards).
        self.frame_xor = if self.deframer.in_frame() {
            self.frame_xor ^ c.byte
        } else {
            0
        };
    }
}

/// The oscillator e^{-j2πf·n/fs} at integer sample `n`, exactly.
fn lo_at(f: u64, n: u64, fs: u32) -> C64 {
    let fs = u64::from(fs.clamp(8000, 192_000));
    let r = (f % fs) * (n % fs) % fs;
    C64::expj(-(r as f64) / fs as f64)
}

/// `floor` for the sample positions and phases of the inner loops (|x| < 2^53): a cast
/// instead of `libm`'s portable implementation, which costs several per cent of the
/// demodulator's time.
#[inline]
fn floor_fast(x: f64) -> f64 {
    let i = x as i64 as f64;
    if i > x {
        i - 1.0
    } else {
        i
    }
}

/// The smallest sample count `n` with `n as f64 >= t` (0 for negative `t`).
#[inline]
fn ceil_count(t: f64) -> u64 {
    if t <= 0.0 {
        return 0;
    }
    let (i, f) = floor_parts(t);
    (if f < t { i + 1 } else { i }) as u64
}

/// `floor_fast(x)` as a float and as an index (`floor_fast(x) as usize`: 0 for a
/// negative position, which the start of a recording can give), with one conversion
/// each way instead of two.
#[inline]
fn floor_parts(x: f64) -> (usize, f64) {
    let i = x as i64;
    let f = i as f64;
    let (i, f) = if f > x { (i - 1, f - 1.0) } else { (i, f) };
    (i.max(0) as usize, f)
}

/// Nearest integer, halves rounded up (the callers do not care which way).
#[inline]
fn round_fast(x: f64) -> f64 {
    floor_fast(x + 0.5)
}

/// e^{+j2πf·t/fs} at a fractional sample position `t` (the conjugate oscillator).
#[inline]
fn lo_frac(f: u64, t: f64, fs: u32) -> C64 {
    let fs_c = u64::from(fs.clamp(8000, 192_000));
    let ti = floor_fast(t);
    let frac = t - ti;
    let r = (f % fs_c) * ((ti as u64) % fs_c) % fs_c;
    C64::expj((r as f64 + f as f64 * frac) / fs_c as f64)
}

/// What the deframer's events need to become frame events.
struct FrameCtx<'c> {
    chars: &'c [CharRec; CHAR_RING],
    /// Frames reported, counted.
    frames_out: &'c core::cell::Cell<u64>,
    char_n: usize,
    rate_error: f64,
    tone_error: f64,
}

impl FrameCtx<'_> {
    fn forward(&self, ev: DeframerEvent<'_>, on_event: &mut impl FnMut(DemodEvent<'_>)) {
        let (pdu, preambles) = match ev {
            DeframerEvent::Frame(f) => (f.pdu, f.preambles),
            DeframerEvent::Damaged(d) => (d.pdu, d.preambles),
            DeframerEvent::Invalid { pdu, .. } => (pdu, 0),
            _ => return,
        };
        // Find the characters of this frame: normally the newest ones; after a
        // rescan, further back.
        let len = pdu.len();
        let avail = self.char_n.min(CHAR_RING);
        let mut first = None;
        let mut end = self.char_n;
        while end >= len && self.char_n - end + len <= avail {
            let start = end - len;
            if (0..len).all(|i| self.chars[(start + i) % CHAR_RING].byte == pdu[i]) {
                first = Some(start);
                break;
            }
            end -= 1;
        }
        let (t, parity_errors, framing_errors, level_vpp) = match first {
            Some(start) => {
                let recs = (start..start + len).map(|i| &self.chars[i % CHAR_RING]);
                let (mut p, mut f, mut l) = (0, 0, 0.0);
                for r in recs {
                    p += usize::from(r.flags.parity);
                    f += usize::from(r.flags.framing);
                    l += r.level;
                }
                (self.chars[start % CHAR_RING].t, p, f, l / len.max(1) as f64)
            }
            None => (0.0, 0, 0, 0.0),
        };
        self.frames_out.set(self.frames_out.get() + 1);
        on_event(DemodEvent::Frame(RxFrame {
            t,
            pdu,
            preambles,
            checksum_ok: checksum(pdu) == 0,
            parity_errors,
            framing_errors,
            level_vpp,
            rate_error: self.rate_error,
            tone_error: self.tone_error,
        }));
    }
}

/// Decodes every frame in a buffer of samples.
#[cfg(feature = "alloc")]
pub fn decode(config: DemodConfig, samples: &[f32]) -> alloc::vec::Vec<DecodedFrame> {
    let mut d = Demodulator::new(config);
    let mut out = alloc::vec::Vec::new();
    let mut take = |ev: DemodEvent<'_>| {
        if let DemodEvent::Frame(f) = ev {
            out.push(f.to_decoded());
        }
    };
    d.push(samples, &mut take);
    d.finish(&mut take);
    out
}

#[cfg(test)]
mod tests {
    use super::{floor_fast, floor_parts, robust_slope, AcqPoint, C64};

    /// Preamble-like transitions (pairs one bit apart, eleven bits between pairs) of a
    /// signal 2 % slow, 40 samples per nominal bit.
    fn preamble(chars: usize) -> [AcqPoint; 32] {
        let mut pts = [AcqPoint::default(); 32];
        for c in 0..chars {
            for (k, dn) in [0.0, 1.0].into_iter().enumerate() {
                let n = c as f64 * 11.0 + dn;
                pts[2 * c + k] = AcqPoint {
                    n,
                    z: 1000.0 + n * 40.8,
                    seg: 0,
                };
            }
        }
        pts
    }

    #[test]
    fn the_robust_fit_drops_a_transition_measured_far_off() {
        let mut pts = preamble(5);
        let clean = robust_slope(&pts[..10], 40.0, 0.0);
        assert!((clean.0 - 40.8).abs() < 1e-9, "{}", clean.0);
        assert_eq!(clean.1, 0b11_1111_1111);
        // A third of a bit off: dropped, and the slope is unchanged.
        pts[4].z += 0.35 * 40.0;
        let (slope, inliers, fitted) = robust_slope(&pts[..10], 40.0, 0.0);
        assert!((slope - 40.8).abs() < 1e-9, "{slope}");
        assert_eq!(inliers, 0b11_1110_1111);
        assert!((fitted.unwrap() - pts[9].z).abs() < 1e-6);
    }

    #[test]
    fn a_segment_after_a_long_gap_keeps_its_own_intercept() {
        // Two preamble characters lost: the bits counted across the gap are one short,
        // as a drifting window count would make them; a new segment must not care.
        let mut pts = preamble(6);
        for p in &mut pts[4..12] {
            p.n -= 1.0;
            p.seg = 1;
        }
        let (slope, inliers, _) = robust_slope(&pts[..12], 40.0, 0.0);
        assert!((slope - 40.8).abs() < 1e-9, "{slope}");
        assert_eq!(inliers.count_ones(), 12);
        // Counted as one segment, the points before the gap no longer fit the line
        // and are lost to the fit.
        for p in &mut pts[4..12] {
            p.seg = 0;
        }
        let (_, inliers, _) = robust_slope(&pts[..12], 40.0, 0.0);
        assert!(inliers.count_ones() < 12, "{inliers:b}");
    }

    #[test]
    fn the_prior_pulls_a_short_fit_towards_nominal() {
        let pts = preamble(2);
        let (slope, _, _) = robust_slope(&pts[..4], 40.0, 50.0);
        assert!(slope > 40.0 && slope < 40.8, "{slope}");
        let (more, _, _) = robust_slope(&preamble(5)[..10], 40.0, 50.0);
        assert!(more > slope && more < 40.8, "{more}");
    }

    #[test]
    fn floor_fast_matches_floor() {
        for x in [
            -2.5,
            -1.0,
            -0.5,
            -0.0,
            0.0,
            0.25,
            1.0,
            1.999_999,
            12_345.678,
            -12_345.678,
        ] {
            assert_eq!(floor_fast(x), libm::floor(x), "{x}");
        }
    }

    #[test]
    fn floor_parts_is_floor_fast_and_its_index() {
        for x in [
            -130.5, -2.5, -1.0, -0.25, -0.0, 0.0, 0.25, 1.0, 39.999, 40.0, 12_345.678,
        ] {
            let f = floor_fast(x);
            assert_eq!(floor_parts(x), (f as usize, f), "{x}");
        }
    }

    #[test]
    fn expj_matches_sin_and_cos() {
        let mut worst = 0.0f64;
        for i in -20_000..=20_000 {
            let c = f64::from(i) * 0.000_173_1;
            let e = C64::expj(c);
            let a = 2.0 * core::f64::consts::PI * c;
            worst = worst
                .max(libm::fabs(e.re - libm::cos(a)))
                .max(libm::fabs(e.im - libm::sin(a)));
        }
        assert!(worst < 5e-7, "worst error {worst}");
    }
}
