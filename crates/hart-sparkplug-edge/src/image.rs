//! A device image's metric values: the engine's [`DeviceImage`] in the order of
//! [`DEVICE_METRICS`] (hart-sparkplug's table), and the units its births carry.

use hart_poller::{DeviceImage, Quality};
use hart_sparkplug::metrics::{Value, DEVICE_METRICS};

fn nonblank(s: &Option<String>) -> Option<String> {
    s.as_deref()
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(str::to_string)
}

/// Every device metric's value, in [`DEVICE_METRICS`] order.
pub fn values(d: &DeviceImage, quality: Quality) -> Vec<Value> {
    let f = |v: Option<f32>| v.map_or(Value::Null, Value::Float);
    let s = |v: Option<String>| v.map_or(Value::Null, Value::Text);
    let mut out = Vec::with_capacity(DEVICE_METRICS.len());
    for v in &d.variables {
        out.push(f(v.map(|v| v.value)));
    }
    out.push(f(d.loop_current));
    out.push(f(d.percent_range));
    out.push(Value::UInt(u32::from(d.device_status)));
    out.push(Value::UInt(u32::from(d.extended_status)));
    out.push(Value::Text(quality.name().to_string()));
    out.push(Value::UInt(u32::from(quality.code())));
    out.push(f(d.range.map(|r| r.upper)));
    out.push(f(d.range.map(|r| r.lower)));
    out.push(f(d.range.map(|r| r.damping)));
    out.push(f(d.fixed_current));
    let info = d.info.as_ref();
    out.push(s(info.and_then(|i| nonblank(&i.tag))));
    out.push(s(info.and_then(|i| nonblank(&i.long_tag))));
    out.push(s(info.and_then(|i| nonblank(&i.descriptor))));
    out.push(s(info.map(|i| i.unique_id().to_string())));
    out.push(Value::Text(d.loop_name.clone()));
    out.push(
        d.polling_address
            .map_or(Value::Null, |p| Value::UInt(u32::from(p))),
    );
    out.push(Value::UInt(u32::try_from(d.position).unwrap_or(u32::MAX)));
    debug_assert_eq!(out.len(), DEVICE_METRICS.len());
    out
}

/// The units codes the births carry as properties: PV..QV's, then the range's.
/// A change of any of them makes a new DBIRTH (properties belong to births).
pub fn units(d: &DeviceImage) -> [Option<u8>; 5] {
    [
        d.variables[0].map(|v| v.units),
        d.variables[1].map(|v| v.units),
        d.variables[2].map(|v| v.units),
        d.variables[3].map(|v| v.units),
        d.range.map(|r| r.units),
    ]
}
