//! How a device image of the engine becomes the historian's samples.

use std::time::SystemTime;

use hart_history::{widen, DeviceKey, Sample, Var, UNITS_MILLIAMPERES, UNITS_PERCENT};
use hart_poller::{DeviceImage, Quality};

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

#[cfg(test)]
mod tests {
    use super::*;
    use hart_poller::Variable;
    use std::time::Duration;

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

    #[test]
    fn quality_names_are_the_engines() {
        for q in Quality::ALL {
            let code = u8::try_from(q.code()).unwrap();
            assert_eq!(hart_history::quality_name(code), q.name());
        }
    }
}
