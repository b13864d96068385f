//! The metrics of a HART device and of the edge node: names, data types and aliases
//! (their values from the engine's image are made by hart-sparkplug-edge). The list is the contract with Sparkplug
//! host applications; docs/mqtt.md has it as a table.

use crate::proto::datatype as dt;
use crate::proto::payload::{metric, Metric, PropertySet, PropertyValue};

/// One metric value as the edge node compares and publishes it.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// No value (the device reports none, or it is not known yet).
    Null,
    /// A Float metric.
    Float(f32),
    /// An unsigned integer metric (UInt8/UInt16/UInt32).
    UInt(u32),
    /// A String metric.
    Text(String),
    /// A Boolean metric.
    Bool(bool),
}

impl Value {
    /// Same value for change detection: NaN equals NaN (a device that keeps
    /// reporting "no value" has not changed).
    pub fn same(&self, other: &Value) -> bool {
        match (self, other) {
            (Value::Float(a), Value::Float(b)) => {
                a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
            }
            _ => self == other,
        }
    }
}

/// How a device metric is defined.
#[derive(Debug, Clone, Copy)]
pub struct MetricDef {
    /// The metric name.
    pub name: &'static str,
    /// Sparkplug data type code.
    pub datatype: u32,
    /// What a DCMD on it does, when it may be written.
    pub write: Option<Writable>,
}

/// The writes a DCMD may carry (the same ones the OPC UA front end's methods offer).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Writable {
    /// PV damping, s (command 34).
    Damping,
    /// Upper range value (command 35, the lower one kept unless written too).
    UpperRange,
    /// Lower range value (command 35).
    LowerRange,
    /// Fixed loop current, mA; 0 leaves fixed current mode (command 40).
    FixedCurrent,
    /// Tag (command 18).
    Tag,
    /// Long tag (command 22).
    LongTag,
}

const fn m(name: &'static str, datatype: u32) -> MetricDef {
    MetricDef {
        name,
        datatype,
        write: None,
    }
}

const fn w(name: &'static str, datatype: u32, write: Writable) -> MetricDef {
    MetricDef {
        name,
        datatype,
        write: Some(write),
    }
}

/// Every device's metrics, in alias order: a device's metric `i` has alias
/// [`device_alias`]`(position, i)`. Appending keeps old aliases; never reorder.
pub const DEVICE_METRICS: &[MetricDef] = &[
    m("PV", dt::FLOAT),
    m("SV", dt::FLOAT),
    m("TV", dt::FLOAT),
    m("QV", dt::FLOAT),
    m("LoopCurrent", dt::FLOAT),
    m("PercentRange", dt::FLOAT),
    m("Status/DeviceStatus", dt::UINT8),
    m("Status/ExtendedStatus", dt::UINT8),
    m("Status/Quality", dt::STRING),
    m("Status/QualityCode", dt::UINT16),
    w("Config/UpperRange", dt::FLOAT, Writable::UpperRange),
    w("Config/LowerRange", dt::FLOAT, Writable::LowerRange),
    w("Config/Damping", dt::FLOAT, Writable::Damping),
    w("Config/FixedCurrent", dt::FLOAT, Writable::FixedCurrent),
    w("Properties/Tag", dt::STRING, Writable::Tag),
    w("Properties/LongTag", dt::STRING, Writable::LongTag),
    m("Properties/Descriptor", dt::STRING),
    m("Properties/UniqueId", dt::STRING),
    m("Properties/Loop", dt::STRING),
    m("Properties/PollingAddress", dt::UINT8),
    m("Properties/Position", dt::UINT32),
];

/// The device metrics the historian stores, by the historian's variable code
/// (`hart_history::Var::code`: 0 PV, 1 SV, 2 TV, 3 QV, 4 loop current, 5 percent of
/// range, 6 device status): the one table between stored variables and Sparkplug
/// metrics, read by the gateway's backfill (historian to metric) and the ingest's
/// decoder (metric to historian).
pub const STORED: [&str; 7] = [
    "PV",
    "SV",
    "TV",
    "QV",
    "LoopCurrent",
    "PercentRange",
    "Status/DeviceStatus",
];

/// The historian's variable code of the device metric called `name`, if it stores it.
pub fn stored_code(name: &str) -> Option<i16> {
    STORED
        .iter()
        .position(|n| *n == name)
        .and_then(|i| i16::try_from(i).ok())
}

/// The index in [`DEVICE_METRICS`] of the metric of the historian's variable `code`.
pub fn stored_metric(code: i16) -> Option<usize> {
    let name = STORED.get(usize::try_from(code).ok()?)?;
    index_of(name)
}

/// Index of `PV` .. `QV` in [`DEVICE_METRICS`].
const VARIABLES: usize = 0;
/// Index of `Config/UpperRange` and `Config/LowerRange`.
const RANGE: usize = 10;
/// Index of `Config/FixedCurrent`.
const FIXED_CURRENT: usize = 13;

/// The node's metrics in NBIRTH: `bdSeq`, `Node Control/Rebirth`, `Properties/Software`.
pub const NODE_BDSEQ: &str = "bdSeq";
/// The rebirth request metric (Sparkplug 3.0 section 6.4.17, required in NBIRTH).
pub const NODE_REBIRTH: &str = "Node Control/Rebirth";
/// The software that publishes.
pub const NODE_SOFTWARE: &str = "Properties/Software";
/// Alias of `Node Control/Rebirth` (node metric aliases are 1..255).
pub const REBIRTH_ALIAS: u64 = 1;
/// Alias of `Properties/Software`.
pub const SOFTWARE_ALIAS: u64 = 2;
/// Alias of `bdSeq` in NBIRTH (the will's NDEATH carries it by name only).
pub const BDSEQ_ALIAS: u64 = 3;

/// The alias of device metric `index` of the device at engine position `position`:
/// `(position + 1) * 256 + index`, unique across the edge node (node metrics are
/// below 256) and stable for the life of the engine (positions never change).
pub fn device_alias(position: usize, index: usize) -> u64 {
    (position as u64 + 1) * 256 + index as u64
}

/// The (position, metric index) an alias names, if it is a device alias.
pub fn from_alias(alias: u64) -> Option<(usize, usize)> {
    let position = (alias / 256).checked_sub(1)?;
    let index = (alias % 256) as usize;
    (index < DEVICE_METRICS.len()).then_some((usize::try_from(position).ok()?, index))
}

/// The index of the device metric called `name`.
pub fn index_of(name: &str) -> Option<usize> {
    DEVICE_METRICS.iter().position(|d| d.name == name)
}

/// The `engUnit` (symbol) and `hartUnitCode` properties of a units code.
fn unit_properties(code: Option<u8>, fixed: Option<&str>) -> Option<PropertySet> {
    let symbol = match (fixed, code) {
        (Some(s), _) => s.to_string(),
        (None, Some(c)) => {
            hart_proto::tables::unit_symbol(c).map_or(format!("code {c}"), str::to_string)
        }
        (None, None) => return None,
    };
    let mut p = PropertySet {
        keys: vec!["engUnit".into()],
        values: vec![PropertyValue {
            r#type: Some(dt::STRING),
            is_null: None,
            value: Some(crate::proto::payload::property_value::Value::StringValue(
                symbol,
            )),
        }],
    };
    if let Some(c) = code {
        p.keys.push("hartUnitCode".into());
        p.values.push(PropertyValue {
            r#type: Some(dt::UINT8),
            is_null: None,
            value: Some(crate::proto::payload::property_value::Value::IntValue(
                u32::from(c),
            )),
        });
    }
    Some(p)
}

/// The properties of device metric `index` in a DBIRTH.
pub fn properties(index: usize, units: &[Option<u8>; 5]) -> Option<PropertySet> {
    match index {
        i @ VARIABLES..=3 => unit_properties(units[i], None),
        4 => unit_properties(None, Some("mA")),
        5 => unit_properties(None, Some("%")),
        i if i == RANGE || i == RANGE + 1 => unit_properties(units[4], None),
        12 => unit_properties(None, Some("s")),
        i if i == FIXED_CURRENT => unit_properties(None, Some("mA")),
        _ => None,
    }
}

/// A metric carrying `value` as `datatype`.
pub fn metric(datatype: u32, value: &Value) -> Metric {
    let mut out = Metric {
        datatype: Some(datatype),
        ..Default::default()
    };
    match value {
        Value::Null => out.is_null = Some(true),
        Value::Float(x) => out.value = Some(metric::Value::FloatValue(*x)),
        Value::UInt(x) => out.value = Some(metric::Value::IntValue(*x)),
        Value::Text(x) => out.value = Some(metric::Value::StringValue(x.clone())),
        Value::Bool(x) => out.value = Some(metric::Value::BooleanValue(*x)),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliases_round_trip_and_stay_above_node_aliases() {
        for p in [0usize, 1, 7, 300] {
            for i in 0..DEVICE_METRICS.len() {
                let a = device_alias(p, i);
                assert!(a >= 256);
                assert_eq!(from_alias(a), Some((p, i)));
            }
        }
        assert_eq!(from_alias(REBIRTH_ALIAS), None);
        assert_eq!(from_alias(256 + 255), None);
    }

    #[test]
    fn names_are_unique_even_in_lower_case() {
        let mut names: Vec<String> = DEVICE_METRICS
            .iter()
            .map(|d| d.name.to_lowercase())
            .collect();
        names.sort();
        names.dedup();
        assert_eq!(names.len(), DEVICE_METRICS.len());
        assert_eq!(index_of("Config/UpperRange"), Some(RANGE));
        assert_eq!(index_of("Config/FixedCurrent"), Some(FIXED_CURRENT));
        assert_eq!(index_of("Config/Damping"), Some(12));
    }

    #[test]
    fn every_stored_variable_is_a_device_metric() {
        for (code, name) in STORED.iter().enumerate() {
            let code = i16::try_from(code).unwrap();
            assert_eq!(stored_code(name), Some(code));
            assert_eq!(
                stored_metric(code).map(|i| DEVICE_METRICS[i].name),
                Some(*name)
            );
        }
        assert_eq!(stored_code("Config/Damping"), None);
        assert_eq!(stored_metric(7), None);
    }
}
