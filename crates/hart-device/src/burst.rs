//! Burst messages: which commands may be published, trigger evaluation, and when each
//! message is due.
//!
//! A message publishes at its minimum update period while its trigger holds and at its
//! maximum update period otherwise: continuous (0) always holds; window (1) holds when
//! the source value moved more than the trigger level from the last published value;
//! rising (2) while the value is above the level; falling (3) while below; on-change
//! (4) when the source value or the device status changed since the last publication.

use hart_link::slave::Reply;
use hart_link::Micros;
use hart_proto::frame::MasterKind;

use crate::config::DeviceConfig;
use crate::device::Device;
use crate::units;

/// Commands a burst message may publish.
pub const BURSTABLE: &[u16] = &[1, 2, 3, 9, 33, 38, 48];

/// Runtime state of one burst message.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BurstRuntime {
    /// When it was last published.
    pub last_publish: Option<Micros>,
    /// Trigger source value published last.
    pub last_value: Option<f32>,
    /// Device status published last (for on-change).
    pub last_status: Option<u8>,
}

/// Classification of the value that triggers message `m`; `None` for commands without
/// a trigger value (38, 48).
pub fn trigger_classification(cfg: &DeviceConfig, m: usize) -> Option<u8> {
    let b = cfg.burst.get(m)?;
    let var_class = |code: u8| cfg.variable(code).map(|v| v.classification);
    match b.command {
        1 | 3 => var_class(cfg.mapping[0]),
        2 => Some(0),
        9 | 33 => var_class(b.slots[0]),
        _ => None,
    }
}

/// Units of the value that triggers message `m`.
pub fn trigger_units(cfg: &DeviceConfig, m: usize) -> Option<u8> {
    let b = cfg.burst.get(m)?;
    let var_units = |code: u8| cfg.variable(code).map(|v| v.units);
    match b.command {
        1 | 3 => var_units(cfg.mapping[0]),
        2 => Some(57),
        9 | 33 => var_units(b.slots[0]),
        _ => None,
    }
}

fn periods(device: &Device, m: usize) -> (Micros, Micros) {
    let b = &device.config().burst[m];
    // Fault injection: a device whose burst timer runs 1.5 times too slow.
    let us = |t: u32| {
        let us = u64::from(t) * 1000 / 32;
        if device.faults().has(crate::faults::Fault::BurstPeriodOff) {
            us * 3 / 2
        } else {
            us
        }
    };
    (
        us(b.update_period),
        us(b.max_update_period).max(us(b.update_period)),
    )
}

/// True when message `m` publishes on the wired (token-passing) link.
fn active(cfg: &DeviceConfig, m: usize) -> bool {
    matches!(cfg.burst[m].control, 1 | 3)
}

impl Device {
    /// True when any burst message publishes on this link.
    pub fn burst_mode(&self) -> bool {
        (0..self.config().burst.len()).any(|m| active(self.config(), m))
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

    pub(crate) fn burst_due_of(&self, m: usize, now: Micros) -> Option<Micros> {
        self.message_due(m, now)
    }

    fn message_due(&self, m: usize, now: Micros) -> Option<Micros> {
        if !active(self.config(), m) {
            return None;
        }
        let (min, max) = periods(self, m);
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
            .filter(|&m| active(self.config(), m))
            .filter_map(|m| {
                let (min, _) = periods(self, m);
                let due = self.message_due(m, now)?;
                let last = self.burst_runtime_ref(m).last_publish.unwrap_or(now);
                // A message already due is the slave's business (it waits for a slot);
                // otherwise look again as soon as the minimum period allows one.
                (due > now).then(|| due.min((last + min).max(now + 50_000)))
            })
            .min()
    }

    fn burst_runtime_ref(&self, m: usize) -> BurstRuntime {
        self.burst_runtime_snapshot(m)
    }
}

/// Builds the BACK content of the message due first and records its publication.
///
/// A BACK is the reply the published command would give, with that reply's response
/// code, and the field device status as the master whose address bit the BACK carries
/// ([`Device::burst_master`]) sees it. Publishing changes nothing the masters see: no
/// status bit is reset or acknowledged (a burst of command 38 or 48 included), and cold
/// start stays reported until that master's next request.
pub fn publish(device: &mut Device, reply: &mut Reply, now: Micros) -> u16 {
    device.tick(now);
    let (due, m) = (0..device.config().burst.len())
        .filter_map(|m| device.burst_message_due(m, now).map(|d| (d, m)))
        .min()
        .unwrap_or((now, 0));
    // Keep the cadence: a BACK waits for a slot on the line, so it goes out a little
    // after it was due; count the period from when it was due (never more than one
    // period back).
    let (min, _) = periods(device, m);
    let published = if due <= now && due + min > now {
        due
    } else {
        now
    };
    let (command, code, data) = device.burst_reply(m, now);
    let value = device.trigger_value(m).map(|x| x.0);
    // The on-change trigger compares the primary master's view of the status.
    let trigger_status = device.device_status(MasterKind::Primary);
    let status = device.device_status(device.burst_master());
    if let Some(rt) = device.burst_runtime().get_mut(m) {
        rt.last_publish = Some(published);
        rt.last_value = value;
        rt.last_status = Some(trigger_status);
    }
    device.count_back();
    reply.response_code = code;
    reply.device_status = status;
    reply.set_data(&data);
    command
}
