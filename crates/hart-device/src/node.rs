//! The sans-IO core of a device on a line: bytes and "now" in, bytes to transmit, the
//! next deadline and [`Effect`]s out. It touches no file: when the configuration
//! changes it asks its runner ([`crate::Node`]) to persist a snapshot.

use hart_link::slave::{Slave, SlaveConfig};
use hart_link::{Micros, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Frame, FrameType, MasterKind};

use crate::config::DeviceConfig;
use crate::device::Device;
use crate::faults;

/// What the core asks its runner to do.
#[derive(Debug, Clone, PartialEq)]
pub enum Effect {
    /// The configuration changed (a master wrote it, or the device changed it): keep
    /// this snapshot in non-volatile memory. The runner writes it before it transmits
    /// the bytes the same call returned, so a write a master sees acknowledged is
    /// durable.
    Persist(Box<DeviceConfig>),
}

/// A device behind its data-link slave, without I/O: the runner moves the bytes and
/// the time and carries out the [`Effect`]s ([`NodeCore::take_effects`]).
pub struct NodeCore {
    /// The data-link slave.
    pub slave: Slave,
    /// The device.
    pub device: Device,
    /// Effects not yet taken by the runner.
    effects: Vec<Effect>,
    /// The master bit of a BACK handed out by [`NodeCore::poll`] and not yet transmitted.
    back_to: Option<MasterKind>,
    /// Faults the device commits ([`faults`]).
    faults: faults::Faults,
    /// The line's timing.
    profile: TimingProfile,
    /// The rest of a reply held back by [`faults::Fault::GapInReply`], and when it goes
    /// out (set once the first part has left).
    held: Option<(Vec<u8>, Option<Micros>)>,
}

impl NodeCore {
    /// Puts `device` on a line with `profile`, powered up at `now`.
    pub fn new(device: Device, profile: TimingProfile, now: Micros) -> Self {
        let c = device.config();
        let slave = Slave::new(
            SlaveConfig {
                polling_address: c.polling_address,
                unique_id: device.unique_id(),
                reply_delay: None,
                response_preambles: usize::from(c.response_preambles),
            },
            profile,
            now,
        );
        let mut n = NodeCore {
            slave,
            device,
            effects: Vec::new(),
            back_to: None,
            faults: faults::Faults::NONE,
            profile,
            held: None,
        };
        n.sync(now);
        n
    }

    /// Makes the device commit `faults` from now on (see [`faults::Fault`]).
    pub fn set_faults(&mut self, list: &[faults::Fault]) {
        use faults::Fault;
        let f = faults::Faults::of(list);
        self.faults = f;
        self.slave
            .set_reply_delay(f.has(Fault::LateReply).then(|| self.profile.chars(40)));
        self.slave
            .set_fault_answers_any_address(f.has(Fault::AnswersOtherAddress));
        self.slave
            .set_fault_executes_bad_check_byte(f.has(Fault::ExecutesBadCheckByte));
        self.device.set_faults(f);
    }

    /// The faults the device commits.
    pub fn faults(&self) -> faults::Faults {
        self.faults
    }

    /// Applies the faults that change a reply on its way out (not burst frames).
    fn damage_reply(&mut self, mut bytes: Vec<u8>) -> Vec<u8> {
        use faults::Fault;
        let f = self.faults;
        let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
        if f.has(Fault::TooFewPreambles) && pre > 2 {
            bytes.drain(..pre - 2);
        }
        let pre = bytes.iter().take_while(|&&b| b == 0xFF).count();
        if f.has(Fault::MasterBitNotEchoed) && bytes.len() > pre + 2 {
            bytes[pre + 1] ^= 0x80;
            let last = bytes.len() - 1;
            bytes[last] ^= 0x80;
        }
        if f.has(Fault::BadReplyCheckByte) {
            if let Some(last) = bytes.last_mut() {
                *last ^= 0x5A;
            }
        }
        if f.has(Fault::GapInReply) && bytes.len() > pre + 7 {
            let rest = bytes.split_off(pre + 6);
            self.held = Some((rest, None));
        }
        bytes
    }

    /// Feeds a received character.
    pub fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        self.slave.receive(byte, flags, now, &mut self.device);
        self.sync(now);
    }

    /// The carrier-detect line changed.
    pub fn carrier(&mut self, on: bool) {
        self.slave.carrier(on);
    }

    /// Advances to `now`; returns bytes to transmit, if it is time.
    pub fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        if let Some((_, at)) = &self.held {
            return match at {
                Some(at) if now >= *at => self.held.take().map(|(rest, _)| rest),
                _ => None,
            };
        }
        self.device.tick(now);
        self.sync(now);
        let out = self
            .slave
            .poll(now, &mut self.device)
            .map(|t| t.bytes.to_vec());
        if let Some(bytes) = &out {
            self.back_to = Frame::parse(bytes)
                .ok()
                .filter(|f| f.frame_type() == FrameType::Back)
                .map(|f| f.address.master());
            self.sync(now);
        }
        match out {
            Some(bytes) if self.back_to.is_none() && self.faults != faults::Faults::NONE => {
                Some(self.damage_reply(bytes))
            }
            other => other,
        }
    }

    /// The last transmission has left.
    pub fn transmitted(&mut self, now: Micros) {
        if let Some((_, at @ None)) = &mut self.held {
            // The first part of a reply with a gap has left: the rest follows later.
            *at = Some(now + self.profile.chars(3));
            return;
        }
        self.slave.transmitted(now);
        // The slave alternates the master bit after each BACK; the device puts the
        // status of the master the next BACK goes to in it.
        if let Some(to) = self.back_to.take() {
            self.device.set_burst_master(to.other());
        }
        self.sync(now);
    }

    /// When to poll again.
    pub fn next_deadline(&self, now: Micros) -> Option<Micros> {
        if let Some((_, at)) = &self.held {
            return *at;
        }
        match (self.slave.next_deadline(), self.device.burst_wakeup(now)) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// Applies configuration changes to the link layer and asks for them to be saved.
    fn sync(&mut self, now: Micros) {
        self.device.tick(now);
        let c = self.device.config();
        self.slave.set_polling_address(c.polling_address);
        self.slave
            .set_response_preambles(usize::from(c.response_preambles));
        let mode = self.device.burst_mode();
        self.slave.set_burst_mode(mode);
        self.slave.set_burst_due(if mode {
            self.device.burst_due(now)
        } else {
            None
        });
        if self.device.take_dirty() {
            // Only the newest snapshot matters: it replaces one not yet taken.
            self.effects.retain(|e| !matches!(e, Effect::Persist(_)));
            self.effects
                .push(Effect::Persist(Box::new(self.device.config().clone())));
        }
    }

    /// The effects asked for since the last call, oldest first; the runner carries
    /// them out before it transmits what [`NodeCore::poll`] returned.
    pub fn take_effects(&mut self) -> Vec<Effect> {
        std::mem::take(&mut self.effects)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hart_proto::command::{PollingAddress, Request};
    use hart_proto::frame::Address;
    use hart_proto::types::LoopCurrentMode;

    /// A write through the core changes the configuration and comes back as an
    /// effect: the core has no path, no store and writes nothing itself.
    #[test]
    fn a_write_comes_back_as_an_effect_and_no_file_is_written() {
        let p = TimingProfile::fsk();
        let cfg = crate::profiles::load("pressure").unwrap();
        let mut core = NodeCore::new(Device::new(cfg), p, 0);
        let _ = core.take_effects();
        let request = Request::WritePollingAddress(PollingAddress {
            polling_address: 5,
            loop_current_mode: Some(LoopCurrentMode(0)),
        });
        let address = Address::long(core.device.unique_id()).with_master(MasterKind::Primary);
        let frame = request.frame(address).unwrap();
        // The master takes the line after a quiet period.
        let mut now = 1_000_000;
        while let Some(t) = core
            .next_deadline(now)
            .filter(|&t| t <= now + p.rt1_primary)
        {
            now = t.max(now + 1);
            let _ = core.poll(now);
        }
        now += p.rt1_primary;
        // Preambles, then the frame.
        for &b in [0xFF; 5].iter().chain(frame.as_slice()) {
            now += p.char_time;
            core.receive(b, UartFlags::OK, now);
        }
        let mut reply = None;
        while reply.is_none() {
            now = core
                .next_deadline(now)
                .expect("a reply is due")
                .max(now + 1);
            reply = core.poll(now);
        }
        let f = Frame::parse(reply.as_deref().unwrap()).unwrap();
        assert_eq!(f.response_code, Some(0));
        let effects = core.take_effects();
        assert_eq!(effects.len(), 1, "{effects:?}");
        let Effect::Persist(saved) = &effects[0];
        assert_eq!(saved.polling_address, 5);
        assert!(core.take_effects().is_empty(), "taken once");
    }
}
