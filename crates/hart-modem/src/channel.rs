//! The channel between a HART transmitter and receiver: white noise at a given Eb/N0,
//! interfering tones, the network's RC low-pass, and the 4-20 mA analog signal with its
//! 10 Hz reading.
//!
//! Everything works in place on buffers of volts at a sample rate `fs`. Noise comes
//! from [`Rng`], a small seeded generator, so every run is repeatable.

use core::f64::consts::PI;

/// The seeded generator of the noise: hartkit's one generator ([`hart_rng::Rng`],
/// xoshiro256** seeded through splitmix64), here so that the channel's functions and
/// their callers name it where they use it.
pub use hart_rng::Rng;

/// Noise standard deviation (volts) that gives `ebn0_db` for a tone of `peak_volts` at
/// sample rate `fs`: Eb = A²/2·Tb and N0 = 2σ²/fs, so σ = A·sqrt(fs / (4·1200·Eb/N0)).
pub fn sigma_for_ebn0(peak_volts: f64, fs: f64, ebn0_db: f64) -> f64 {
    let ebn0 = libm::pow(10.0, ebn0_db / 10.0);
    peak_volts * libm::sqrt(fs / (4.0 * crate::BIT_RATE * ebn0))
}

/// Adds white Gaussian noise of standard deviation `sigma` volts.
pub fn add_white_noise(samples: &mut [f32], sigma: f64, rng: &mut Rng) {
    for x in samples.iter_mut() {
        *x += (sigma * rng.gaussian()) as f32;
    }
}

/// Adds a sine of `freq_hz` and `vpp` volts peak-to-peak, starting at `phase` cycles.
pub fn add_tone(samples: &mut [f32], fs: u32, freq_hz: f64, vpp: f64, phase: f64) {
    let w = 2.0 * PI * freq_hz / f64::from(fs);
    let (mut re, mut im) = (libm::cos(2.0 * PI * phase), libm::sin(2.0 * PI * phase));
    let (cr, ci) = (libm::cos(w), libm::sin(w));
    for (i, x) in samples.iter_mut().enumerate() {
        *x += (vpp / 2.0 * im) as f32;
        let r = re * cr - im * ci;
        im = re * ci + im * cr;
        re = r;
        if i % 4096 == 4095 {
            // Keep the oscillator on the unit circle.
            let n = libm::sqrt(re * re + im * im);
            re /= n;
            im /= n;
        }
    }
}

/// A single-pole RC low-pass of time constant `tau_s`: the network's loop resistance
/// against cable and device capacitance. Discretised by impulse invariance
/// (y += (1 - e^(-1/(fs·τ)))·(x - y)), stable at every rate.
pub fn rc_lowpass(samples: &mut [f32], fs: u32, tau_s: f64) {
    if tau_s <= 0.0 {
        return;
    }
    let a = 1.0 - libm::exp(-1.0 / (f64::from(fs) * tau_s));
    let mut y = 0.0f64;
    for x in samples.iter_mut() {
        y += a * (f64::from(*x) - y);
        *x = y as f32;
    }
}

/// The analog loop current as a function of time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AnalogProfile {
    /// A constant current, mA.
    Constant(f64),
    /// A sinusoidal sweep between two currents (mA) at a frequency (Hz): full swing
    /// 4 ↔ 20 mA at 10 or 18 Hz is the receiver test's worst case.
    Sweep {
        /// Lowest current, mA.
        low_ma: f64,
        /// Highest current, mA.
        high_ma: f64,
        /// Sweep frequency, Hz.
        hz: f64,
    },
}

impl AnalogProfile {
    /// The current at time `t` seconds, mA.
    pub fn current_ma(&self, t: f64) -> f64 {
        match *self {
            AnalogProfile::Constant(ma) => ma,
            AnalogProfile::Sweep {
                low_ma,
                high_ma,
                hz,
            } => (low_ma + high_ma) / 2.0 + (high_ma - low_ma) / 2.0 * libm::sin(2.0 * PI * hz * t),
        }
    }

    /// Adds the voltage this current develops across `r_ohm` to `samples`.
    pub fn add_volts(&self, samples: &mut [f32], fs: u32, r_ohm: f64) {
        for (i, x) in samples.iter_mut().enumerate() {
            *x += (self.current_ma(i as f64 / f64::from(fs)) * 1e-3 * r_ohm) as f32;
        }
    }
}

/// A 4-20 mA loop: the sense resistor, the cable and the devices on it, and the analog
/// current. Turns a device's FSK current (or a master's voltage) into the voltage a
/// receiver across the resistor sees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopModel {
    /// Loop (sense) resistance, Ω (230-1100).
    pub loop_resistance_ohm: f64,
    /// Cable length, m.
    pub cable_length_m: f64,
    /// Cable capacitance, pF per metre.
    pub cable_pf_per_m: f64,
    /// Cable resistance (both conductors), Ω per metre.
    pub cable_ohm_per_m: f64,
    /// Devices on the loop.
    pub devices: u32,
    /// Capacitance of each device, pF.
    pub device_capacitance_pf: f64,
    /// Capacitance of the master and receiver, pF.
    pub fixed_capacitance_pf: f64,
    /// The analog current.
    pub analog: AnalogProfile,
}

impl Default for LoopModel {
    /// 250 Ω, no cable, one device, 12 mA, capacitances as in [`crate::cable::CableParams`].
    fn default() -> Self {
        let c = crate::cable::CableParams::default();
        LoopModel {
            loop_resistance_ohm: c.loop_resistance_ohm,
            cable_length_m: 0.0,
            cable_pf_per_m: 100.0,
            cable_ohm_per_m: c.cable_ohm_per_m,
            devices: 1,
            device_capacitance_pf: c.device_capacitance_pf,
            fixed_capacitance_pf: c.fixed_capacitance_pf,
            analog: AnalogProfile::Constant(12.0),
        }
    }
}

impl LoopModel {
    /// The network's RC time constant, seconds.
    pub fn time_constant_s(&self) -> f64 {
        let p = crate::cable::CableParams {
            loop_resistance_ohm: self.loop_resistance_ohm,
            cable_ohm_per_m: self.cable_ohm_per_m,
            device_capacitance_pf: self.device_capacitance_pf,
            fixed_capacitance_pf: self.fixed_capacitance_pf,
            rc_limit_s: 65e-6,
        };
        crate::cable::time_constant_s(self.cable_length_m, self.cable_pf_per_m, self.devices, &p)
    }

    /// A device transmitting: `current_ma` (its FSK current, mA, in place) becomes the
    /// voltage across the loop resistor, low-passed by the network's RC, with the analog
    /// current's voltage added.
    pub fn device_to_receiver(&self, current_ma: &mut [f32], fs: u32) {
        let r = self.loop_resistance_ohm;
        for x in current_ma.iter_mut() {
            *x = (f64::from(*x) * 1e-3 * r) as f32;
        }
        rc_lowpass(current_ma, fs, self.time_constant_s());
        self.analog.add_volts(current_ma, fs, r);
    }
}

/// A 4-20 mA analog input: volts across the sense resistor through a 10 Hz
/// second-order Butterworth low-pass (bilinear, pre-warped), read sample by sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnalogInput {
    b0: f64,
    a1: f64,
    a2: f64,
    z1: f64,
    z2: f64,
    ma_per_volt: f64,
}

impl AnalogInput {
    /// An input across `r_ohm` sampled at `fs`.
    pub fn new(fs: u32, r_ohm: f64) -> Self {
        let k = libm::tan(PI * 10.0 / f64::from(fs));
        let q = core::f64::consts::FRAC_1_SQRT_2;
        let norm = 1.0 / (1.0 + k / q + k * k);
        AnalogInput {
            b0: k * k * norm,
            a1: 2.0 * (k * k - 1.0) * norm,
            a2: (1.0 - k / q + k * k) * norm,
            z1: 0.0,
            z2: 0.0,
            ma_per_volt: 1e3 / r_ohm,
        }
    }

    /// Starts settled at `ma` (as if that current had flowed for ever).
    pub fn settle(&mut self, ma: f64) {
        // Steady state of the transposed direct form II for a constant input x = y.
        self.z1 = ma - self.b0 * ma;
        self.z2 = self.b0 * ma - self.a2 * ma;
    }

    /// The next sample (volts across the resistor); returns the reading in mA.
    pub fn next(&mut self, volts: f64) -> f64 {
        let x = volts * self.ma_per_volt;
        let y = self.b0 * x + self.z1;
        self.z1 = 2.0 * self.b0 * x - self.a1 * y + self.z2;
        self.z2 = self.b0 * x - self.a2 * y;
        y
    }
}

/// Reads the analog current the way a 4-20 mA input does ([`AnalogInput`]). Returns mA
/// per sample.
#[cfg(feature = "alloc")]
pub fn analog_reading_ma(volts: &[f32], fs: u32, r_ohm: f64) -> alloc::vec::Vec<f64> {
    let mut input = AnalogInput::new(fs, r_ohm);
    volts.iter().map(|&v| input.next(f64::from(v))).collect()
}

/// How much an FSK signal (volts across `r_ohm`, e.g. a modem's output) shifts the
/// 10 Hz analog reading: (mean, largest) absolute difference in µA against no FSK,
/// after the filter has settled (the first 0.5 s are skipped). HART asks that the FSK
/// averages to zero, so a correct modulator shifts the reading by a few µA at most.
#[cfg(feature = "alloc")]
pub fn analog_shift_ua(fsk_volts: &[f32], fs: u32, r_ohm: f64) -> (f64, f64) {
    let reading = analog_reading_ma(fsk_volts, fs, r_ohm);
    let skip = (fs / 2) as usize;
    let tail = reading.get(skip..).unwrap_or(&[]);
    if tail.is_empty() {
        return (0.0, 0.0);
    }
    let mean = tail.iter().map(|m| libm::fabs(*m)).sum::<f64>() / tail.len() as f64;
    let peak = tail.iter().fold(0.0f64, |a, m| a.max(libm::fabs(*m)));
    (mean * 1e3, peak * 1e3)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::modulator::{Modulator, ModulatorConfig};
    use alloc::vec::Vec;

    #[test]
    fn noise_has_the_asked_for_power() {
        let mut rng = Rng::new(7);
        let mut s = alloc::vec![0.0f32; 200_000];
        let sigma = sigma_for_ebn0(0.25, 48000.0, 10.0);
        add_white_noise(&mut s, sigma, &mut rng);
        let var = s.iter().map(|&x| f64::from(x) * f64::from(x)).sum::<f64>() / s.len() as f64;
        assert!((libm::sqrt(var) / sigma - 1.0).abs() < 0.01);
        // σ = 0.25 · sqrt(48000 / (4 · 1200 · 10)) = 0.25
        assert!((sigma - 0.25).abs() < 1e-12);
    }

    #[test]
    fn rc_corner_is_where_it_should_be() {
        // At f = 1/(2πτ) a single pole passes 1/√2.
        let fs = 48000;
        let tau = 65e-6;
        let f = 1.0 / (2.0 * PI * tau);
        let mut s = alloc::vec![0.0f32; 48000];
        add_tone(&mut s, fs, f, 2.0, 0.0);
        rc_lowpass(&mut s, fs, tau);
        let peak = s[24000..].iter().fold(0f32, |a, x| a.max(x.abs()));
        assert!(
            (f64::from(peak) - core::f64::consts::FRAC_1_SQRT_2).abs() < 0.01,
            "{peak}"
        );
    }

    #[test]
    fn a_loop_turns_device_current_into_volts() {
        // 1 mA peak-to-peak at 1200 Hz, 250 Ω, no cable: 250 mVpp on 3 V (12 mA).
        let fs = 48000;
        let mut s = alloc::vec![0.0f32; 48000];
        add_tone(&mut s, fs, 1200.0, 1.0, 0.0);
        let lp = LoopModel::default();
        assert!((lp.time_constant_s() - 250.0 * 12_500e-12).abs() < 1e-12);
        lp.device_to_receiver(&mut s, fs);
        let (lo, hi) = s[24000..]
            .iter()
            .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        assert!((f64::from(hi - lo) - 0.25).abs() < 0.005, "{}", hi - lo);
        assert!((f64::from(hi + lo) / 2.0 - 3.0).abs() < 0.005);
        // The 10 Hz reading gives the 12 mA back.
        let ma = analog_reading_ma(&s, fs, 250.0);
        assert!((ma[47_999] - 12.0).abs() < 0.01, "{}", ma[47_999]);
    }

    #[test]
    fn a_phase_continuous_fsk_signal_barely_moves_the_analog_reading() {
        // A device's 1 mApp signal across 250 Ω, two seconds of back-to-back frames.
        let fs = 48000;
        let mut cfg = ModulatorConfig::new(fs);
        cfg.amplitude_vpp = 0.25; // 1 mA peak-to-peak across 250 Ω
        let mut m = Modulator::new(cfg);
        let mut s = Vec::new();
        let mut rng = Rng::new(3);
        while s.len() < 2 * fs as usize {
            let bytes: Vec<u8> = (0..30).map(|_| rng.next_u64() as u8).collect();
            m.frame(5, &bytes, |x| s.push(x));
            m.silence(0.005, |x| s.push(x));
        }
        let (mean, peak) = analog_shift_ua(&s, fs, 250.0);
        std::println!(
            "FSK shifts the 10 Hz reading by {mean:.2} µA on average, {peak:.2} µA at most"
        );
        assert!(mean < 5.0 && peak < 20.0, "{mean} {peak}");
    }
}

/// A channel applied to a stream of samples block by block, with its state carried
/// across blocks (the RC filter's output, the hum's phase, the noise generator): the
/// same result whatever the block sizes. `hartkit modem channel` runs one between
/// `modem tx` and `modem rx` in a pipe.
#[derive(Debug, Clone)]
pub struct StreamChannel {
    fs: u32,
    sigma: f64,
    rc_a: Option<f64>,
    rc_y: f64,
    hum: Option<(f64, f64)>,
    hum_phase: f64,
    rng: Rng,
    /// The 4-20 mA current and the resistance it develops its voltage across.
    analog: Option<(AnalogProfile, f64)>,
    /// Samples processed so far (the analog current's clock).
    n: u64,
}

impl StreamChannel {
    /// A channel at sample rate `fs`: white noise of `sigma` volts (0: none), an RC
    /// low-pass of `tau_s` seconds (0: none), a hum of `hum_hz` at `hum_vpp` volts peak
    /// to peak (0 Hz: none); `seed` for the noise.
    pub fn new(fs: u32, sigma: f64, tau_s: f64, hum_hz: f64, hum_vpp: f64, seed: u64) -> Self {
        StreamChannel {
            fs,
            sigma,
            rc_a: (tau_s > 0.0).then(|| 1.0 - libm::exp(-1.0 / (f64::from(fs) * tau_s))),
            rc_y: 0.0,
            hum: (hum_hz > 0.0 && hum_vpp > 0.0).then_some((hum_hz, hum_vpp)),
            hum_phase: 0.0,
            rng: Rng::new(seed),
            analog: None,
            n: 0,
        }
    }

    /// Adds the 4-20 mA current's voltage across `r_ohm` (the sense resistor a
    /// receiver across the loop sees) to the stream.
    pub fn with_analog(mut self, profile: AnalogProfile, r_ohm: f64) -> Self {
        self.analog = Some((profile, r_ohm));
        self
    }

    /// The noise sigma that gives `snr_db` against a sine of `signal_vpp` volts peak to
    /// peak (signal power (Vpp/2)²/2 over noise power σ²).
    pub fn sigma_for_snr(signal_vpp: f64, snr_db: f64) -> f64 {
        let a = signal_vpp / 2.0;
        libm::sqrt(a * a / 2.0 / libm::pow(10.0, snr_db / 10.0))
    }

    /// Applies the channel to the next block, in place: the cable's low-pass on the
    /// signal, then the analog current's voltage, the hum and the noise picked up at
    /// the receiver.
    pub fn process(&mut self, samples: &mut [f32]) {
        if let Some(a) = self.rc_a {
            for x in samples.iter_mut() {
                self.rc_y += a * (f64::from(*x) - self.rc_y);
                *x = self.rc_y as f32;
            }
        }
        if let Some((profile, r)) = self.analog {
            let fs = f64::from(self.fs);
            for (i, x) in samples.iter_mut().enumerate() {
                let t = (self.n + i as u64) as f64 / fs;
                *x += (profile.current_ma(t) * 1e-3 * r) as f32;
            }
        }
        self.n += samples.len() as u64;
        if let Some((hz, vpp)) = self.hum {
            add_tone(samples, self.fs, hz, vpp, self.hum_phase);
            let p = self.hum_phase + hz * samples.len() as f64 / f64::from(self.fs);
            self.hum_phase = p - libm::floor(p);
        }
        if self.sigma > 0.0 {
            add_white_noise(samples, self.sigma, &mut self.rng);
        }
    }
}

#[cfg(test)]
mod stream_tests {
    use super::*;

    /// The same input in one block or in blocks of any size gives the same output
    /// (the state crosses the block boundaries).
    #[test]
    fn blocks_do_not_matter() {
        let input: alloc::vec::Vec<f32> = (0..10_000)
            .map(|i| libm::sinf(i as f32 * 0.157) * 0.25)
            .collect();
        let mut whole = input.clone();
        let analog = AnalogProfile::Sweep {
            low_ma: 4.0,
            high_ma: 20.0,
            hz: 10.0,
        };
        StreamChannel::new(48_000, 0.01, 65e-6, 50.0, 0.1, 7)
            .with_analog(analog, 250.0)
            .process(&mut whole);
        let mut parts = input.clone();
        let mut c =
            StreamChannel::new(48_000, 0.01, 65e-6, 50.0, 0.1, 7).with_analog(analog, 250.0);
        for chunk in parts.chunks_mut(997) {
            c.process(chunk);
        }
        for (a, b) in whole.iter().zip(&parts) {
            assert!((a - b).abs() < 1e-4, "{a} {b}");
        }
    }

    #[test]
    fn snr_sigma() {
        // 0 dB against a 2 Vpp sine (power 0.5): sigma² = 0.5.
        let s = StreamChannel::sigma_for_snr(2.0, 0.0);
        assert!((s * s - 0.5).abs() < 1e-12);
    }
}
