//! The field device: process model, status, and every command handler.
//!
//! A [`Device`] is a [`hart_link::Handler`]: put it behind a [`hart_link::Slave`] on a
//! simulated line, a serial port or (later) HART-IP. Time is injected: every request
//! and [`Device::tick`] carry "now" in microseconds, which drives the process values,
//! damping, the valve travel, burst triggers and delayed responses.

use hart_link::slave::{Handler, Reply};
use hart_link::Micros;
use hart_proto::command::{self as cmd, Request};
use hart_proto::frame::{Frame, MasterKind, UniqueId};
use hart_proto::tables::rc;
use hart_proto::types::*;
use hart_proto::wire::{List, Reader, Wire, Writer};

use crate::burst::{self, BurstRuntime};
use crate::config::{DeviceConfig, DeviceKind, Waveform};
use crate::units;

/// Lowest loop current in normal operation (saturation), mA.
pub const SATURATION_LOW: f32 = 3.8;
/// Highest loop current in normal operation (saturation), mA.
pub const SATURATION_HIGH: f32 = 20.5;
/// Alarm current for "high" alarm selection, mA.
pub const ALARM_HIGH: f32 = 21.75;
/// Alarm current for "low" alarm selection, mA.
pub const ALARM_LOW: f32 = 3.6;
/// How long the delayed response of command 41 (self test) takes.
pub const SELF_TEST_DURATION: Micros = 5_000_000;
/// Step of the process model.
pub const TICK: Micros = 10_000;
/// How long a finished delayed response is kept for the master to collect it.
pub const DELAYED_RESULT_KEPT: Micros = 30_000_000;

/// Status bits a device keeps per master (HART 7 keeps these for each master).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
struct MasterFlags {
    config_changed: bool,
    cold_start: bool,
    /// Command 48 bytes 0-8 this master acknowledged last.
    acked48: [u8; 9],
}

/// A command 79 simulation of a device variable.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Simulation {
    units: u8,
    value: f32,
    status: u8,
}

#[derive(Debug, Clone, PartialEq)]
struct Delayed {
    command: u16,
    data: Vec<u8>,
    done_at: Micros,
    dead: bool,
}

/// Result of a command handler.
enum Outcome {
    /// Reply with this response code and data.
    Reply(u8, Vec<u8>),
    /// No reply at all (e.g. command 11 with another tag).
    Silent,
}

fn ok(data: Vec<u8>) -> Outcome {
    Outcome::Reply(rc::SUCCESS, data)
}

fn err(code: u8) -> Outcome {
    Outcome::Reply(code, vec![])
}

fn encode(v: &impl Wire) -> Vec<u8> {
    let mut buf = vec![0u8; v.encoded_len()];
    let mut w = Writer::new(&mut buf);
    let _ = v.encode(&mut w);
    buf
}

/// The device variable codes a burst message's slots select for command 9 (`N` = 8)
/// or 33 (`N` = 4): up to the first unused slot (250), device variable 0 when none.
fn burst_slots<const N: usize>(slots: &[u8]) -> List<DeviceVariableCode, N, 1> {
    let mut list = List::default();
    for &c in slots.iter().take(N).take_while(|&&c| c != 250) {
        let _ = list.push(DeviceVariableCode(c));
    }
    if list.is_empty() {
        let _ = list.push(DeviceVariableCode(0));
    }
    list
}

fn master_index(m: MasterKind) -> usize {
    match m {
        MasterKind::Primary => 0,
        MasterKind::Secondary => 1,
    }
}

/// Legal burst periods below one minute, in seconds.
const SHORT_PERIODS: [f32; 7] = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0];

/// A simulated HART 7 field device.
pub struct Device {
    cfg: DeviceConfig,
    write_protect: bool,
    last_tick: Option<Micros>,
    filtered: Vec<f32>,
    walk: Vec<f32>,
    walk_next: Vec<Micros>,
    /// The random walks' generator, seeded from the device ID.
    rng: hart_rng::Rng,
    simulated: Vec<Option<Simulation>>,
    fixed_current: Option<f32>,
    malfunction: bool,
    masters: [MasterFlags; 2],
    stx_count: u16,
    ack_count: u16,
    back_count: u16,
    burst: Vec<BurstRuntime>,
    delayed: Option<Delayed>,
    travel: f32,
    dirty: bool,
    reset_pending: bool,
    /// The master whose address bit the next BACK carries.
    burst_to: MasterKind,
    /// Faults the device commits on purpose ([`crate::faults`]).
    faults: crate::faults::Faults,
}

impl Device {
    /// A device powered up with `cfg` (cold start set for both masters).
    pub fn new(mut cfg: DeviceConfig) -> Self {
        cfg.normalise();
        let n = cfg.variables.len();
        let walk: Vec<f32> = cfg
            .variables
            .iter()
            .map(|v| match v.waveform {
                Waveform::RandomWalk { start, .. } => start,
                _ => 0.0,
            })
            .collect();
        let rng = hart_rng::Rng::new(u64::from(cfg.identity.device_id));
        let travel = cfg.valve.digital_setpoint;
        let burst = vec![BurstRuntime::default(); cfg.burst.len()];
        let mut d = Device {
            cfg,
            write_protect: false,
            last_tick: None,
            filtered: vec![0.0; n],
            walk,
            walk_next: vec![0; n],
            rng,
            simulated: vec![None; n],
            fixed_current: None,
            malfunction: false,
            masters: [MasterFlags {
                cold_start: true,
                ..MasterFlags::default()
            }; 2],
            stx_count: 0,
            ack_count: 0,
            back_count: 0,
            burst,
            delayed: None,
            travel,
            dirty: false,
            reset_pending: false,
            burst_to: MasterKind::Primary,
            faults: crate::faults::Faults::NONE,
        };
        // Start every filter at its input, as a device that has been running.
        for i in 0..n {
            d.filtered[i] = d.raw_value(i, 0);
        }
        d
    }

    /// The configuration (what the state file keeps).
    pub fn config(&self) -> &DeviceConfig {
        &self.cfg
    }

    /// The unique ID used in long frames.
    pub fn unique_id(&self) -> UniqueId {
        UniqueId::new(
            self.cfg.identity.expanded_device_type,
            self.cfg.identity.device_id,
        )
    }

    /// Makes the device commit `faults` (those of the application layer: missing
    /// response code 5, command 38 not resetting, burst period off).
    pub fn set_faults(&mut self, faults: crate::faults::Faults) {
        self.faults = faults;
    }

    /// The faults the device commits.
    pub fn faults(&self) -> crate::faults::Faults {
        self.faults
    }

    /// Sets the write-protect jumper.
    pub fn set_write_protect(&mut self, on: bool) {
        self.write_protect = on;
    }

    /// Simulates a device malfunction (alarm current, status bit 7).
    pub fn set_malfunction(&mut self, on: bool) {
        self.malfunction = on;
    }

    /// Sets the loop current a valve positioner receives from its controller, mA.
    pub fn set_input_current(&mut self, ma: f32) {
        self.cfg.valve.input_current = ma;
    }

    /// The master whose address bit the next burst frame (BACK) carries: its status
    /// byte is the field device status as that master sees it.
    pub fn burst_master(&self) -> MasterKind {
        self.burst_to
    }

    /// Tells the device which master the next BACK goes to. The data link alternates
    /// the master bit from one BACK to the next, starting with the primary; [`crate::Node`]
    /// keeps this in step with its slave. A caller that publishes with a fixed master
    /// bit leaves it at that master.
    pub fn set_burst_master(&mut self, master: MasterKind) {
        self.burst_to = master;
    }

    /// True once the configuration changed since the last [`Device::take_dirty`].
    pub fn take_dirty(&mut self) -> bool {
        std::mem::take(&mut self.dirty)
    }

    /// Power cycle or reset: volatile state cleared, cold start set for both masters.
    pub fn reset(&mut self) {
        self.fixed_current = None;
        self.simulated.iter_mut().for_each(|s| *s = None);
        for m in &mut self.masters {
            m.cold_start = true;
        }
        if let Some(d) = &mut self.delayed {
            d.dead = true;
        }
        self.burst
            .iter_mut()
            .for_each(|b| *b = BurstRuntime::default());
    }

    fn changed(&mut self) {
        self.cfg.config_change_counter = self.cfg.config_change_counter.wrapping_add(1);
        for m in &mut self.masters {
            m.config_changed = true;
        }
        self.dirty = true;
    }

    /// Uniform in [-1, 1).
    fn next_random(&mut self) -> f32 {
        (self.rng.uniform() * 2.0 - 1.0) as f32
    }

    fn raw_value(&self, i: usize, now: Micros) -> f32 {
        let v = &self.cfg.variables[i];
        if self.cfg.kind == DeviceKind::ValvePositioner {
            match v.code {
                0 => return self.travel,
                1 => return self.setpoint(),
                _ => {}
            }
        }
        let t = now as f64 / 1e6;
        match &v.waveform {
            Waveform::Constant { value } => *value,
            Waveform::Sine {
                offset,
                amplitude,
                period_s,
            } => {
                offset
                    + amplitude
                        * (2.0 * std::f64::consts::PI * t / f64::from(period_s.max(1e-3))).sin()
                            as f32
            }
            Waveform::Ramp { from, to, period_s } => {
                let p = f64::from(period_s.max(1e-3));
                from + (to - from) * ((t % p) / p) as f32
            }
            Waveform::RandomWalk { .. } => self.walk[i],
            Waveform::Steps { values, period_s } => {
                if values.is_empty() {
                    0.0
                } else {
                    let k = (t / f64::from(period_s.max(1e-3))) as usize % values.len();
                    values[k]
                }
            }
        }
    }

    /// The valve positioner's setpoint, % travel.
    pub fn setpoint(&self) -> f32 {
        if self.cfg.valve.setpoint_source == "digital" {
            self.cfg.valve.digital_setpoint
        } else {
            ((self.cfg.valve.input_current - 4.0) / 16.0 * 100.0).clamp(-5.0, 105.0)
        }
    }

    /// Advances the process model to `now`.
    pub fn tick(&mut self, now: Micros) {
        let last = self.last_tick.unwrap_or(now);
        // The process model runs in steps of at least 10 ms (a real device's
        // acquisition is slower still); finer calls cost time and change nothing.
        if now < last || (self.last_tick.is_some() && now < last + TICK) {
            return;
        }
        let dt = (now - last) as f32 / 1e6;
        self.last_tick = Some(now);
        // Valve travel: first-order towards the setpoint, rate limited.
        if self.cfg.kind == DeviceKind::ValvePositioner && dt > 0.0 {
            let sp = self.setpoint();
            let tau = self.cfg.valve.time_constant_s.max(1e-3);
            let mut step = (sp - self.travel) * (1.0 - (-dt / tau).exp());
            let max_step = self.cfg.valve.rate_limit * dt;
            step = step.clamp(-max_step, max_step);
            self.travel += step;
        }
        for i in 0..self.cfg.variables.len() {
            if let Waveform::RandomWalk {
                step,
                min,
                max,
                interval_s,
                ..
            } = self.cfg.variables[i].waveform
            {
                let interval = (interval_s.max(0.01) * 1e6) as Micros;
                while self.walk_next[i] <= now {
                    let r = self.next_random();
                    self.walk[i] = (self.walk[i] + r * step).clamp(min, max);
                    self.walk_next[i] += interval;
                }
            }
            let input = self.raw_value(i, now);
            let tau = self.damping_of(i);
            if tau <= 0.0 || dt <= 0.0 {
                self.filtered[i] = if tau <= 0.0 { input } else { self.filtered[i] };
            } else {
                self.filtered[i] += (input - self.filtered[i]) * (1.0 - (-dt / tau).exp());
            }
        }
    }

    fn index_of(&self, code: u8) -> Option<usize> {
        self.cfg.variables.iter().position(|v| v.code == code)
    }

    fn damping_of(&self, i: usize) -> f32 {
        if Some(i) == self.index_of(self.cfg.mapping[0]) {
            self.cfg.range.damping
        } else {
            self.cfg.variables[i].damping
        }
    }

    /// A device variable's value, units and status.
    fn variable_value(&self, i: usize) -> (f32, u8, u8) {
        if let Some(s) = self.simulated[i] {
            return (s.value, s.units, s.status);
        }
        let v = &self.cfg.variables[i];
        let mut value = self.filtered[i];
        if Some(i) == self.index_of(self.cfg.mapping[0]) {
            value -= self.cfg.pv_zero_offset;
        }
        let status = if value < v.lower_limit {
            0x40 | 0x10 // poor accuracy, low limited
        } else if value > v.upper_limit {
            0x40 | 0x20
        } else {
            0xC0
        };
        (value, v.units, status)
    }

    /// Value, units, status and classification of device variable code `code`,
    /// including the special codes 244-249; `None` for an unknown code.
    fn read_code(&self, code: u8) -> Option<(f32, u8, u8, u8)> {
        match code {
            244 => Some((self.percent_of_range(), 57, 0xC0, 0)),
            245 => Some((self.loop_current().0, 39, 0xC0, 84)),
            246..=249 => {
                let mapped = self.cfg.mapping[usize::from(code - 246)];
                if mapped == 250 {
                    None
                } else {
                    self.read_code(mapped)
                }
            }
            _ => {
                let i = self.index_of(code)?;
                let (v, u, s) = self.variable_value(i);
                Some((v, u, s, self.cfg.variables[i].classification))
            }
        }
    }

    fn pv(&self) -> (f32, u8, u8) {
        self.index_of(self.cfg.mapping[0])
            .map_or((hart_nan(), 250, 0x30), |i| self.variable_value(i))
    }

    /// Percent of range of PV (not clamped).
    pub fn percent_of_range(&self) -> f32 {
        if self.cfg.kind == DeviceKind::ValvePositioner {
            return (self.cfg.valve.input_current - 4.0) / 16.0 * 100.0;
        }
        let (pv, _, _) = self.pv();
        let r = &self.cfg.range;
        let span = r.upper - r.lower;
        if span == 0.0 {
            return 0.0;
        }
        let pct = (pv - r.lower) / span * 100.0;
        if r.transfer_function == 1 {
            if pct <= 0.0 {
                0.0
            } else {
                (pct / 100.0).sqrt() * 100.0
            }
        } else {
            pct
        }
    }

    /// The loop current (mA), whether it is saturated, and whether it is fixed.
    pub fn loop_current(&self) -> (f32, bool, bool) {
        if self.cfg.kind == DeviceKind::ValvePositioner {
            return (self.cfg.valve.input_current, false, false);
        }
        let (ideal, saturated, fixed) = if self.cfg.loop_current_mode == 0 {
            (4.0, false, true)
        } else if let Some(f) = self.fixed_current {
            (f, false, true)
        } else if self.malfunction {
            (
                if self.cfg.range.alarm_selection == 1 {
                    ALARM_LOW
                } else {
                    ALARM_HIGH
                },
                false,
                false,
            )
        } else {
            let i = 4.0 + 16.0 * self.percent_of_range() / 100.0;
            let c = i.clamp(SATURATION_LOW, SATURATION_HIGH);
            (c, c != i, false)
        };
        // The analog output as the device reads it back: trims correct the output's error.
        let actual = (ideal * self.cfg.trim_gain + self.cfg.trim_zero) * self.cfg.output_gain_error
            + self.cfg.output_offset_error;
        (actual, saturated, fixed)
    }

    /// Command 48 bytes 0-13.
    fn additional_status(&self) -> cmd::AdditionalStatus {
        // Device-specific byte 0: bit 0 self test running.
        let self_test = self
            .delayed
            .as_ref()
            .is_some_and(|d| d.command == 41 && !d.dead);
        // Standardized status 0: bit 0 device variable simulation active.
        let simulating = self.simulated.iter().any(Option::is_some);
        cmd::AdditionalStatus::from(cmd::AdditionalStatusParts {
            device_specific_status: [u8::from(self_test), 0, 0, 0, 0, 0],
            extended_status: ExtendedStatus(self.extended_status()),
            standardized_status_0: StandardizedStatus0(u8::from(simulating)),
            ..Default::default()
        })
    }

    fn extended_status(&self) -> u8 {
        let mut e = 0;
        if self.malfunction {
            e |= 0x08; // failure
        }
        if self.simulated.iter().any(Option::is_some) || self.fixed_current.is_some() {
            e |= 0x20; // function check
        }
        e
    }

    /// The field device status byte for `master`.
    pub fn device_status(&self, master: MasterKind) -> u8 {
        let m = &self.masters[master_index(master)];
        let (_, saturated, fixed) = self.loop_current();
        let (pv, _, _) = self.pv();
        let mut s = 0u8;
        if self.malfunction {
            s |= 0x80;
        }
        if m.config_changed {
            s |= 0x40;
        }
        if m.cold_start {
            s |= 0x20;
        }
        if self.additional_status().acknowledged() != m.acked48 {
            s |= 0x10;
        }
        if fixed {
            s |= 0x08;
        }
        if saturated {
            s |= 0x04;
        }
        let pv_var = self.index_of(self.cfg.mapping[0]);
        if let Some(i) = pv_var {
            let v = &self.cfg.variables[i];
            if pv < v.lower_limit || pv > v.upper_limit {
                s |= 0x01;
            }
        }
        for (k, &code) in self.cfg.mapping.iter().enumerate().skip(1) {
            if let Some(i) = self.index_of(code) {
                let v = &self.cfg.variables[i];
                let (x, _, _) = self.variable_value(i);
                if x < v.lower_limit || x > v.upper_limit {
                    s |= 0x02;
                }
            }
            let _ = k;
        }
        s
    }

    /// The command 0 identity this device reports.
    pub fn identity(&self) -> cmd::Identity {
        let id = &self.cfg.identity;
        cmd::Identity {
            expansion_code: 254,
            expanded_device_type: id.expanded_device_type,
            min_request_preambles: id.min_request_preambles,
            universal_revision: self.revision(),
            device_revision: id.device_revision,
            software_revision: id.software_revision,
            hardware: HardwareRevision::new(id.hardware_revision, 0),
            flags: Flags(id.flags),
            device_id: DeviceId::new(id.device_id & 0xFF_FFFF).unwrap_or_default(),
            min_response_preambles: (self.revision() >= 6).then_some(self.cfg.response_preambles),
            max_device_variables: (self.revision() >= 6).then_some(self.cfg.variables.len() as u8),
            config_change_counter: (self.revision() >= 6).then_some(self.cfg.config_change_counter),
            extended_status: (self.revision() >= 6)
                .then_some(ExtendedStatus(self.extended_status())),
            manufacturer_id: (self.revision() >= 7).then_some(id.manufacturer_id),
            private_label_distributor: (self.revision() >= 7)
                .then_some(id.private_label_distributor),
            device_profile: (self.revision() >= 7).then_some(DeviceProfile(id.device_profile)),
        }
    }

    /// The HART universal revision the device speaks (5, 6 or 7; the profile's
    /// `identity.universal_revision`).
    pub fn revision(&self) -> u8 {
        self.cfg.identity.universal_revision.clamp(5, 7)
    }

    fn time_of_day(now: Micros) -> HartTime {
        HartTime::time_of_day(now)
    }

    /// Answers one request; `None` means stay silent.
    pub fn handle(&mut self, f: &Frame<'_>, now: Micros) -> Option<(u8, u8, Vec<u8>)> {
        self.tick(now);
        self.stx_count = self.stx_count.wrapping_add(1);
        let master = f.address.master();
        let outcome = self.dispatch(f.command, f.data, master, now);
        let Outcome::Reply(code, data) = outcome else {
            return None;
        };
        let status = self.device_status(master);
        // Cold start is reported once to each master.
        self.masters[master_index(master)].cold_start = false;
        self.ack_count = self.ack_count.wrapping_add(1);
        if std::mem::take(&mut self.reset_pending) {
            self.reset();
        }
        let data = if hart_proto::tables::response_class(code)
            == hart_proto::tables::ResponseClass::Error
        {
            vec![]
        } else {
            data
        };
        Some((code, status, data))
    }

    fn dispatch(&mut self, command: u16, data: &[u8], master: MasterKind, now: Micros) -> Outcome {
        let info = cmd::info(command);
        // Universal commands added by HART 6 (and command 31) are not in older devices.
        if self.revision() < 6 && matches!(command, 7 | 8 | 9 | 20 | 21 | 22 | 31) {
            return err(rc::NOT_IMPLEMENTED);
        }
        let request = match hart_proto::decode_request(command, data) {
            Some(Ok(r)) => Some(r),
            // A field device answers the commands of I/O systems (77) and HART-IP servers
            // (532, 533) only as its profile declares them, "not implemented" otherwise,
            // whatever their length.
            Some(Err(_)) if matches!(command, 77 | 532 | 533) => None,
            // Fault injection: too few data bytes answered as a success, without data.
            Some(Err(_)) if self.faults.has(crate::faults::Fault::NoTooFewDataBytes) => {
                return ok(vec![])
            }
            Some(Err(_)) => return err(rc::TOO_FEW_DATA_BYTES),
            None => None,
        };
        // Command-specific length rules the layouts cannot express.
        match (&request, data.len()) {
            (Some(Request::ReadAdditionalStatus(_)), 1..=8)
            | (Some(Request::ResetConfigurationChanged(_)), 1) => {
                return err(rc::TOO_FEW_DATA_BYTES)
            }
            _ => {}
        }
        // Command 38 is a write in the table, but it only resets the asking master's own
        // flag: write protection, access restriction and the self test do not stop it.
        let writes = info.is_some_and(|i| i.writes) && command != 38;
        if writes {
            if let Some(code) = self.write_refused(master, now) {
                return err(code);
            }
        }
        let Some(request) = request else {
            return self.custom(command, data, master, now);
        };
        self.command(request, data, master, now)
    }

    /// Why a write from `master` is refused now, if it is: write protection (7), a
    /// restricted secondary master (16), or the self test running (32).
    fn write_refused(&self, master: MasterKind, now: Micros) -> Option<u8> {
        if self.write_protect {
            return Some(rc::WRITE_PROTECTED);
        }
        if master == MasterKind::Secondary && self.cfg.restrict_secondary_writes {
            return Some(rc::ACCESS_RESTRICTED);
        }
        // While the self test runs the device cannot take configuration changes.
        if self
            .delayed
            .as_ref()
            .is_some_and(|d| d.command == 41 && !d.dead && now < d.done_at)
        {
            return Some(rc::BUSY);
        }
        None
    }

    fn custom(&mut self, command: u16, data: &[u8], master: MasterKind, now: Micros) -> Outcome {
        let Some(c) = self
            .cfg
            .commands
            .iter()
            .find(|c| c.number == command)
            .cloned()
        else {
            return err(rc::NOT_IMPLEMENTED);
        };
        if let Some(h) = &c.reply_hex {
            let bytes: Vec<u8> = (0..h.len() / 2)
                .filter_map(|i| u8::from_str_radix(h.get(2 * i..2 * i + 2)?, 16).ok())
                .collect();
            return ok(bytes);
        }
        // The profile's own commands have no layout of their own; their replies are a
        // units code and a value.
        let float_reply = |units: u8, value: f32| {
            encode(&cmd::UnitValue {
                units: UnitCode(units),
                value,
            })
        };
        match c.computed.as_deref() {
            Some("setpoint") => ok(float_reply(57, self.setpoint())),
            Some("input_current") => ok(float_reply(39, self.cfg.valve.input_current)),
            Some("write_setpoint") | Some("write_input_current") => {
                let Ok(v) = f32::decode(&mut Reader::new(data)) else {
                    return err(rc::TOO_FEW_DATA_BYTES);
                };
                // Device-specific writes follow the same rules as the table's writes.
                if let Some(code) = self.write_refused(master, now) {
                    return err(code);
                }
                if !v.is_finite() {
                    return err(rc::INVALID_SELECTION);
                }
                if c.computed.as_deref() == Some("write_setpoint") {
                    if !(-5.0..=105.0).contains(&v) {
                        return err(if v > 105.0 {
                            rc::TOO_LARGE
                        } else {
                            rc::TOO_SMALL
                        });
                    }
                    self.cfg.valve.digital_setpoint = v;
                    self.cfg.valve.setpoint_source = "digital".into();
                    self.changed();
                    ok(float_reply(57, v))
                } else {
                    if !(3.5..=22.0).contains(&v) {
                        return err(if v > 22.0 {
                            rc::TOO_LARGE
                        } else {
                            rc::TOO_SMALL
                        });
                    }
                    self.cfg.valve.input_current = v;
                    ok(float_reply(39, v))
                }
            }
            Some(s) if s.starts_with("variable:") => match s[9..]
                .parse::<u8>()
                .ok()
                .and_then(|code| self.read_code(code))
            {
                Some((v, u, _, _)) => ok(float_reply(u, v)),
                None => err(rc::DEVICE_SPECIFIC_ERROR),
            },
            _ => err(rc::NOT_IMPLEMENTED),
        }
    }

    /// The process reads 1, 2, 3, 9 and 33: what a master reads and what burst messages
    /// publish. They only look at the device (`&self`), so publishing has no side effects.
    fn process_read(&self, request: &Request, now: Micros) -> Outcome {
        use Request as R;
        match request {
            R::ReadPrimaryVariable(_) => {
                let (pv, units, _) = self.pv();
                ok(encode(&cmd::ReadPvResponse {
                    pv_units: UnitCode(units),
                    pv,
                }))
            }
            R::ReadLoopCurrent(_) => ok(encode(&cmd::ReadLoopCurrentResponse {
                loop_current: MilliAmps(self.loop_current().0),
                percent_of_range: Percent(self.percent_of_range()),
            })),
            R::ReadDynamicVariables(_) => {
                let mut variables = List::<cmd::UnitValue, 4>::default();
                for k in 0..4 {
                    let code = self.cfg.mapping[k];
                    if code == 250 {
                        break;
                    }
                    let (v, u, _, _) = self.read_code(code).unwrap_or((hart_nan(), 250, 0x30, 0));
                    let _ = variables.push(cmd::UnitValue {
                        units: UnitCode(u),
                        value: v,
                    });
                }
                ok(encode(&cmd::ReadDynamicVariablesResponse {
                    loop_current: MilliAmps(self.loop_current().0),
                    variables,
                }))
            }
            R::ReadDeviceVariablesWithStatus(r) => {
                let mut slots = List::<cmd::VariableSlot, 8>::default();
                for code in r.slots.as_slice() {
                    if code.0 >= 251 {
                        return err(rc::INVALID_SELECTION);
                    }
                    let slot = match self.read_code(code.0) {
                        Some((v, u, s, c)) => cmd::VariableSlot {
                            code: *code,
                            classification: Classification(c),
                            units: UnitCode(u),
                            value: v,
                            status: VariableStatus(s),
                        },
                        None => cmd::VariableSlot {
                            code: *code,
                            classification: Classification(0),
                            units: UnitCode(250),
                            value: hart_nan(),
                            status: VariableStatus(0x30),
                        },
                    };
                    let _ = slots.push(slot);
                }
                ok(encode(&cmd::ReadDeviceVariablesResponse {
                    extended_status: ExtendedStatus(self.extended_status()),
                    data: cmd::SlotsWithTimestamp {
                        slots,
                        timestamp: Some(Self::time_of_day(now)),
                    },
                }))
            }
            R::ReadDeviceVariables(r) => {
                let mut variables = List::<cmd::CodeUnitValue, 4>::default();
                for code in r.slots.as_slice() {
                    let (v, u, _, _) = self.read_code(code.0).unwrap_or((hart_nan(), 250, 0x30, 0));
                    let _ = variables.push(cmd::CodeUnitValue {
                        code: *code,
                        units: UnitCode(u),
                        value: v,
                    });
                }
                ok(encode(&cmd::ReadVariablesResponse { variables }))
            }
            _ => err(rc::NOT_IMPLEMENTED),
        }
    }

    fn command(
        &mut self,
        request: Request,
        raw: &[u8],
        master: MasterKind,
        now: Micros,
    ) -> Outcome {
        use Request as R;
        match request {
            R::ReadUniqueIdentifier(_) => ok(encode(&self.identity())),
            R::ReadPrimaryVariable(_)
            | R::ReadLoopCurrent(_)
            | R::ReadDynamicVariables(_)
            | R::ReadDeviceVariablesWithStatus(_)
            | R::ReadDeviceVariables(_) => self.process_read(&request, now),
            R::WritePollingAddress(r) => {
                if r.polling_address > 63 {
                    return err(rc::INVALID_SELECTION);
                }
                let mode = match r.loop_current_mode {
                    Some(LoopCurrentMode(m)) if m > 1 => return err(12),
                    Some(LoopCurrentMode(m)) => m,
                    // HART 5 form: address 0 means analog, any other multidrop.
                    None => u8::from(r.polling_address == 0),
                };
                self.cfg.polling_address = r.polling_address;
                self.cfg.loop_current_mode = mode;
                if mode == 0 {
                    self.fixed_current = None;
                }
                self.changed();
                ok(encode(&cmd::PollingAddress {
                    polling_address: r.polling_address,
                    loop_current_mode: r.loop_current_mode.map(|_| LoopCurrentMode(mode)),
                }))
            }
            R::ReadLoopConfiguration(_) => ok(encode(&cmd::LoopConfiguration {
                polling_address: self.cfg.polling_address,
                loop_current_mode: LoopCurrentMode(self.cfg.loop_current_mode),
            })),
            R::ReadDynamicVariableClassifications(_) => {
                let c = |k: usize| {
                    Classification(self.read_code(self.cfg.mapping[k]).map_or(0, |x| x.3))
                };
                ok(encode(&cmd::DynamicVariableClassifications {
                    pv_classification: c(0),
                    sv_classification: c(1),
                    tv_classification: c(2),
                    qv_classification: c(3),
                }))
            }
            R::ReadUniqueIdentifierByTag(r) => {
                let tag = PackedString::<6>::new(&self.cfg.tag).unwrap_or_default();
                if r.tag.0 == tag.0 {
                    ok(encode(&self.identity()))
                } else {
                    Outcome::Silent
                }
            }
            R::ReadMessage(_) => ok(encode(&cmd::Message {
                message: PackedString::new(&self.cfg.message).unwrap_or_default(),
            })),
            R::ReadTagDescriptorDate(_) => ok(encode(&self.tag_descriptor_date())),
            R::ReadPvTransducerInformation(_) => {
                let Some(i) = self.index_of(self.cfg.mapping[0]) else {
                    return err(rc::DEVICE_SPECIFIC_ERROR);
                };
                let v = &self.cfg.variables[i];
                ok(encode(&cmd::TransducerInfo {
                    transducer_serial_number: U24::new(v.serial_number & 0xFF_FFFF)
                        .unwrap_or_default(),
                    limits_units: UnitCode(v.units),
                    upper_transducer_limit: v.upper_limit,
                    lower_transducer_limit: v.lower_limit,
                    minimum_span: v.minimum_span,
                }))
            }
            R::ReadDeviceInformation(_) => {
                let r = &self.cfg.range;
                ok(encode(&cmd::DeviceInformation {
                    alarm_selection: AlarmSelection(r.alarm_selection),
                    transfer_function: TransferFunction(r.transfer_function),
                    range_units: UnitCode(r.units),
                    upper_range_value: r.upper,
                    lower_range_value: r.lower,
                    damping: Seconds(r.damping),
                    write_protect: WriteProtect(u8::from(self.write_protect)),
                    reserved: 250,
                    analog_channel_flags: Some(AnalogChannelFlags(u8::from(
                        self.cfg.kind == DeviceKind::ValvePositioner,
                    ))),
                }))
            }
            R::ReadFinalAssemblyNumber(_) => ok(encode(&cmd::FinalAssemblyNumber {
                final_assembly_number: U24::new(self.cfg.final_assembly_number & 0xFF_FFFF)
                    .unwrap_or_default(),
            })),
            R::WriteMessage(r) => {
                self.cfg.message = r.message.to_string();
                self.changed();
                ok(encode(&r))
            }
            R::WriteTagDescriptorDate(r) => {
                if !r.date.is_valid() {
                    return err(9);
                }
                self.cfg.tag = r.tag.to_string();
                self.cfg.descriptor = r.descriptor.to_string();
                self.cfg.date = [r.date.day, r.date.month, r.date.year_since_1900];
                self.changed();
                ok(encode(&r))
            }
            R::WriteFinalAssemblyNumber(r) => {
                self.cfg.final_assembly_number = r.final_assembly_number.get();
                self.changed();
                ok(encode(&r))
            }
            R::ReadLongTag(_) => ok(encode(&cmd::LongTag {
                long_tag: Latin1String::new(&self.cfg.long_tag).unwrap_or_default(),
            })),
            R::ReadUniqueIdentifierByLongTag(r) => {
                let mine = Latin1String::<32>::new(&self.cfg.long_tag).unwrap_or_default();
                if r.long_tag.to_string() == mine.to_string() {
                    ok(encode(&self.identity()))
                } else {
                    Outcome::Silent
                }
            }
            R::WriteLongTag(r) => {
                self.cfg.long_tag = r.long_tag.to_string();
                self.changed();
                ok(encode(&r))
            }
            R::WritePvDamping(r) => {
                let d = r.damping.0;
                if !d.is_finite() || d < 0.0 {
                    return err(rc::TOO_SMALL);
                }
                if d > 60.0 {
                    return err(rc::TOO_LARGE);
                }
                // The device's damping resolution is 0.1 s.
                let applied = (d * 10.0).round() / 10.0;
                self.cfg.range.damping = applied;
                self.changed();
                let code = if applied != d { 8 } else { rc::SUCCESS };
                Outcome::Reply(
                    code,
                    encode(&cmd::Damping {
                        damping: Seconds(applied),
                    }),
                )
            }
            R::WritePvRange(r) => {
                self.write_range(r.range_units.0, r.upper_range_value, r.lower_range_value)
            }
            R::SetPvUpperRange(_) | R::SetPvLowerRange(_) => {
                let Some(i) = self.index_of(self.cfg.mapping[0]) else {
                    return err(rc::DEVICE_SPECIFIC_ERROR);
                };
                let (pv, _, _) = self.pv();
                let (lo, hi) = (
                    self.cfg.variables[i].lower_limit,
                    self.cfg.variables[i].upper_limit,
                );
                if pv > hi {
                    return err(9); // applied process too high
                }
                if pv < lo {
                    return err(10); // applied process too low
                }
                let (units, urv, lrv) = (
                    self.cfg.range.units,
                    self.cfg.range.upper,
                    self.cfg.range.lower,
                );
                let mut warning = rc::SUCCESS;
                let (new_u, new_l) = if matches!(request, R::SetPvUpperRange(_)) {
                    (pv, lrv)
                } else {
                    // Setting the LRV keeps the span; an URV pushed beyond the sensor
                    // limit stops there (warning 14).
                    let shifted = urv + (pv - lrv);
                    if shifted > hi {
                        warning = 14;
                        (hi, pv)
                    } else {
                        (shifted, pv)
                    }
                };
                if new_u == new_l {
                    return err(if matches!(request, R::SetPvUpperRange(_)) {
                        10
                    } else {
                        9
                    });
                }
                match self.write_range(units, new_u, new_l) {
                    Outcome::Reply(code, _)
                        if hart_proto::tables::response_class(code)
                            == hart_proto::tables::ResponseClass::Error =>
                    {
                        err(code)
                    }
                    Outcome::Reply(code, _) => {
                        Outcome::Reply(if warning != 0 { warning } else { code }, vec![])
                    }
                    o => o,
                }
            }
            R::ResetConfigurationChanged(r) => {
                if let Some(counter) = r.config_change_counter {
                    if counter != self.cfg.config_change_counter {
                        return err(9);
                    }
                }
                if !self.faults.has(crate::faults::Fault::Cmd38NoReset) {
                    self.masters[master_index(master)].config_changed = false;
                }
                ok(encode(&cmd::ResetConfigChanged {
                    config_change_counter: Some(self.cfg.config_change_counter),
                }))
            }
            R::EnterExitFixedCurrent(r) => {
                if self.cfg.kind == DeviceKind::ValvePositioner {
                    return err(rc::NOT_IMPLEMENTED);
                }
                if self.cfg.loop_current_mode == 0 {
                    return err(11);
                }
                let v = r.loop_current.0;
                if !v.is_finite() {
                    return err(rc::INVALID_SELECTION);
                }
                if v == 0.0 {
                    self.fixed_current = None;
                } else if v < ALARM_LOW {
                    return err(rc::TOO_SMALL);
                } else if v > ALARM_HIGH {
                    return err(rc::TOO_LARGE);
                } else {
                    self.fixed_current = Some(v);
                }
                ok(encode(&r))
            }
            R::PerformSelfTest(_) => self.delayed_command(41, raw, now),
            R::PerformDeviceReset(_) => {
                // The device resets after its reply has gone out.
                self.reset_pending = true;
                ok(vec![])
            }
            R::SetPvZero(_) => {
                let Some(i) = self.index_of(self.cfg.mapping[0]) else {
                    return err(rc::DEVICE_SPECIFIC_ERROR);
                };
                let raw_pv = self.filtered[i];
                let v = &self.cfg.variables[i];
                // Only a zero shift within 5 % of the sensor span is accepted.
                let limit = 0.05 * (v.upper_limit - v.lower_limit);
                if raw_pv > limit {
                    return err(9);
                }
                if raw_pv < -limit {
                    return err(10);
                }
                self.cfg.pv_zero_offset = raw_pv;
                self.changed();
                ok(vec![])
            }
            R::WritePvUnits(r) => {
                let Some(i) = self.index_of(self.cfg.mapping[0]) else {
                    return err(rc::DEVICE_SPECIFIC_ERROR);
                };
                if !self.set_variable_units(i, r.pv_units.0) {
                    return err(rc::INVALID_SELECTION);
                }
                self.changed();
                ok(encode(&r))
            }
            R::TrimLoopCurrentZero(r) => self.trim(r.measured_current.0, 4.0, true),
            R::TrimLoopCurrentGain(r) => self.trim(r.measured_current.0, 20.0, false),
            R::ReadAdditionalStatus(r) => {
                let status = self.additional_status();
                let shown = status.acknowledged();
                let m = &mut self.masters[master_index(master)];
                let copy = r.status_copy.as_slice();
                let code = if copy.len() >= shown.len() {
                    if copy.starts_with(shown) {
                        m.acked48.copy_from_slice(shown);
                        rc::SUCCESS
                    } else {
                        14 // status bytes mismatch (warning)
                    }
                } else {
                    // A legacy read acknowledges what it returns.
                    m.acked48.copy_from_slice(shown);
                    rc::SUCCESS
                };
                Outcome::Reply(code, encode(&status))
            }
            R::ReadDynamicVariableAssignments(_) => ok(self.cfg.mapping.to_vec()),
            R::WriteDynamicVariableAssignments(r) => {
                let new = [Some(r.pv_code), r.sv_code, r.tv_code, r.qv_code]
                    .map(|c| c.map_or(250, |c| c.0));
                for (k, &code) in new.iter().enumerate() {
                    let valid = if k == 0 {
                        self.index_of(code).is_some()
                    } else {
                        code == 250 || self.index_of(code).is_some()
                    };
                    if !valid {
                        return err(rc::INVALID_SELECTION);
                    }
                }
                self.cfg.mapping = new;
                if let Some(i) = self.index_of(new[0]) {
                    self.cfg.range.units = self.cfg.variables[i].units;
                }
                self.changed();
                ok(new.to_vec())
            }
            R::WriteDeviceVariableUnits(r) => {
                let Some(i) = self.index_of(r.code.0) else {
                    return err(rc::INVALID_SELECTION);
                };
                if !self.set_variable_units(i, r.units.0) {
                    return err(12);
                }
                self.changed();
                ok(encode(&r))
            }
            R::ReadDeviceVariableInformation(r) => {
                let Some(i) = self.index_of(r.code.0) else {
                    return err(rc::INVALID_SELECTION);
                };
                let v = &self.cfg.variables[i];
                ok(encode(&cmd::VariableInformation {
                    code: r.code,
                    transducer_serial_number: U24::new(v.serial_number & 0xFF_FFFF)
                        .unwrap_or_default(),
                    limits_units: UnitCode(v.units),
                    upper_transducer_limit: v.upper_limit,
                    lower_transducer_limit: v.lower_limit,
                    damping: Seconds(self.damping_of(i)),
                    minimum_span: v.minimum_span,
                    classification: Classification(v.classification),
                    family: VariableFamily(v.family),
                    acquisition_period: HartTime::from_millis(v.update_period_ms),
                    properties: Some(u8::from(self.simulated[i].is_some()) << 7 | 1),
                }))
            }
            R::WriteResponsePreambles(r) => {
                if r.response_preambles < 5 {
                    return err(rc::TOO_SMALL);
                }
                if r.response_preambles > 20 {
                    return err(rc::TOO_LARGE);
                }
                self.cfg.response_preambles = r.response_preambles;
                self.changed();
                ok(encode(&r))
            }
            R::WriteDeviceVariable(r) => {
                let Some(i) = self.index_of(r.code.0) else {
                    return err(rc::INVALID_SELECTION);
                };
                match r.write_code.0 {
                    0 => self.simulated[i] = None,
                    1 => {
                        if r.units.0 != self.cfg.variables[i].units {
                            return err(12);
                        }
                        self.simulated[i] = Some(Simulation {
                            units: r.units.0,
                            value: r.value,
                            status: r.status.0,
                        });
                    }
                    _ => return err(10),
                }
                ok(encode(&r))
            }
            // No real-time clock in this device.
            R::ReadRealTimeClock(_) => err(rc::NOT_IMPLEMENTED),
            // I/O-system commands: a field device has none, unless its profile adds them.
            R::ReadIoSystemCapabilities(_)
            | R::PollSubDevice(_)
            | R::ReadSubDeviceIdentitySummary(_)
            | R::ReadSubDeviceBurstMap(_)
            | R::MapSubDeviceToBurstMessage(_)
            | R::SendCommandToSubDevice(_)
            | R::ReadClientSubscriptionSummary(_)
            | R::WriteClientSubscriptionFlags(_) => {
                self.custom(request.command(), raw, master, now)
            }
            R::ReadCommunicationStatistics(_) => ok(encode(&cmd::CommunicationStatistics {
                stx_count: self.stx_count,
                ack_count: self.ack_count,
                back_count: self.back_count,
            })),
            R::WriteBurstPeriod(r) => self.write_burst_period(r),
            R::WriteBurstTrigger(r) => self.write_burst_trigger(r),
            R::ReadBurstConfiguration(r) => {
                let m = usize::from(r.burst_message.unwrap_or(0));
                let Some(b) = self.cfg.burst.get(m) else {
                    return err(9);
                };
                let mut slots = List::<DeviceVariableCode, 8>::default();
                for s in b.slots {
                    let _ = slots.push(DeviceVariableCode(s));
                }
                ok(encode(&cmd::BurstConfiguration {
                    control: BurstModeControl(b.control),
                    command_expansion: 31,
                    slots,
                    burst_message: Some(m as u8),
                    max_burst_messages: Some(self.cfg.burst.len() as u8),
                    command_number: Some(CommandNumber(b.command)),
                    update_period: Some(HartTime(b.update_period)),
                    max_update_period: Some(HartTime(b.max_update_period)),
                    trigger_mode: Some(TriggerMode(b.trigger_mode)),
                    trigger_classification: Some(Classification(b.trigger_classification)),
                    trigger_units: Some(UnitCode(b.trigger_units)),
                    trigger_level: Some(b.trigger_level),
                }))
            }
            R::WriteBurstDeviceVariables(r) => {
                let m = usize::from(r.burst_message.unwrap_or(0));
                if m >= self.cfg.burst.len() {
                    return err(9);
                }
                let mut slots = [250u8; 8];
                for (k, c) in r.slots.as_slice().iter().enumerate() {
                    if c.0 != 250 && self.read_code(c.0).is_none() {
                        return err(rc::INVALID_SELECTION);
                    }
                    slots[k] = c.0;
                }
                self.cfg.burst[m].slots = slots;
                self.changed();
                ok(encode(&r))
            }
            R::WriteBurstCommandNumber(r) => {
                let m = usize::from(r.burst_message.unwrap_or(0));
                if m >= self.cfg.burst.len() {
                    return err(9);
                }
                if !burst::BURSTABLE.contains(&r.command_number)
                    && !self.faults.has(crate::faults::Fault::BurstAnyCommand)
                {
                    return err(rc::INVALID_SELECTION);
                }
                let b = &mut self.cfg.burst[m];
                b.command = r.command_number;
                // A trigger that compares a value of another classification cannot stay.
                let mut code = rc::SUCCESS;
                if (1..=3).contains(&b.trigger_mode)
                    && burst::trigger_classification(&self.cfg, m)
                        != Some(self.cfg.burst[m].trigger_classification)
                {
                    let b = &mut self.cfg.burst[m];
                    b.trigger_mode = 0;
                    b.trigger_classification = 0;
                    b.trigger_units = 250;
                    b.trigger_level = hart_nan();
                    code = 8;
                }
                if matches!(r.command_number, 38 | 48)
                    && self.cfg.burst[m].trigger_mode != 4
                    && self.cfg.burst[m].trigger_mode != 0
                {
                    self.cfg.burst[m].trigger_mode = 0;
                    code = 8;
                }
                self.burst[m] = BurstRuntime::default();
                self.changed();
                Outcome::Reply(code, encode(&r))
            }
            R::BurstModeControl(r) => {
                let m = usize::from(r.burst_message.unwrap_or(0));
                if m >= self.cfg.burst.len() {
                    return err(9);
                }
                if r.control.0 > 4 {
                    return err(rc::INVALID_SELECTION);
                }
                self.cfg.burst[m].control = r.control.0;
                self.burst[m] = BurstRuntime::default();
                self.changed();
                ok(encode(&r))
            }
        }
    }

    fn tag_descriptor_date(&self) -> cmd::TagDescriptorDate {
        let [day, month, year_since_1900] = self.cfg.date;
        cmd::TagDescriptorDate {
            tag: PackedString::new(&self.cfg.tag).unwrap_or_default(),
            descriptor: PackedString::new(&self.cfg.descriptor).unwrap_or_default(),
            date: Date {
                day,
                month,
                year_since_1900,
            },
        }
    }

    /// Changes a variable's units, converting its limits, value source and (for PV) the
    /// range. False when the units are not of the variable's family.
    fn set_variable_units(&mut self, i: usize, units: u8) -> bool {
        let v = &mut self.cfg.variables[i];
        let from = v.units;
        if !units::compatible(from, units) {
            return false;
        }
        let conv = |x: f32| units::convert(x, from, units).unwrap_or(x);
        let span = |x: f32| units::convert_span(x, from, units).unwrap_or(x);
        v.units = units;
        v.lower_limit = conv(v.lower_limit);
        v.upper_limit = conv(v.upper_limit);
        v.minimum_span = span(v.minimum_span);
        v.waveform = match v.waveform.clone() {
            Waveform::Constant { value } => Waveform::Constant { value: conv(value) },
            Waveform::Sine {
                offset,
                amplitude,
                period_s,
            } => Waveform::Sine {
                offset: conv(offset),
                amplitude: span(amplitude),
                period_s,
            },
            Waveform::Ramp {
                from: a,
                to: b,
                period_s,
            } => Waveform::Ramp {
                from: conv(a),
                to: conv(b),
                period_s,
            },
            Waveform::RandomWalk {
                start,
                step,
                min,
                max,
                interval_s,
            } => Waveform::RandomWalk {
                start: conv(start),
                step: span(step),
                min: conv(min),
                max: conv(max),
                interval_s,
            },
            Waveform::Steps { values, period_s } => Waveform::Steps {
                values: values.into_iter().map(conv).collect(),
                period_s,
            },
        };
        self.walk[i] = conv(self.walk[i]);
        self.filtered[i] = conv(self.filtered[i]);
        if Some(i) == self.index_of(self.cfg.mapping[0]) {
            let r = &mut self.cfg.range;
            r.upper = conv(r.upper);
            r.lower = conv(r.lower);
            r.units = units;
            self.cfg.pv_zero_offset = span(self.cfg.pv_zero_offset);
        }
        true
    }

    fn write_range(&mut self, units: u8, urv: f32, lrv: f32) -> Outcome {
        let Some(i) = self.index_of(self.cfg.mapping[0]) else {
            return err(rc::DEVICE_SPECIFIC_ERROR);
        };
        let v = &self.cfg.variables[i];
        // Values come in `units`; check them in the PV's units.
        let (Some(u), Some(l)) = (
            units::convert(urv, units, v.units),
            units::convert(lrv, units, v.units),
        ) else {
            return err(rc::INVALID_SELECTION);
        };
        if !u.is_finite() || !l.is_finite() {
            return err(rc::INVALID_SELECTION);
        }
        let (lo, hi) = (v.lower_limit, v.upper_limit);
        if l > hi {
            return err(9);
        }
        if l < lo {
            return err(10);
        }
        if u > hi {
            return err(11);
        }
        if u < lo {
            return err(12);
        }
        if u == l {
            return err(29);
        }
        let code = if (u - l).abs() < v.minimum_span {
            14
        } else {
            rc::SUCCESS
        };
        let pv_units = v.units;
        let r = &mut self.cfg.range;
        r.upper = u;
        r.lower = l;
        r.units = pv_units;
        self.changed();
        Outcome::Reply(
            code,
            encode(&cmd::RangeValues {
                range_units: UnitCode(units),
                upper_range_value: urv,
                lower_range_value: lrv,
            }),
        )
    }

    fn trim(&mut self, measured: f32, point: f32, zero: bool) -> Outcome {
        if self.cfg.kind == DeviceKind::ValvePositioner {
            return err(rc::NOT_IMPLEMENTED);
        }
        if self.cfg.loop_current_mode == 0 {
            return err(11);
        }
        if self.fixed_current.is_none_or(|f| (f - point).abs() > 1e-3) {
            return err(9); // not in fixed current mode at the trim point
        }
        if !measured.is_finite() {
            return err(rc::INVALID_SELECTION);
        }
        if measured > point + 0.5 {
            return err(rc::TOO_LARGE);
        }
        if measured < point - 0.5 {
            return err(rc::TOO_SMALL);
        }
        // The device commanded `point`; the meter read `measured`. A zero trim shifts the
        // output by the difference; a gain trim scales it about the 4 mA point.
        if zero {
            self.cfg.trim_zero -= measured - point;
        } else {
            let c4 = 4.0 * self.cfg.trim_gain + self.cfg.trim_zero;
            let k = (point - 4.0) / (measured - 4.0).max(1e-3);
            self.cfg.trim_gain *= k;
            self.cfg.trim_zero = c4 - 4.0 * self.cfg.trim_gain;
        }
        self.changed();
        ok(encode(&cmd::TrimCurrent {
            measured_current: MilliAmps(measured),
        }))
    }

    fn delayed_command(&mut self, command: u16, raw: &[u8], now: Micros) -> Outcome {
        match &mut self.delayed {
            Some(d) if d.command == command && d.data == raw => {
                if d.dead {
                    self.delayed = None;
                    return err(rc::DR_DEAD);
                }
                if now >= d.done_at + DELAYED_RESULT_KEPT {
                    self.delayed = None;
                    return err(rc::DR_DEAD);
                }
                if now >= d.done_at {
                    self.delayed = None;
                    return ok(vec![]);
                }
                err(rc::DR_RUNNING)
            }
            Some(d) if !d.dead && now < d.done_at => err(rc::DR_CONFLICT),
            _ => {
                self.delayed = Some(Delayed {
                    command,
                    data: raw.to_vec(),
                    done_at: now + SELF_TEST_DURATION,
                    dead: false,
                });
                err(rc::DR_INITIATED)
            }
        }
    }

    fn write_burst_period(&mut self, r: cmd::BurstPeriod) -> Outcome {
        let m = usize::from(r.burst_message);
        if m >= self.cfg.burst.len() {
            return err(9);
        }
        let min_allowed = match self.cfg.phy {
            crate::config::Phy::Fsk => 0.5,
            crate::config::Phy::Fast => 0.1,
            crate::config::Phy::HartIp => 0.05,
        };
        let legal = |s: f32| -> f32 {
            if s < 60.0 {
                // The listed short periods (and, on faster layers, anything from the
                // layer's minimum), whichever is nearest; 45 s and above round to 60 s.
                if s >= 46.0 {
                    return 60.0;
                }
                if s < 0.5 && min_allowed < 0.5 {
                    return (s.max(min_allowed) * 100.0).round() / 100.0;
                }
                let mut best = SHORT_PERIODS[0];
                for p in SHORT_PERIODS {
                    // Ties go to the longer period.
                    if (p - s).abs() <= (best - s).abs() {
                        best = p;
                    }
                }
                best.max(min_allowed)
            } else {
                s.min(3600.0).round()
            }
        };
        let want_min = r.update_period.as_secs_f64() as f32;
        let want_max = r.max_update_period.as_secs_f64() as f32;
        let min = legal(want_min);
        let mut max = legal(want_max);
        if max < min {
            max = min;
        }
        let to_time = |s: f32| HartTime((f64::from(s) * 32_000.0).round() as u32);
        let (min_t, max_t) = (to_time(min), to_time(max));
        let code = if min_t != r.update_period || max_t != r.max_update_period {
            8
        } else {
            rc::SUCCESS
        };
        let b = &mut self.cfg.burst[m];
        b.update_period = min_t.0;
        b.max_update_period = max_t.0;
        self.changed();
        Outcome::Reply(
            code,
            encode(&cmd::BurstPeriod {
                burst_message: r.burst_message,
                update_period: min_t,
                max_update_period: max_t,
            }),
        )
    }

    fn write_burst_trigger(&mut self, r: cmd::BurstTrigger) -> Outcome {
        let m = usize::from(r.burst_message);
        if m >= self.cfg.burst.len() {
            return err(9);
        }
        let mode = r.trigger_mode.0;
        if mode > 4 && !self.faults.has(crate::faults::Fault::BurstTriggerAnyMode) {
            return err(13);
        }
        let command = self.cfg.burst[m].command;
        if matches!(command, 38 | 48) && !matches!(mode, 0 | 4) {
            return err(13);
        }
        // Past the check above, a mode over 4 is the fault's: kept like mode 0.
        let (class, units, level) = if matches!(mode, 0 | 4) || mode > 4 {
            (0, 250, hart_nan())
        } else {
            let Some(src_class) = burst::trigger_classification(&self.cfg, m) else {
                return err(13);
            };
            if r.classification.0 != src_class {
                return err(11);
            }
            let src_units = burst::trigger_units(&self.cfg, m).unwrap_or(250);
            if !units::compatible(src_units, r.units.0) {
                return err(12);
            }
            if !r.trigger_level.is_finite() || (mode == 1 && r.trigger_level <= 0.0) {
                return err(rc::INVALID_SELECTION);
            }
            (r.classification.0, r.units.0, r.trigger_level)
        };
        let b = &mut self.cfg.burst[m];
        b.trigger_mode = mode;
        b.trigger_classification = class;
        b.trigger_units = units;
        b.trigger_level = level;
        self.burst[m] = BurstRuntime::default();
        self.changed();
        let code = if class != r.classification.0 || units != r.units.0 {
            8
        } else {
            rc::SUCCESS
        };
        Outcome::Reply(
            code,
            encode(&cmd::BurstTrigger {
                burst_message: r.burst_message,
                trigger_mode: TriggerMode(mode),
                classification: Classification(class),
                units: UnitCode(units),
                trigger_level: level,
            }),
        )
    }

    /// What a BACK of burst message `m` carries: the command number, the response code
    /// and the data of that command's reply.
    ///
    /// Publishing is not a request from a master, so this only looks at the device
    /// (`&self`): a burst of command 38 resets no configuration-changed flag and a burst
    /// of command 48 acknowledges no status for either master.
    pub(crate) fn burst_reply(&self, m: usize, now: Micros) -> (u16, u8, Vec<u8>) {
        let Some(b) = self.cfg.burst.get(m) else {
            return (0, rc::NOT_IMPLEMENTED, vec![]);
        };

        let outcome = match b.command {
            // The reply to a master's command 38, without resetting its flag.
            38 => ok(encode(&cmd::ResetConfigChanged {
                config_change_counter: Some(self.cfg.config_change_counter),
            })),
            // The reply to a legacy command 48, without acknowledging anything.
            48 => ok(encode(&self.additional_status())),
            c @ (1 | 2 | 3 | 9 | 33) => {
                let request = match c {
                    9 => Some(Request::ReadDeviceVariablesWithStatus(
                        cmd::ReadDeviceVariablesRequest {
                            slots: burst_slots(&b.slots),
                        },
                    )),
                    33 => Some(Request::ReadDeviceVariables(cmd::ReadVariablesRequest {
                        slots: burst_slots(&b.slots),
                    })),
                    _ => hart_proto::decode_request(c, &[]).and_then(Result::ok),
                };
                match request {
                    Some(r) => self.process_read(&r, now),
                    None => err(rc::TOO_FEW_DATA_BYTES),
                }
            }
            // Only a hand-written profile or state file can name another command.
            _ => err(rc::NOT_IMPLEMENTED),
        };
        match outcome {
            Outcome::Reply(code, data)
                if hart_proto::tables::response_class(code)
                    != hart_proto::tables::ResponseClass::Error =>
            {
                (b.command, code, data)
            }
            Outcome::Reply(code, _) => (b.command, code, vec![]),
            Outcome::Silent => (b.command, rc::NOT_IMPLEMENTED, vec![]),
        }
    }

    /// The trigger source value of burst message `m`, in its own units.
    pub(crate) fn trigger_value(&self, m: usize) -> Option<(f32, u8)> {
        let b = &self.cfg.burst[m];
        match b.command {
            1 | 3 => {
                let (v, u, _) = self.pv();
                Some((v, u))
            }
            2 => Some((self.percent_of_range(), 57)),
            9 | 33 => self.read_code(b.slots[0]).map(|(v, u, _, _)| (v, u)),
            _ => None,
        }
    }
}

/// Burst mode: when each message is due, and its BACK content (the rules are in
/// [`crate::burst`]).
impl Device {
    /// True when any burst message publishes on this link.
    pub fn burst_mode(&self) -> bool {
        (0..self.config().burst.len()).any(|m| burst::active(self.config(), m))
    }

    fn trigger_holds(&self, m: usize) -> bool {
        let cfg = self.config();
        let b = &cfg.burst[m];
        let rt = self.burst_runtime_ref(m);
        match b.trigger_mode {
            0 => true,
            4 => {
                let value = self.trigger_value(m).map(|x| x.0);
                value != rt.last_value
                    || Some(self.device_status(MasterKind::Primary)) != rt.last_status
            }
            mode => {
                let Some((v, u)) = self.trigger_value(m) else {
                    return true;
                };
                let level =
                    units::convert(b.trigger_level, b.trigger_units, u).unwrap_or(b.trigger_level);
                match mode {
                    1 => {
                        let window = units::convert_span(b.trigger_level, b.trigger_units, u)
                            .unwrap_or(b.trigger_level);
                        rt.last_value.is_none_or(|last| (v - last).abs() > window)
                    }
                    2 => v > level,
                    3 => v < level,
                    _ => true,
                }
            }
        }
    }

    fn message_due(&self, m: usize, now: Micros) -> Option<Micros> {
        if !burst::active(self.config(), m) {
            return None;
        }
        let (min, max) = self.burst_periods(m);
        let Some(last) = self.burst_runtime_ref(m).last_publish else {
            return Some(now);
        };
        Some(if self.trigger_holds(m) {
            last + min
        } else {
            last + max
        })
    }

    /// When the device next wants to publish (`None`: no burst message active).
    pub fn burst_due(&self, now: Micros) -> Option<Micros> {
        (0..self.config().burst.len())
            .filter_map(|m| self.message_due(m, now))
            .min()
    }

    /// When trigger conditions should be looked at again: values move between
    /// publications, so a message waiting for its maximum period is re-checked at its
    /// minimum period.
    pub fn burst_wakeup(&self, now: Micros) -> Option<Micros> {
        (0..self.config().burst.len())
            .filter(|&m| burst::active(self.config(), m))
            .filter_map(|m| {
                let (min, _) = self.burst_periods(m);
                let due = self.message_due(m, now)?;
                let last = self.burst_runtime_ref(m).last_publish.unwrap_or(now);
                // A message already due is the slave's business (it waits for a slot);
                // otherwise look again as soon as the minimum period allows one.
                (due > now).then(|| due.min((last + min).max(now + 50_000)))
            })
            .min()
    }

    fn burst_runtime_ref(&self, m: usize) -> BurstRuntime {
        self.burst.get(m).cloned().unwrap_or_default()
    }

    /// The minimum and maximum update periods of message `m`, µs.
    fn burst_periods(&self, m: usize) -> (Micros, Micros) {
        burst::periods(
            self.config(),
            m,
            self.faults().has(crate::faults::Fault::BurstPeriodOff),
        )
    }

    /// Builds the BACK content of the message due first and records its publication.
    ///
    /// A BACK is the reply the published command would give, with that reply's response
    /// code, and the field device status as the master whose address bit the BACK carries
    /// ([`Device::burst_master`]) sees it. Publishing changes nothing the masters see: no
    /// status bit is reset or acknowledged (a burst of command 38 or 48 included), and cold
    /// start stays reported until that master's next request.
    fn publish_burst(&mut self, reply: &mut Reply, now: Micros) -> u16 {
        self.tick(now);
        let (due, m) = (0..self.config().burst.len())
            .filter_map(|m| self.message_due(m, now).map(|d| (d, m)))
            .min()
            .unwrap_or((now, 0));
        // Keep the cadence: a BACK waits for a slot on the line, so it goes out a little
        // after it was due; count the period from when it was due (never more than one
        // period back).
        let (min, _) = self.burst_periods(m);
        let published = if due <= now && due + min > now {
            due
        } else {
            now
        };
        let (command, code, data) = self.burst_reply(m, now);
        let value = self.trigger_value(m).map(|x| x.0);
        // The on-change trigger compares the primary master's view of the status.
        let trigger_status = self.device_status(MasterKind::Primary);
        let status = self.device_status(self.burst_master());
        if let Some(rt) = self.burst.get_mut(m) {
            rt.last_publish = Some(published);
            rt.last_value = value;
            rt.last_status = Some(trigger_status);
        }
        self.back_count = self.back_count.wrapping_add(1);
        reply.response_code = code;
        reply.device_status = status;
        reply.set_data(&data);
        command
    }
}

impl Handler for Device {
    fn request(&mut self, request: &Frame<'_>, reply: &mut Reply, now: Micros) -> bool {
        match self.handle(request, now) {
            Some((code, status, data)) => {
                reply.response_code = code;
                reply.device_status = status;
                reply.set_data(&data);
                true
            }
            None => false,
        }
    }

    fn burst(&mut self, reply: &mut Reply, now: Micros) -> u16 {
        self.publish_burst(reply, now)
    }

    fn device_status(&self) -> u8 {
        self.device_status(MasterKind::Primary)
    }
}
