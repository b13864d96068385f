//! Typed requests and replies from named fields given as JSON (hart-proto's
//! [`hart_proto::json::fields`]), and command data as the command line takes it.

pub use hart_proto::json::fields::*;

use serde_json::Value as Json;

/// Command data as the command line takes it: empty, hex (`"00 F6"`), or the fields
/// of `command`'s request (`reply`: of its reply) as a JSON object, told apart by the
/// opening `{`. The error says which of the two it was read as.
pub fn data_arg(command: u16, text: &str, reply: bool) -> Result<Vec<u8>, String> {
    let t = text.trim();
    if t.is_empty() {
        return Ok(vec![]);
    }
    if !t.starts_with('{') {
        return crate::hex::parse(&[t]);
    }
    let fields: Json = serde_json::from_str(t).map_err(|e| format!("not JSON: {e}"))?;
    let built = if reply {
        response_bytes(command, &fields)
    } else {
        request_bytes(command, &fields)
    };
    built.map_err(|e| format!("command {command}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn data_as_the_command_line_takes_it() {
        assert_eq!(data_arg(44, "", false).unwrap(), Vec::<u8>::new());
        assert_eq!(data_arg(44, " 0c ", false).unwrap(), [12]);
        assert_eq!(data_arg(44, r#"{"pv_units": "kPa"}"#, false).unwrap(), [12]);
        assert_eq!(
            data_arg(1, r#"{"pv_units": "kPa", "pv": 1.5}"#, true).unwrap(),
            [12, 0x3F, 0xC0, 0, 0]
        );
        assert!(data_arg(44, "{pv_units", false)
            .unwrap_err()
            .starts_with("not JSON"));
        assert!(data_arg(44, "{}", false)
            .unwrap_err()
            .starts_with("command 44: field pv_units is missing"));
    }
}
