//! The analog medium: the stations' link layers on [`hart_modem::line::AnalogLine`].
//!
//! Time still advances from event to event, but in steps no longer than a fraction of
//! a character while the line runs, so what a demodulator finds reaches its station
//! within about 2 ms (on top of the demodulator's own few bits of decision delay, as
//! with a hardware modem).

use hart_link::Micros;
use hart_modem::line::{AnalogLine, Drive, LineEvent, Place, PortId};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Address, Frame, FrameType, MasterKind};

use crate::{is_silent, reply_delay, set_carrier, FrameKind, Kind, Medium, Sim, Source};

/// Longest step between two looks at the line, µs.
const STEP_US: Micros = 1_000;

/// A transmission on the analog line.
struct OnAir {
    src: usize,
    t0: Micros,
    end: Micros,
    bytes: Vec<u8>,
    /// Delimiter through check byte, to recognise it when a demodulator reports it.
    pdu: Vec<u8>,
    kind: FrameKind,
    /// The station it is for, if it exists.
    dest: Option<usize>,
    heard: bool,
    collided: bool,
    done: bool,
}

/// The analog line and what is on it.
pub(crate) struct Air {
    line: AnalogLine,
    /// Port of each station, by station index.
    ports: Vec<PortId>,
    on_air: Vec<OnAir>,
}

impl Sim<'_> {
    /// Connects every station to an analog line when the configuration asks for one.
    pub(crate) fn with_medium(mut self) -> Self {
        let Medium::Analog { mut model, options } = self.cfg.medium else {
            return self;
        };
        model.devices = u32::from(self.cfg.devices.clamp(1, 63));
        let mut line = AnalogLine::new(model, options);
        let ports = self
            .stations
            .iter()
            .map(|st| match &st.kind {
                Kind::Master(m) if m.role == Source::Primary => {
                    line.add_port(Place::ControlRoom, Drive::Voltage)
                }
                Kind::Master(_) => line.add_port(Place::Field, Drive::Voltage),
                Kind::Slave(_) => line.add_port(Place::Field, Drive::Current),
            })
            .collect();
        self.air = Some(Air {
            line,
            ports,
            on_air: vec![],
        });
        self
    }

    /// The station a frame is for: the device it addresses, or the master a reply or
    /// burst frame names.
    fn destination(&self, pdu: &[u8]) -> Option<usize> {
        let f = Frame::parse_pdu(pdu).ok()?;
        let master = f.address.master();
        self.stations.iter().position(|st| match &st.kind {
            Kind::Slave(s) if f.frame_type() == FrameType::Stx => match f.address {
                Address::Short(a) => a.polling_address == s.poll,
                Address::Long(a) => a.id == s.unique_id(),
            },
            Kind::Master(m) if f.frame_type() != FrameType::Stx => {
                matches!(
                    (m.role, master),
                    (Source::Primary, MasterKind::Primary)
                        | (Source::Secondary, MasterKind::Secondary)
                )
            }
            _ => false,
        })
    }

    pub(crate) fn start_analog_tx(&mut self, src: usize, bytes: &[u8], now: Micros) {
        let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
        let pdu = bytes[pre..].to_vec();
        let dest = self.destination(&pdu);
        let kind = crate::frame_kind(bytes);
        let Some(air) = self.air.as_mut() else {
            return;
        };
        let end = air.line.transmit(air.ports[src], bytes, now);
        let mut collided = false;
        for other in air.on_air.iter_mut().filter(|o| !o.done && o.end > now) {
            other.collided = true;
            collided = true;
        }
        // Carrier time: union of transmissions (starts come in time order).
        if now >= self.carrier_until {
            self.carrier_time += end - now;
        } else if end > self.carrier_until {
            self.carrier_time += end - self.carrier_until;
        }
        self.carrier_until = self.carrier_until.max(end);
        air.on_air.push(OnAir {
            src,
            t0: now,
            end,
            bytes: bytes.to_vec(),
            pdu,
            kind,
            dest,
            heard: false,
            collided,
            done: false,
        });
    }

    pub(crate) fn run_analog(mut self) -> crate::SimReport {
        let end = self.cfg.duration;
        let mut now: Micros = 0;
        let mut events = vec![];
        loop {
            let t_station = self.stations.iter().filter_map(|s| s.deadline).min();
            let until = t_station.map_or(now + STEP_US, |t| t.min(now + STEP_US));
            let until = until.max(now);
            if until > end {
                break;
            }
            if let Some(air) = self.air.as_mut() {
                air.line.advance(until, |e| events.push(e));
            }
            for e in events.drain(..) {
                self.line_event(e);
            }
            now = until;
            self.poll_stations(now);
        }
        self.finish(end)
    }

    fn line_event(&mut self, e: LineEvent) {
        let Some(air) = self.air.as_mut() else {
            return;
        };
        let station = |port: PortId| air.ports.iter().position(|p| *p == port);
        match e {
            LineEvent::Char {
                port,
                byte,
                flags,
                t_us,
            } => {
                let Some(k) = station(port) else { return };
                let cfg = self.cfg;
                let st = &mut self.stations[k];
                if flags != UartFlags::OK {
                    st.damaged_chars += 1;
                }
                match &mut st.kind {
                    Kind::Master(m) => m.m.receive(byte, flags, t_us),
                    Kind::Slave(s) => {
                        if !is_silent(cfg, s.poll, t_us) {
                            if let Some(late) = cfg.faults.late_device {
                                if late.poll == s.poll {
                                    s.set_reply_delay(reply_delay(cfg, s.poll, t_us));
                                }
                            }
                            s.receive(byte, flags, t_us);
                        }
                    }
                }
                st.dirty = true;
            }
            LineEvent::Carrier { port, on, .. } => {
                let Some(k) = station(port) else { return };
                set_carrier(&mut self.stations[k], on);
                self.stations[k].dirty = true;
            }
            LineEvent::Frame { port, pdu, .. } => {
                let Some(k) = station(port) else { return };
                if let Some(tx) = air
                    .on_air
                    .iter_mut()
                    .find(|o| !o.heard && o.dest == Some(k) && o.pdu == pdu)
                {
                    tx.heard = true;
                }
            }
            LineEvent::TxDone { port, t_us } => {
                let Some(k) = station(port) else { return };
                let Some(i) = air.on_air.iter().position(|o| o.src == k && !o.done) else {
                    return;
                };
                air.on_air[i].done = true;
                let (t0, bytes, kind, collided) = {
                    let o = &air.on_air[i];
                    (o.t0, o.bytes.clone(), o.kind, o.collided)
                };
                // Frames long heard or lost leave the list.
                let horizon = t_us.saturating_sub(2_000_000);
                let mut sent = 0;
                let mut heard = 0;
                air.on_air.retain(|o| {
                    let old = o.done && o.end < horizon;
                    if old && o.dest.is_some() {
                        sent += 1;
                        heard += u64::from(o.heard);
                    }
                    !old
                });
                self.report.frames_sent += sent;
                self.report.frames_heard += heard;
                self.finished(k, t0, &bytes, kind, collided, t_us);
            }
        }
    }

    /// Counts what is still on the list and reads the analog disturbance; the run
    /// ended at `end`.
    pub(crate) fn finish_analog(&mut self, end: Micros) {
        let Some(air) = self.air.as_mut() else {
            return;
        };
        for o in air.on_air.drain(..) {
            // A frame cut off by the end of the run, or with too little time left to
            // be decoded, counts only if it was heard.
            if o.dest.is_some() && ((o.done && o.end + 100_000 <= end) || o.heard) {
                self.report.frames_sent += 1;
                self.report.frames_heard += u64::from(o.heard);
            }
        }
        self.report.analog_disturbance = Some(air.line.analog_disturbance());
    }
}
