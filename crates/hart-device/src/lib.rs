//! # hart-device
//!
//! Simulated HART 7 field devices that behave like well-made instruments: identity,
//! device variables with dynamics, PV range and damping, the 4-20 mA loop current with
//! saturation, alarm, fixed-current and multidrop modes and trims, status bits kept per
//! master, write protection, delayed responses, three burst messages with triggers, and
//! a state file that survives restarts.
//!
//! * [`Device`]: the device; a [`hart_link::Handler`].
//! * [`Node`]: a device with its data-link slave, ready for a serial port or a
//!   simulated line.
//! * [`config::DeviceConfig`]: profile and state-file contents; [`profiles`] has the
//!   built-in pressure, temperature and valve positioner profiles.
//! * [`persist`]: atomic state files.
//!
//! The command table with every response code is in `docs/field-device.md`.

pub mod burst;
pub mod config;
pub mod device;
pub mod faults;
pub mod persist;
pub mod profiles;
pub mod units;

use std::path::PathBuf;

use hart_link::slave::{Slave, SlaveConfig};
use hart_link::{Micros, TimingProfile};
use hart_proto::deframer::UartFlags;
use hart_proto::frame::{Frame, FrameType, MasterKind};

pub use config::DeviceConfig;
pub use device::Device;

/// A device behind its data-link slave, with optional persistence.
pub struct Node {
    /// The data-link slave.
    pub slave: Slave,
    /// The device.
    pub device: Device,
    state_path: Option<PathBuf>,
    /// The master bit of a BACK handed out by [`Node::poll`] and not yet transmitted.
    back_to: Option<MasterKind>,
    /// Faults the device commits ([`faults`]).
    faults: faults::Faults,
    /// The line's timing.
    profile: TimingProfile,
    /// The rest of a reply held back by [`faults::Fault::GapInReply`], and when it goes
    /// out (set once the first part has left).
    held: Option<(Vec<u8>, Option<Micros>)>,
}

impl Node {
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
        let mut n = Node {
            slave,
            device,
            state_path: None,
            back_to: None,
            faults: faults::Faults::NONE,
            profile,
            held: None,
        };
        n.sync(now);
        n
    }

    /// Saves the configuration to `path` whenever it changes.
    pub fn persist_to(&mut self, path: PathBuf) {
        self.state_path = Some(path);
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

    /// Applies configuration changes to the link layer and saves them.
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
            if let Some(p) = &self.state_path {
                if let Err(e) = persist::save(p, self.device.config()) {
                    tracing::error!(
                        "cannot save the device state to {}: {e}; its changes live on in memory only (check the directory exists and may be written)",
                        p.display()
                    );
                }
            }
        }
    }
}
