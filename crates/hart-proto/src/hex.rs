//! Hex text of bytes, the one writer every view uses (the `--json` view, the annotated
//! listing, the command line, the Python package). Needs the `std` feature.

use std::format;
use std::string::String;
use std::vec::Vec;

/// Upper-case hex without separators: `[0x0A, 0xFF]` gives `"0AFF"`.
pub fn compact(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02X}")).collect()
}

/// Upper-case hex with a space between bytes: `[0x0A, 0xFF]` gives `"0A FF"`.
pub fn spaced(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_forms() {
        assert_eq!(compact(&[0x0A, 0xFF, 0]), "0AFF00");
        assert_eq!(spaced(&[0x0A, 0xFF, 0]), "0A FF 00");
        assert_eq!(compact(&[]), "");
        assert_eq!(spaced(&[]), "");
    }
}
