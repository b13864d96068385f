//! The one runner of a multidrop HART line: stations on a shared line, character by
//! character, sans-IO with the time injected.
//!
//! Every simulated line of hartkit runs here: [`crate::run`]'s scripted masters and
//! devices, `hart-host`'s simulated plant (`SimTransport`, the host outside the line
//! in virtual or real time) and `hartkit sim serve` (devices on a real serial port or
//! pseudo-terminal, in real time). What differs between them is a parameter, not a
//! copy: the stations ([`Station`], implemented for [`hart_device::Node`]), whether
//! something outside the simulation listens and talks ([`Bus::add_outside`],
//! [`Bus::transmit`], [`Bus::receive_outside`]), the medium (digital by default, the
//! analog loop with [`Bus::set_analog`]) and who owns the clock: the caller passes
//! "now" to [`Bus::run_until`], from virtual time or from a real clock.
//!
//! The digital medium delivers each character whole at its stop bit to every other
//! station; characters of overlapping transmissions arrive garbled (framing error),
//! and bit errors are drawn per receiver at a bit error rate from a seeded
//! [`hart_rng::Rng`]. Carrier detect is on from the first bit of a transmission until
//! the line is quiet. The analog medium is [`hart_modem::line::AnalogLine`]: every
//! station's own modulator and demodulator on one electrical model of the loop, so
//! collisions, noise and the cable act through the signal.
//!
//! A station is polled when its deadline is due or something happened to it (a
//! character, a carrier change, the end of its transmission); what it returns goes on
//! the line at once.

use hart_link::{Micros, TimingProfile};
use hart_modem::channel::LoopModel;
use hart_modem::line::{
    AnalogDisturbance, AnalogLine, Drive, LineEvent, LineOptions, Place, PortId,
};
use hart_proto::deframer::UartFlags;
use hart_rng::Rng;

/// Longest step of the analog line between two looks at the stations, µs: what a
/// demodulator finds reaches its station within about 1 ms (on top of the
/// demodulator's own few bits of decision delay, as with a hardware modem).
pub const ANALOG_STEP_US: Micros = 1_000;

/// A station on the line: a link layer with whatever drives it (a field device, a
/// master with its script).
pub trait Station {
    /// A character arrived (its stop bit ended at `now`), with its UART's flags.
    fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros);
    /// Carrier detect changed.
    fn carrier(&mut self, on: bool);
    /// What to transmit now (preambles included), if anything.
    fn poll(&mut self, now: Micros) -> Option<Vec<u8>>;
    /// The last character of the station's transmission left at `now`.
    fn transmitted(&mut self, now: Micros);
    /// When the station next needs [`Station::poll`] (`None`: only when something
    /// happens to it).
    fn next_deadline(&self, now: Micros) -> Option<Micros>;
}

impl Station for hart_device::Node {
    fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        hart_device::Node::receive(self, byte, flags, now)
    }
    fn carrier(&mut self, on: bool) {
        hart_device::Node::carrier(self, on)
    }
    fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        hart_device::Node::poll(self, now)
    }
    fn transmitted(&mut self, now: Micros) {
        hart_device::Node::transmitted(self, now)
    }
    fn next_deadline(&self, now: Micros) -> Option<Micros> {
        hart_device::Node::next_deadline(self, now)
    }
}

/// Where a station (or the outside) is attached to the analog loop; the digital
/// medium does not use it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attach {
    /// Control room (across the sense resistor) or field end of the cable.
    pub place: Place,
    /// How its modem drives the loop.
    pub drive: Drive,
}

impl Attach {
    /// A field device: current-modulating, at the field end.
    pub const DEVICE: Attach = Attach {
        place: Place::Field,
        drive: Drive::Current,
    };
    /// The primary master: voltage-modulating, across the sense resistor.
    pub const CONTROL_ROOM: Attach = Attach {
        place: Place::ControlRoom,
        drive: Drive::Voltage,
    };
    /// A handheld (secondary master): voltage-modulating, at the field end.
    pub const HANDHELD: Attach = Attach {
        place: Place::Field,
        drive: Drive::Voltage,
    };
}

/// Who sent a transmission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sender {
    /// The station with this index ([`Bus::add`]).
    Station(usize),
    /// The outside ([`Bus::transmit`]).
    Outside,
}

/// What happened on the line, reported by [`Bus::run_until`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BusEvent<'a> {
    /// A transmission started at `t0`; its last character leaves at `t1`.
    Started {
        /// Its sender.
        src: Sender,
        /// Start of the first bit.
        t0: Micros,
        /// End of the last bit.
        t1: Micros,
        /// Everything sent, preambles included.
        bytes: &'a [u8],
    },
    /// The outside received a character a station sent.
    Heard {
        /// The byte as received.
        byte: u8,
        /// Its UART flags.
        flags: UartFlags,
        /// End of its stop bit.
        at: Micros,
    },
    /// Analog medium: a receiver's demodulator decoded a whole frame with a good check
    /// byte.
    Frame {
        /// The receiver.
        to: Sender,
        /// Delimiter through check byte.
        pdu: &'a [u8],
        /// When.
        at: Micros,
    },
    /// A transmission ended.
    Ended {
        /// Its sender.
        src: Sender,
        /// Start of the first bit.
        t0: Micros,
        /// End of the last bit.
        t1: Micros,
        /// Everything sent.
        bytes: &'a [u8],
        /// It overlapped another transmission.
        collided: bool,
    },
}

struct Slot<S> {
    station: S,
    attach: Attach,
    deadline: Option<Micros>,
    dirty: bool,
    bits_to_error: u64,
    damaged: u64,
}

impl<S> Slot<S> {
    /// Something happened to the station outside a step: it is polled at `now`.
    fn wake(&mut self, now: Micros) {
        self.dirty = true;
        self.deadline = Some(self.deadline.map_or(now, |d| d.min(now)));
    }
}

/// A transmission on the line.
struct Tx {
    src: Sender,
    t0: Micros,
    end: Micros,
    bytes: Vec<u8>,
    /// Digital: the next character to deliver.
    next: usize,
    /// Digital: the stretches during which another transmission was on the line.
    overlaps: Vec<(Micros, Micros)>,
    collided: bool,
}

/// The analog loop and the port of each station.
struct Analog {
    line: AnalogLine,
    ports: Vec<PortId>,
    outside: Option<PortId>,
    outside_carrier: bool,
}

/// A multidrop line of stations of type `S` (see the [module documentation](self)).
pub struct Bus<S> {
    profile: TimingProfile,
    slots: Vec<Slot<S>>,
    txs: Vec<Tx>,
    rng: Rng,
    ber: f64,
    /// The outside listens: its attachment and bit error budget.
    outside: Option<(Attach, u64)>,
    analog: Option<Analog>,
    now: Micros,
    carrier_until: Micros,
    carrier_time: Micros,
    /// An ideal line ([`Bus::set_ideal`]).
    ideal: bool,
}

impl<S: Station> Bus<S> {
    /// An empty digital line with `profile`'s character time, bit errors at `ber` at
    /// every receiver, drawn from a generator seeded with `seed`.
    pub fn new(profile: TimingProfile, seed: u64, ber: f64) -> Self {
        Bus {
            profile,
            slots: vec![],
            txs: vec![],
            rng: Rng::new(seed),
            ber,
            outside: None,
            analog: None,
            now: 0,
            carrier_until: 0,
            carrier_time: 0,
            ideal: false,
        }
    }

    /// Makes the digital medium ideal (the analog loop is never): one transmission at a time (a station due while
    /// another sends is polled when the line is quiet again, so nothing collides), and
    /// every character reaches the other stations and the outside as soon as its
    /// transmission starts, stamped with the time it will end; carrier detect is not
    /// driven. For lines whose stations are tested rather than the line itself:
    /// `hart-host`'s simulated plant (two devices answering one broadcast, such as
    /// command 11 to a tag they share, answer one after the other) and `hartkit sim
    /// serve`, whose real timing is the port's (a pseudo-terminal delivers a whole
    /// write at once, and the host may answer before the characters would have ended
    /// on a wire), so that the stations hear each other in the order the host does.
    pub fn set_ideal(&mut self, on: bool) {
        self.ideal = on;
    }

    /// The line is ideal (never on the analog medium).
    fn is_ideal(&self) -> bool {
        self.ideal && self.analog.is_none()
    }

    /// Adds a station (polled at once); returns its index.
    pub fn add(&mut self, station: S, attach: Attach) -> usize {
        let bits_to_error = self.rng.geometric(self.ber);
        self.slots.push(Slot {
            station,
            attach,
            deadline: Some(self.now),
            dirty: true,
            bits_to_error,
            damaged: 0,
        });
        if let Some(a) = &mut self.analog {
            a.ports.push(a.line.add_port(attach.place, attach.drive));
        }
        self.slots.len() - 1
    }

    /// Lets something outside the simulation listen: what the stations send is
    /// reported as [`BusEvent::Heard`].
    pub fn add_outside(&mut self, attach: Attach) {
        let bits = self.rng.geometric(self.ber);
        self.outside = Some((attach, bits));
        if let Some(a) = &mut self.analog {
            a.outside = Some(a.line.add_port(attach.place, attach.drive));
        }
    }

    /// Puts the line on the 4-20 mA loop sample by sample ([`hart_modem::line`]), the
    /// outside first, then every station in order. Call it while the line is quiet.
    pub fn set_analog(&mut self, model: LoopModel, options: LineOptions) {
        let mut line = AnalogLine::new(model, options);
        let outside = self.outside.map(|(a, _)| line.add_port(a.place, a.drive));
        let ports = self
            .slots
            .iter()
            .map(|s| line.add_port(s.attach.place, s.attach.drive))
            .collect();
        self.analog = Some(Analog {
            line,
            ports,
            outside,
            outside_carrier: false,
        });
    }

    /// The line's timing profile.
    pub fn profile(&self) -> TimingProfile {
        self.profile
    }

    /// How far the line has run.
    pub fn now(&self) -> Micros {
        self.now
    }

    /// The number of stations.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// True without stations.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Station `i`.
    pub fn station(&self, i: usize) -> &S {
        &self.slots[i].station
    }

    /// Station `i`, to change (it is polled at the next step).
    pub fn station_mut(&mut self, i: usize) -> &mut S {
        let now = self.now;
        let s = &mut self.slots[i];
        s.wake(now);
        &mut s.station
    }

    /// Every station, in order.
    pub fn stations(&self) -> impl Iterator<Item = &S> {
        self.slots.iter().map(|s| &s.station)
    }

    /// Every station, in order, to read what it keeps or change it; a station is
    /// polled again at its deadline or when something happens to it (use
    /// [`Bus::station_mut`] to have it polled at the next step).
    pub fn stations_mut(&mut self) -> impl Iterator<Item = &mut S> {
        self.slots.iter_mut().map(|s| &mut s.station)
    }

    /// Characters station `i` received damaged (altered by a collision or bit errors,
    /// or flagged by its UART).
    pub fn damaged_chars(&self, i: usize) -> u64 {
        self.slots[i].damaged
    }

    /// Time a carrier was on the line up to `end` (the union of all transmissions).
    pub fn carrier_time(&self, end: Micros) -> Micros {
        self.carrier_time
            - self
                .carrier_until
                .saturating_sub(end)
                .min(self.carrier_time)
    }

    /// When the transmissions on the line now end (the line's time when it is quiet).
    pub fn quiet_at(&self) -> Micros {
        self.txs.iter().map(|t| t.end).fold(self.now, Micros::max)
    }

    /// The analog loop's model, on the analog medium.
    pub fn analog_model(&self) -> Option<&LoopModel> {
        self.analog.as_ref().map(|a| a.line.model())
    }

    /// The outside's carrier detect (analog medium; on the digital one, whether a
    /// station is transmitting).
    pub fn outside_carrier(&self) -> bool {
        match &self.analog {
            Some(a) => a.outside_carrier,
            None => self.txs.iter().any(|t| t.src != Sender::Outside),
        }
    }

    /// Analog medium: how much the digital traffic moved the control system's 10 Hz
    /// reading of the 4-20 mA current.
    pub fn analog_disturbance(&self) -> Option<AnalogDisturbance> {
        self.analog.as_ref().map(|a| a.line.analog_disturbance())
    }

    /// When something next happens on the digital line (a character ends or a
    /// station's deadline comes); on the analog line, the next look at the stations.
    /// `None`: nothing will until something is sent or received from outside.
    pub fn next_event(&self) -> Option<Micros> {
        let stations = self.slots.iter().filter_map(|s| s.deadline).min();
        // On an ideal line, stations wait for the line to be quiet.
        let stations = match self.is_ideal() && !self.txs.is_empty() {
            true => stations.map(|d| d.max(self.quiet_at())),
            false => stations,
        };
        let other = match &self.analog {
            Some(_) => Some(self.now + ANALOG_STEP_US),
            None => {
                let ct = self.profile.char_time;
                self.txs
                    .iter()
                    .map(|t| t.t0 + (t.next as Micros + 1) * ct)
                    .min()
            }
        };
        match (stations, other) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Runs the line up to `until`: every character and deadline up to then (and on
    /// the analog medium, the loop's samples to exactly `until`), reporting to
    /// `on_event` what the caller may want to see.
    pub fn run_until(&mut self, until: Micros, mut on_event: impl FnMut(BusEvent<'_>)) {
        if self.analog.is_some() {
            self.run_analog(until, &mut on_event);
        } else {
            while let Some(t) = self.next_event() {
                if t > until {
                    break;
                }
                let t = t.max(self.now);
                self.now = t;
                self.deliver(t, &mut on_event);
                self.poll_stations(t, &mut on_event);
            }
        }
        self.now = self.now.max(until);
    }

    /// The outside transmits `bytes` from `now` (at least the line's time); returns
    /// when its last character leaves. The stations hear it as the line runs on.
    pub fn transmit(&mut self, bytes: &[u8], now: Micros) -> Micros {
        let now = now.max(self.now);
        self.start_tx(Sender::Outside, bytes, now, &mut |_| {})
    }

    /// Characters received from outside the simulation (a real line) go straight to
    /// every station, each at its own time and with its UART's flags.
    pub fn receive_outside(&mut self, byte: u8, flags: UartFlags, at: Micros) {
        let now = self.now.max(at);
        for s in &mut self.slots {
            s.station.receive(byte, flags, at);
            if flags != UartFlags::OK {
                s.damaged += 1;
            }
            s.wake(now);
        }
    }

    fn start_tx(
        &mut self,
        src: Sender,
        bytes: &[u8],
        now: Micros,
        on_event: &mut dyn FnMut(BusEvent<'_>),
    ) -> Micros {
        let ct = self.profile.char_time;
        let end = match (&mut self.analog, src) {
            (Some(a), Sender::Station(i)) => a.line.transmit(a.ports[i], bytes, now),
            (Some(a), Sender::Outside) => match a.outside {
                Some(p) => a.line.transmit(p, bytes, now),
                None => now + bytes.len() as Micros * ct,
            },
            (None, _) => now + bytes.len() as Micros * ct,
        };
        let mut tx = Tx {
            src,
            t0: now,
            end,
            bytes: bytes.to_vec(),
            next: 0,
            overlaps: vec![],
            collided: false,
        };
        for other in self.txs.iter_mut().filter(|o| o.end > now) {
            let overlap = (now, end.min(other.end));
            other.overlaps.push(overlap);
            other.collided = true;
            tx.overlaps.push(overlap);
            tx.collided = true;
        }
        // Carrier time: union of transmissions (starts come in time order).
        if now >= self.carrier_until {
            self.carrier_time += end - now;
        } else if end > self.carrier_until {
            self.carrier_time += end - self.carrier_until;
        }
        self.carrier_until = self.carrier_until.max(end);
        on_event(BusEvent::Started {
            src,
            t0: now,
            t1: end,
            bytes,
        });
        if self.is_ideal() && !bytes.is_empty() {
            for (i, &b) in bytes.iter().enumerate() {
                let at = now + (i as Micros + 1) * ct;
                for (k, s) in self.slots.iter_mut().enumerate() {
                    if src != Sender::Station(k) {
                        s.station.receive(b, UartFlags::OK, at);
                        s.dirty = true;
                    }
                }
                if self.outside.is_some() && src != Sender::Outside {
                    on_event(BusEvent::Heard {
                        byte: b,
                        flags: UartFlags::OK,
                        at,
                    });
                }
            }
            // Only its end is left to happen.
            tx.next = bytes.len() - 1;
            tx.overlaps.clear();
            tx.collided = false;
            self.txs.push(tx);
            return end;
        }
        self.txs.push(tx);
        if self.analog.is_none() {
            // Carrier detect: every other station hears the carrier from the first bit.
            for (k, s) in self.slots.iter_mut().enumerate() {
                if src != Sender::Station(k) {
                    s.station.carrier(true);
                    s.dirty = true;
                }
            }
        }
        end
    }

    /// Polls every station that is due or had something happen to it.
    fn poll_stations(&mut self, now: Micros, on_event: &mut dyn FnMut(BusEvent<'_>)) {
        for i in 0..self.slots.len() {
            if self.is_ideal() && !self.txs.is_empty() {
                // One transmission at a time: the others are polled when it ends.
                break;
            }
            let s = &mut self.slots[i];
            let due = s.deadline.is_some_and(|d| d <= now);
            if !(due || s.dirty) {
                continue;
            }
            s.dirty = false;
            let sent = s.station.poll(now);
            s.deadline = s.station.next_deadline(now).map(|d| d.max(now + 1));
            if let Some(bytes) = sent {
                self.start_tx(Sender::Station(i), &bytes, now, on_event);
            }
        }
    }

    /// Digital medium: delivers every character that finishes at `now`.
    fn deliver(&mut self, now: Micros, on_event: &mut dyn FnMut(BusEvent<'_>)) {
        let ct = self.profile.char_time;
        let mut i = 0;
        while i < self.txs.len() {
            let tx = &self.txs[i];
            let char_end = tx.t0 + (tx.next as Micros + 1) * ct;
            if char_end != now {
                i += 1;
                continue;
            }
            if self.is_ideal() {
                let tx = self.txs.swap_remove(i);
                self.finished(tx, now, on_event);
                continue;
            }
            let start = char_end - ct;
            let collided = tx.overlaps.iter().any(|&(a, b)| a < char_end && b > start);
            let byte = tx.bytes[tx.next];
            let src = tx.src;
            for (k, s) in self.slots.iter_mut().enumerate() {
                if src == Sender::Station(k) {
                    continue;
                }
                let (b, flags) = corrupt(
                    byte,
                    collided,
                    &mut s.bits_to_error,
                    &mut self.rng,
                    self.ber,
                );
                if b != byte || flags != UartFlags::OK {
                    s.damaged += 1;
                }
                s.station.receive(b, flags, now);
                s.dirty = true;
            }
            if let (Some((_, bits)), true) = (&mut self.outside, src != Sender::Outside) {
                let (b, flags) = corrupt(byte, collided, bits, &mut self.rng, self.ber);
                on_event(BusEvent::Heard {
                    byte: b,
                    flags,
                    at: now,
                });
            }
            let tx = &mut self.txs[i];
            tx.next += 1;
            if tx.next == tx.bytes.len() {
                let tx = self.txs.swap_remove(i);
                if self.txs.is_empty() {
                    for s in &mut self.slots {
                        s.station.carrier(false);
                        s.dirty = true;
                    }
                }
                self.finished(tx, now, on_event);
            } else {
                i += 1;
            }
        }
    }

    /// A transmission ended at `now`.
    fn finished(&mut self, tx: Tx, now: Micros, on_event: &mut dyn FnMut(BusEvent<'_>)) {
        if let Sender::Station(k) = tx.src {
            let s = &mut self.slots[k];
            s.station.transmitted(now);
            s.dirty = true;
        }
        on_event(BusEvent::Ended {
            src: tx.src,
            t0: tx.t0,
            t1: now,
            bytes: &tx.bytes,
            collided: tx.collided,
        });
    }

    /// Analog medium: runs the loop to `until` in steps no longer than
    /// [`ANALOG_STEP_US`], polling the stations after each.
    fn run_analog(&mut self, until: Micros, on_event: &mut dyn FnMut(BusEvent<'_>)) {
        // Whatever is due already (a station just added, a deadline of now).
        self.poll_stations(self.now, on_event);
        let mut events = vec![];
        while self.now < until {
            let t = self.now;
            let next = self
                .slots
                .iter()
                .filter_map(|s| s.deadline)
                .min()
                .unwrap_or(Micros::MAX)
                .max(t + 1);
            let step = until.min(t + ANALOG_STEP_US).min(next);
            if let Some(a) = &mut self.analog {
                a.line.advance(step, |e| events.push(e));
            }
            for e in events.drain(..) {
                self.line_event(e, on_event);
            }
            self.now = step;
            self.poll_stations(step, on_event);
        }
    }

    fn line_event(&mut self, e: LineEvent, on_event: &mut dyn FnMut(BusEvent<'_>)) {
        let Some(a) = &mut self.analog else {
            return;
        };
        let who = |port: PortId| match a.ports.iter().position(|p| *p == port) {
            Some(k) => Some(Sender::Station(k)),
            None => (a.outside == Some(port)).then_some(Sender::Outside),
        };
        match e {
            LineEvent::Char {
                port,
                byte,
                flags,
                t_us,
            } => match who(port) {
                Some(Sender::Station(k)) => {
                    let s = &mut self.slots[k];
                    if flags != UartFlags::OK {
                        s.damaged += 1;
                    }
                    s.station.receive(byte, flags, t_us);
                    s.dirty = true;
                }
                Some(Sender::Outside) => on_event(BusEvent::Heard {
                    byte,
                    flags,
                    at: t_us,
                }),
                None => {}
            },
            LineEvent::Carrier { port, on, .. } => match who(port) {
                Some(Sender::Station(k)) => {
                    let s = &mut self.slots[k];
                    s.station.carrier(on);
                    s.dirty = true;
                }
                Some(Sender::Outside) => a.outside_carrier = on,
                None => {}
            },
            LineEvent::Frame {
                port, pdu, t_us, ..
            } => {
                if let Some(to) = who(port) {
                    on_event(BusEvent::Frame {
                        to,
                        pdu: &pdu,
                        at: t_us,
                    });
                }
            }
            LineEvent::TxDone { port, t_us } => {
                let Some(src) = who(port) else { return };
                if let Some(i) = self.txs.iter().position(|t| t.src == src) {
                    let tx = self.txs.remove(i);
                    self.finished(tx, t_us, on_event);
                }
            }
        }
    }
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
