//! The annotated, field-by-field view of a frame (`hartkit frame decode`), in the
//! spirit of a protocol analyser: offset, raw bytes, field, meaning.

use std::fmt::Write as _;
use std::format;
use std::string::{String, ToString};
use std::vec;
use std::vec::Vec;

use crate::command;
use crate::frame::{Address, Frame};
use crate::tables::{
    self, response_class, response_code_name, ResponseClass, COMMUNICATION_ERROR,
    FIELD_DEVICE_STATUS, LIMIT_STATUS, PROCESS_DATA_STATUS,
};
use crate::types::HartTime;
use crate::wire::{Field, Meaning, Value, Visitor};

use crate::hex;

struct Lines<'a> {
    out: String,
    pdu: &'a [u8],
    /// Offset of the PDU within the input (number of preambles).
    base: usize,
}

impl Lines<'_> {
    fn row(&mut self, offset: usize, len: usize, name: &str, meaning: &str) {
        let start = offset.min(self.pdu.len());
        let end = (offset + len).min(self.pdu.len());
        let mut bytes = hex::spaced(&self.pdu[start..end]);
        if bytes.len() > 23 {
            bytes.truncate(20);
            bytes.push_str("...");
        }
        let _ = writeln!(
            self.out,
            "{:>4}  {:<23}  {:<26} {}",
            self.base + offset,
            bytes,
            name,
            meaning
        );
    }
}

/// Explains a bit-field value: the names of the set bits, or "none".
pub fn bits(table: &tables::BitTable, value: u8) -> String {
    let mut names: Vec<&str> = table.set_bits(value).map(|b| b.name).collect();
    let undefined = table.undefined_bits(value);
    let extra;
    if undefined != 0 {
        extra = format!("undefined bits 0x{undefined:02X}");
        names.push(&extra);
    }
    if names.is_empty() {
        format!("0x{value:02X} (none set)")
    } else {
        format!("0x{value:02X} {}", names.join(", "))
    }
}

fn fmt_float(x: f32) -> String {
    if x.to_bits() == crate::types::HART_NAN_BITS {
        "NaN (0x7FA00000, not available)".into()
    } else {
        format!("{x}")
    }
}

/// Explains one decoded field.
pub fn meaning(f: &Field<'_>) -> String {
    match (f.value, f.meaning) {
        (Value::Uint(u), Meaning::Unit) => {
            let code = u as u8;
            match tables::unit(code) {
                Some(unit) if unit.symbol == unit.name => format!("{u} ({})", unit.name),
                Some(unit) => format!("{u} ({}, {})", unit.symbol, unit.name),
                None if tables::is_manufacturer_specific_unit(code) => {
                    format!("{u} (manufacturer specific)")
                }
                None => format!("{u} (unknown unit)"),
            }
        }
        (Value::Uint(u), Meaning::Code(t)) => match t.name(u as u8) {
            Some(n) => format!("{u} ({n})"),
            None => format!("{u} (not in {} {})", t.id, t.title),
        },
        (Value::Uint(u), Meaning::Bits(t)) => bits(t, u as u8),
        (Value::Uint(u), Meaning::VariableStatus) => {
            let s = u as u8;
            let pd = PROCESS_DATA_STATUS.name(s >> 6).unwrap_or("?");
            let lim = LIMIT_STATUS.name((s >> 4) & 3).unwrap_or("?");
            let more = if s & 0x08 != 0 {
                ", more status available"
            } else {
                ""
            };
            format!("0x{s:02X} {pd}, {lim}{more}")
        }
        (Value::Uint(u), Meaning::Time) => format!("{} ({u} × 1/32 ms)", HartTime(u)),
        (Value::Uint(u), Meaning::Command) => match command::info(u as u16) {
            Some(i) => format!("{u} ({})", i.title),
            None => format!("{u}"),
        },
        (Value::Float(x), Meaning::Quantity(unit)) => format!("{} {unit}", fmt_float(x)),
        (Value::Float(x), _) => fmt_float(x),
        (Value::Str(s), _) => format!("\"{s}\""),
        (Value::Hex(b), _) => hex::spaced(b),
        (Value::Date(d), _) if d.is_valid() => d.to_string(),
        (Value::Date(d), _) => format!("{d} (not a valid date)"),
        (Value::Bool(b), _) => b.to_string(),
        (Value::Uint(u), _) => format!("{u}"),
    }
}

struct DataRows<'a, 'b> {
    lines: &'b mut Lines<'a>,
    data_offset: usize,
    prefix: Vec<String>,
}

impl Visitor for DataRows<'_, '_> {
    fn field(&mut self, f: Field<'_>) {
        let name = if f.name == "item" {
            self.prefix.join("")
        } else {
            format!("{}{}", self.prefix.join(""), f.name)
        };
        let m = meaning(&f);
        self.lines
            .row(self.data_offset + f.offset, f.len, &name, &m);
    }
    fn begin_list(&mut self, name: &'static str) {
        self.prefix.push(name.to_string());
    }
    fn begin_item(&mut self, index: usize) {
        self.prefix.push(format!("[{index}]."));
    }
    fn end_item(&mut self) {
        self.prefix.pop();
    }
    fn end_list(&mut self) {
        self.prefix.pop();
    }
}

/// Renders `frame` (parsed from `input`) as an annotated listing.
pub fn frame(f: &Frame<'_>) -> String {
    let mut l = Lines {
        out: String::new(),
        pdu: f.pdu,
        base: f.preambles,
    };
    let ft = f.frame_type();
    let title = command::info(f.command)
        .map(|i| i.title)
        .unwrap_or("unknown command");
    let _ = writeln!(
        l.out,
        "HART {} frame: command {} ({}), {}, {} preamble(s), {}-byte PDU{}",
        ft.name(),
        f.command,
        title,
        f.address,
        f.preambles,
        f.pdu.len(),
        if f.trailing.is_empty() {
            String::new()
        } else {
            format!(", {} trailing byte(s)", f.trailing.len())
        }
    );
    let _ = writeln!(
        l.out,
        "{:>4}  {:<23}  {:<26} meaning",
        "off", "bytes", "field"
    );
    if f.preambles > 0 {
        let _ = writeln!(
            l.out,
            "{:>4}  {:<23}  {:<26} {} × 0xFF",
            0,
            if f.preambles <= 7 {
                hex::spaced(&vec![0xFF; f.preambles])
            } else {
                "FF FF FF ...".into()
            },
            "preamble",
            f.preambles
        );
    }
    let d = f.delimiter;
    let phys = match d.physical_layer {
        0 => "asynchronous physical layer (FSK/RS-485)",
        1 => "synchronous physical layer (PSK)",
        _ => "reserved physical layer bits",
    };
    l.row(
        0,
        1,
        "delimiter",
        &format!(
            "{}, {} address, {} expansion byte(s), {phys}",
            ft.name(),
            if d.long_address { "long" } else { "short" },
            d.expansion_len
        ),
    );
    let addr = match f.address {
        Address::Short(_) => f.address.to_string(),
        Address::Long(a) => format!(
            "{}; device type field 0x{:04X} (HART 5/6: manufacturer 0x{:02X}, type 0x{:02X}), device ID {:06X}",
            f.address,
            a.id.expanded_device_type,
            a.id.manufacturer_id(),
            a.id.device_type(),
            a.id.device_id
        ),
    };
    l.row(1, f.address.len(), "address", &addr);
    let mut p = 1 + f.address.len();
    if !f.expansion.is_empty() {
        l.row(
            p,
            f.expansion.len(),
            "expansion",
            "expansion bytes (no use defined)",
        );
        p += f.expansion.len();
    }
    let cmd_text = if f.command_byte == crate::frame::EXTENDED_COMMAND {
        "31 (extended command follows)".to_string()
    } else {
        format!("{} ({title})", f.command)
    };
    l.row(p, 1, "command", &cmd_text);
    p += 1;
    let mut parts = vec![];
    if f.response_code.is_some() {
        parts.push("2 status".to_string());
    }
    if f.extended {
        parts.push("2 command".to_string());
    }
    parts.push(format!("{} data", f.data.len()));
    l.row(
        p,
        1,
        "byte count",
        &format!("{} ({})", f.byte_count, parts.join(" + ")),
    );
    p += 1;
    if let (Some(rc), Some(ds)) = (f.response_code, f.device_status) {
        let rc_text = if f.is_communication_error() {
            format!(
                "communication error: {}",
                bits(&COMMUNICATION_ERROR, rc & 0x7F)
            )
        } else {
            let class = match response_class(rc) {
                ResponseClass::Success => "success",
                ResponseClass::Error => "error",
                ResponseClass::Warning => "warning",
            };
            match response_code_name(f.command, rc) {
                Some(name) if rc != 0 => format!("{rc} {class}: {name}"),
                Some(_) => "0 success".to_string(),
                None => format!("{rc} {class}: code not defined for this command"),
            }
        };
        l.row(p, 1, "response code", &rc_text);
        l.row(p + 1, 1, "device status", &bits(&FIELD_DEVICE_STATUS, ds));
        p += 2;
    }
    if f.extended {
        l.row(
            p,
            2,
            "extended command",
            &format!("{} ({title})", f.command),
        );
        p += 2;
    }
    match crate::decode::decode_body(f) {
        Some(Ok(decoded)) => {
            let mut rows = DataRows {
                lines: &mut l,
                data_offset: p,
                prefix: vec![],
            };
            decoded.describe(&mut rows);
            let used = match decoded {
                crate::decode::Decoded::Request(r) => r.encoded_len(),
                crate::decode::Decoded::Response(r) => r.encoded_len(),
            };
            if used < f.data.len() {
                l.row(
                    p + used,
                    f.data.len() - used,
                    "surplus data",
                    "not used by this command's layout (ignored)",
                );
            }
        }
        Some(Err(e)) => {
            if !f.data.is_empty() {
                l.row(p, f.data.len(), "data", &format!("cannot decode: {e}"));
            } else {
                l.row(p, 0, "data", &format!("none ({e})"));
            }
        }
        None if !f.data.is_empty() => l.row(p, f.data.len(), "data", "not decoded"),
        None => {}
    }
    let ck = if f.checksum_ok() {
        "ok".to_string()
    } else {
        format!("BAD, expected 0x{:02X}", f.expected_check_byte)
    };
    l.row(f.pdu.len() - 1, 1, "check byte", &ck);
    if !f.trailing.is_empty() {
        let _ = writeln!(
            l.out,
            "{:>4}  {:<23}  {:<26} {} byte(s) after the check byte, not part of this frame",
            l.base + f.pdu.len(),
            hex::spaced(&f.trailing[..f.trailing.len().min(7)]),
            "trailing",
            f.trailing.len()
        );
    }
    l.out
}
