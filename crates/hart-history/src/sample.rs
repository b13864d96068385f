//! The sample model: what is stored per value, and how a device image becomes samples.

use std::time::SystemTime;

use hart_poller::{DeviceImage, Quality};

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

/// The key of a device image, once the device is identified.
pub fn device_key(device: &DeviceImage) -> Option<DeviceKey> {
    let info = device.info.as_ref()?;
    let nonblank = |s: &Option<String>| {
        s.as_deref()
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(str::to_string)
    };
    Some(DeviceKey {
        unique_id: info.unique_id().to_string(),
        tag: nonblank(&info.long_tag)
            .or_else(|| nonblank(&info.tag))
            .unwrap_or_default(),
        loop_name: device.loop_name.clone(),
    })
}

/// The samples of one device image at `at` with `quality`: each of PV, SV, TV, QV,
/// loop current and percent of range the image holds (each device value, an IEEE
/// single, stored as the double nearest its shortest decimal: 80.545975, not
/// 80.54597473144531), and the device status once the
/// device has answered. A device not identified yet (no unique ID) gives none.
pub fn samples_of(device: &DeviceImage, quality: Quality, at: SystemTime) -> Vec<Sample> {
    let Some(key) = device_key(device) else {
        return vec![];
    };
    let quality = u8::try_from(quality.code()).unwrap_or(u8::MAX);
    let mut out = Vec::with_capacity(7);
    let mut push = |var, value: f64, units| {
        out.push(Sample {
            device: key.clone(),
            var,
            value,
            units,
            quality,
            time: at,
        })
    };
    for (var, v) in [Var::Pv, Var::Sv, Var::Tv, Var::Qv]
        .into_iter()
        .zip(device.variables.iter())
    {
        if let Some(v) = v {
            push(var, widen(v.value), Some(v.units));
        }
    }
    if let Some(c) = device.loop_current {
        push(Var::LoopCurrent, widen(c), Some(UNITS_MILLIAMPERES));
    }
    if let Some(p) = device.percent_range {
        push(Var::PercentRange, widen(p), Some(UNITS_PERCENT));
    }
    if device.updated.is_some() {
        push(Var::DeviceStatus, f64::from(device.device_status), None);
    }
    out
}

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
    use hart_poller::Variable;
    use std::time::Duration;

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

    #[test]
    fn unidentified_device_gives_nothing() {
        let mut d = DeviceImage::new(0, 0, "loop1", Duration::from_secs(10));
        d.variables[0] = Some(Variable {
            value: 1.0,
            units: 12,
            status: None,
        });
        assert!(samples_of(&d, Quality::Good, SystemTime::now()).is_empty());
    }
}
