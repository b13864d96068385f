//! The `--json` view of a frame. Field names are a contract other tools read; see
//! `docs/frame-json.md`. Needs the `json` feature.

pub mod fields;

use crate::frame::{Address, Frame};
use crate::hex;
use crate::wire::{Field, Meaning, Value, Visitor};
use serde_json::{json, Map, Value as Json};

use alloc::format;
use alloc::string::{String, ToString};
use alloc::vec::Vec;

/// A float as JSON: the shortest decimal that reads back as the same `f32`
/// (so 23.4 stays 23.4), `null` when not finite (e.g. the HART NaN 0x7FA00000).
pub fn float(x: f32) -> Json {
    if !x.is_finite() {
        return Json::Null;
    }
    let shortest: f64 = format!("{x}").parse().unwrap_or(f64::from(x));
    serde_json::Number::from_f64(shortest).map_or(Json::Null, Json::Number)
}

/// The names of the bits set in `value` of a bit table, as a JSON list: the words that
/// go under `<name>_set` beside a bit field's integer (docs/frame-json.md).
pub fn bits_set(table: &crate::tables::BitTable, value: u8) -> Json {
    Json::Array(
        table
            .set_bits(value)
            .map(|b| Json::String(b.name.into()))
            .collect(),
    )
}

/// `device_status_set`: the names of the field device status bits set in a reply's
/// status byte, the one name every view (command line, Python, web) gives them beside
/// the integer `device_status`.
pub fn device_status_set(status: u8) -> Json {
    bits_set(&crate::tables::FIELD_DEVICE_STATUS, status)
}

/// The address object.
pub fn address(a: &Address) -> Json {
    match a {
        Address::Short(s) => json!({
            "type": "short",
            "master": s.master.name(),
            "burst": s.burst,
            "polling_address": s.polling_address,
        }),
        Address::Long(l) => json!({
            "type": "long",
            "master": l.master.name(),
            "burst": l.burst,
            "unique_id": l.id.to_string(),
            "expanded_device_type": l.id.expanded_device_type,
            "device_id": format!("{:06X}", l.id.device_id),
            "broadcast": l.id.is_broadcast(),
        }),
    }
}

/// The whole frame as one JSON object.
pub fn frame(f: &Frame<'_>) -> Json {
    let mut m = Map::new();
    m.insert("preambles".into(), json!(f.preambles));
    m.insert("delimiter".into(), json!(f.delimiter_byte));
    m.insert("frame_type".into(), json!(f.frame_type().name()));
    m.insert("address".into(), address(&f.address));
    m.insert("expansion".into(), json!(hex::compact(f.expansion)));
    m.insert("command".into(), json!(f.command));
    if f.command_byte == crate::frame::EXTENDED_COMMAND {
        m.insert("command_byte".into(), json!(f.command_byte));
    }
    m.insert("byte_count".into(), json!(f.byte_count));
    if let (Some(rc), Some(ds)) = (f.response_code, f.device_status) {
        m.insert("response_code".into(), json!(rc));
        m.insert("device_status".into(), json!(ds));
        m.insert(
            "communication_error".into(),
            json!(f.is_communication_error()),
        );
    }
    m.insert("data".into(), json!(hex::compact(f.data)));
    m.insert("checksum_ok".into(), json!(f.checksum_ok()));
    m.insert("trailing".into(), json!(hex::compact(f.trailing)));
    match crate::decode::decode_body(f) {
        Some(Ok(d)) => {
            let mut v = JsonVisitor::default();
            d.describe(&mut v);
            m.insert("decoded".into(), v.finish());
        }
        Some(Err(e)) => {
            m.insert("decode_error".into(), json!(e.to_string()));
        }
        None => {}
    }
    Json::Object(m)
}

/// Builds a JSON object from a [`Visitor`] walk.
#[derive(Default)]
pub struct JsonVisitor {
    /// Open containers: the root object, lists, list items.
    stack: Vec<Open>,
    root: Map<String, Json>,
    /// Add the meaning of codes next to them (see [`JsonVisitor::with_words`]).
    words: bool,
}

enum Open {
    List(&'static str, Vec<Json>),
    Item(Map<String, Json>),
}

/// A field value as JSON.
pub fn value(v: &Value<'_>) -> Json {
    match v {
        Value::Uint(u) => json!(u),
        Value::Float(x) => float(*x),
        Value::Str(s) => json!(s),
        Value::Hex(b) => json!(hex::compact(b)),
        Value::Date(d) => json!(d.to_string()),
        Value::Bool(b) => json!(b),
    }
}

impl JsonVisitor {
    /// A visitor that also puts each code's meaning beside it: `<name>_symbol` and
    /// `<name>_name` for a unit code (`"kPa"`, `"kilopascals"`), `<name>_name` for a
    /// code of another table, `<name>_set` (the names of the bits set) for a bit field.
    /// The CLI's `--json` view does not use it (its fields are a contract); the Python
    /// package does.
    pub fn with_words() -> Self {
        JsonVisitor {
            words: true,
            ..Self::default()
        }
    }

    /// The finished object.
    pub fn finish(self) -> Json {
        Json::Object(self.root)
    }

    fn current(&mut self) -> &mut Map<String, Json> {
        match self.stack.last_mut() {
            Some(Open::Item(m)) => m,
            _ => &mut self.root,
        }
    }
}

impl Visitor for JsonVisitor {
    fn field(&mut self, f: Field<'_>) {
        let v = value(&f.value);
        let words = self.words;
        let m = self.current();
        m.insert(f.name.to_string(), v);
        if !words {
            return;
        }
        let Value::Uint(code) = f.value else {
            return;
        };
        let code = code as u8;
        match f.meaning {
            Meaning::Unit => {
                if let Some(u) = crate::tables::unit(code) {
                    m.insert(format!("{}_symbol", f.name), json!(u.symbol));
                    m.insert(format!("{}_name", f.name), json!(u.name));
                }
            }
            Meaning::Code(t) => {
                if let Some(n) = t.name(code) {
                    m.insert(format!("{}_name", f.name), json!(n));
                }
            }
            Meaning::Bits(t) => {
                let set: Vec<&str> = t.set_bits(code).map(|b| b.name).collect();
                m.insert(format!("{}_set", f.name), json!(set));
            }
            _ => {}
        }
    }
    fn begin_list(&mut self, name: &'static str) {
        self.stack.push(Open::List(name, Vec::new()));
    }
    fn begin_item(&mut self, _index: usize) {
        self.stack.push(Open::Item(Map::new()));
    }
    fn end_item(&mut self) {
        if let Some(Open::Item(mut m)) = self.stack.pop() {
            // A list of scalars (e.g. device variable codes) describes each element as one
            // field named "item": store the bare value.
            let item = if m.len() == 1 && m.contains_key("item") {
                m.remove("item").unwrap_or(Json::Null)
            } else {
                Json::Object(m)
            };
            if let Some(Open::List(_, items)) = self.stack.last_mut() {
                items.push(item);
            }
        }
    }
    fn end_list(&mut self) {
        if let Some(Open::List(name, items)) = self.stack.pop() {
            self.current().insert(name.to_string(), Json::Array(items));
        }
    }
}
