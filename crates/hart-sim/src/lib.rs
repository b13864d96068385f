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
pub mod bus;
pub mod cable;
pub mod device;
#[cfg(feature = "json")]
mod json;

pub use hart_modem::channel::{AnalogProfile, LoopModel};
pub use hart_modem::line::{AnalogDisturbance, LineOptions};

use hart_link::master::{MasterOutput, RetryPolicy};
use hart_link::slave::{BurstConfig, Slave, SlaveConfig};
use hart_link::{LinkError, Master, Micros, TimingProfile};
use hart_proto::command::{Identity, ReadDeviceVariablesRequest, ReadVariablesRequest, Request};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Address, Frame, FrameSpec, FrameType, MasterKind, UniqueId};
use hart_proto::types::DeviceVariableCode;
use hart_proto::wire::{List, Reader, Wire, Writer};

use bus::{Attach, Bus, BusEvent, Sender};
use device::SimpleDevice;

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
    /// Replies accepted since the simulation last looked, to check against what the
    /// devices sent.
    replies: Vec<Vec<u8>>,
    /// Failures and outcomes since the simulation last looked.
    failures: Vec<Failure>,
    outcomes: Vec<Outcome>,
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

    /// Outcomes first (they advance the script), then the next request, then whatever
    /// the master wants to send now.
    fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        for _ in 0..2 {
            while let Some(out) = self.m.poll(now) {
                match out {
                    MasterOutput::Transmit(frame, preambles) => {
                        let mut buf = vec![0xFF; preambles];
                        buf.extend_from_slice(frame.as_slice());
                        return Some(buf);
                    }
                    MasterOutput::Done(result) => {
                        let (device, started_us) = self.current;
                        match &result {
                            Ok(r) => {
                                self.completed += 1;
                                self.replies.push(r.as_slice().to_vec());
                            }
                            // An empty polling address during the scan is no failure.
                            Err(_) if matches!(self.phase, Phase::Scan(_)) => {}
                            Err(error) => {
                                self.failed += 1;
                                self.failures.push(Failure {
                                    t_us: now,
                                    master: self.role,
                                    device,
                                    error: *error,
                                });
                            }
                        }
                        if let Phase::Scheduled(index) = self.phase {
                            self.outcomes.push(Outcome {
                                master: self.role,
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
                        request_done(self, reply.as_ref().map(|r| r.as_slice()), now);
                    }
                    MasterOutput::Burst(_) => {}
                }
            }
            if self.m.is_busy() {
                break;
            }
            next_request(self, now);
        }
        None
    }
}

struct SlaveStation {
    link: SlaveLink,
    poll: u8,
    last_reply: Vec<u8>,
    /// The faults of the run (silence and late replies concern this device when they
    /// name its polling address).
    faults: Faults,
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

    /// A character arrives: a silent device hears nothing; a late device learns the
    /// delay of the request this character may end.
    fn receive(&mut self, b: u8, flags: UartFlags, now: Micros) {
        if is_silent(&self.faults, self.poll, now) {
            return;
        }
        if self.faults.late_device.is_some_and(|l| l.poll == self.poll) {
            let delay = reply_delay(&self.faults, self.poll, now);
            self.set_reply_delay(delay);
        }
        match &mut self.link {
            SlaveLink::Simple(sd) => {
                let (s, d) = &mut **sd;
                s.receive(b, flags, now, d)
            }
            SlaveLink::Full(n) => n.receive(b, flags, now),
        }
    }

    /// Bytes to send now (a silent device sends nothing); a reply is kept to check
    /// what the master accepts.
    fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        if is_silent(&self.faults, self.poll, now) {
            return None;
        }
        let (bytes, burst) = match &mut self.link {
            SlaveLink::Simple(sd) => {
                let (s, d) = &mut **sd;
                s.poll(now, d).map(|t| (t.bytes.to_vec(), t.burst))?
            }
            SlaveLink::Full(n) => n.poll(now).map(|b| {
                let burst = Frame::parse(&b).is_ok_and(|f| f.frame_type() == FrameType::Back);
                (b, burst)
            })?,
        };
        if !burst {
            let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
            self.last_reply = bytes[pre..].to_vec();
        }
        Some(bytes)
    }

    fn set_reply_delay(&mut self, delay: Option<Micros>) {
        match &mut self.link {
            SlaveLink::Simple(sd) => sd.0.set_reply_delay(delay),
            SlaveLink::Full(n) => n.slave.set_reply_delay(delay),
        }
    }
}

/// A station of the simulation: a scripted master or a device.
enum Kind {
    Master(Box<MasterStation>),
    Slave(Box<SlaveStation>),
}

impl bus::Station for Kind {
    fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        match self {
            Kind::Master(m) => m.m.receive(byte, flags, now),
            Kind::Slave(s) => s.receive(byte, flags, now),
        }
    }

    fn carrier(&mut self, on: bool) {
        match self {
            Kind::Master(m) => m.m.carrier(on),
            Kind::Slave(s) => match &mut s.link {
                SlaveLink::Simple(sd) => sd.0.carrier(on),
                SlaveLink::Full(n) => n.carrier(on),
            },
        }
    }

    fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        match self {
            Kind::Master(m) => m.poll(now),
            Kind::Slave(s) => s.poll(now),
        }
    }

    fn transmitted(&mut self, now: Micros) {
        match self {
            Kind::Master(m) => m.m.transmitted(now),
            Kind::Slave(s) => match &mut s.link {
                SlaveLink::Simple(sd) => sd.0.transmitted(now),
                SlaveLink::Full(n) => n.transmitted(now),
            },
        }
    }

    fn next_deadline(&self, now: Micros) -> Option<Micros> {
        match self {
            Kind::Master(m) => {
                let d = m.m.next_deadline();
                match m.wake_at(now).filter(|_| !m.m.is_busy()) {
                    Some(wake) => Some(d.map_or(wake, |d| d.min(wake))),
                    None => d,
                }
            }
            Kind::Slave(s) => match &s.link {
                SlaveLink::Simple(sd) => sd.0.next_deadline(),
                SlaveLink::Full(n) => n.next_deadline(now),
            },
        }
    }
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
        .bus
        .stations()
        .filter_map(|st| match st {
            Kind::Slave(s) => Some((s.poll, s.unique_id())),
            Kind::Master(_) => None,
        })
        .collect();
    for st in sim.bus.stations_mut() {
        if let Kind::Master(ms) = st {
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

/// Who each station is, for telling whom a frame is for.
#[derive(Clone, Copy)]
enum Whom {
    Master(Source),
    Device(u8, UniqueId),
}

/// What the line reported, kept until the step is over.
enum Seen {
    Started(usize, Micros, Micros, Vec<u8>),
    Frame(usize, Vec<u8>),
    Ended(usize, Micros, Micros, Vec<u8>, bool),
}

struct Sim<'a> {
    cfg: &'a SimConfig,
    bus: Bus<Kind>,
    whom: Vec<Whom>,
    report: SimReport,
    sent: Vec<Sent>,
    backs: Vec<(Micros, MasterKind)>,
    /// The analog medium's frames, to count those heard.
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
        let p = cfg.profile;
        let mut bus = Bus::new(p, cfg.seed, cfg.ber);
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
            let station = Kind::Master(Box::new(MasterStation {
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
                replies: vec![],
                failures: vec![],
                outcomes: vec![],
            }));
            let attach = match role {
                Source::Primary => Attach::CONTROL_ROOM,
                _ => Attach::HANDHELD,
            };
            bus.add(station, attach);
        }
        for poll in 1..=cfg.devices.min(63) {
            let reply_delay = reply_delay(&cfg.faults, poll, 0);
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
            let station = Kind::Slave(Box::new(SlaveStation {
                link,
                poll,
                last_reply: vec![],
                faults: cfg.faults,
            }));
            bus.add(station, Attach::DEVICE);
        }
        let whom = bus
            .stations()
            .map(|st| match st {
                Kind::Master(m) => Whom::Master(m.role),
                Kind::Slave(s) => Whom::Device(s.poll, s.unique_id()),
            })
            .collect();
        let mut air = None;
        if let Medium::Analog { mut model, options } = cfg.medium {
            model.devices = u32::from(cfg.devices.clamp(1, 63));
            bus.set_analog(model, options);
            air = Some(analog::Air::default());
        }
        Sim {
            cfg,
            bus,
            whom,
            report: SimReport::default(),
            sent: vec![],
            backs: vec![],
            air,
        }
    }

    fn run(mut self) -> SimReport {
        let end = self.cfg.duration;
        let mut seen = vec![];
        while let Some(t) = self.bus.next_event() {
            if t > end {
                break;
            }
            self.step(t, &mut seen);
        }
        self.step(end, &mut seen);
        self.finish(end)
    }

    /// Runs the line to `t`, then takes in what it reported and what the masters did.
    fn step(&mut self, t: Micros, seen: &mut Vec<Seen>) {
        let station = |s: Sender| match s {
            Sender::Station(k) => k,
            Sender::Outside => usize::MAX,
        };
        self.bus.run_until(t, |e| match e {
            BusEvent::Started { src, t0, t1, bytes } => {
                seen.push(Seen::Started(station(src), t0, t1, bytes.to_vec()))
            }
            BusEvent::Frame { to, pdu, .. } => seen.push(Seen::Frame(station(to), pdu.to_vec())),
            BusEvent::Ended {
                src,
                t0,
                t1,
                bytes,
                collided,
            } => seen.push(Seen::Ended(station(src), t0, t1, bytes.to_vec(), collided)),
            BusEvent::Heard { .. } => {}
        });
        for s in seen.drain(..) {
            match s {
                Seen::Started(k, t0, t1, bytes) => self.started(k, t0, t1, bytes),
                Seen::Frame(k, pdu) => self.heard(k, &pdu),
                Seen::Ended(k, t0, t1, bytes, collided) => {
                    self.ended(k, t1);
                    self.finished(k, t0, &bytes, collided, t1);
                }
            }
        }
        let mut replies = vec![];
        for st in self.bus.stations_mut() {
            if let Kind::Master(ms) = st {
                replies.append(&mut ms.replies);
                self.report.failures.append(&mut ms.failures);
                self.report.outcomes.append(&mut ms.outcomes);
            }
        }
        for r in replies {
            if !self.reply_matches_device(&r) {
                self.report.wrong_data += 1;
            }
        }
    }

    /// A transmission by station `src` that started at `t0` ended at `now`.
    fn finished(&mut self, src: usize, t0: Micros, bytes: &[u8], collided: bool, now: Micros) {
        let kind = frame_kind(bytes);
        if collided {
            self.report.collisions += 1;
        }
        let src = match self.whom[src] {
            Whom::Master(role) => role,
            Whom::Device(poll, _) => Source::Device(poll),
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

    /// True when a reply a master accepted is byte for byte what the device sent.
    fn reply_matches_device(&self, pdu: &[u8]) -> bool {
        let Ok(f) = Frame::parse_pdu(pdu) else {
            return false;
        };
        self.bus.stations().any(|st| match st {
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
        for (k, st) in self.bus.stations().enumerate() {
            let src = match st {
                Kind::Master(m) => m.role,
                Kind::Slave(s) => Source::Device(s.poll),
            };
            r.damaged_chars.push((src, self.bus.damaged_chars(k)));
            if let Kind::Master(m) = st {
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
        let carrier = self.bus.carrier_time(end);
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

/// The reply delay of the device at `poll` for a request ending at `now` (`None`: HOLD).
fn reply_delay(faults: &Faults, poll: u8, now: Micros) -> Option<Micros> {
    match faults.late_device {
        Some(l) if l.poll == poll && (l.from..l.until).contains(&now) => Some(l.delay),
        _ => faults
            .slow_device
            .filter(|(a, _)| *a == poll)
            .map(|(_, d)| d),
    }
}

fn is_silent(faults: &Faults, poll: u8, now: Micros) -> bool {
    faults
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
                let command = ms.command;
                send(ms, Address::long(id), command, now);
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
                send(ms, address, r.command, now);
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

/// The request the simulated master sends with `command`: one slot (device variable 0)
/// for commands 9 and 33, the request without data for the others; `None` for a
/// command whose request needs data (it is sent without any, and the device answers
/// "too few data bytes") or that hart-proto does not know.
fn request(command: u16) -> Option<Request> {
    let variable_0 = DeviceVariableCode(0);
    match command {
        9 => Some(Request::ReadDeviceVariablesWithStatus(
            ReadDeviceVariablesRequest {
                slots: List::from_slice(&[variable_0]).ok()?,
            },
        )),
        33 => Some(Request::ReadDeviceVariables(ReadVariablesRequest {
            slots: List::from_slice(&[variable_0]).ok()?,
        })),
        c => hart_proto::decode_request(c, &[]).and_then(Result::ok),
    }
}

/// Starts the master's transaction of `command` with `address`.
fn send(ms: &mut MasterStation, address: Address, command: u16, now: Micros) {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    let n = request(command)
        .and_then(|r| r.encode(&mut w).ok())
        .map_or(0, |()| w.position());
    let _ =
        ms.m.request(&FrameSpec::request(address, command, &buf[..n]), now);
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
