//! Burst messages: which commands may be published, the value that triggers a message,
//! its periods and whether it publishes on this link. The device applies them
//! ([`Device::burst_due`](crate::Device::burst_due) and its BACK content).
//!
//! A message publishes at its minimum update period while its trigger holds and at its
//! maximum update period otherwise: continuous (0) always holds; window (1) holds when
//! the source value moved more than the trigger level from the last published value;
//! rising (2) while the value is above the level; falling (3) while below; on-change
//! (4) when the source value or the device status changed since the last publication.

use hart_link::Micros;

use crate::config::DeviceConfig;

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

/// The minimum and maximum update periods of message `m` in µs (the maximum never
/// below the minimum); `timer_slow`: the fault of a burst timer running 1.5 times too
/// slow.
pub(crate) fn periods(cfg: &DeviceConfig, m: usize, timer_slow: bool) -> (Micros, Micros) {
    let b = &cfg.burst[m];
    // Fault injection: a device whose burst timer runs 1.5 times too slow.
    let us = |t: u32| {
        let us = u64::from(t) * 1000 / 32;
        if timer_slow {
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
pub(crate) fn active(cfg: &DeviceConfig, m: usize) -> bool {
    matches!(cfg.burst[m].control, 1 | 3)
}
