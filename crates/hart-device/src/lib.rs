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
        };
        n.sync(now);
        n
    }

    /// Saves the configuration to `path` whenever it changes.
    pub fn persist_to(&mut self, path: PathBuf) {
        self.state_path = Some(path);
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
        out
    }

    /// The last transmission has left.
    pub fn transmitted(&mut self, now: Micros) {
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
