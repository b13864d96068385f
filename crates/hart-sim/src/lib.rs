//! # hart-sim
//!
//! A deterministic discrete-event simulation of one shared HART line, character by
//! character, in virtual time: one or two [`hart_link::Master`]s, N
//! [`hart_link::Slave`]s with minimal responders ([`device::SimpleDevice`]), an optional
//! burst device. Overlapping transmissions collide and every receiver sees damaged
//! characters; bit errors are injected per receiver; devices can fall silent or answer
//! slowly. A seeded generator ([`hart_rng::Rng`]) makes every run reproducible bit
//! for bit.
//!
//! The masters run a fixed script ([`run`]): the primary discovers the devices with
//! command 0 in short frames, then polls them round-robin with a chosen command in long
//! frames; an optional secondary does the same with command 1. Or they follow a given
//! schedule of requests ([`run_schedule`]), one transaction at a time.
//!
//! Two media carry the characters ([`Medium`]). The digital one delivers each
//! character whole at its stop bit, garbled by overlap and by a bit error rate. The
//! analog one ([`Medium::Analog`]) is the loop sample by sample
//! ([`hart_modem::line`]): every station modulates, the signals add on one electrical
//! model of the loop, and every station's own demodulator decides what it heard and
//! when its carrier detect is on, so collisions, noise and too long a cable act
//! through the signal.

mod analog;
pub mod cable;
pub mod device;

pub use hart_modem::channel::{AnalogProfile, LoopModel};
pub use hart_modem::line::{AnalogDisturbance, LineOptions};

use hart_link::master::{MasterOutput, RetryPolicy, MAX_TX_LEN};
use hart_link::slave::{BurstConfig, Slave, SlaveConfig};
use hart_link::{LinkError, Master, Micros, TimingProfile};
use hart_proto::command::Identity;
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType, MasterKind, UniqueId};
use hart_proto::wire::{Reader, Wire};

use device::SimpleDevice;
use hart_rng::Rng;

/// Faults to inject.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Faults {
    /// This polling address stops answering at this time.
    pub silent_device: Option<(u8, Micros)>,
    /// This polling address answers after this delay instead of HOLD.
    pub slow_device: Option<(u8, Micros)>,
    /// A device that answers late for a while (see [`LateDevice`]).
    pub late_device: Option<LateDevice>,
}

/// A device that, from `from` until `until`, answers `delay` after each request instead
/// of HOLD (or its [`Faults::slow_device`] delay).
///
/// Slaves answer without listening, so a delay beyond STO runs the reply into the
/// master's retry, which goes out at STO: the one collision the access rules cannot
/// prevent. Every station then receives the overlapping characters garbled (framing
/// error); the master reports the transaction failed with
/// [`LinkError::CommunicationError`] once its retries are used up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LateDevice {
    /// Polling address of the device.
    pub poll: u8,
    /// Delay from the request's last character to the reply's first.
    pub delay: Micros,
    /// Requests that end at or after this time are answered late...
    pub from: Micros,
    /// ...until this time (exclusive); later ones on time again.
    pub until: Micros,
}

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimConfig {
    /// Physical layer timing.
    pub profile: TimingProfile,
    /// Number of devices (polling addresses 1..=N, at most 63).
    pub devices: u8,
    /// Add a secondary master polling command 1.
    pub secondary: bool,
    /// Put device 1 in burst mode with this period, publishing command 3.
    pub burst_period: Option<Micros>,
    /// Command the primary polls (default 3).
    pub command: u16,
    /// Virtual time to simulate.
    pub duration: Micros,
    /// Bit error rate at every receiver.
    pub ber: f64,
    /// Seed of the random generator.
    pub seed: u64,
    /// Record every transmission.
    pub trace: bool,
    /// Faults.
    pub faults: Faults,
    /// Run full field devices of this profile (`hart-device`) instead of minimal
    /// responders.
    pub device_profile: Option<&'static str>,
    /// What carries the characters.
    pub medium: Medium,
}

/// What carries the characters between the stations.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Medium {
    /// Whole characters at their stop bit; overlapping ones garbled, bit errors at
    /// [`SimConfig::ber`].
    #[default]
    Digital,
    /// The 4-20 mA loop sample by sample. The primary master sits across the sense
    /// resistor, the secondary (a handheld) and the devices at the field end; every
    /// device adds its capacitance (the model's `devices` is set from
    /// [`SimConfig::devices`]). [`SimConfig::ber`] does not apply: errors come from
    /// the noise, the cable and collisions.
    Analog {
        /// The loop: resistance, cable, capacitances, analog current.
        model: LoopModel,
        /// Sample rate, transmit levels, receiver noise.
        options: LineOptions,
    },
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            profile: TimingProfile::fsk(),
            devices: 15,
            secondary: false,
            burst_period: None,
            command: 3,
            duration: 60_000_000,
            ber: 0.0,
            seed: 1,
            trace: false,
            faults: Faults::default(),
            device_profile: None,
            medium: Medium::Digital,
        }
    }
}

/// Who sent a transmission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// The primary master.
    Primary,
    /// The secondary master.
    Secondary,
    /// The device with this polling address.
    Device(u8),
}

impl core::fmt::Display for Source {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Source::Primary => f.write_str("primary"),
            Source::Secondary => f.write_str("secondary"),
            Source::Device(p) => write!(f, "dev:{p}"),
        }
    }
}

/// One transmission on the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TraceRecord {
    /// Start of the first bit.
    pub t0_us: Micros,
    /// End of the last bit.
    pub t1_us: Micros,
    /// Sender.
    pub src: Source,
    /// Everything sent, preambles included.
    pub bytes: Vec<u8>,
    /// True when it overlapped another transmission.
    pub collided: bool,
}

/// Results of a run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimReport {
    /// Virtual time simulated, s.
    pub virtual_seconds: f64,
    /// Completed transactions of the primary master.
    pub transactions_primary: u64,
    /// Completed transactions of the secondary master.
    pub transactions_secondary: u64,
    /// BACK frames sent.
    pub burst_frames: u64,
    /// Transactions that failed after all retries.
    pub failed: u64,
    /// Repeated transmissions.
    pub retries: u64,
    /// Transmissions that overlapped another.
    pub collisions: u64,
    /// Replies accepted by a master whose bytes differ from what the device sent.
    pub wrong_data: u64,
    /// Fraction of the time a carrier was on the line.
    pub line_utilization: f64,
    /// Transactions per second if no time were lost beyond frames and mandatory silences.
    pub theoretical_transactions_per_s: f64,
    /// Achieved / theoretical.
    pub efficiency: f64,
    /// Devices found by the primary's scan.
    pub devices_found: u64,
    /// Mean time between BACK frames, s (0 without burst).
    pub burst_mean_period_s: f64,
    /// True when every BACK carried the other master bit than the one before.
    pub burst_alternates: bool,
    /// Characters each station received damaged (altered by a collision or bit errors,
    /// or flagged by its UART), masters first, then devices by polling address.
    pub damaged_chars: Vec<(Source, u64)>,
    /// Every transaction counted in `failed`, with the error its master reported.
    pub failures: Vec<Failure>,
    /// With [`run_schedule`]: the outcome of every request a master started, in the
    /// order they ended.
    pub outcomes: Vec<Outcome>,
    /// Every transmission, when tracing.
    pub trace: Vec<TraceRecord>,
    /// Analog medium: frames sent to a station that exists (requests to a device,
    /// replies and burst frames to a master).
    pub frames_sent: u64,
    /// Analog medium: those of them the addressee's demodulator decoded intact.
    pub frames_heard: u64,
    /// Analog medium: how much the digital traffic moved the control system's 10 Hz
    /// reading of the 4-20 mA current.
    pub analog_disturbance: Option<AnalogDisturbance>,
}

impl SimReport {
    /// Frames the addressee did not decode, as a fraction of those sent (analog
    /// medium; 0 when none were sent).
    pub fn frame_error_rate(&self) -> f64 {
        if self.frames_sent == 0 {
            0.0
        } else {
            1.0 - self.frames_heard as f64 / self.frames_sent as f64
        }
    }
}

/// A transaction that failed after all retries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Failure {
    /// When the master gave up.
    pub t_us: Micros,
    /// The master.
    pub master: Source,
    /// Polling address of the device it addressed.
    pub device: u8,
    /// What the master reported.
    pub error: LinkError,
}

/// One request of a master's schedule, for [`run_schedule`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScheduledRequest {
    /// The master starts the transaction at this time, or when its previous one ends
    /// if that is later.
    pub at: Micros,
    /// Polling address of the device (there may be none at that address).
    pub device: u8,
    /// Command number (commands 9 and 33 get one slot, device variable 0).
    pub command: u16,
    /// A long frame to the unique ID of the device at that address, instead of a short
    /// frame.
    pub long_frame: bool,
}

/// How a scheduled request ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Outcome {
    /// The master.
    pub master: Source,
    /// Index of the request in that master's schedule.
    pub index: usize,
    /// When the master started the transaction.
    pub started_us: Micros,
    /// When the transaction ended.
    pub ended_us: Micros,
    /// The reply's response code, or the error the master reported.
    pub result: Result<u8, LinkError>,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Phase {
    Scan(u8),
    Poll(usize),
    /// The next request of the schedule.
    Scheduled(usize),
    Done,
}

struct MasterStation {
    m: Master,
    role: Source,
    command: u16,
    scan_last: u8,
    phase: Phase,
    found: Vec<(u8, UniqueId)>,
    completed: u64,
    failed: u64,
    /// The requests to make, in schedule mode.
    schedule: Vec<ScheduledRequest>,
    /// Unique IDs by polling address, for long frames in schedule mode.
    directory: Vec<(u8, UniqueId)>,
    /// Device addressed by the transaction in progress, and when it started.
    current: (u8, Micros),
}

impl MasterStation {
    /// When an idle master next has something to start (`None`: never again).
    fn wake_at(&self, now: Micros) -> Option<Micros> {
        match self.phase {
            Phase::Done => None,
            Phase::Scheduled(k) => self.schedule.get(k).map(|r| r.at.max(now + 1)),
            Phase::Scan(_) | Phase::Poll(_) => Some(now + 1),
        }
    }
}

struct SlaveStation {
    link: SlaveLink,
    poll: u8,
    last_reply: Vec<u8>,
}

/// A minimal responder behind its own slave, or a full field device (node).
enum SlaveLink {
    Simple(Box<(Slave, SimpleDevice)>),
    Full(Box<hart_device::Node>),
}

impl SlaveStation {
    fn unique_id(&self) -> UniqueId {
        match &self.link {
            SlaveLink::Simple(b) => b.1.unique_id(),
            SlaveLink::Full(n) => n.device.unique_id(),
        }
    }

    fn receive(&mut self, b: u8, flags: UartFlags, now: Micros) {
        match &mut self.link {
            SlaveLink::Simple(sd) => {
                let (s, d) = &mut **sd;
                s.receive(b, flags, now, d)
            }
            SlaveLink::Full(n) => n.receive(b, flags, now),
        }
    }

    /// Bytes to send now, and whether they are a burst frame.
    fn poll(&mut self, now: Micros) -> Option<(Vec<u8>, bool)> {
        match &mut self.link {
            SlaveLink::Simple(sd) => {
                let (s, d) = &mut **sd;
                s.poll(now, d).map(|t| (t.bytes.to_vec(), t.burst))
            }
            SlaveLink::Full(n) => n.poll(now).map(|b| {
                let burst = Frame::parse(&b).is_ok_and(|f| f.frame_type() == FrameType::Back);
                (b, burst)
            }),
        }
    }

    fn set_reply_delay(&mut self, delay: Option<Micros>) {
        match &mut self.link {
            SlaveLink::Simple(sd) => sd.0.set_reply_delay(delay),
            SlaveLink::Full(n) => n.slave.set_reply_delay(delay),
        }
    }

    fn transmitted(&mut self, now: Micros) {
        match &mut self.link {
            SlaveLink::Simple(sd) => sd.0.transmitted(now),
            SlaveLink::Full(n) => n.transmitted(now),
        }
    }

    fn next_deadline(&self, now: Micros) -> Option<Micros> {
        match &self.link {
            SlaveLink::Simple(sd) => sd.0.next_deadline(),
            SlaveLink::Full(n) => n.next_deadline(now),
        }
    }

    fn carrier(&mut self, on: bool) {
        match &mut self.link {
            SlaveLink::Simple(sd) => sd.0.carrier(on),
            SlaveLink::Full(n) => n.carrier(on),
        }
    }
}

enum Kind {
    Master(Box<MasterStation>),
    Slave(Box<SlaveStation>),
}

struct Station {
    kind: Kind,
    deadline: Option<Micros>,
    dirty: bool,
    bits_to_error: u64,
    damaged_chars: u64,
}

/// A transmission as the access rules see it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// A request from this master.
    Stx(MasterKind),
    /// A reply to this master.
    Ack(MasterKind),
    /// A burst frame granting the line to this master.
    Back(MasterKind),
    /// Anything else.
    Other,
}

struct Tx {
    src: usize,
    t0: Micros,
    bytes: [u8; MAX_TX_LEN],
    len: usize,
    next: usize,
    overlaps: Vec<(Micros, Micros)>,
    kind: FrameKind,
}

struct Sent {
    t0: Micros,
    t1: Micros,
    kind: FrameKind,
}

/// Runs a simulation: the masters scan and then poll (see the [crate documentation](crate)).
pub fn run(config: &SimConfig) -> SimReport {
    Sim::new(config).run()
}

/// Runs a simulation in which the masters make the requests of `primary` and
/// `secondary` (in order, one transaction at a time) instead of scanning and polling;
/// `config.command` is not used. The secondary master is there when `config.secondary`
/// is set. Every request a master started gets an [`Outcome`] in the report.
pub fn run_schedule(
    config: &SimConfig,
    primary: &[ScheduledRequest],
    secondary: &[ScheduledRequest],
) -> SimReport {
    let mut sim = Sim::new(config);
    let directory: Vec<(u8, UniqueId)> = sim
        .stations
        .iter()
        .filter_map(|st| match &st.kind {
            Kind::Slave(s) => Some((s.poll, s.unique_id())),
            Kind::Master(_) => None,
        })
        .collect();
    for st in &mut sim.stations {
        if let Kind::Master(ms) = &mut st.kind {
            ms.schedule = match ms.role {
                Source::Secondary => secondary.to_vec(),
                _ => primary.to_vec(),
            };
            ms.directory = directory.clone();
            ms.phase = Phase::Scheduled(0);
            ms.m.set_policy(RetryPolicy::default());
        }
    }
    sim.run()
}

struct Sim<'a> {
    cfg: &'a SimConfig,
    stations: Vec<Station>,
    txs: Vec<Tx>,
    rng: Rng,
    report: SimReport,
    sent: Vec<Sent>,
    carrier_until: Micros,
    carrier_time: Micros,
    backs: Vec<(Micros, MasterKind)>,
    /// The analog medium, when it is the one.
    air: Option<analog::Air>,
}

fn frame_kind(bytes: &[u8]) -> FrameKind {
    match Frame::parse(bytes) {
        Ok(f) => match f.frame_type() {
            FrameType::Stx => FrameKind::Stx(f.address.master()),
            FrameType::Ack => FrameKind::Ack(f.address.master()),
            FrameType::Back => FrameKind::Back(f.address.master()),
        },
        Err(_) => FrameKind::Other,
    }
}

impl<'a> Sim<'a> {
    fn new(cfg: &'a SimConfig) -> Self {
        let mut rng = Rng::new(cfg.seed);
        let p = cfg.profile;
        let mut stations = vec![];
        let scan_last = if cfg.devices > 15 { 63 } else { 15 };
        let mut masters = vec![(MasterKind::Primary, Source::Primary, cfg.command)];
        if cfg.secondary {
            masters.push((MasterKind::Secondary, Source::Secondary, 1));
        }
        for (kind, role, command) in masters {
            // A short scan: one retry per polling address.
            let m = Master::new(
                kind,
                p,
                RetryPolicy {
                    retries: 1,
                    ..RetryPolicy::default()
                },
                0,
            );
            stations.push(Station {
                kind: Kind::Master(Box::new(MasterStation {
                    m,
                    role,
                    command,
                    scan_last,
                    phase: Phase::Scan(0),
                    found: vec![],
                    completed: 0,
                    failed: 0,
                    schedule: vec![],
                    directory: vec![],
                    current: (0, 0),
                })),
                deadline: Some(0),
                dirty: true,
                bits_to_error: rng.geometric(cfg.ber),
                damaged_chars: 0,
            });
        }
        for poll in 1..=cfg.devices.min(63) {
            let reply_delay = reply_delay(cfg, poll, 0);
            let link = match cfg.device_profile {
                None => {
                    let dev = SimpleDevice::new(poll);
                    let mut s = Slave::new(
                        SlaveConfig {
                            polling_address: poll,
                            unique_id: dev.unique_id(),
                            reply_delay,
                            response_preambles: 5,
                        },
                        p,
                        0,
                    );
                    if poll == 1 {
                        if let Some(period) = cfg.burst_period {
                            s.set_burst(Some(BurstConfig { period }), period);
                        }
                    }
                    SlaveLink::Simple(Box::new((s, dev)))
                }
                Some(name) => {
                    let mut c = hart_device::profiles::load(name).unwrap_or_default();
                    c.polling_address = poll;
                    c.identity.device_id =
                        c.identity.device_id.wrapping_add(u32::from(poll)) & 0xFF_FFFF;
                    if poll == 1 {
                        if let Some(period) = cfg.burst_period {
                            let b = &mut c.burst[0];
                            b.command = 3;
                            b.control = 1;
                            b.trigger_mode = 0;
                            b.update_period = (period * 32 / 1000) as u32;
                            b.max_update_period = b.update_period;
                        }
                    }
                    let mut node = hart_device::Node::new(hart_device::Device::new(c), p, 0);
                    if let Some(d) = reply_delay {
                        node.slave.set_reply_delay(Some(d));
                    }
                    SlaveLink::Full(Box::new(node))
                }
            };
            stations.push(Station {
                kind: Kind::Slave(Box::new(SlaveStation {
                    link,
                    poll,
                    last_reply: vec![],
                })),
                deadline: Some(0),
                dirty: true,
                bits_to_error: rng.geometric(cfg.ber),
                damaged_chars: 0,
            });
        }
        Sim {
            cfg,
            stations,
            txs: vec![],
            rng,
            report: SimReport::default(),
            sent: vec![],
            carrier_until: 0,
            carrier_time: 0,
            backs: vec![],
            air: None,
        }
        .with_medium()
    }

    fn run(mut self) -> SimReport {
        if self.air.is_some() {
            return self.run_analog();
        }
        let ct = self.cfg.profile.char_time;
        let end = self.cfg.duration;
        loop {
            let t_char = self
                .txs
                .iter()
                .map(|t| t.t0 + (t.next as Micros + 1) * ct)
                .min();
            let t_station = self.stations.iter().filter_map(|s| s.deadline).min();
            let now = match (t_char, t_station) {
                (Some(a), Some(b)) => a.min(b),
                (a, b) => match a.or(b) {
                    Some(t) => t,
                    None => break,
                },
            };
            if now > end {
                break;
            }
            self.deliver(now);
            self.poll_stations(now);
        }
        self.finish(end)
    }

    /// Delivers every character that finishes at `now`.
    fn deliver(&mut self, now: Micros) {
        let ct = self.cfg.profile.char_time;
        let mut i = 0;
        while i < self.txs.len() {
            let tx = &self.txs[i];
            let char_end = tx.t0 + (tx.next as Micros + 1) * ct;
            if char_end != now {
                i += 1;
                continue;
            }
            let start = char_end - ct;
            let collided = tx.overlaps.iter().any(|&(a, b)| a < char_end && b > start);
            let byte = tx.bytes[tx.next];
            let src = tx.src;
            for (k, st) in self.stations.iter_mut().enumerate() {
                if k == src {
                    continue;
                }
                let (b, flags) = corrupt(
                    byte,
                    collided,
                    &mut st.bits_to_error,
                    &mut self.rng,
                    self.cfg.ber,
                );
                if b != byte || flags != UartFlags::OK {
                    st.damaged_chars += 1;
                }
                match &mut st.kind {
                    Kind::Master(m) => m.m.receive(b, flags, now),
                    Kind::Slave(s) => {
                        if !is_silent(self.cfg, s.poll, now) {
                            if let Some(late) = self.cfg.faults.late_device {
                                if late.poll == s.poll {
                                    s.set_reply_delay(reply_delay(self.cfg, s.poll, now));
                                }
                            }
                            s.receive(b, flags, now)
                        }
                    }
                }
                st.dirty = true;
            }
            let tx = &mut self.txs[i];
            tx.next += 1;
            if tx.next == tx.len {
                let tx = self.txs.swap_remove(i);
                if self.txs.is_empty() {
                    for st in &mut self.stations {
                        set_carrier(st, false);
                        st.dirty = true;
                    }
                }
                let collided = !tx.overlaps.is_empty();
                self.finished(tx.src, tx.t0, &tx.bytes[..tx.len], tx.kind, collided, now);
            } else {
                i += 1;
            }
        }
    }

    /// A transmission by station `src` that started at `t0` ended at `now`.
    fn finished(
        &mut self,
        src: usize,
        t0: Micros,
        bytes: &[u8],
        kind: FrameKind,
        collided: bool,
        now: Micros,
    ) {
        let st = &mut self.stations[src];
        st.dirty = true;
        if collided {
            self.report.collisions += 1;
        }
        let src = match &mut st.kind {
            Kind::Master(m) => {
                m.m.transmitted(now);
                m.role
            }
            Kind::Slave(s) => {
                s.transmitted(now);
                Source::Device(s.poll)
            }
        };
        if let FrameKind::Back(to) = kind {
            self.report.burst_frames += 1;
            self.backs.push((t0, to));
        }
        self.sent.push(Sent { t0, t1: now, kind });
        if self.cfg.trace {
            self.report.trace.push(TraceRecord {
                t0_us: t0,
                t1_us: now,
                src,
                bytes: bytes.to_vec(),
                collided,
            });
        }
    }

    fn start_tx(&mut self, src: usize, bytes: &[u8], now: Micros) {
        if self.air.is_some() {
            self.start_analog_tx(src, bytes, now);
            return;
        }
        let ct = self.cfg.profile.char_time;
        let mut tx = Tx {
            src,
            t0: now,
            bytes: [0; MAX_TX_LEN],
            len: bytes.len().min(MAX_TX_LEN),
            next: 0,
            overlaps: vec![],
            kind: FrameKind::Other,
        };
        tx.bytes[..tx.len].copy_from_slice(&bytes[..tx.len]);
        tx.kind = frame_kind(&tx.bytes[..tx.len]);
        let end = now + tx.len as Micros * ct;
        for other in &mut self.txs {
            let other_end = other.t0 + other.len as Micros * ct;
            let overlap = (now, end.min(other_end));
            other.overlaps.push(overlap);
            tx.overlaps.push(overlap);
        }
        // Carrier time: union of transmissions (starts come in time order).
        if now >= self.carrier_until {
            self.carrier_time += end - now;
        } else if end > self.carrier_until {
            self.carrier_time += end - self.carrier_until;
        }
        self.carrier_until = self.carrier_until.max(end);
        self.txs.push(tx);
        // Carrier detect: every other station hears the carrier from the first bit.
        for (k, st) in self.stations.iter_mut().enumerate() {
            if k != src {
                set_carrier(st, true);
                st.dirty = true;
            }
        }
    }

    fn poll_stations(&mut self, now: Micros) {
        for i in 0..self.stations.len() {
            let due = self.stations[i].deadline.is_some_and(|d| d <= now);
            if !(due || self.stations[i].dirty) {
                continue;
            }
            self.stations[i].dirty = false;
            self.poll_station(i, now);
            let st = &mut self.stations[i];
            st.deadline = match &st.kind {
                Kind::Master(m) => m.m.next_deadline(),
                Kind::Slave(s) => s.next_deadline(now),
            }
            .map(|d| d.max(now + 1));
            if let Kind::Master(m) = &st.kind {
                if !m.m.is_busy() {
                    if let Some(wake) = m.wake_at(now) {
                        st.deadline = Some(st.deadline.map_or(wake, |d| d.min(wake)));
                    }
                }
            }
        }
    }

    fn poll_station(&mut self, i: usize, now: Micros) {
        let cfg = self.cfg;
        let mut to_send: Option<Vec<u8>> = None;
        let mut replies: Vec<Vec<u8>> = vec![];
        let mut failures: Vec<Failure> = vec![];
        let mut outcomes: Vec<Outcome> = vec![];
        match &mut self.stations[i].kind {
            Kind::Master(ms) => {
                // Outcomes first (they advance the script), then the next request, then
                // whatever the master wants to send now.
                'outer: for _ in 0..2 {
                    while let Some(out) = ms.m.poll(now) {
                        match out {
                            MasterOutput::Transmit(frame, preambles) => {
                                let mut buf = vec![0xFF; preambles];
                                buf.extend_from_slice(frame.as_slice());
                                to_send = Some(buf);
                                break 'outer;
                            }
                            MasterOutput::Done(result) => {
                                let (device, started_us) = ms.current;
                                match &result {
                                    Ok(r) => {
                                        ms.completed += 1;
                                        replies.push(r.as_slice().to_vec());
                                    }
                                    // An empty polling address during the scan is no failure.
                                    Err(_) if matches!(ms.phase, Phase::Scan(_)) => {}
                                    Err(error) => {
                                        ms.failed += 1;
                                        failures.push(Failure {
                                            t_us: now,
                                            master: ms.role,
                                            device,
                                            error: *error,
                                        });
                                    }
                                }
                                if let Phase::Scheduled(index) = ms.phase {
                                    outcomes.push(Outcome {
                                        master: ms.role,
                                        index,
                                        started_us,
                                        ended_us: now,
                                        result: match &result {
                                            Ok(r) => Ok(Frame::parse_pdu(r.as_slice())
                                                .ok()
                                                .and_then(|f| f.response_code)
                                                .unwrap_or(0)),
                                            Err(e) => Err(*e),
                                        },
                                    });
                                }
                                let reply = result.ok();
                                request_done(ms, reply.as_ref().map(|r| r.as_slice()), now);
                            }
                            MasterOutput::Burst(_) => {}
                        }
                    }
                    if ms.m.is_busy() {
                        break;
                    }
                    next_request(ms, now);
                }
            }
            Kind::Slave(ss) => {
                if !is_silent(cfg, ss.poll, now) {
                    if let Some((bytes, burst)) = ss.poll(now) {
                        if !burst {
                            let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
                            ss.last_reply = bytes[pre..].to_vec();
                        }
                        to_send = Some(bytes);
                    }
                }
            }
        }
        for r in replies {
            if !self.reply_matches_device(&r) {
                self.report.wrong_data += 1;
            }
        }
        self.report.failures.extend(failures);
        self.report.outcomes.extend(outcomes);
        if let Some(bytes) = to_send {
            self.start_tx(i, &bytes, now);
        }
    }

    /// True when a reply a master accepted is byte for byte what the device sent.
    fn reply_matches_device(&self, pdu: &[u8]) -> bool {
        let Ok(f) = Frame::parse_pdu(pdu) else {
            return false;
        };
        self.stations.iter().any(|st| match &st.kind {
            Kind::Slave(s) => {
                let me = match f.address {
                    Address::Short(a) => a.polling_address == s.poll,
                    Address::Long(a) => a.id == s.unique_id(),
                };
                me && s.last_reply == pdu
            }
            Kind::Master(_) => false,
        })
    }

    fn finish(mut self, end: Micros) -> SimReport {
        let p = self.cfg.profile;
        self.finish_analog(end);
        let mut r = std::mem::take(&mut self.report);
        r.virtual_seconds = end as f64 / 1e6;
        for st in &self.stations {
            let src = match &st.kind {
                Kind::Master(m) => m.role,
                Kind::Slave(s) => Source::Device(s.poll),
            };
            r.damaged_chars.push((src, st.damaged_chars));
            if let Kind::Master(m) = &st.kind {
                match m.role {
                    Source::Secondary => r.transactions_secondary = m.completed,
                    _ => {
                        r.transactions_primary = m.completed;
                        r.devices_found = m.found.len() as u64;
                    }
                }
                r.failed += m.failed;
                r.retries += m.m.stats().retries;
            }
        }
        let carrier = self.carrier_time
            - self
                .carrier_until
                .saturating_sub(end)
                .min(self.carrier_time);
        r.line_utilization = carrier as f64 / end.max(1) as f64;
        // Mandatory time: every frame, plus the silences the rules require between
        // consecutive frames (capped at the silence actually there).
        self.sent.sort_by_key(|s| s.t0);
        let mut mandatory: Micros = 0;
        for (k, s) in self.sent.iter().enumerate() {
            mandatory += s.t1.min(end) - s.t0.min(end);
            if let Some(next) = self.sent.get(k + 1) {
                let gap = next.t0.saturating_sub(s.t1);
                mandatory += gap.min(required_gap(&p, s.kind, next.kind));
            }
        }
        let mandatory = mandatory.min(end);
        let total = (r.transactions_primary + r.transactions_secondary) as f64;
        if mandatory > 0 {
            r.theoretical_transactions_per_s = total / (mandatory as f64 / 1e6);
            r.efficiency = mandatory as f64 / end as f64;
        }
        if self.backs.len() > 1 {
            let first = self.backs[0].0;
            let last = self.backs[self.backs.len() - 1].0;
            r.burst_mean_period_s = (last - first) as f64 / 1e6 / (self.backs.len() - 1) as f64;
        }
        r.burst_alternates = self.backs.windows(2).all(|w| w[0].1 != w[1].1);
        r
    }
}

/// The silence the access rules require between two consecutive frames; 0 where the
/// rules require none (anything longer is time lost, e.g. waiting for STO).
pub fn required_gap(p: &TimingProfile, prev: FrameKind, next: FrameKind) -> Micros {
    use FrameKind::*;
    match (prev, next) {
        (Stx(_), Ack(_)) => p.hold,
        (Ack(to), Stx(from)) if to == from => p.rt2,
        (Ack(_), Stx(_)) => p.hold + p.chars(2),
        (Ack(_), Back(_)) => p.hold,
        (Back(to), Stx(from)) if to == from => p.hold,
        _ => 0,
    }
}

fn set_carrier(st: &mut Station, on: bool) {
    match &mut st.kind {
        Kind::Master(m) => m.m.carrier(on),
        Kind::Slave(s) => s.carrier(on),
    }
}

/// The reply delay of the device at `poll` for a request ending at `now` (`None`: HOLD).
fn reply_delay(cfg: &SimConfig, poll: u8, now: Micros) -> Option<Micros> {
    match cfg.faults.late_device {
        Some(l) if l.poll == poll && (l.from..l.until).contains(&now) => Some(l.delay),
        _ => cfg
            .faults
            .slow_device
            .filter(|(a, _)| *a == poll)
            .map(|(_, d)| d),
    }
}

fn is_silent(cfg: &SimConfig, poll: u8, now: Micros) -> bool {
    cfg.faults
        .silent_device
        .is_some_and(|(a, from)| a == poll && now >= from)
}

/// Issues the master's next request according to its script.
fn next_request(ms: &mut MasterStation, now: Micros) {
    loop {
        match ms.phase {
            Phase::Scan(addr) if addr > ms.scan_last => {
                ms.m.set_policy(RetryPolicy::default());
                ms.phase = if ms.found.is_empty() {
                    Phase::Done
                } else {
                    Phase::Poll(0)
                };
            }
            Phase::Scan(addr) => {
                ms.current = (addr, now);
                let _ =
                    ms.m.request(&FrameSpec::request(Address::short(addr), 0, &[]), now);
                return;
            }
            Phase::Poll(k) => {
                let (poll, id) = ms.found[k % ms.found.len()];
                ms.current = (poll, now);
                let _ = ms.m.request(
                    &FrameSpec::request(Address::long(id), ms.command, request_data(ms.command)),
                    now,
                );
                return;
            }
            Phase::Scheduled(k) => {
                let Some(r) = ms.schedule.get(k).copied() else {
                    ms.phase = Phase::Done;
                    return;
                };
                if now < r.at {
                    return;
                }
                let address = if r.long_frame {
                    let id = ms
                        .directory
                        .iter()
                        .find(|(p, _)| *p == r.device)
                        .map_or_else(|| SimpleDevice::new(r.device).unique_id(), |(_, id)| *id);
                    Address::long(id)
                } else {
                    Address::short(r.device)
                };
                ms.current = (r.device, now);
                let _ = ms.m.request(
                    &FrameSpec::request(address, r.command, request_data(r.command)),
                    now,
                );
                return;
            }
            Phase::Done => return,
        }
    }
}

fn request_done(ms: &mut MasterStation, reply: Option<&[u8]>, _now: Micros) {
    match ms.phase {
        Phase::Scan(addr) => {
            if let Some(id) = reply.and_then(identity_of) {
                ms.found.push((addr, id));
            }
            ms.phase = Phase::Scan(addr + 1);
        }
        Phase::Poll(k) => ms.phase = Phase::Poll(k + 1),
        Phase::Scheduled(k) => ms.phase = Phase::Scheduled(k + 1),
        Phase::Done => {}
    }
}

/// Request data the simulated devices need: one slot (device variable 0) for commands 9
/// and 33.
fn request_data(command: u16) -> &'static [u8] {
    if command == 9 || command == 33 {
        &[0]
    } else {
        &[]
    }
}

fn identity_of(pdu: &[u8]) -> Option<UniqueId> {
    let f = Frame::parse_pdu(pdu).ok()?;
    if f.response_code != Some(0) {
        return None;
    }
    Identity::decode(&mut Reader::new(f.data))
        .ok()
        .map(|i| i.unique_id())
}

/// What a receiver makes of one character: collisions garble it with a framing error;
/// bit errors flip bits of the 11-bit character (start, 8 data, odd parity, stop).
fn corrupt(
    byte: u8,
    collided: bool,
    bits_to_error: &mut u64,
    rng: &mut Rng,
    ber: f64,
) -> (u8, UartFlags) {
    if collided {
        return (
            byte ^ (rng.next_u64() as u8 | 1),
            UartFlags {
                framing: true,
                ..UartFlags::OK
            },
        );
    }
    if *bits_to_error >= 11 {
        if *bits_to_error != u64::MAX {
            *bits_to_error -= 11;
        }
        return (byte, UartFlags::OK);
    }
    let parity = u16::from(byte.count_ones() % 2 == 0);
    let mut word: u16 = (u16::from(byte) << 1) | (parity << 9) | (1 << 10);
    let mut pos = *bits_to_error;
    while pos < 11 {
        word ^= 1 << pos;
        pos = pos.saturating_add(1).saturating_add(rng.geometric(ber));
    }
    *bits_to_error = pos - 11;
    let data = (word >> 1) as u8;
    let par = (word >> 9) & 1;
    let parity_error = (data.count_ones() + u32::from(par)) % 2 == 0;
    let framing = word & 1 != 0 || (word >> 10) & 1 == 0;
    (
        data,
        UartFlags {
            parity: parity_error,
            framing,
            overrun: false,
        },
    )
}
