//! Hex input (the command line's syntax) and output (hart-proto's writer).

/// Parses hex bytes from one or more arguments. Spaces, colons, dashes, commas and
/// `0x` prefixes are allowed between bytes; a byte's two digits must be adjacent.
pub fn parse(args: &[impl AsRef<str>]) -> Result<Vec<u8>, String> {
    let text = args
        .iter()
        .map(|a| a.as_ref())
        .collect::<Vec<_>>()
        .join(" ");
    let mut out = Vec::new();
    let mut digits = String::new();
    let flush =
        |digits: &mut String, out: &mut Vec<u8>, at: usize| -> Result<(), String> {
            let d = digits
                .strip_prefix("0x")
                .or_else(|| digits.strip_prefix("0X"))
                .unwrap_or(digits);
            if d.len() % 2 != 0 {
                return Err(format!(
                    "hex input at character {at}: odd number of hex digits in \"{digits}\""
                ));
            }
            for pair in d.as_bytes().chunks(2) {
                let s = std::str::from_utf8(pair).unwrap_or("");
                out.push(u8::from_str_radix(s, 16).map_err(|_| {
                    format!("hex input at character {at}: \"{s}\" is not a hex byte")
                })?);
            }
            digits.clear();
            Ok(())
        };
    let mut start = 0;
    for (i, c) in text.char_indices() {
        if c.is_ascii_hexdigit() || ((c == 'x' || c == 'X') && digits == "0") {
            if digits.is_empty() {
                start = i;
            }
            digits.push(c);
        } else if c.is_whitespace() || matches!(c, ':' | '-' | ',') {
            flush(&mut digits, &mut out, start)?;
        } else {
            return Err(format!(
                "hex input at character {i}: '{c}' is not a hex digit or separator"
            ));
        }
    }
    flush(&mut digits, &mut out, start)?;
    if out.is_empty() {
        return Err("no hex bytes given".into());
    }
    Ok(out)
}

pub use hart_proto::hex::{compact, spaced};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separators() {
        assert_eq!(
            parse(&["FF:ff 02", "80-00,00 0x82"]).unwrap(),
            vec![0xFF, 0xFF, 2, 0x80, 0, 0, 0x82]
        );
        assert_eq!(parse(&["0280000082"]).unwrap(), vec![2, 0x80, 0, 0, 0x82]);
        assert!(parse(&["028"]).unwrap_err().contains("odd"));
        assert!(parse(&["02 zz"]).unwrap_err().contains("'z'"));
        assert!(parse(&[""]).is_err());
    }
}
