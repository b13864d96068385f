//! HART code tables as data.
//!
//! Every table is defined exactly once, as a `static` slice of plain entries; the
//! encoders, the decoders, the annotated frame view, JSON output and the docs all read
//! the same slices. Each entry keeps the numeric code so unknown codes still round-trip
//! unchanged: lookups return `Option` and never fail.
//!
//! Sources are recorded next to each table (see `docs/protocol-decisions.md` for the
//! choices made where public sources disagree).

mod bits;
mod codes;
mod response;
mod units;

pub use bits::*;
pub use codes::*;
pub use response::*;
pub use units::*;

/// One entry of an enumerated code table (HART "Common Table").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Code {
    /// The code as sent on the wire.
    pub code: u8,
    /// Human-readable meaning.
    pub name: &'static str,
}

/// A range of codes that share one meaning (e.g. "manufacturer specific").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodeRange {
    /// First code of the range (inclusive).
    pub first: u8,
    /// Last code of the range (inclusive).
    pub last: u8,
    /// Meaning shared by every code in the range.
    pub name: &'static str,
}

/// An enumerated code table such as transfer function (Common Table 3).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CodeTable {
    /// Short identifier, e.g. `"CT3"`.
    pub id: &'static str,
    /// Title, e.g. `"Transfer function"`.
    pub title: &'static str,
    /// Individually defined codes, sorted by code.
    pub entries: &'static [Code],
    /// Ranges with a shared meaning, consulted when no entry matches.
    pub ranges: &'static [CodeRange],
}

impl CodeTable {
    /// The meaning of `code`, if the table defines it.
    pub fn name(&self, code: u8) -> Option<&'static str> {
        self.entries
            .iter()
            .find(|e| e.code == code)
            .map(|e| e.name)
            .or_else(|| {
                self.ranges
                    .iter()
                    .find(|r| r.first <= code && code <= r.last)
                    .map(|r| r.name)
            })
    }
}

/// One bit of a bit-field table such as the field device status byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Bit {
    /// The bit's mask within the byte.
    pub mask: u8,
    /// Short machine-friendly name (`snake_case`), used as a JSON key.
    pub key: &'static str,
    /// Human-readable meaning.
    pub name: &'static str,
}

/// A bit-field table (one byte).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BitTable {
    /// Short identifier, e.g. `"CT17"` or `"field-device-status"`.
    pub id: &'static str,
    /// Title.
    pub title: &'static str,
    /// Defined bits, most significant first.
    pub bits: &'static [Bit],
}

impl BitTable {
    /// The defined bits that are set in `value`.
    pub fn set_bits(&self, value: u8) -> impl Iterator<Item = &'static Bit> {
        self.bits.iter().filter(move |b| value & b.mask != 0)
    }

    /// Bits set in `value` that this table does not define.
    pub fn undefined_bits(&self, value: u8) -> u8 {
        let defined = self.bits.iter().fold(0u8, |acc, b| acc | b.mask);
        value & !defined
    }
}

/// An engineering unit (Common Table 2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unit {
    /// Unit code as sent on the wire.
    pub code: u8,
    /// Full name, e.g. `"pounds per square inch"`.
    pub name: &'static str,
    /// Symbol, e.g. `"psi"`.
    pub symbol: &'static str,
}

/// Looks up an engineering unit code.
pub fn unit(code: u8) -> Option<&'static Unit> {
    UNITS.iter().find(|u| u.code == code)
}
