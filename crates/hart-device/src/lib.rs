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
//!   simulated line; it runs the sans-IO [`NodeCore`] and writes the state file the
//!   core asks for ([`Effect`]).
//! * [`config::DeviceConfig`]: profile and state-file contents; [`profiles`] has the
//!   built-in pressure, temperature and valve positioner profiles.
//! * [`persist`]: atomic state files.
//!
//! The command table with every response code is in `docs/field-device.md`.

pub mod burst;
pub mod config;
pub mod device;
pub mod faults;
pub mod node;
pub mod persist;
pub mod profiles;
pub mod units;

use std::path::PathBuf;

pub use config::DeviceConfig;
pub use device::Device;
pub use node::{Effect, NodeCore};

use hart_link::Micros;
use hart_proto::deframer::UartFlags;

/// A device behind its data-link slave, with optional persistence: the runner of a
/// [`NodeCore`], which owns the state file and carries out the core's [`Effect`]s.
///
/// Durability: each call that can change the configuration ([`Node::receive`],
/// [`Node::poll`], [`Node::transmitted`]) writes and fsyncs the snapshot the core asked
/// for before it returns, so the bytes [`Node::poll`] hands out for transmission (the
/// reply acknowledging a write) always leave after the write is on disk, as when the
/// core saved it itself.
///
/// The core's other methods and fields are reached through `Deref`.
pub struct Node {
    core: NodeCore,
    state_path: Option<PathBuf>,
}

impl std::ops::Deref for Node {
    type Target = NodeCore;
    fn deref(&self) -> &NodeCore {
        &self.core
    }
}

impl std::ops::DerefMut for Node {
    fn deref_mut(&mut self) -> &mut NodeCore {
        &mut self.core
    }
}

impl Node {
    /// Puts `device` on a line with `profile`, powered up at `now`.
    pub fn new(device: Device, profile: hart_link::TimingProfile, now: Micros) -> Self {
        let mut core = NodeCore::new(device, profile, now);
        // No state file is attached yet: nothing to write.
        let _ = core.take_effects();
        Node {
            core,
            state_path: None,
        }
    }

    /// Saves the configuration to `path` whenever it changes.
    pub fn persist_to(&mut self, path: PathBuf) {
        self.state_path = Some(path);
    }

    /// The core, for a runner of its own.
    pub fn core(&mut self) -> &mut NodeCore {
        &mut self.core
    }

    /// Feeds a received character.
    pub fn receive(&mut self, byte: u8, flags: UartFlags, now: Micros) {
        self.core.receive(byte, flags, now);
        self.carry_out();
    }

    /// Advances to `now`; returns bytes to transmit, if it is time. The state the
    /// step changed is on disk before the bytes are returned.
    pub fn poll(&mut self, now: Micros) -> Option<Vec<u8>> {
        let out = self.core.poll(now);
        self.carry_out();
        out
    }

    /// The last transmission has left.
    pub fn transmitted(&mut self, now: Micros) {
        self.core.transmitted(now);
        self.carry_out();
    }

    /// The carrier-detect line changed.
    pub fn carrier(&mut self, on: bool) {
        self.core.carrier(on);
    }

    /// When to poll again.
    pub fn next_deadline(&self, now: Micros) -> Option<Micros> {
        self.core.next_deadline(now)
    }

    /// Makes the device commit `faults` from now on (see [`faults::Fault`]).
    pub fn set_faults(&mut self, list: &[faults::Fault]) {
        self.core.set_faults(list);
    }

    /// The faults the device commits.
    pub fn faults(&self) -> faults::Faults {
        self.core.faults()
    }

    /// Carries out the core's effects: writes the newest snapshot to the state file,
    /// when there is one.
    fn carry_out(&mut self) {
        for effect in self.core.take_effects() {
            match effect {
                Effect::Persist(config) => {
                    let Some(p) = &self.state_path else {
                        continue;
                    };
                    if let Err(e) = persist::save(p, &config) {
                        tracing::error!(
                            "cannot save the device state to {}: {e}; its changes live on in memory only (check the directory exists and may be written)",
                            p.display()
                        );
                    }
                }
            }
        }
    }
}
