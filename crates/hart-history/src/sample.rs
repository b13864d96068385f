//! The sample model: what is stored per value (hart-recorder makes them of the
//! engine's device images).

use std::time::SystemTime;

use crate::Error;

/// Units code of milliamperes (HART Common Table 2), for the loop current.
pub const UNITS_MILLIAMPERES: u8 = 39;
/// Units code of percent (HART Common Table 2), for the percent of range.
pub const UNITS_PERCENT: u8 = 57;

/// Which device a sample is of.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct DeviceKey {
    /// The unique ID as 10 upper-case hex digits (as `hart_proto`'s `UniqueId` prints
    /// it): the device's identity in the database.
    pub unique_id: String,
    /// The long tag, else the tag, trimmed (empty when neither was read yet).
    pub tag: String,
    /// The name of the loop the device is on.
    pub loop_name: String,
}

/// A variable of a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Var {
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
    /// The field device status byte of the last reply.
    DeviceStatus,
}

impl Var {
    /// Every variable, in code order.
    pub const ALL: [Var; 7] = [
        Var::Pv,
        Var::Sv,
        Var::Tv,
        Var::Qv,
        Var::LoopCurrent,
        Var::PercentRange,
        Var::DeviceStatus,
    ];

    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Var::Pv => "pv",
            Var::Sv => "sv",
            Var::Tv => "tv",
            Var::Qv => "qv",
            Var::LoopCurrent => "loop_current",
            Var::PercentRange => "percent_range",
            Var::DeviceStatus => "device_status",
        }
    }

    /// The code stored in the database's `var` column (0 PV ... 6 device status).
    pub fn code(self) -> i16 {
        match self {
            Var::Pv => 0,
            Var::Sv => 1,
            Var::Tv => 2,
            Var::Qv => 3,
            Var::LoopCurrent => 4,
            Var::PercentRange => 5,
            Var::DeviceStatus => 6,
        }
    }

    /// The variable stored with `code`.
    pub fn from_code(code: i64) -> Option<Var> {
        Var::ALL.into_iter().find(|v| i64::from(v.code()) == code)
    }
}

impl std::fmt::Display for Var {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Var {
    type Err = Error;
    fn from_str(s: &str) -> Result<Var, Error> {
        let s = s.trim().to_ascii_lowercase().replace('-', "_");
        Var::ALL.into_iter().find(|v| v.name() == s).ok_or_else(|| {
            Error::Usage(format!(
                "no variable '{s}': use one of pv, sv, tv, qv, loop_current, percent_range, device_status"
            ))
        })
    }
}

/// One stored value.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// The device.
    pub device: DeviceKey,
    /// The variable.
    pub var: Var,
    /// The value (NaN when the device reports none: stored as NULL).
    pub value: f64,
    /// HART units code (Common Table 2); `None` for the device status.
    pub units: Option<u8>,
    /// The image's quality code (`hart_poller::Quality::code`: 0 good, 1 stale, 2 no
    /// reply, 3 device malfunction, 4 configuration changed, 5 waiting for data).
    pub quality: u8,
    /// When the value was true (the image's time stamp).
    pub time: SystemTime,
}

/// Microseconds since 1970-01-01 UTC (negative before), the database's time.
pub use hart_clock::epoch::signed_micros as micros;

/// The time `us` microseconds after 1970-01-01 UTC.
pub use hart_clock::epoch::from_signed_micros as from_micros;

/// A device's single-precision value as the double of its shortest decimal form, so
/// what is stored and shown is the value the device sent, without the digits a plain
/// widening adds (also used by `hartkit history ingest` for Sparkplug Float metrics,
/// so both paths store the same number).
pub fn widen(v: f32) -> f64 {
    if v.is_finite() {
        v.to_string().parse().unwrap_or(f64::from(v))
    } else {
        f64::from(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn singles_are_stored_as_their_shortest_decimal() {
        assert_eq!(widen(80.545_975), 80.545975);
        assert_eq!(widen(0.1), 0.1);
        assert!(widen(f32::NAN).is_nan());
        assert_eq!(widen(f32::INFINITY), f64::INFINITY);
        assert_eq!(widen(f32::MAX) as f32, f32::MAX);
    }

    #[test]
    fn var_names_round_trip() {
        for v in Var::ALL {
            assert_eq!(v.name().parse::<Var>().unwrap(), v);
            assert_eq!(Var::from_code(i64::from(v.code())), Some(v));
        }
        assert_eq!("Loop-Current".parse::<Var>().unwrap(), Var::LoopCurrent);
        let e = "xv".parse::<Var>().unwrap_err();
        assert!(e.to_string().contains("pv, sv"), "{e}");
    }

    #[test]
    fn micros_round_trip() {
        for us in [0, 1, -1, 1_700_000_000_123_456, -86_400_000_000] {
            assert_eq!(micros(from_micros(us)), us);
        }
    }
}
