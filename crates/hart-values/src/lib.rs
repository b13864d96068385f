//! # hart-values
//!
//! The values of the polling engine's image that the gateway's front ends publish as
//! numbers: [`Value`] names each (PV, loop current, status, quality, age, identity,
//! range...), says which can be written to the device and describes it, and
//! [`number`] gives the number it has for a device at a time, with the conventions
//! every such front end shares (NaN for a float the device has not given, 250 for
//! unknown units, the quality's code, `u32::MAX` for the age before the first good
//! reply). Modbus (`hart-modbus`: registers) and PROFIBUS (`hart-profibus`: input
//! modules) each put these numbers in their own encoding.
//!
//! Why a crate of its own: the model was hart-modbus's, so PROFIBUS had to link the
//! Modbus front end (and its TCP server) to read the image the same way. It belongs
//! with neither front end, and not inside the polling engine either: `hart-poller`
//! owns the image and how it is filled; which of its fields a front end publishes,
//! under which names (contracts of the configuration file and the printed maps) and
//! with which codes for "not known" is the front ends' shared vocabulary, read from
//! the image without the engine knowing of it. The OPC UA front end publishes typed
//! variables with statuses instead of numbers and does not use it.

#![warn(missing_docs)]

use std::time::Instant;

use hart_poller::DeviceImage;
use serde::{Deserialize, Serialize};

/// A value of a device's image (or of its configuration, for the writable ones), as
/// the front ends name it: the names (`pv`, `loop_current`, `upper_range`...) are those
/// of the gateway's configuration file (`[[modbus.register]] value = ...`) and of the
/// printed maps, a contract.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Value {
    /// Primary variable.
    Pv,
    /// Secondary variable.
    Sv,
    /// Tertiary variable.
    Tv,
    /// Quaternary variable.
    Qv,
    /// Loop current, mA.
    LoopCurrent,
    /// PV percent of range.
    PercentRange,
    /// PV units code (HART Common Table 2).
    PvUnits,
    /// SV units code.
    SvUnits,
    /// TV units code.
    TvUnits,
    /// QV units code.
    QvUnits,
    /// Field device status byte.
    DeviceStatus,
    /// Extended device status byte.
    ExtendedStatus,
    /// Quality: 0 good, 1 stale, 2 no reply, 3 device malfunction, 4 configuration
    /// changed, 5 waiting for first data (nothing asked yet), 6 loop disturbed (a babbling
    /// device on the loop).
    Quality,
    /// Seconds since the last good reply (0xFFFFFFFF: none yet).
    Age,
    /// Polling address (0xFFFF: unknown).
    PollingAddress,
    /// Device ID (24 bits).
    DeviceId,
    /// Manufacturer ID.
    ManufacturerId,
    /// Expanded device type.
    DeviceType,
    /// PV upper range value (20 mA point), in the range units; writable (command 35).
    UpperRange,
    /// PV lower range value (4 mA point); writable (command 35).
    LowerRange,
    /// Units of the range values; writable (command 35).
    RangeUnits,
    /// PV damping, s; writable (command 34).
    Damping,
    /// Loop current held in fixed current mode, mA (0: not fixed); writable (command
    /// 40: a value enters the mode, 0 leaves it).
    FixedCurrent,
}

impl Value {
    /// Whether the value can be written to the device (a Modbus holding register with
    /// it writes; the command is in its [`Value::description`]).
    pub fn writable(self) -> bool {
        matches!(
            self,
            Value::UpperRange
                | Value::LowerRange
                | Value::RangeUnits
                | Value::Damping
                | Value::FixedCurrent
        )
    }

    /// The name in the maps' JSON and the configuration file (`pv`, `upper_range`...).
    pub fn name(self) -> String {
        serde_json::to_value(self)
            .ok()
            .and_then(|v| v.as_str().map(str::to_string))
            .unwrap_or_default()
    }

    /// A description for the printed maps.
    pub fn description(self) -> &'static str {
        use Value::*;
        match self {
            Pv => "PV, in PV units",
            Sv => "SV, in SV units",
            Tv => "TV, in TV units",
            Qv => "QV, in QV units",
            LoopCurrent => "loop current, mA",
            PercentRange => "PV percent of range, %",
            PvUnits => "PV units code (HART Common Table 2)",
            SvUnits => "SV units code",
            TvUnits => "TV units code",
            QvUnits => "QV units code",
            DeviceStatus => "field device status byte",
            ExtendedStatus => "extended device status byte",
            Quality => "0 good, 1 stale, 2 no reply, 3 device malfunction, 4 configuration changed, 5 waiting for first data, 6 loop disturbed",
            Age => "seconds since the last good reply (4294967295: none yet)",
            PollingAddress => "polling address (65535: unknown)",
            DeviceId => "device ID",
            ManufacturerId => "manufacturer ID",
            DeviceType => "expanded device type",
            UpperRange => "PV upper range value (20 mA), range units; write: command 35",
            LowerRange => "PV lower range value (4 mA), range units; write: command 35",
            RangeUnits => "range units code; write: command 35",
            Damping => "PV damping, s; write: command 34",
            FixedCurrent => "fixed loop current, mA, 0 = not fixed; write: command 40 (0 leaves)",
        }
    }
}

/// The number `value` has for device `d` at `now`, as every front end that publishes
/// the image's values as numbers gives it (Modbus registers, PROFIBUS input modules):
/// NaN for a float the device has not given, 250 ("not used") for unknown units, the
/// quality's code, `u32::MAX` for the age before the first good reply; `None` for an
/// identity not known yet.
pub fn number(value: Value, d: &DeviceImage, now: Instant) -> Option<f64> {
    use Value::*;
    let var = |i: usize| d.variables[i];
    let f = |x: Option<f32>| x.unwrap_or(f32::NAN);
    let id = d.info.as_ref().map(|i| i.identity);
    match value {
        Pv | Sv | Tv | Qv => {
            let i = [Pv, Sv, Tv, Qv]
                .iter()
                .position(|v| *v == value)
                .unwrap_or(0);
            Some(f64::from(f(var(i).map(|v| v.value))))
        }
        LoopCurrent => Some(f64::from(f(d.loop_current))),
        PercentRange => Some(f64::from(f(d.percent_range))),
        PvUnits | SvUnits | TvUnits | QvUnits => {
            let i = [PvUnits, SvUnits, TvUnits, QvUnits]
                .iter()
                .position(|v| *v == value)
                .unwrap_or(0);
            // 250: "not used" in Common Table 2.
            Some(f64::from(var(i).map_or(250, |v| v.units)))
        }
        DeviceStatus => Some(f64::from(d.device_status)),
        ExtendedStatus => Some(f64::from(d.extended_status)),
        Quality => Some(f64::from(d.quality(now).code())),
        Age => Some(
            d.seconds_since_good(now)
                .map_or(f64::from(u32::MAX), f64::from),
        ),
        PollingAddress => Some(f64::from(d.polling_address.map_or(0xFFFF, u16::from))),
        DeviceId => id.map(|i| f64::from(i.device_id.get())),
        ManufacturerId => d.info.as_ref().map(|i| f64::from(i.manufacturer_id())),
        DeviceType => id.map(|i| f64::from(i.expanded_device_type)),
        UpperRange => Some(f64::from(f(d.range.map(|r| r.upper)))),
        LowerRange => Some(f64::from(f(d.range.map(|r| r.lower)))),
        RangeUnits => Some(f64::from(d.range.map_or(250, |r| r.units))),
        Damping => Some(f64::from(f(d.range.map(|r| r.damping)))),
        FixedCurrent => Some(f64::from(d.fixed_current.unwrap_or(0.0))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn device(now: Instant) -> DeviceImage {
        let mut d = DeviceImage::new(0, 0, "loop1", std::time::Duration::from_secs(10));
        // Command 3: current 12 mA, PV 50.0 kPa (12), no SV.
        let data = [0x41, 0x40, 0, 0, 12, 0x42, 0x48, 0, 0];
        d.apply_reply(3, 0, 0, &data, now, std::time::SystemTime::now());
        d
    }

    #[test]
    fn numbers_of_a_device() {
        let now = Instant::now();
        let d = device(now);
        assert_eq!(number(Value::Pv, &d, now), Some(50.0));
        assert!(number(Value::Sv, &d, now).is_some_and(f64::is_nan));
        assert_eq!(number(Value::LoopCurrent, &d, now), Some(12.0));
        assert_eq!(number(Value::PvUnits, &d, now), Some(12.0));
        assert_eq!(number(Value::SvUnits, &d, now), Some(250.0));
        assert_eq!(number(Value::Quality, &d, now), Some(0.0));
        assert_eq!(number(Value::FixedCurrent, &d, now), Some(0.0));
        assert_eq!(number(Value::DeviceId, &d, now), None);
        let waiting = DeviceImage::new(1, 0, "loop1", std::time::Duration::from_secs(10));
        assert_eq!(number(Value::Age, &waiting, now), Some(f64::from(u32::MAX)));
        assert_eq!(number(Value::PollingAddress, &waiting, now), Some(65_535.0));
    }

    #[test]
    fn names_are_the_configuration_file_s() {
        assert_eq!(Value::Pv.name(), "pv");
        assert_eq!(Value::LoopCurrent.name(), "loop_current");
        assert_eq!(Value::UpperRange.name(), "upper_range");
        assert!(Value::Damping.writable() && !Value::Pv.writable());
    }
}
