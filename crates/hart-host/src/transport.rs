//! Transports: how bytes reach the line. One trait; a target string selects one.
//!
//! * [`SerialTransport`]: a HART modem on a serial port (or a pseudo-terminal), 1200
//!   bit/s 8O1 by default, optional RTS keying, parity and framing errors reported per
//!   character, optional carrier detect on DCD; or baseband RS-485 with its own
//!   transmission read back and dropped.
//! * [`SimTransport`]: an in-process plant of `hart-device` devices on a simulated
//!   line, in real time or in virtual time (instant); the line either delivers whole
//!   characters or is the 4-20 mA loop sample by sample ([`SimTransport::set_analog`]).

use std::io;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hart_device::{profiles, Device, Node};
use hart_link::{Micros, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_sim::bus::{Attach, Bus, BusEvent, Station};

/// A line to talk HART on.
#[allow(async_fn_in_trait)]
pub trait Transport {
    /// The timing profile of the line.
    fn profile(&self) -> TimingProfile;
    /// The transport's clock, in microseconds.
    fn now(&self) -> Micros;
    /// Sends `bytes` (preambles included) and returns when the last one has left.
    async fn send(&mut self, bytes: &[u8]) -> io::Result<()>;
    /// Waits until bytes arrive or the clock reaches `deadline`. Returns the bytes with
    /// the time each finished arriving (empty on time-out).
    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>>;
    /// Like [`Transport::recv`], with the error flags the UART reported for each
    /// character (parity, framing, overrun). Lines without a UART (simulated plants,
    /// HART-IP) keep this default: every character [`UartFlags::OK`].
    async fn recv_flagged(&mut self, deadline: Micros) -> io::Result<Vec<RxChar>> {
        Ok(self
            .recv(deadline)
            .await?
            .into_iter()
            .map(|(byte, at)| RxChar {
                byte,
                flags: UartFlags::OK,
                at,
            })
            .collect())
    }
    /// The carrier-detect line now, when this transport watches one (a serial port
    /// opened with `carrier=dcd`); `None` when it does not (the default).
    fn carrier(&mut self) -> Option<bool> {
        None
    }
    /// A short description for messages ("serial /dev/ttyUSB0 at 1200 bit/s").
    fn describe(&self) -> String;
    /// Whether the far end has reported that the request in progress will get no
    /// reply (a HART-IP server whose device did not answer on its loop, after its own
    /// retries): the reason, taken once. Lines with no such far end never report it.
    fn take_no_reply(&mut self) -> Option<String> {
        None
    }
}

/// A received character.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RxChar {
    /// The character.
    pub byte: u8,
    /// Errors the UART reported for it.
    pub flags: UartFlags,
    /// When it finished arriving, transport time.
    pub at: Micros,
}

/// RTS keying of a HART modem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Rts {
    /// Leave RTS alone (modems that key themselves, pseudo-terminals).
    None,
    /// RTS high while transmitting.
    HighTx,
    /// RTS low while transmitting.
    LowTx,
}

/// Settings of a serial transport.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialOptions {
    /// Device path.
    pub path: PathBuf,
    /// Bit rate.
    pub baud: u32,
    /// RTS keying.
    pub rts: Rts,
    /// Wait after keying RTS before the first byte.
    pub rts_pre: Duration,
    /// Wait after the last byte before releasing RTS.
    pub rts_post: Duration,
    /// Baseband RS-485: our own transmission is read back and dropped; RS-485 timing.
    pub rs485: bool,
    /// Watch the modem's DCD line as carrier detect (`carrier=dcd`): while it is on
    /// the line counts as busy, even before the first character arrives.
    pub carrier_detect: bool,
}

/// The decoder of marked input (parity and framing errors), hart-serial's.
pub use hart_serial::ParmrkDecoder;
/// Bit rates a serial transport can be opened at.
pub use hart_serial::BAUD_RATES;

/// A serial port or pseudo-terminal.
pub struct SerialTransport {
    port: hart_serial::aio::AsyncPort,
    opts: SerialOptions,
    profile: TimingProfile,
    start: Instant,
    echo: Vec<u8>,
    /// Characters with their error flags from what the port gives.
    reader: hart_serial::ErrorReader,
}

impl SerialTransport {
    /// Opens and configures the port (raw, 8 data bits, odd parity, 1 stop bit,
    /// characters with parity or framing errors marked, see [`ParmrkDecoder`]).
    pub fn open(opts: SerialOptions) -> io::Result<Self> {
        let port = hart_serial::Port::open(
            &opts.path,
            &hart_serial::Line::hart(opts.baud),
            hart_serial::OpenOptions {
                mark_errors: true,
                ..Default::default()
            },
        )?;
        if opts.carrier_detect {
            port.modem_lines().map_err(|e| {
                io::Error::new(
                    e.kind(),
                    format!("carrier=dcd: {e}; leave out carrier=dcd for ports without a DCD line"),
                )
            })?;
        }
        let reader = hart_serial::ErrorReader::new(&port);
        let profile = if opts.rs485 && opts.baud > 1200 {
            TimingProfile::rs485(opts.baud)
        } else if opts.rs485 {
            TimingProfile::rs485(1200)
        } else {
            TimingProfile::fsk()
        };
        let port = hart_serial::aio::AsyncPort::new(port)?;
        let t = SerialTransport {
            port,
            opts,
            profile,
            start: Instant::now(),
            echo: vec![],
            reader,
        };
        t.set_rts(false);
        Ok(t)
    }

    fn set_rts(&self, transmitting: bool) {
        let level = match self.opts.rts {
            Rts::None => return,
            Rts::HighTx => transmitting,
            Rts::LowTx => !transmitting,
        };
        let _ = self.port.get_ref().set_rts(level);
    }
}

impl Transport for SerialTransport {
    fn profile(&self) -> TimingProfile {
        self.profile
    }

    fn now(&self) -> Micros {
        self.start.elapsed().as_micros() as Micros
    }

    async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.set_rts(true);
        if !self.opts.rts_pre.is_zero() {
            tokio::time::sleep(self.opts.rts_pre).await;
        }
        if let Err(e) = self.port.write_all(bytes).await {
            self.set_rts(false);
            return Err(e);
        }
        // Wait until the UART has sent everything (a pseudo-terminal returns at once).
        self.port.get_ref().drain();
        if !self.opts.rts_post.is_zero() {
            tokio::time::sleep(self.opts.rts_post).await;
        }
        self.set_rts(false);
        if self.opts.rs485 {
            self.echo.extend_from_slice(bytes);
        }
        Ok(())
    }

    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>> {
        let chars = self.recv_flagged(deadline).await?;
        Ok(chars.into_iter().map(|c| (c.byte, c.at)).collect())
    }

    async fn recv_flagged(&mut self, deadline: Micros) -> io::Result<Vec<RxChar>> {
        let ct = self.profile.char_time;
        loop {
            let now = self.now();
            if now >= deadline {
                return Ok(vec![]);
            }
            let wait = Duration::from_micros(deadline - now);
            let mut buf = [0u8; 512];
            // A hang-up (a pseudo-terminal whose other end closed, a modem that
            // dropped the line) is an error: it would otherwise look like silence
            // forever.
            let Ok(n) = tokio::time::timeout(wait, self.port.read(&mut buf)).await else {
                return Ok(vec![]);
            };
            let n = n?;
            let t = self.now();
            let chars = self.reader.decode(self.port.get_ref(), &buf[..n]);
            let n = chars.len();
            let mut out = Vec::with_capacity(n);
            for (i, (byte, flags)) in chars.into_iter().enumerate() {
                // Drop our own transmission read back on a two-wire RS-485 line (a
                // damaged character while it is expected is taken as a damaged echo).
                if !self.echo.is_empty() && (self.echo[0] == byte || flags.any()) {
                    self.echo.remove(0);
                    continue;
                }
                self.echo.clear();
                out.push(RxChar {
                    byte,
                    flags,
                    at: t.saturating_sub((n - 1 - i) as Micros * ct),
                });
            }
            if !out.is_empty() {
                return Ok(out);
            }
        }
    }

    fn carrier(&mut self) -> Option<bool> {
        if !self.opts.carrier_detect {
            return None;
        }
        Some(self.port.get_ref().modem_lines().ok()?.carrier)
    }

    fn describe(&self) -> String {
        format!(
            "{} {} at {} bit/s",
            if self.opts.rs485 { "RS-485" } else { "serial" },
            self.opts.path.display(),
            self.opts.baud
        )
    }
}

/// One device of a simulated plant.
#[derive(Debug, Clone, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantDevice {
    /// Built-in profile name or profile file.
    pub profile: String,
    /// Polling address.
    pub poll: u8,
    /// Burst: command published and period in seconds.
    #[serde(default)]
    pub burst: Option<PlantBurst>,
    /// HART universal revision the device speaks (5, 6 or 7), overriding its
    /// profile's (`revision = 5` makes a HART 5 identity of any profile).
    #[serde(default)]
    pub revision: Option<u8>,
    /// Rules the device breaks on purpose, by name (`faults = ["late-reply"]`; the
    /// names are in [`hart_device::faults::ALL`]), for testing conformance testers.
    #[serde(default)]
    pub faults: Vec<String>,
}

/// Burst settings of a plant device.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlantBurst {
    /// Command published (1, 2, 3, 9, 33, 48).
    pub command: u16,
    /// Period, s.
    pub period: f32,
}

/// A simulated plant: `[[device]]` entries.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plant {
    /// The devices.
    pub device: Vec<PlantDevice>,
}

impl Plant {
    /// The built-in demo plant: a pressure transmitter (1), a temperature transmitter
    /// in burst mode (2), a valve positioner (3) and a pressure transmitter at 17.
    pub fn demo() -> Self {
        let d = |profile: &str, poll: u8, burst: Option<PlantBurst>| PlantDevice {
            profile: profile.into(),
            poll,
            burst,
            ..Default::default()
        };
        Plant {
            device: vec![
                d("pressure", 1, None),
                d(
                    "temperature",
                    2,
                    Some(PlantBurst {
                        command: 3,
                        period: 2.0,
                    }),
                ),
                d("valve", 3, None),
                d("pressure", 17, None),
            ],
        }
    }

    /// Reads a plant file.
    pub fn load(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("plant file {}: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| format!("plant file {}: {e}", path.display()))
    }

    /// A plant of `profiles` (built-in names or profile files) at polling addresses 1,
    /// 2, ... in the order given, none bursting: what `hartkit serve --sim PROFILES...`
    /// puts behind the server. `xN` after a profile makes N devices of it (`pressure
    /// x15`). More than 63 profiles is an error (polling addresses end at 63).
    pub fn from_profiles(given: &[String]) -> Result<Self, String> {
        // `PROFILE xN`: N devices of that profile.
        let mut profiles: Vec<String> = vec![];
        for p in given {
            let count = p
                .strip_prefix('x')
                .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
            match (count, profiles.last().cloned()) {
                (Some(n), Some(last)) => {
                    let n: usize = n.parse().unwrap_or(usize::MAX);
                    if n == 0 || n > 63 {
                        return Err(format!("{p}: give 1 to 63 devices"));
                    }
                    profiles.extend(std::iter::repeat_n(last, n - 1));
                }
                (Some(_), None) => {
                    return Err(format!(
                        "{p} repeats the profile before it; give one first (pressure {p})"
                    ))
                }
                (None, _) => profiles.push(p.clone()),
            }
        }
        if profiles.len() > 63 {
            return Err(format!(
                "{} profiles given; a loop has polling addresses 1-63 for them, so give at most 63",
                profiles.len()
            ));
        }
        Ok(Plant {
            device: profiles
                .iter()
                .zip(1u8..)
                .map(|(p, poll)| PlantDevice {
                    profile: p.clone(),
                    poll,
                    burst: None,
                    ..Default::default()
                })
                .collect(),
        })
    }

    /// Builds the devices, configured as they go on the line (polling address, device
    /// ID offset by the polling address, loop current mode, burst message), without a
    /// data-link slave: for hosts that answer them in memory (`hartkit serve --sim
    /// --instant`). Fails naming the profile that cannot be loaded.
    pub fn devices(&self) -> Result<Vec<Device>, String> {
        let mut devices = vec![];
        for d in &self.device {
            let mut c = profiles::load(&d.profile)?;
            c.polling_address = d.poll & 0x3F;
            c.loop_current_mode = u8::from(d.poll == 0);
            c.identity.device_id = (c.identity.device_id + u32::from(d.poll)) & 0xFF_FFFF;
            if let Some(r) = d.revision {
                if !(5..=7).contains(&r) {
                    return Err(format!(
                        "device at polling address {}: revision = {r}: give 5, 6 or 7",
                        d.poll
                    ));
                }
                c.identity.universal_revision = r;
            }
            if let Some(b) = &d.burst {
                let m = &mut c.burst[0];
                m.command = b.command;
                m.control = 1;
                m.update_period = (b.period * 32_000.0) as u32;
                m.max_update_period = m.update_period;
            }
            let mut device = Device::new(c);
            device.set_faults(hart_device::faults::Faults::of(&self.faults_of(d)?));
            devices.push(device);
        }
        Ok(devices)
    }

    /// Builds the devices ([`Plant::devices`]), each behind its data-link slave on a
    /// line with `profile`.
    pub fn nodes(&self, profile: TimingProfile) -> Result<Vec<Node>, String> {
        let mut nodes = vec![];
        for (d, spec) in self.devices()?.into_iter().zip(&self.device) {
            let mut node = Node::new(d, profile, 0);
            node.set_faults(&self.faults_of(spec)?);
            nodes.push(node);
        }
        Ok(nodes)
    }

    /// The faults a plant device is told to commit; an unknown name is an error that
    /// lists the known ones.
    fn faults_of(&self, d: &PlantDevice) -> Result<Vec<hart_device::faults::Fault>, String> {
        d.faults
            .iter()
            .map(|name| {
                hart_device::faults::Fault::parse(name)
                    .map_err(|e| format!("device at polling address {}: {e}", d.poll))
            })
            .collect()
    }
}

/// A secondary master inside the simulated plant, reading command 1 now and then.
struct Secondary {
    master: hart_link::Master,
    polls: Vec<u8>,
    next: usize,
    every: Micros,
    next_at: Micros,
    done: u64,
}

impl Secondary {
    /// Lets the master act at `t`; returns the bytes it sends, if any.
    fn poll(&mut self, t: Micros) -> Option<Vec<u8>> {
        if !self.master.is_busy() && t >= self.next_at && !self.polls.is_empty() {
            let poll = self.polls[self.next % self.polls.len()];
            self.next += 1;
            let _ = self.master.request(
                &hart_proto::FrameSpec::request(hart_proto::Address::short(poll), 1, &[]),
                t,
            );
        }
        while let Some(out) = self.master.poll(t) {
            match out {
                hart_link::MasterOutput::Transmit(f, pre) => {
                    let mut bytes = vec![0xFF; pre];
                    bytes.extend_from_slice(f.as_slice());
                    return Some(bytes);
                }
                hart_link::MasterOutput::Done(r) => {
                    if r.is_ok() {
                        self.done += 1;
                    }
                    self.next_at = t + self.every;
                }
                hart_link::MasterOutput::Burst(_) => {}
            }
        }
        None
    }
}

/// A station of the simulated plant's line: a field device, or the in-plant
/// secondary master.
enum PlantStation {
    Device(Box<Node>),
    Secondary(Box<Secondary>),
}

impl Station for PlantStation {
    fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        match self {
            PlantStation::Device(n) => n.receive(byte, flags, now),
            PlantStation::Secondary(s) => s.master.receive(byte, flags, now),
        }
    }
    fn carrier(&mut self, on: bool) {
        match self {
            PlantStation::Device(n) => n.carrier(on),
            PlantStation::Secondary(s) => s.master.carrier(on),
        }
    }
    fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        match self {
            PlantStation::Device(n) => n.poll(now),
            PlantStation::Secondary(s) => s.poll(now),
        }
    }
    fn transmitted(&mut self, now: Micros) {
        match self {
            PlantStation::Device(n) => n.transmitted(now),
            PlantStation::Secondary(s) => s.master.transmitted(now),
        }
    }
    fn next_deadline(&self, now: Micros) -> Option<Micros> {
        match self {
            PlantStation::Device(n) => n.next_deadline(now),
            PlantStation::Secondary(s) if s.master.is_busy() => s.master.next_deadline(),
            PlantStation::Secondary(s) => Some(s.next_at),
        }
    }
}

/// An in-process plant on a simulated line: the devices (and an optional handheld)
/// are stations of [`hart_sim::bus::Bus`], the host is its outside.
pub struct SimTransport {
    bus: Bus<PlantStation>,
    profile: TimingProfile,
    start: Instant,
    virtual_time: Option<Micros>,
    /// Characters on the way to the host, in order.
    pending: Vec<RxChar>,
    /// The plant is on the analog loop.
    analog: bool,
}

impl SimTransport {
    /// A plant in real time (`virtual_time` false) or in virtual time, where waiting
    /// costs nothing.
    pub fn new(plant: &Plant, virtual_time: bool) -> Result<Self, String> {
        let profile = TimingProfile::fsk();
        let mut bus = Bus::new(profile, 0, 0.0);
        // The plant's digital line is ideal: it tests the devices and the host, not
        // the line (the analog loop is the line as it is).
        bus.set_ideal(true);
        // The host's modem sits across the sense resistor.
        bus.add_outside(Attach::CONTROL_ROOM);
        for node in plant.nodes(profile)? {
            bus.add(PlantStation::Device(Box::new(node)), Attach::DEVICE);
        }
        Ok(SimTransport {
            bus,
            profile,
            start: Instant::now(),
            virtual_time: virtual_time.then_some(0),
            pending: vec![],
            analog: false,
        })
    }

    /// Puts the plant on the 4-20 mA loop, sample by sample: every character goes
    /// through the sender's modulator, the loop and each receiver's demodulator
    /// ([`hart_modem::line`]), so what arrives may be damaged, late or lost as on a
    /// real loop. Each device adds its capacitance to `model`.
    pub fn set_analog(
        &mut self,
        mut model: hart_modem::channel::LoopModel,
        options: hart_modem::line::LineOptions,
    ) {
        model.devices = self.devices().max(1) as u32;
        self.bus.set_analog(model, options);
        self.analog = true;
    }

    /// The number of field devices.
    fn devices(&self) -> usize {
        self.bus
            .stations()
            .filter(|s| matches!(s, PlantStation::Device(_)))
            .count()
    }

    /// Adds a secondary master that reads command 1 from each device in turn, one
    /// request every `every` µs (a handheld on the same loop).
    pub fn add_secondary(&mut self, every: Micros) {
        let polls = self
            .bus
            .stations()
            .filter_map(|s| match s {
                PlantStation::Device(n) => Some(n.device.config().polling_address),
                PlantStation::Secondary(_) => None,
            })
            .collect();
        let now = self.bus.now();
        let master = hart_link::Master::new(
            hart_proto::MasterKind::Secondary,
            self.profile,
            hart_link::RetryPolicy::default(),
            now,
        );
        let secondary = Secondary {
            master,
            polls,
            next: 0,
            every,
            next_at: now + every,
            done: 0,
        };
        self.bus.add(
            PlantStation::Secondary(Box::new(secondary)),
            Attach::HANDHELD,
        );
    }

    /// Transactions the in-plant secondary master completed.
    pub fn secondary_transactions(&self) -> u64 {
        self.bus
            .stations()
            .map(|s| match s {
                PlantStation::Secondary(s) => s.done,
                PlantStation::Device(_) => 0,
            })
            .sum()
    }

    /// The simulated devices.
    pub fn nodes_mut(&mut self) -> impl Iterator<Item = &mut Node> {
        self.bus.stations_mut().filter_map(|s| match s {
            PlantStation::Device(n) => Some(&mut **n),
            PlantStation::Secondary(_) => None,
        })
    }

    /// Runs the line up to `until`; what the stations send reaches the host (and the
    /// other stations).
    fn run_devices(&mut self, until: Micros) {
        let pending = &mut self.pending;
        self.bus.run_until(until, |e| {
            if let BusEvent::Heard { byte, flags, at } = e {
                pending.push(RxChar { byte, flags, at });
            }
        });
    }

    /// Lets the clock reach `end`: at once in virtual time, by sleeping in real time.
    async fn pass_time(&mut self, end: Micros) {
        match &mut self.virtual_time {
            Some(v) => *v = end,
            None => {
                tokio::time::sleep(Duration::from_micros(
                    end.saturating_sub(self.start.elapsed().as_micros() as Micros),
                ))
                .await
            }
        }
    }
}

impl Transport for SimTransport {
    fn profile(&self) -> TimingProfile {
        self.profile
    }

    fn now(&self) -> Micros {
        self.virtual_time
            .unwrap_or_else(|| self.start.elapsed().as_micros() as Micros)
    }

    async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
        let mut t0 = self.now().max(self.bus.now());
        self.run_devices(t0);
        if !self.analog {
            // The ideal line: the host's modem waits for what a station is sending to
            // end, as a master that senses the carrier would (on the analog loop the
            // host sees the carrier itself).
            while self.bus.quiet_at() > t0 {
                t0 = self.bus.quiet_at();
                self.run_devices(t0);
            }
        }
        // The host's modem sends; the stations hear it as the line runs on.
        let end = self.bus.transmit(bytes, t0);
        self.run_devices(end);
        self.pass_time(end).await;
        Ok(())
    }

    async fn recv(&mut self, deadline: Micros) -> io::Result<Vec<(u8, Micros)>> {
        Ok(self
            .recv_flagged(deadline)
            .await?
            .into_iter()
            .map(|c| (c.byte, c.at))
            .collect())
    }

    fn carrier(&mut self) -> Option<bool> {
        self.analog.then(|| self.bus.outside_carrier())
    }

    async fn recv_flagged(&mut self, deadline: Micros) -> io::Result<Vec<RxChar>> {
        loop {
            let now = self.now();
            let horizon = if self.virtual_time.is_some() {
                deadline
            } else {
                now
            };
            self.run_devices(horizon);
            let n = self.pending.iter().take_while(|p| p.at <= horizon).count();
            if n > 0 {
                let ready: Vec<RxChar> = self.pending.drain(..n).collect();
                if let (Some(v), Some(last)) = (&mut self.virtual_time, ready.last()) {
                    *v = (*v).max(last.at);
                }
                return Ok(ready);
            }
            if let Some(v) = &mut self.virtual_time {
                *v = (*v).max(deadline);
                return Ok(vec![]);
            }
            if now >= deadline {
                return Ok(vec![]);
            }
            let next = self
                .bus
                .next_event()
                .unwrap_or(deadline)
                .min(deadline)
                .min(now + 20_000);
            tokio::time::sleep(Duration::from_micros(next.saturating_sub(now).max(200))).await;
        }
    }

    fn describe(&self) -> String {
        format!(
            "simulated plant of {} device(s){}{}",
            self.devices(),
            match self.bus.analog_model() {
                Some(m) => format!(" on an analog loop ({} m of cable)", m.cable_length_m),
                None => String::new(),
            },
            if self.virtual_time.is_some() {
                " (virtual time)"
            } else {
                ""
            }
        )
    }
}
