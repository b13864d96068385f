//! The 4-20 mA loop, sample by sample: every station has its own modulator and
//! demodulator on one electrical model of the loop, so carrier detect, collisions and
//! a cable that is too long arise from the signal itself.
//!
//! # The electrical model
//!
//! ```text
//!   control room                      cable (R·L, C·L)                  field
//!  ┌──────────┐  node 0                                           node 1  ┌────────────┐
//!  │ supply + ├──────┬──────────┬────────/\/\/\/─────────┬─────────┬────┤ devices:   │
//!  │  R_loop  │      │ C_fixed  │ C·L/2     R_cable·L     │ C·L/2   │    │ current    │
//!  └──────────┘  master(s):     ┴                         ┴  N·C_dev ┴    │ sources    │
//!                voltage source                                          └────────────┘
//!                behind R_out
//! ```
//!
//! * The loop supply is a stiff voltage source, so for the signal the sense resistor
//!   `R_loop` ties node 0 (the control room) to ground.
//! * The cable is one π section: half its capacitance at each end, its resistance
//!   (both conductors) between. At HART's frequencies a cable of a few kilometres is
//!   electrically short (the diffusion length of an RC line at 2200 Hz is some
//!   200 km), so one section is accurate.
//! * Field devices, at node 1, transmit as current sources (1 mA peak to peak by
//!   default) and load the line with their capacitance; their analog 4-20 mA current
//!   flows through the cable and the sense resistor.
//! * Masters transmit as a voltage source behind an output resistance, connected (AC
//!   coupled) only while they transmit, as modems switch their output off when RTS
//!   drops; a primary master sits in the control room, a handheld in the field.
//! * Every receiver is high-impedance and hears the voltage at its node plus its own
//!   white noise, given as the rms it has in the 0.5-10 kHz band of the HART receive
//!   test filter (HCF_TOOL-31), so the figure is the one data sheets quote.
//!
//! The two node voltages are a linear system `C·dv/dt = -G·v + i`. It is discretised
//! exactly for inputs held over a sample (zero-order hold, closed-form 2×2 matrix
//! exponential), once per combination of transmitting masters, so any cable, however
//! short, is stable at any sample rate. The analog current is a second instance of the
//! same network (the masters' coupling capacitors keep it from their outputs), added
//! to the signal at every receiver and read by the control system's 10 Hz analog input;
//! the digital traffic's own share of that reading is how much HART disturbs the
//! 4-20 mA value.

use alloc::vec;
use alloc::vec::Vec;

use crate::channel::{AnalogInput, LoopModel, Rng};
use crate::demod::{DemodConfig, DemodEvent, Demodulator};
use crate::modulator::{Modulator, ModulatorConfig};
use hart_proto::deframer::UartFlags;

/// Where a station is connected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    /// Across the sense resistor in the control room (node 0).
    ControlRoom,
    /// At the field end of the cable, with the devices (node 1).
    Field,
}

/// How a station transmits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Drive {
    /// A master: a voltage source behind [`LineOptions::master_output_ohm`].
    Voltage,
    /// A field device: a current source of [`LineOptions::device_mapp`].
    Current,
}

/// Settings of an [`AnalogLine`] beyond the loop itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineOptions {
    /// Samples per second (8000 and up; 9600 is 8 per bit and plenty).
    pub sample_rate: u32,
    /// A master's open-circuit transmit level, volts peak to peak.
    pub master_vpp: f64,
    /// A master's output resistance while it transmits, Ω.
    pub master_output_ohm: f64,
    /// A device's transmit current, mA peak to peak (HART: 1 mA).
    pub device_mapp: f64,
    /// Noise at every receiver, mV rms in the 0.5-10 kHz band.
    pub noise_mv_rms: f64,
    /// Every receiver's carrier detect switches on at this level, volts peak to peak
    /// (off at 85 % of it). HART receivers must accept 120 mVpp and ignore 80 mVpp.
    pub carrier_on_vpp: f64,
    /// Seed of the noise.
    pub seed: u64,
}

impl Default for LineOptions {
    /// 9600 samples/s, masters 500 mVpp behind 50 Ω, devices 1 mApp, 2.2 mV rms of
    /// noise (the in-band figure usually quoted from HCF_SPEC-54), carrier detect on
    /// at 100 mVpp (the demodulator's default).
    fn default() -> Self {
        LineOptions {
            sample_rate: 9600,
            master_vpp: 0.5,
            master_output_ohm: 50.0,
            device_mapp: 1.0,
            noise_mv_rms: 2.2,
            carrier_on_vpp: 0.1,
            seed: 1,
        }
    }
}

/// A station on the line, as [`AnalogLine::add_port`] returns it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct PortId(pub usize);

/// What the line reports while it runs; times in µs since the line started.
#[derive(Debug, Clone, PartialEq)]
pub enum LineEvent {
    /// A port's demodulator read a character (its stop bit ended at about `t_us`).
    Char {
        /// The receiving port.
        port: PortId,
        /// The byte.
        byte: u8,
        /// Parity and framing errors.
        flags: UartFlags,
        /// When it is delivered.
        t_us: u64,
    },
    /// A port's carrier detect changed.
    Carrier {
        /// The receiving port.
        port: PortId,
        /// New state.
        on: bool,
        /// When.
        t_us: u64,
    },
    /// A port's demodulator found a whole frame with a good check byte.
    Frame {
        /// The receiving port.
        port: PortId,
        /// Delimiter through check byte.
        pdu: Vec<u8>,
        /// Its level, volts peak to peak.
        level_vpp: f64,
        /// When.
        t_us: u64,
    },
    /// A port's transmission ended (its last sample went out).
    TxDone {
        /// The transmitting port.
        port: PortId,
        /// When.
        t_us: u64,
    },
}

impl LineEvent {
    /// When the event happened, µs.
    pub fn t_us(&self) -> u64 {
        match self {
            LineEvent::Char { t_us, .. }
            | LineEvent::Carrier { t_us, .. }
            | LineEvent::Frame { t_us, .. }
            | LineEvent::TxDone { t_us, .. } => *t_us,
        }
    }
}

/// How much the digital traffic moved the control system's 10 Hz analog reading.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AnalogDisturbance {
    /// Mean absolute shift, µA.
    pub mean_ua: f64,
    /// Largest absolute shift, µA.
    pub peak_ua: f64,
}

/// The exact discretisation of the two-node network for one set of master loads.
#[derive(Debug, Clone, Copy)]
struct Step {
    /// Masters transmitting at node 0 and node 1.
    key: (u8, u8),
    ad: [[f64; 2]; 2],
    bd: [[f64; 2]; 2],
}

/// The two-node network: capacitances and fixed conductances.
#[derive(Debug, Clone, Copy)]
struct Network {
    c: [f64; 2],
    g0: f64,
    gc: f64,
    g_out: f64,
    h: f64,
}

impl Network {
    fn from_model(m: &LoopModel, o: &LineOptions) -> Self {
        let cable_c = m.cable_pf_per_m * m.cable_length_m * 1e-12;
        // A cable of no length still has its terminals: 1 mΩ keeps the system regular.
        let r_cable = (m.cable_ohm_per_m * m.cable_length_m).max(1e-3);
        Network {
            c: [
                m.fixed_capacitance_pf * 1e-12 + cable_c / 2.0,
                f64::from(m.devices) * m.device_capacitance_pf * 1e-12 + cable_c / 2.0,
            ]
            .map(|c| c.max(1e-12)),
            g0: 1.0 / m.loop_resistance_ohm,
            gc: 1.0 / r_cable,
            g_out: 1.0 / o.master_output_ohm.max(1e-3),
            h: 1.0 / (f64::from(o.sample_rate) * f64::from(OVERSAMPLE)),
        }
    }

    /// `x' = Ad·x + Bd·i` for `masters` transmitting at each node.
    fn step(&self, masters: (u8, u8)) -> Step {
        let g0 = self.g0 + f64::from(masters.0) * self.g_out;
        let g1 = f64::from(masters.1) * self.g_out;
        let gc = self.gc;
        let [c0, c1] = self.c;
        // A = -C⁻¹·G.
        let a = [[-(g0 + gc) / c0, gc / c0], [gc / c1, -(g1 + gc) / c1]];
        let det_g = g0 * g1 + gc * (g0 + g1);
        let det = det_g / (c0 * c1);
        let half = (a[0][0] + a[1][1]) / 2.0;
        let half_diff = (a[0][0] - a[1][1]) / 2.0;
        let disc = half_diff * half_diff + a[0][1] * a[1][0];
        let fast = half - libm::sqrt(disc);
        let slow = det / fast;
        let ad = if (slow - fast).abs() < 1e-12 * fast.abs() {
            // Repeated eigenvalue: e^{λh}(I + (A - λI)h).
            let e = libm::exp(slow * self.h);
            [
                [e * (1.0 + (a[0][0] - slow) * self.h), e * a[0][1] * self.h],
                [e * a[1][0] * self.h, e * (1.0 + (a[1][1] - slow) * self.h)],
            ]
        } else {
            // e^{Ah} = (e^{λ1 h}(A - λ2 I) - e^{λ2 h}(A - λ1 I)) / (λ1 - λ2).
            let (e1, e2) = (libm::exp(slow * self.h), libm::exp(fast * self.h));
            let d = slow - fast;
            let f = |i: usize, j: usize| {
                let id = if i == j { 1.0 } else { 0.0 };
                (e1 * (a[i][j] - fast * id) - e2 * (a[i][j] - slow * id)) / d
            };
            [[f(0, 0), f(0, 1)], [f(1, 0), f(1, 1)]]
        };
        // Bd = A⁻¹(Ad - I)C⁻¹ = -G⁻¹·C·(Ad - I)·C⁻¹.
        let g_inv = [
            [(g1 + gc) / det_g, gc / det_g],
            [gc / det_g, (g0 + gc) / det_g],
        ];
        let m = |i: usize, j: usize| {
            let id = if i == j { 1.0 } else { 0.0 };
            self.c[i] * (ad[i][j] - id) / self.c[j]
        };
        let cm = [[m(0, 0), m(0, 1)], [m(1, 0), m(1, 1)]];
        let bd = [
            [
                -(g_inv[0][0] * cm[0][0] + g_inv[0][1] * cm[1][0]),
                -(g_inv[0][0] * cm[0][1] + g_inv[0][1] * cm[1][1]),
            ],
            [
                -(g_inv[1][0] * cm[0][0] + g_inv[1][1] * cm[1][0]),
                -(g_inv[1][0] * cm[0][1] + g_inv[1][1] * cm[1][1]),
            ],
        ];
        Step {
            key: masters,
            ad,
            bd,
        }
    }

    /// The node voltages a constant current `i1` into node 1 settles to.
    fn dc(&self, i1: f64) -> [f64; 2] {
        let v0 = i1 / self.g0;
        [v0, v0 + i1 / self.gc]
    }
}

struct Port {
    place: Place,
    drive: Drive,
    modulator: Modulator,
    demod: Demodulator,
    rng: Rng,
    /// Samples still to send (volts for a master's source, amperes for a device).
    tx: Vec<f32>,
    /// Position in `tx`.
    tx_pos: usize,
    /// First sample of the transmission in progress (or the last one), at the
    /// network's rate.
    tx_start: u64,
    /// The sample after the last one of the last transmission, at the network's rate.
    tx_end: u64,
    /// Carrier as last reported.
    carrier: bool,
}

/// One electrical loop with stations on it, run sample by sample in virtual time.
/// Sans-IO: stations hand it bytes to send at a time, [`AnalogLine::advance`] runs
/// the signal forward and reports what every station's demodulator found.
pub struct AnalogLine {
    model: LoopModel,
    opts: LineOptions,
    net: Network,
    steps: Vec<Step>,
    analog_step: Step,
    ports: Vec<Port>,
    /// Node voltages of the digital signal and of the analog current.
    x: [f64; 2],
    xa: [f64; 2],
    /// Samples run so far.
    n: u64,
    sigma: f64,
    input: AnalogInput,
    disturbance_sum: f64,
    disturbance_peak: f64,
    disturbance_count: u64,
    node_buf: [Vec<f32>; 2],
    rx_buf: Vec<f32>,
}

impl core::fmt::Debug for AnalogLine {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("AnalogLine")
            .field("model", &self.model)
            .field("opts", &self.opts)
            .field("ports", &self.ports.len())
            .field("samples", &self.n)
            .finish()
    }
}

/// The network and the transmitters run this many times faster than the receivers
/// sample: held over a quarter of a receiver's sample, the tones lose at most 0.5 %
/// (sinc(2200 Hz / 38 400 Hz) at the default rate).
const OVERSAMPLE: u32 = 4;

/// Samples run per block inside [`AnalogLine::advance`] (at most): events are
/// delivered with at most this much delay on top of the demodulator's own.
const BLOCK: usize = 16;

impl AnalogLine {
    /// A loop as `model` describes it (loop resistance, cable, device capacitance, the
    /// analog current), with no stations yet.
    pub fn new(model: LoopModel, opts: LineOptions) -> Self {
        let net = Network::from_model(&model, &opts);
        // White noise of σ over 0..fs/2 has σ·sqrt(9500 / (fs/2)) in the 0.5-10 kHz
        // band; the noise is specified in that band.
        let fs = f64::from(opts.sample_rate);
        let sigma = opts.noise_mv_rms * 1e-3 * libm::sqrt((fs / 2.0) / 9500.0);
        let i0 = model.analog.current_ma(0.0) * 1e-3;
        let mut input = AnalogInput::new(opts.sample_rate * OVERSAMPLE, model.loop_resistance_ohm);
        input.settle(0.0);
        AnalogLine {
            steps: vec![net.step((0, 0))],
            analog_step: net.step((0, 0)),
            xa: net.dc(i0),
            x: [0.0; 2],
            net,
            model,
            opts,
            ports: vec![],
            n: 0,
            sigma,
            input,
            disturbance_sum: 0.0,
            disturbance_peak: 0.0,
            disturbance_count: 0,
            node_buf: [vec![], vec![]],
            rx_buf: vec![],
        }
    }

    /// The loop.
    pub fn model(&self) -> &LoopModel {
        &self.model
    }

    /// The options.
    pub fn options(&self) -> &LineOptions {
        &self.opts
    }

    /// Connects a station; its demodulator listens from now on.
    pub fn add_port(&mut self, place: Place, drive: Drive) -> PortId {
        let fs = self.opts.sample_rate;
        let mut mc = ModulatorConfig::new(fs * OVERSAMPLE);
        mc.amplitude_vpp = match drive {
            Drive::Voltage => self.opts.master_vpp,
            Drive::Current => self.opts.device_mapp * 1e-3,
        };
        let k = self.ports.len() as u64;
        self.ports.push(Port {
            place,
            drive,
            modulator: Modulator::new(mc),
            demod: Demodulator::new(DemodConfig {
                carrier_on_vpp: self.opts.carrier_on_vpp,
                carrier_off_vpp: self.opts.carrier_on_vpp * 0.85,
                ..DemodConfig::new(fs)
            }),
            rng: Rng::new(self.opts.seed ^ (k + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
            tx: vec![],
            tx_pos: 0,
            tx_start: 0,
            tx_end: 0,
            carrier: false,
        });
        PortId(self.ports.len() - 1)
    }

    /// Time of sample `n`, µs.
    fn us(&self, n: u64) -> u64 {
        n * 1_000_000 / u64::from(self.opts.sample_rate)
    }

    /// The first sample at or after `t_us`.
    fn sample_at(&self, t_us: u64) -> u64 {
        (t_us * u64::from(self.opts.sample_rate)).div_ceil(1_000_000)
    }

    /// Where the line is, µs.
    pub fn now_us(&self) -> u64 {
        self.us(self.n)
    }

    /// True while `port` is transmitting.
    pub fn transmitting(&self, port: PortId) -> bool {
        self.ports[port.0].tx_pos < self.ports[port.0].tx.len()
    }

    /// `port` sends `bytes` (preambles included) as one carrier burst starting at
    /// `t_us` (or now, if the line is past it). A port already transmitting queues it
    /// behind. Returns when the last sample will have gone out, µs.
    pub fn transmit(&mut self, port: PortId, bytes: &[u8], t_us: u64) -> u64 {
        let os = u64::from(OVERSAMPLE);
        let start = self.sample_at(t_us).max(self.n);
        let now_hi = self.n * os;
        let p = &mut self.ports[port.0];
        if p.tx_pos >= p.tx.len() {
            p.tx.clear();
            p.tx_pos = 0;
            p.tx_start = start * os;
            // Silence until the start.
            p.tx.resize(((start - self.n) * os) as usize, 0.0);
        }
        p.modulator.bytes(bytes.iter().copied(), |s| p.tx.push(s));
        let end = now_hi + (p.tx.len() - p.tx_pos) as u64;
        p.tx_end = end;
        end * 1_000_000 / (u64::from(self.opts.sample_rate) * os)
    }

    /// How much the digital traffic so far moved the 10 Hz analog reading (after the
    /// first 0.5 s, while the filter settles).
    pub fn analog_disturbance(&self) -> AnalogDisturbance {
        AnalogDisturbance {
            mean_ua: self.disturbance_sum / self.disturbance_count.max(1) as f64,
            peak_ua: self.disturbance_peak,
        }
    }

    fn step_for(&mut self, key: (u8, u8)) -> Step {
        match self.steps.iter().find(|s| s.key == key) {
            Some(s) => *s,
            None => {
                let s = self.net.step(key);
                self.steps.push(s);
                s
            }
        }
    }

    /// Runs the line up to `until_us` and reports, in time order, what every port's
    /// demodulator found and whose transmission ended. A port does not hear itself:
    /// what it receives while it transmits (and what started then) is dropped, as a
    /// half-duplex modem's receiver is while RTS is on.
    pub fn advance(&mut self, until_us: u64, mut on_event: impl FnMut(LineEvent)) {
        let end = self.sample_at(until_us);
        let mut events: Vec<LineEvent> = vec![];
        while self.n < end {
            let len = ((end - self.n) as usize).min(BLOCK);
            self.run_block(len, &mut events);
            events.sort_by_key(LineEvent::t_us);
            for e in events.drain(..) {
                on_event(e);
            }
        }
    }

    fn run_block(&mut self, len: usize, events: &mut Vec<LineEvent>) {
        let fs = f64::from(self.opts.sample_rate);
        let settle = u64::from(self.opts.sample_rate) / 2;
        for b in &mut self.node_buf {
            b.clear();
        }
        let a_step = self.analog_step;
        let os = u64::from(OVERSAMPLE);
        let fs_hi = fs * f64::from(OVERSAMPLE);
        for k in 0..len {
            for sub in 0..os {
                let n = (self.n + k as u64) * os + sub;
                // Sources of this sample.
                let mut masters = (0u8, 0u8);
                let mut inj = [0.0f64; 2];
                for p in &mut self.ports {
                    let Some(&s) = p.tx.get(p.tx_pos) else {
                        continue;
                    };
                    p.tx_pos += 1;
                    let node = match p.place {
                        Place::ControlRoom => 0,
                        Place::Field => 1,
                    };
                    match p.drive {
                        Drive::Current => inj[node] += f64::from(s),
                        Drive::Voltage => {
                            inj[node] += f64::from(s) * self.net.g_out;
                            if node == 0 {
                                masters.0 += 1;
                            } else {
                                masters.1 += 1;
                            }
                        }
                    }
                }
                let st = if masters == (0, 0) {
                    self.steps[0]
                } else {
                    self.step_for(masters)
                };
                self.x = apply(&st, self.x, inj);
                let ia = self.model.analog.current_ma(n as f64 / fs_hi) * 1e-3;
                self.xa = apply(&a_step, self.xa, [0.0, ia]);
                let reading = self.input.next(self.x[0]);
                if n >= settle * os {
                    let ua = libm::fabs(reading) * 1e3;
                    self.disturbance_sum += ua;
                    self.disturbance_count += 1;
                    self.disturbance_peak = self.disturbance_peak.max(ua);
                }
            }
            self.node_buf[0].push((self.x[0] + self.xa[0]) as f32);
            self.node_buf[1].push((self.x[1] + self.xa[1]) as f32);
        }
        let block_start = self.n;
        self.n += len as u64;
        let t_start = self.us(block_start);
        let t_end = self.us(self.n);
        let sigma = self.sigma;
        for (k, p) in self.ports.iter_mut().enumerate() {
            let port = PortId(k);
            let node = match p.place {
                Place::ControlRoom => 0,
                Place::Field => 1,
            };
            self.rx_buf.clear();
            self.rx_buf.extend_from_slice(&self.node_buf[node]);
            if sigma > 0.0 {
                crate::channel::add_white_noise(&mut self.rx_buf, sigma, &mut p.rng);
            }
            // Own transmission: from its first sample to a bit after its last.
            let own = (
                p.tx_start as f64 / fs_hi,
                p.tx_end as f64 / fs_hi + 1.0 / 1200.0,
            );
            let busy = p.tx_pos < p.tx.len();
            let clamp = |t: f64| ((t * 1e6) as u64).clamp(t_start, t_end);
            let carrier = &mut p.carrier;
            p.demod.push(&self.rx_buf, |e| match e {
                DemodEvent::Char(c) => {
                    if busy || (c.t >= own.0 && c.t < own.1) {
                        return;
                    }
                    events.push(LineEvent::Char {
                        port,
                        byte: c.byte,
                        flags: c.flags,
                        t_us: clamp(c.t + 11.0 / 1200.0),
                    });
                }
                DemodEvent::Carrier { on, t, .. } => {
                    if (busy && on) || *carrier == on {
                        return;
                    }
                    *carrier = on;
                    events.push(LineEvent::Carrier {
                        port,
                        on,
                        t_us: clamp(t),
                    });
                }
                DemodEvent::Frame(f) => {
                    if f.checksum_ok && !busy && !(f.t >= own.0 && f.t < own.1) {
                        events.push(LineEvent::Frame {
                            port,
                            pdu: f.pdu.to_vec(),
                            level_vpp: f.level_vpp,
                            t_us: clamp(f.t),
                        });
                    }
                }
            });
            if p.tx_pos >= p.tx.len() && !p.tx.is_empty() {
                p.tx.clear();
                p.tx_pos = 0;
                events.push(LineEvent::TxDone {
                    port,
                    t_us: clamp(p.tx_end as f64 / fs_hi),
                });
            }
        }
    }
}

fn apply(st: &Step, x: [f64; 2], i: [f64; 2]) -> [f64; 2] {
    [
        st.ad[0][0] * x[0] + st.ad[0][1] * x[1] + st.bd[0][0] * i[0] + st.bd[0][1] * i[1],
        st.ad[1][0] * x[0] + st.ad[1][1] * x[1] + st.bd[1][0] * i[0] + st.bd[1][1] * i[1],
    ]
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::channel::AnalogProfile;

    fn quiet() -> LineOptions {
        LineOptions {
            noise_mv_rms: 0.0,
            ..LineOptions::default()
        }
    }

    /// A tone current into the field node: its amplitude at the control room against
    /// the sense resistor alone (rms over the second half of a second).
    fn gain(model: LoopModel, hz: f64) -> f64 {
        let opts = quiet();
        let net = Network::from_model(&model, &opts);
        let st = net.step((0, 0));
        let mut x = [0.0; 2];
        let fs = f64::from(opts.sample_rate * OVERSAMPLE);
        let i = |n: usize| libm::sin(2.0 * core::f64::consts::PI * hz * n as f64 / fs) * 1e-3;
        let (mut sum, mut count) = (0.0, 0);
        for n in 0..(fs as usize) {
            x = apply(&st, x, [0.0, i(n)]);
            if n > fs as usize / 2 {
                sum += x[0] * x[0];
                count += 1;
            }
        }
        libm::sqrt(2.0 * sum / f64::from(count)) / (1e-3 * model.loop_resistance_ohm)
    }

    /// The same, from the π network's impedances.
    fn gain_exact(m: LoopModel, hz: f64) -> f64 {
        // Complex arithmetic on (re, im) pairs.
        type C = (f64, f64);
        let mul = |a: C, b: C| (a.0 * b.0 - a.1 * b.1, a.0 * b.1 + a.1 * b.0);
        let inv = |a: C| {
            let d = a.0 * a.0 + a.1 * a.1;
            (a.0 / d, -a.1 / d)
        };
        let add = |a: C, b: C| (a.0 + b.0, a.1 + b.1);
        let w = 2.0 * core::f64::consts::PI * hz;
        let cable = m.cable_pf_per_m * m.cable_length_m * 1e-12;
        let c0 = m.fixed_capacitance_pf * 1e-12 + cable / 2.0;
        let c1 = f64::from(m.devices) * m.device_capacitance_pf * 1e-12 + cable / 2.0;
        let rc = (m.cable_ohm_per_m * m.cable_length_m).max(1e-3);
        let z0 = inv((1.0 / m.loop_resistance_ohm, w * c0));
        let z1 = inv((0.0, w * c1));
        // V0 = I · z1 / (z1 + rc + z0) · z0.
        let v0 = mul(mul(z1, inv(add(add(z1, (rc, 0.0)), z0))), z0);
        libm::sqrt(v0.0 * v0.0 + v0.1 * v0.1) / m.loop_resistance_ohm
    }

    #[test]
    fn a_short_loop_is_the_sense_resistor() {
        let m = LoopModel::default();
        assert!((gain(m, 1200.0) - 1.0).abs() < 0.03, "{}", gain(m, 1200.0));
    }

    #[test]
    fn the_network_is_the_pi_section_at_both_tones() {
        for (length, pf, devices) in [(0.0, 100.0, 1), (2000.0, 100.0, 10), (5000.0, 225.0, 15)] {
            let m = LoopModel {
                cable_length_m: length,
                cable_pf_per_m: pf,
                devices,
                ..LoopModel::default()
            };
            for hz in [1200.0, 2200.0] {
                let (got, want) = (gain(m, hz), gain_exact(m, hz));
                assert!(
                    (got / want - 1.0).abs() < 0.015,
                    "{length} m, {hz} Hz: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn the_rc_rule_is_the_pessimistic_side_of_the_network() {
        // The rule lumps every capacitance behind all the resistance; the network's
        // field capacitance sits behind the cable only, so it passes more.
        let m = LoopModel {
            cable_length_m: 2000.0,
            devices: 10,
            ..LoopModel::default()
        };
        let w = 2.0 * core::f64::consts::PI * 2200.0;
        let tau = m.time_constant_s();
        let rule = 1.0 / libm::sqrt(1.0 + (w * tau) * (w * tau));
        let got = gain_exact(m, 2200.0);
        assert!(got > rule && got < rule * 1.15, "{got} vs {rule}");
    }

    #[test]
    fn dc_settles_where_ohm_says() {
        let m = LoopModel {
            cable_length_m: 1000.0,
            ..LoopModel::default()
        };
        let line = AnalogLine::new(m, quiet());
        let v = line.xa;
        assert!((v[0] - 3.0).abs() < 1e-9);
        assert!((v[1] - 0.012 * (250.0 + 36.0)).abs() < 1e-9);
        let st = line.analog_step;
        let next = apply(&st, v, [0.0, 0.012]);
        assert!((next[0] - v[0]).abs() < 1e-9 && (next[1] - v[1]).abs() < 1e-9);
    }

    fn exchange(model: LoopModel, opts: LineOptions) -> (usize, usize) {
        let mut line = AnalogLine::new(model, opts);
        let master = line.add_port(Place::ControlRoom, Drive::Voltage);
        let dev = line.add_port(Place::Field, Drive::Current);
        let req = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02, 0x80, 0x00, 0x00, 0x82];
        let rep = [
            0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x06, 0x80, 0x00, 0x02, 0x00, 0x00, 0x84,
        ];
        let (mut at_dev, mut at_master) = (0, 0);
        let mut t = 10_000;
        for _ in 0..20 {
            let end = line.transmit(master, &req, t);
            line.advance(end + 30_000, |e| {
                if let LineEvent::Frame { port, pdu, .. } = e {
                    if port == dev && pdu == req[5..] {
                        at_dev += 1;
                    }
                }
            });
            let end = line.transmit(dev, &rep, line.now_us());
            line.advance(end + 30_000, |e| {
                if let LineEvent::Frame { port, pdu, .. } = e {
                    if port == master && pdu == rep[5..] {
                        at_master += 1;
                    }
                }
            });
            t = line.now_us();
        }
        (at_dev, at_master)
    }

    #[test]
    fn a_master_and_a_device_understand_each_other() {
        let m = LoopModel {
            cable_length_m: 1000.0,
            analog: AnalogProfile::Sweep {
                low_ma: 4.0,
                high_ma: 20.0,
                hz: 1.0,
            },
            ..LoopModel::default()
        };
        assert_eq!(exchange(m, LineOptions::default()), (20, 20));
    }

    #[test]
    fn too_long_a_cable_silences_the_device() {
        // 5 km of 225 pF/m: the master's voltage still reaches the field, but the
        // device's 1 mApp reaches the control room below carrier detect.
        let m = LoopModel {
            cable_length_m: 5_000.0,
            cable_pf_per_m: 225.0,
            ..LoopModel::default()
        };
        let (at_dev, at_master) = exchange(m, LineOptions::default());
        assert_eq!(at_dev, 20, "the master's voltage still reaches the field");
        assert_eq!(at_master, 0);
    }

    fn frames_heard(line: &mut AnalogLine, until: u64) -> (Vec<PortId>, Vec<PortId>) {
        let mut frames = std::vec::Vec::new();
        let mut done = std::vec::Vec::new();
        line.advance(until, |e| match e {
            LineEvent::Frame { port, .. } => frames.push(port),
            LineEvent::TxDone { port, .. } => done.push(port),
            _ => {}
        });
        (frames, done)
    }

    #[test]
    fn two_devices_talking_at_once_are_heard_by_nobody() {
        let mut line = AnalogLine::new(LoopModel::default(), quiet());
        let m = line.add_port(Place::ControlRoom, Drive::Voltage);
        let a = line.add_port(Place::Field, Drive::Current);
        let b = line.add_port(Place::Field, Drive::Current);
        let c = line.add_port(Place::Field, Drive::Current);
        let fa = [0xFF, 0xFF, 0xFF, 0x06, 0x81, 0x03, 0x02, 0x00, 0x00, 0x86];
        let fb = [0xFF, 0xFF, 0xFF, 0x06, 0x82, 0x03, 0x02, 0x00, 0x00, 0x85];
        line.transmit(a, &fa, 0);
        let end = line.transmit(b, &fb, 15_000);
        let (frames, done) = frames_heard(&mut line, end + 50_000);
        assert!(frames.is_empty(), "decoded out of a collision: {frames:?}");
        assert_eq!(done, [a, b]);
        let _ = (m, c);
    }

    #[test]
    fn a_master_talking_over_a_device_wins_in_the_field() {
        // A device answering late, into the master's next request: the master's
        // low-impedance source swamps the device's current (the capture effect of
        // HART's mixed drives), so the other device still decodes the request.
        let mut line = AnalogLine::new(LoopModel::default(), quiet());
        let m = line.add_port(Place::ControlRoom, Drive::Voltage);
        let a = line.add_port(Place::Field, Drive::Current);
        let b = line.add_port(Place::Field, Drive::Current);
        let req = [0xFF, 0xFF, 0xFF, 0x02, 0x82, 0x03, 0x00, 0x83];
        let rep = [0xFF, 0xFF, 0xFF, 0x06, 0x81, 0x03, 0x02, 0x00, 0x00, 0x86];
        let end = line.transmit(m, &req, 0);
        line.transmit(a, &rep, 30_000);
        let (frames, _) = frames_heard(&mut line, end + 50_000);
        assert_eq!(frames, [b]);
    }

    #[test]
    fn digital_traffic_barely_moves_the_analog_reading() {
        let mut line = AnalogLine::new(LoopModel::default(), quiet());
        let m = line.add_port(Place::ControlRoom, Drive::Voltage);
        let d = line.add_port(Place::Field, Drive::Current);
        let bytes: Vec<u8> = (0..40u8).map(|b| b.wrapping_mul(37)).collect();
        for k in 0..20 {
            let who = if k % 2 == 0 { m } else { d };
            let end = line.transmit(who, &bytes, line.now_us());
            line.advance(end + 10_000, |_| {});
        }
        let dist = line.analog_disturbance();
        std::println!("{dist:?}");
        assert!(dist.mean_ua < 10.0 && dist.peak_ua < 50.0, "{dist:?}");
    }
}
