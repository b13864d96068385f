//! Typed requests and replies built from named fields given as JSON: the reverse of
//! the `--json` view, with the same names (`docs/frame-json.md`), so what
//! `hartkit decode --json` shows under `decoded` can be edited and sent back.
//!
//! ```
//! use serde_json::json;
//! let data = hart_proto::json::fields::request_bytes(18, &json!({
//!     "tag": "PT-101", "descriptor": "FEED PUMP", "date": "2026-11-26"
//! })).unwrap();
//! assert_eq!(data.len(), 21);
//! ```
//!
//! A unit or code may be given by name (`"units": "kPa"`); the words the decoded view
//! adds beside a code (`units_symbol`, `..._name`, `..._set`) are accepted and ignored,
//! so a decoded object goes back as it is. A key that is no field of the layout is an
//! error that lists the fields, as is a missing field or a value out of range.

use std::fmt;

use crate::wire::{BuildError, DecodeError, EncodeError, Source, Value, Visitor, Writer};
use crate::{Request, Response};
use serde_json::{Map, Value as Json};

use crate::json::JsonVisitor;
use std::string::String;
use std::vec;
use std::vec::Vec;

/// Why fields could not be turned into a request or reply.
#[derive(Debug, Clone, PartialEq)]
pub enum FieldsError {
    /// hartkit has no layout for the command: its data must be given as hex.
    NotTyped(u16),
    /// The fields were not a JSON object.
    NotObject,
    /// A field was missing, of the wrong kind or out of range.
    Build(BuildError),
    /// A key that is no field of the layout (a misspelling, or another command's).
    Unknown {
        /// The key.
        key: String,
        /// The fields the layout has.
        fields: Vec<String>,
    },
}

impl fmt::Display for FieldsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FieldsError::NotTyped(n) => write!(
                f,
                "hartkit has no layout for command {n}: give its data as hex instead of fields"
            ),
            FieldsError::NotObject => f.write_str(
                "the fields must be a JSON object, e.g. {\"tag\": \"PT-101\"} (see `hartkit decode --json`)",
            ),
            FieldsError::Build(e) => e.fmt(f),
            FieldsError::Unknown { key, fields } if fields.is_empty() => {
                write!(f, "no field {key}: this command's data is empty")
            }
            FieldsError::Unknown { key, fields } => write!(
                f,
                "no field {key}; the fields are {}",
                fields.join(", ")
            ),
        }
    }
}

impl std::error::Error for FieldsError {}

impl From<BuildError> for FieldsError {
    fn from(e: BuildError) -> Self {
        FieldsError::Build(e)
    }
}

/// The request of `command` from its fields.
pub fn request(command: u16, fields: &Json) -> Result<Request, FieldsError> {
    build(command, fields)
}

/// The reply data of `command` (after the status bytes) from its fields.
pub fn response(command: u16, fields: &Json) -> Result<Response, FieldsError> {
    build(command, fields)
}

/// The request data bytes of `command` from its fields.
pub fn request_bytes(command: u16, fields: &Json) -> Result<Vec<u8>, FieldsError> {
    bytes(&request(command, fields)?)
}

/// The reply data bytes (after the status bytes) of `command` from its fields.
pub fn response_bytes(command: u16, fields: &Json) -> Result<Vec<u8>, FieldsError> {
    bytes(&response(command, fields)?)
}

/// A request or a reply: what building needs of either.
trait Typed: Sized {
    fn build(command: u16, src: &mut dyn Source) -> Option<Result<Self, BuildError>>;
    fn decode(command: u16, data: &[u8]) -> Option<Result<Self, DecodeError>>;
    fn describe(&self, v: &mut dyn Visitor);
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError>;
}

impl Typed for Request {
    fn build(command: u16, src: &mut dyn Source) -> Option<Result<Self, BuildError>> {
        crate::build_request(command, src)
    }
    fn decode(command: u16, data: &[u8]) -> Option<Result<Self, DecodeError>> {
        crate::decode_request(command, data)
    }
    fn describe(&self, v: &mut dyn Visitor) {
        Request::describe(self, v)
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        Request::encode(self, w)
    }
}

impl Typed for Response {
    fn build(command: u16, src: &mut dyn Source) -> Option<Result<Self, BuildError>> {
        crate::build_response(command, src)
    }
    fn decode(command: u16, data: &[u8]) -> Option<Result<Self, DecodeError>> {
        crate::decode_response(command, data)
    }
    fn describe(&self, v: &mut dyn Visitor) {
        Response::describe(self, v)
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        Response::encode(self, w)
    }
}

fn build<T: Typed>(command: u16, fields: &Json) -> Result<T, FieldsError> {
    let obj = fields.as_object().ok_or(FieldsError::NotObject)?;
    let built =
        T::build(command, &mut JsonSource::new(obj)).ok_or(FieldsError::NotTyped(command))?;
    let view = |t: &T| {
        let mut v = JsonVisitor::with_words();
        t.describe(&mut v);
        v.finish()
    };
    match built {
        Ok(t) => {
            no_unknown_keys(obj, &view(&t))?;
            Ok(t)
        }
        Err(e) => {
            // A misspelt key is the likelier cause of a missing field: check the keys
            // against the layout filled with zeros (every field present).
            if let Some(Ok(full)) = T::decode(command, &[0; 255]) {
                no_unknown_keys(obj, &view(&full))?;
            }
            Err(e.into())
        }
    }
}

fn bytes<T: Typed>(t: &T) -> Result<Vec<u8>, FieldsError> {
    let mut buf = [0u8; 255];
    let mut w = Writer::new(&mut buf);
    // Built values are checked to encode (crate::build_request), so this only
    // repeats that check.
    t.encode(&mut w).map_err(|e| {
        FieldsError::Build(BuildError::Invalid {
            field: "data",
            reason: match e {
                EncodeError::Invalid(why) => why,
                EncodeError::BufferTooSmall { .. } => "too long",
            },
        })
    })?;
    Ok(w.written().to_vec())
}

/// Every key given must be one the built value describes (its fields and the words
/// beside them); lists are compared item by item.
fn no_unknown_keys(given: &Map<String, Json>, built: &Json) -> Result<(), FieldsError> {
    let empty = Map::new();
    let built = built.as_object().unwrap_or(&empty);
    for (key, value) in given {
        let Some(counterpart) = built.get(key) else {
            return Err(FieldsError::Unknown {
                key: key.clone(),
                fields: built
                    .keys()
                    .filter(|k| !is_word(k, built))
                    .cloned()
                    .collect(),
            });
        };
        if let (Json::Array(items), Json::Array(built_items)) = (value, counterpart) {
            for (item, built_item) in items.iter().zip(built_items) {
                if let Json::Object(m) = item {
                    no_unknown_keys(m, built_item)?;
                }
            }
        }
    }
    Ok(())
}

/// A key the decoded view adds beside a field (`units_symbol` beside `units`).
fn is_word(key: &str, obj: &Map<String, Json>) -> bool {
    ["_symbol", "_name", "_set"].iter().any(|suffix| {
        key.strip_suffix(suffix)
            .is_some_and(|field| obj.contains_key(field))
    })
}

/// Reads field values out of a JSON object for [`crate::build_request`].
pub struct JsonSource<'a> {
    stack: Vec<Scope<'a>>,
}

enum Scope<'a> {
    Object(&'a Map<String, Json>),
    List(&'a [Json]),
    /// An item of a list of scalars: its value is the field `item`.
    Scalar(&'a Json),
}

impl<'a> JsonSource<'a> {
    /// A source over `obj`.
    pub fn new(obj: &'a Map<String, Json>) -> Self {
        JsonSource {
            stack: vec![Scope::Object(obj)],
        }
    }

    fn lookup(&self, name: &str) -> Option<&'a Json> {
        match self.stack.last()? {
            Scope::Object(m) => m.get(name),
            Scope::Scalar(j) if name == "item" => Some(j),
            _ => None,
        }
    }
}

impl Source for JsonSource<'_> {
    fn value(&mut self, name: &'static str) -> Result<Option<Value<'_>>, BuildError> {
        let Some(j) = self.lookup(name) else {
            return Ok(None);
        };
        Ok(Some(match j {
            Json::Bool(b) => Value::Bool(*b),
            Json::String(s) => Value::Str(s),
            // The decoded view shows a float that is not a number as null.
            Json::Null => Value::Float(crate::types::hart_nan()),
            Json::Number(n) => match n.as_u64() {
                Some(u) => match u32::try_from(u) {
                    Ok(u) => Value::Uint(u),
                    Err(_) => Value::Float(u as f32),
                },
                None => Value::Float(n.as_f64().unwrap_or(f64::NAN) as f32),
            },
            Json::Array(_) | Json::Object(_) => {
                return Err(BuildError::WrongKind {
                    field: name,
                    expected: "a single value, not a list or object",
                })
            }
        }))
    }

    fn begin_list(&mut self, name: &'static str) -> Result<Option<usize>, BuildError> {
        match self.lookup(name) {
            None => Ok(None),
            Some(Json::Array(items)) => {
                self.stack.push(Scope::List(items));
                Ok(Some(items.len()))
            }
            Some(_) => Err(BuildError::WrongKind {
                field: name,
                expected: "a list",
            }),
        }
    }

    fn begin_item(&mut self, index: usize) -> Result<(), BuildError> {
        let Some(Scope::List(items)) = self.stack.last() else {
            return Ok(());
        };
        let scope = match items.get(index) {
            Some(Json::Object(m)) => Scope::Object(m),
            Some(j) => Scope::Scalar(j),
            None => return Err(BuildError::Missing { field: "item" }),
        };
        self.stack.push(scope);
        Ok(())
    }

    fn end_item(&mut self) {
        self.stack.pop();
    }

    fn end_list(&mut self) {
        self.stack.pop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;
    use std::string::ToString;

    fn hexs(b: &[u8]) -> String {
        crate::hex::compact(b)
    }

    #[test]
    fn command_18_from_fields() {
        // Tag "PT-101" packs to 41 4B 71 C3 18 20 (hart-reference.md §10.1).
        let b = request_bytes(
            18,
            &json!({"tag": "PT-101", "descriptor": "", "date": "2025-11-21"}),
        )
        .unwrap();
        assert_eq!(&b[..6], &[0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20]);
        assert_eq!(&b[18..], &[21, 11, 125]);
    }

    #[test]
    fn units_by_symbol_and_by_code() {
        let by_code = request_bytes(44, &json!({"pv_units": 12})).unwrap();
        let by_symbol = request_bytes(44, &json!({"pv_units": "kPa"})).unwrap();
        assert_eq!(by_code, [12]);
        assert_eq!(by_symbol, by_code);
        let e = request_bytes(44, &json!({"pv_units": "furlongs"})).unwrap_err();
        assert!(e.to_string().contains("pv_units"), "{e}");
    }

    #[test]
    fn errors_explain() {
        let e = request_bytes(18, &json!({"tag": "PT-101"})).unwrap_err();
        assert_eq!(e.to_string(), "field descriptor is missing");
        // A misspelling that leaves a field missing is named as the cause.
        let e = request_bytes(44, &json!({"pv_unit": "kPa"})).unwrap_err();
        assert_eq!(e.to_string(), "no field pv_unit; the fields are pv_units");
        let e = request_bytes(
            18,
            &json!({"tag": "PT-101", "descriptor": "", "date": "2025-11-21", "tga": 1}),
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .starts_with("no field tga; the fields are tag, descriptor, date"),
            "{e}"
        );
        let e = request_bytes(6, &json!({"polling_address": 300})).unwrap_err();
        assert!(e.to_string().contains("0 to 255"), "{e}");
        let e = request_bytes(6, &json!({"polling_address": -1})).unwrap_err();
        assert!(e.to_string().contains("0 to 255"), "{e}");
        let e = request_bytes(6, &json!({"polling_address": "x"})).unwrap_err();
        assert!(e.to_string().contains("whole number"), "{e}");
        assert_eq!(
            request_bytes(200, &json!({})).unwrap_err(),
            FieldsError::NotTyped(200)
        );
        assert_eq!(
            request_bytes(1, &json!([1])).unwrap_err(),
            FieldsError::NotObject
        );
        let e = request_bytes(1, &json!({"x": 1})).unwrap_err();
        assert_eq!(e.to_string(), "no field x: this command's data is empty");
    }

    #[test]
    fn optional_fields_cannot_leave_a_gap() {
        // Command 9's request: codes, then (HART 7) nothing else; command 38 has an
        // optional counter. Command 103: period fields are required.
        assert_eq!(request_bytes(38, &json!({})).unwrap(), Vec::<u8>::new());
        assert_eq!(
            request_bytes(38, &json!({"config_change_counter": 513})).unwrap(),
            [2, 1]
        );
        let id = json!({
            "expansion_code": 254, "expanded_device_type": 0x26AB,
            "min_request_preambles": 5, "universal_revision": 7, "device_revision": 1,
            "software_revision": 1, "hardware_revision": 1, "physical_signaling": 0,
            "flags": 0, "device_id": "ABCDEF", "min_response_preambles": 5,
            "manufacturer_id": 0x26
        });
        let e = response_bytes(0, &id).unwrap_err();
        assert!(
            matches!(
                e,
                FieldsError::Build(BuildError::Gap {
                    missing: "max_device_variables",
                    given: "manufacturer_id"
                })
            ),
            "{e}"
        );
    }

    #[test]
    fn lists_of_scalars_and_of_objects() {
        assert_eq!(
            hexs(&request_bytes(9, &json!({"slots": [0, 1, 246]})).unwrap()),
            "0001F6"
        );
        let e = request_bytes(9, &json!({"slots": [0, 1, 2, 3, 4, 5, 6, 7, 8]})).unwrap_err();
        assert!(e.to_string().contains("too many"), "{e}");
    }

    #[test]
    fn a_decoded_reply_goes_back_byte_for_byte() {
        // Command 3 reply with NaN in an unused slot and a unit shown in words.
        let data = [
            0x40, 0x9F, 0xD7, 0x0A, // 4.995 mA
            0x0C, 0x41, 0x20, 0x00, 0x00, // kPa 10.0
            0x20, 0x7F, 0xA0, 0x00, 0x00, // °C NaN
        ];
        let decoded = crate::decode_response(3, &data).unwrap().unwrap();
        let mut v = JsonVisitor::with_words();
        decoded.describe(&mut v);
        let j = v.finish();
        assert_eq!(response_bytes(3, &j).unwrap(), data, "{j}");
    }
}
