//! Decoding NCMD and DCMD payloads: untrusted bytes from the broker, turned into
//! metric names or aliases with values, or a typed error that says what was wrong.
//! Never panics (fuzz target `sparkplug_command`).

use prost::Message as _;

use crate::proto::payload::metric::Value as V;
use crate::proto::Payload;

/// Most metrics one command may carry: a host application writes a few at a time.
pub const MAX_COMMAND_METRICS: usize = 64;

/// One metric of a command.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandMetric {
    /// Its name, when the host gave one.
    pub name: Option<String>,
    /// Its alias, when the host gave one.
    pub alias: Option<u64>,
    /// The value to write.
    pub value: CommandValue,
}

impl CommandMetric {
    /// The name, or `alias N`, for messages.
    pub fn label(&self) -> String {
        match (&self.name, self.alias) {
            (Some(n), _) => n.clone(),
            (None, Some(a)) => format!("alias {a}"),
            (None, None) => "a metric without name or alias".into(),
        }
    }
}

/// A command metric's value.
#[derive(Debug, Clone, PartialEq)]
pub enum CommandValue {
    /// A Boolean.
    Bool(bool),
    /// A number (int, long, float or double value).
    Number(f64),
    /// A string.
    Text(String),
    /// No value (`is_null`, or none given).
    Null,
    /// A kind of value no command here takes (bytes, data set, template, extension).
    Unsupported(&'static str),
}

/// Why a command payload was not taken.
#[derive(Debug, Clone, PartialEq)]
pub enum CommandError {
    /// Not a Sparkplug B protobuf payload.
    Protobuf(String),
    /// A payload without metrics.
    NoMetrics,
    /// More metrics than [`MAX_COMMAND_METRICS`].
    TooManyMetrics(usize),
    /// Metric `index` (0-based) has neither a name nor an alias.
    Unnamed(usize),
}

impl std::fmt::Display for CommandError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CommandError::Protobuf(e) => write!(
                f,
                "the payload is not a Sparkplug B protobuf payload ({e}); check that the sender encodes with sparkplug_b.proto"
            ),
            CommandError::NoMetrics => f.write_str("the payload carries no metric; a command names the metrics to write"),
            CommandError::TooManyMetrics(n) => write!(
                f,
                "the payload carries {n} metrics, more than the {MAX_COMMAND_METRICS} one command may write"
            ),
            CommandError::Unnamed(i) => write!(
                f,
                "metric {} has neither a name nor an alias; give the name from the birth certificate",
                i + 1
            ),
        }
    }
}

impl std::error::Error for CommandError {}

/// Decodes an NCMD or DCMD payload.
pub fn decode(payload: &[u8]) -> Result<Vec<CommandMetric>, CommandError> {
    let p = Payload::decode(payload).map_err(|e| CommandError::Protobuf(e.to_string()))?;
    if p.metrics.is_empty() {
        return Err(CommandError::NoMetrics);
    }
    if p.metrics.len() > MAX_COMMAND_METRICS {
        return Err(CommandError::TooManyMetrics(p.metrics.len()));
    }
    p.metrics
        .into_iter()
        .enumerate()
        .map(|(i, m)| {
            if m.name.is_none() && m.alias.is_none() {
                return Err(CommandError::Unnamed(i));
            }
            let value = if m.is_null == Some(true) {
                CommandValue::Null
            } else {
                match m.value {
                    None => CommandValue::Null,
                    Some(V::BooleanValue(b)) => CommandValue::Bool(b),
                    Some(V::IntValue(x)) => CommandValue::Number(int32(x, m.datatype)),
                    Some(V::LongValue(x)) => CommandValue::Number(int64(x, m.datatype)),
                    Some(V::FloatValue(x)) => CommandValue::Number(f64::from(x)),
                    Some(V::DoubleValue(x)) => CommandValue::Number(x),
                    Some(V::StringValue(s)) => CommandValue::Text(s),
                    Some(V::BytesValue(_)) => CommandValue::Unsupported("bytes"),
                    Some(V::DatasetValue(_)) => CommandValue::Unsupported("a data set"),
                    Some(V::TemplateValue(_)) => CommandValue::Unsupported("a template"),
                    Some(V::ExtensionValue(_)) => CommandValue::Unsupported("an extension"),
                }
            };
            Ok(CommandMetric {
                name: m.name,
                alias: m.alias,
                value,
            })
        })
        .collect()
}

/// A 32-bit `int_value` as its data type reads it (signed types are two's complement).
fn int32(x: u32, datatype: Option<u32>) -> f64 {
    use crate::proto::datatype as dt;
    match datatype {
        Some(dt::INT8) => f64::from(x as u8 as i8),
        Some(dt::INT16) => f64::from(x as u16 as i16),
        Some(dt::INT32) => f64::from(x as i32),
        _ => f64::from(x),
    }
}

/// A 64-bit `long_value` as its data type reads it.
fn int64(x: u64, datatype: Option<u32>) -> f64 {
    if datatype == Some(crate::proto::datatype::INT64) {
        x as i64 as f64
    } else {
        x as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::proto::payload::Metric;

    fn encode(metrics: Vec<Metric>) -> Vec<u8> {
        Payload {
            timestamp: Some(1),
            metrics,
            ..Default::default()
        }
        .encode_to_vec()
    }

    #[test]
    fn rebirth_request() {
        let bytes = encode(vec![Metric {
            name: Some("Node Control/Rebirth".into()),
            datatype: Some(11),
            value: Some(V::BooleanValue(true)),
            ..Default::default()
        }]);
        let m = decode(&bytes).unwrap();
        assert_eq!(m[0].name.as_deref(), Some("Node Control/Rebirth"));
        assert_eq!(m[0].value, CommandValue::Bool(true));
    }

    #[test]
    fn bad_payloads_are_typed_errors() {
        assert!(matches!(
            decode(&[0xFF, 0xFF, 0xFF]),
            Err(CommandError::Protobuf(_))
        ));
        assert_eq!(decode(&encode(vec![])), Err(CommandError::NoMetrics));
        assert_eq!(
            decode(&encode(vec![Metric::default()])),
            Err(CommandError::Unnamed(0))
        );
        let many = vec![
            Metric {
                alias: Some(1),
                ..Default::default()
            };
            MAX_COMMAND_METRICS + 1
        ];
        assert_eq!(
            decode(&encode(many)),
            Err(CommandError::TooManyMetrics(MAX_COMMAND_METRICS + 1))
        );
        // Truncated in the middle of a metric.
        let bytes = encode(vec![Metric {
            name: Some("Config/Damping".into()),
            value: Some(V::FloatValue(2.0)),
            ..Default::default()
        }]);
        assert!(decode(&bytes[..bytes.len() - 2]).is_err());
    }

    #[test]
    fn signed_ints_read_as_their_type() {
        assert_eq!(int32(0xFFFF_FFFF, Some(3)), -1.0);
        assert_eq!(int32(0xFF, Some(1)), -1.0);
        assert_eq!(int32(0xFF, Some(5)), 255.0);
        assert_eq!(int64(u64::MAX, Some(4)), -1.0);
    }

    proptest::proptest! {
        /// Any bytes decode to metrics or a typed error, never a panic.
        #[test]
        fn any_bytes(bytes in proptest::collection::vec(proptest::num::u8::ANY, 0..256)) {
            let _ = decode(&bytes);
        }
    }
}
