//! HART data types: packed ASCII, Latin-1 strings, dates, times, 24-bit integers, the
//! HART NaN, and code newtypes that keep unknown codes intact.
//!
//! All types store the raw wire bytes (or the raw number), so decoding and re-encoding
//! reproduces the input byte for byte; the human reading is computed on demand.

use core::fmt;

use crate::tables;
use crate::wire::{
    required, BuildError, DecodeError, EncodeError, Field, FromValue, Meaning, Reader, Source,
    Value, Visitor, Wire, Writer,
};

/// The bit pattern HART uses for "not a number" (0x7FA00000), sent for values a device
/// does not have (e.g. unused dynamic variables).
pub const HART_NAN_BITS: u32 = 0x7FA0_0000;

/// The HART NaN as an `f32`.
pub fn hart_nan() -> f32 {
    f32::from_bits(HART_NAN_BITS)
}

/// Packed ASCII: 4 characters of the 6-bit set 0x20..=0x5F in every 3 bytes.
pub mod packed_ascii {
    /// Decodes the 6-bit value `v` (0..=63) to its ASCII character.
    pub fn decode_char(v: u8) -> u8 {
        let v = v & 0x3F;
        v | (((v & 0x20) ^ 0x20) << 1)
    }

    /// Encodes an ASCII character to its 6-bit value; lower case is upper-cased.
    /// Returns `None` for characters outside the packed set.
    pub fn encode_char(c: char) -> Option<u8> {
        let c = c.to_ascii_uppercase();
        if (' '..='_').contains(&c) {
            Some(c as u8 & 0x3F)
        } else {
            None
        }
    }

    /// Unpacks `packed` (a multiple of 3 bytes; a shorter tail is ignored) into `out`,
    /// returning the number of characters written (4 per 3 bytes, bounded by `out`).
    pub fn unpack(packed: &[u8], out: &mut [u8]) -> usize {
        let mut n = 0;
        for chunk in packed.chunks_exact(3) {
            let bits = u32::from(chunk[0]) << 16 | u32::from(chunk[1]) << 8 | u32::from(chunk[2]);
            for shift in [18u32, 12, 6, 0] {
                if n < out.len() {
                    out[n] = decode_char((bits >> shift) as u8);
                    n += 1;
                }
            }
        }
        n
    }

    /// Packs `text` into `out` (whose length must be a multiple of 3), padding with
    /// spaces. Fails on a character outside the packed set or text that is too long.
    pub fn pack(text: &str, out: &mut [u8]) -> Result<(), &'static str> {
        let capacity = out.len() / 3 * 4;
        if text.chars().count() > capacity {
            return Err("text too long for this packed-ASCII field");
        }
        let mut chars = text.chars();
        for chunk in out.chunks_exact_mut(3) {
            let mut bits = 0u32;
            for _ in 0..4 {
                let v = match chars.next() {
                    Some(c) => encode_char(c).ok_or(
                        "character not in the packed-ASCII set (space to '_', letters upper-cased)",
                    )?,
                    None => 0x20,
                };
                bits = bits << 6 | u32::from(v);
            }
            chunk.copy_from_slice(&bits.to_be_bytes()[1..]);
        }
        Ok(())
    }
}

fn trim_padding(s: &[u8]) -> &[u8] {
    let end = s
        .iter()
        .rposition(|&b| b != b' ' && b != 0)
        .map_or(0, |i| i + 1);
    &s[..end]
}

/// Implements [`Wire`] for a fixed-size text type over `[u8; N]` with `with_str`.
macro_rules! text_wire {
    ($name:ident) => {
        impl<const N: usize> Wire for $name<N> {
            const MIN_LEN: usize = N;
            const MAX_LEN: usize = N;
            fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
                Ok($name(r.array()?))
            }
            fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
                w.put(&self.0)
            }
            fn encoded_len(&self) -> usize {
                N
            }
            fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
                self.with_str(|s| {
                    v.field(Field {
                        name,
                        offset,
                        len: N,
                        value: Value::Str(s),
                        meaning: Meaning::Plain,
                    })
                });
            }
            fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
                match required(src, name)? {
                    Value::Str(text) => $name::new(text).map_err(|e| BuildError::Invalid {
                        field: name,
                        reason: match e {
                            EncodeError::Invalid(why) => why,
                            EncodeError::BufferTooSmall { .. } => "text too long",
                        },
                    }),
                    _ => Err(BuildError::WrongKind {
                        field: name,
                        expected: "text",
                    }),
                }
            }
        }
    };
}

/// A fixed-size packed-ASCII string of `N` bytes (`N / 3 * 4` characters): tag (6 bytes),
/// descriptor (12), message (24).
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct PackedString<const N: usize>(pub [u8; N]);

impl<const N: usize> Default for PackedString<N> {
    fn default() -> Self {
        let mut s = PackedString([0; N]);
        let _ = packed_ascii::pack("", &mut s.0);
        s
    }
}

impl<const N: usize> PackedString<N> {
    /// Packs `text`, upper-casing letters and padding with spaces.
    pub fn new(text: &str) -> Result<Self, EncodeError> {
        let mut s = PackedString([0; N]);
        packed_ascii::pack(text, &mut s.0).map_err(EncodeError::Invalid)?;
        Ok(s)
    }

    /// Writes the unpacked characters (padding included) to `out`; returns the count.
    pub fn unpack_into(&self, out: &mut [u8]) -> usize {
        packed_ascii::unpack(&self.0, out)
    }

    /// Calls `f` with the text, trailing spaces removed.
    pub fn with_str<R>(&self, f: impl FnOnce(&str) -> R) -> R {
        let mut buf = [0u8; 48];
        let n = self.unpack_into(&mut buf);
        // Packed characters are always ASCII.
        f(core::str::from_utf8(trim_padding(&buf[..n])).unwrap_or(""))
    }
}

impl<const N: usize> fmt::Display for PackedString<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.with_str(|s| f.write_str(s))
    }
}

impl<const N: usize> fmt::Debug for PackedString<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", DisplayStr(self))
    }
}

struct DisplayStr<'a, T: fmt::Display>(&'a T);
impl<T: fmt::Display> fmt::Debug for DisplayStr<'_, T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "\"{}\"", self.0)
    }
}

text_wire!(PackedString);

/// A fixed-size ISO 8859-1 (Latin-1) string of `N` bytes, e.g. the 32-byte long tag.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Latin1String<const N: usize>(pub [u8; N]);

impl<const N: usize> Default for Latin1String<N> {
    fn default() -> Self {
        Latin1String([0; N])
    }
}

impl<const N: usize> Latin1String<N> {
    /// Encodes `text` (characters up to U+00FF), padding with NUL.
    pub fn new(text: &str) -> Result<Self, EncodeError> {
        let mut s = Latin1String([0; N]);
        for (n, c) in text.chars().enumerate() {
            let b = u8::try_from(u32::from(c))
                .map_err(|_| EncodeError::Invalid("character outside ISO 8859-1 (Latin-1)"))?;
            *s.0.get_mut(n)
                .ok_or(EncodeError::Invalid("text too long for this Latin-1 field"))? = b;
        }
        Ok(s)
    }

    /// Calls `f` with the text as UTF-8, trailing spaces and NULs removed.
    pub fn with_str<R>(&self, f: impl FnOnce(&str) -> R) -> R {
        let mut buf = [0u8; 128];
        let mut n = 0;
        for &b in trim_padding(&self.0) {
            let c = char::from(b);
            if n + c.len_utf8() > buf.len() {
                break;
            }
            n += c.encode_utf8(&mut buf[n..]).len();
        }
        f(core::str::from_utf8(&buf[..n]).unwrap_or(""))
    }
}

impl<const N: usize> fmt::Display for Latin1String<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.with_str(|s| f.write_str(s))
    }
}

impl<const N: usize> fmt::Debug for Latin1String<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", DisplayStr(self))
    }
}

text_wire!(Latin1String);

/// A HART date: day, month, year − 1900 (3 bytes). Values are kept as received, so an
/// invalid date (e.g. day 0) still round-trips; [`Date::is_valid`] checks it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct Date {
    /// Day of month, 1..=31.
    pub day: u8,
    /// Month, 1..=12.
    pub month: u8,
    /// Years since 1900 (e.g. 125 = 2025).
    pub year_since_1900: u8,
}

impl Date {
    /// Builds a date from a calendar year (1900..=2155), month and day.
    pub fn new(year: u16, month: u8, day: u8) -> Result<Self, EncodeError> {
        let y = year
            .checked_sub(1900)
            .and_then(|y| u8::try_from(y).ok())
            .ok_or(EncodeError::Invalid("year must be 1900..=2155"))?;
        let d = Date {
            day,
            month,
            year_since_1900: y,
        };
        if d.is_valid() {
            Ok(d)
        } else {
            Err(EncodeError::Invalid("not a calendar date"))
        }
    }

    /// Reads `YYYY-MM-DD` as [`Date`]'s `Display` writes it. Day and month are kept as
    /// written (0 included, as devices that never had a date set report), so every
    /// displayed date reads back; the year must be 1900..=2155.
    pub fn parse(text: &str) -> Option<Self> {
        let mut parts = text.trim().split('-');
        let (y, m, d) = (parts.next()?, parts.next()?, parts.next()?);
        if parts.next().is_some() || y.len() != 4 {
            return None;
        }
        let year: u16 = y.parse().ok()?;
        Some(Date {
            day: d.parse().ok()?,
            month: m.parse().ok()?,
            year_since_1900: u8::try_from(year.checked_sub(1900)?).ok()?,
        })
    }

    /// The calendar year.
    pub fn year(&self) -> u16 {
        1900 + u16::from(self.year_since_1900)
    }

    /// True for a real calendar date (leap years included).
    pub fn is_valid(&self) -> bool {
        let y = self.year();
        let leap = (y % 4 == 0 && y % 100 != 0) || y % 400 == 0;
        let days = match self.month {
            1 | 3 | 5 | 7 | 8 | 10 | 12 => 31,
            4 | 6 | 9 | 11 => 30,
            2 if leap => 29,
            2 => 28,
            _ => return false,
        };
        (1..=days).contains(&self.day)
    }
}

impl fmt::Display for Date {
    /// `YYYY-MM-DD`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year(), self.month, self.day)
    }
}

impl Wire for Date {
    const MIN_LEN: usize = 3;
    const MAX_LEN: usize = 3;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let [day, month, year_since_1900] = r.array()?;
        Ok(Date {
            day,
            month,
            year_since_1900,
        })
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&[self.day, self.month, self.year_since_1900])
    }
    fn encoded_len(&self) -> usize {
        3
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: 3,
            value: Value::Date(*self),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        match required(src, name)? {
            Value::Date(d) => Ok(d),
            Value::Str(text) => Date::parse(text).ok_or(BuildError::Invalid {
                field: name,
                reason: "a date is written YYYY-MM-DD, year 1900 to 2155",
            }),
            _ => Err(BuildError::WrongKind {
                field: name,
                expected: "a date (\"YYYY-MM-DD\")",
            }),
        }
    }
}

/// A HART time: unsigned 32-bit count of 1/32 ms, used for time of day (since midnight)
/// and for durations such as burst update periods.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct HartTime(pub u32);

impl HartTime {
    /// Ticks per millisecond.
    pub const TICKS_PER_MS: u32 = 32;

    /// From milliseconds (saturating).
    pub fn from_millis(ms: u32) -> Self {
        HartTime(ms.saturating_mul(Self::TICKS_PER_MS))
    }

    /// The time of day of an instant given in microseconds since any midnight (a Unix
    /// time, a device's clock started at midnight): whole milliseconds since the last
    /// midnight, as command 9's time stamp and command 90's clock carry them.
    pub fn time_of_day(micros: u64) -> Self {
        HartTime(((micros / 1000) % 86_400_000) as u32 * Self::TICKS_PER_MS)
    }

    /// Whole milliseconds.
    pub fn as_millis(&self) -> u32 {
        self.0 / Self::TICKS_PER_MS
    }

    /// Microseconds, rounded down (one tick is 31.25 µs).
    pub fn as_micros(&self) -> u64 {
        u64::from(self.0) * 1000 / u64::from(Self::TICKS_PER_MS)
    }

    /// Seconds as a float.
    pub fn as_secs_f64(&self) -> f64 {
        f64::from(self.0) / 32_000.0
    }
}

impl fmt::Display for HartTime {
    /// `HH:MM:SS.mmm` when below one day, else seconds.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = self.as_millis();
        let frac = (self.0 % 32) * 1000 / 32;
        if ms < 86_400_000 {
            write!(
                f,
                "{:02}:{:02}:{:02}.{:03}",
                ms / 3_600_000,
                ms / 60_000 % 60,
                ms / 1000 % 60,
                ms % 1000
            )?;
            if frac != 0 {
                write!(f, "+{frac}µs")?;
            }
            Ok(())
        } else {
            write!(f, "{} s", self.as_secs_f64())
        }
    }
}

crate::newtype_wire!(HartTime, u32, 4, Value::Uint, Meaning::Time);

/// An unsigned 24-bit integer (e.g. final assembly number, transducer serial number).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct U24(u32);

impl U24 {
    /// Largest value.
    pub const MAX: u32 = 0x00FF_FFFF;

    /// Wraps `v`; fails above 2^24 − 1.
    pub fn new(v: u32) -> Result<Self, EncodeError> {
        if v > Self::MAX {
            Err(EncodeError::Invalid("value does not fit 24 bits"))
        } else {
            Ok(U24(v))
        }
    }

    /// The value.
    pub fn get(&self) -> u32 {
        self.0
    }

    fn from_bytes(b: [u8; 3]) -> Self {
        U24(u32::from_be_bytes([0, b[0], b[1], b[2]]))
    }

    fn to_bytes(self) -> [u8; 3] {
        let b = self.0.to_be_bytes();
        [b[1], b[2], b[3]]
    }
}

impl Wire for U24 {
    const MIN_LEN: usize = 3;
    const MAX_LEN: usize = 3;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(U24::from_bytes(r.array()?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&self.to_bytes())
    }
    fn encoded_len(&self) -> usize {
        3
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: 3,
            value: Value::Uint(self.0),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let n = u32::from_value(required(src, name)?, name)?;
        U24::new(n).map_err(|_| BuildError::Invalid {
            field: name,
            reason: "out of range: the field is three bytes (0 to 16777215)",
        })
    }
}

/// A 24-bit device ID, shown as 6 hex digits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
pub struct DeviceId(pub [u8; 3]);

impl DeviceId {
    /// The ID as a number.
    pub fn get(&self) -> u32 {
        U24::from_bytes(self.0).0
    }

    /// From a number (upper 8 bits must be zero).
    pub fn new(v: u32) -> Result<Self, EncodeError> {
        Ok(DeviceId(U24::new(v)?.to_bytes()))
    }
}

impl fmt::Display for DeviceId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:06X}", self.get())
    }
}

impl Wire for DeviceId {
    const MIN_LEN: usize = 3;
    const MAX_LEN: usize = 3;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(DeviceId(r.array()?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(&self.0)
    }
    fn encoded_len(&self) -> usize {
        3
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: 3,
            value: Value::Hex(&self.0),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let bad = BuildError::Invalid {
            field: name,
            reason: "a device ID is three bytes: six hex digits or a number below 2^24",
        };
        match required(src, name)? {
            Value::Hex(b) => Ok(DeviceId(b.try_into().map_err(|_| bad)?)),
            Value::Str(text) => {
                let mut id = [0u8; 3];
                crate::wire::hex_into(text, &mut id)
                    .filter(|&n| n == 3)
                    .ok_or(bad)?;
                Ok(DeviceId(id))
            }
            v => DeviceId::new(u32::from_value(v, name)?).map_err(|_| bad),
        }
    }
}

/// Raw bytes of a field whose length is "whatever is left" (up to `N`), e.g. the
/// additional status of command 48 or an unknown tail. Shown as hex.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Bytes<const N: usize> {
    buf: [u8; N],
    len: usize,
}

impl<const N: usize> Default for Bytes<N> {
    fn default() -> Self {
        Bytes {
            buf: [0; N],
            len: 0,
        }
    }
}

impl<const N: usize> Bytes<N> {
    /// Copies `b`; fails when longer than `N`.
    pub fn new(b: &[u8]) -> Result<Self, EncodeError> {
        if b.len() > N {
            return Err(EncodeError::Invalid("too many bytes for this field"));
        }
        let mut s = Self::default();
        s.buf[..b.len()].copy_from_slice(b);
        s.len = b.len();
        Ok(s)
    }

    /// The bytes.
    pub fn as_slice(&self) -> &[u8] {
        &self.buf[..self.len]
    }
}

impl<const N: usize> fmt::Debug for Bytes<N> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for b in self.as_slice() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

impl<const N: usize> Wire for Bytes<N> {
    const MIN_LEN: usize = 0;
    const MAX_LEN: usize = N;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let n = r.remaining().min(N);
        let mut s = Self::default();
        s.buf[..n].copy_from_slice(r.take(n)?);
        s.len = n;
        Ok(s)
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.put(self.as_slice())
    }
    fn encoded_len(&self) -> usize {
        self.len
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name,
            offset,
            len: self.len,
            value: Value::Hex(self.as_slice()),
            meaning: Meaning::Plain,
        });
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let too_long = BuildError::Invalid {
            field: name,
            reason: "too many bytes for this field",
        };
        match src.value(name)? {
            None => Ok(Self::default()),
            Some(Value::Hex(b)) => Bytes::new(b).map_err(|_| too_long),
            Some(Value::Str(text)) => {
                let mut s = Self::default();
                s.len = crate::wire::hex_into(text, &mut s.buf).ok_or(BuildError::Invalid {
                    field: name,
                    reason:
                        "raw bytes are written as hex digits, two per byte, and must fit the field",
                })?;
                Ok(s)
            }
            Some(_) => Err(BuildError::WrongKind {
                field: name,
                expected: "hex digits",
            }),
        }
    }
}

/// Defines a one-byte code newtype that keeps any value and explains it with `$meaning`.
macro_rules! code_type {
    ($(#[$m:meta])* $name:ident, $meaning:expr) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, PartialOrd, Ord)]
        pub struct $name(pub u8);

        crate::newtype_wire!($name, u8, 1, |x| Value::Uint(x.into()), $meaning);

        impl From<u8> for $name {
            fn from(v: u8) -> Self {
                $name(v)
            }
        }
    };
}

code_type!(
    /// Engineering unit code (Common Table 2).
    UnitCode,
    Meaning::Unit
);
code_type!(
    /// Device variable code (Common Table 34: 0..=239 device variables, 244 percent of
    /// range, 245 loop current, 246..=249 PV..QV, 250 not used).
    DeviceVariableCode,
    Meaning::Code(&tables::DEVICE_VARIABLE_CODE)
);
code_type!(
    /// Device variable classification (Common Table 21).
    Classification,
    Meaning::Code(&tables::DEVICE_VARIABLE_CLASSIFICATION)
);
code_type!(
    /// Device variable family (Common Table 20).
    VariableFamily,
    Meaning::Code(&tables::DEVICE_VARIABLE_FAMILY)
);
code_type!(
    /// Transfer function (Common Table 3).
    TransferFunction,
    Meaning::Code(&tables::TRANSFER_FUNCTION)
);
code_type!(
    /// Alarm selection (Common Table 6).
    AlarmSelection,
    Meaning::Code(&tables::ALARM_SELECTION)
);
code_type!(
    /// Write protect code (Common Table 7).
    WriteProtect,
    Meaning::Code(&tables::WRITE_PROTECT)
);
code_type!(
    /// Loop current mode (Common Table 16): 0 disabled (multidrop), 1 enabled.
    LoopCurrentMode,
    Meaning::Code(&tables::LOOP_CURRENT_MODE)
);
code_type!(
    /// Device profile (Common Table 57).
    DeviceProfile,
    Meaning::Code(&tables::DEVICE_PROFILE)
);
code_type!(
    /// Burst mode control code.
    BurstModeControl,
    Meaning::Code(&tables::BURST_MODE_CONTROL)
);
code_type!(
    /// Burst trigger mode (Common Table 33).
    TriggerMode,
    Meaning::Code(&tables::BURST_TRIGGER_MODE)
);
code_type!(
    /// Write device variable code (Common Table 19): 0 normal, 1 fixed value.
    WriteVariableCode,
    Meaning::Code(&tables::WRITE_DEVICE_VARIABLE_CODE)
);
code_type!(
    /// Device operating mode (Common Table 14).
    OperatingMode,
    Meaning::Code(&tables::DEVICE_OPERATING_MODE)
);
code_type!(
    /// Flags (Common Table 11), a bit field.
    Flags,
    Meaning::Bits(&tables::FLAGS)
);
code_type!(
    /// Extended field device status (Common Table 17), a bit field.
    ExtendedStatus,
    Meaning::Bits(&tables::EXTENDED_DEVICE_STATUS)
);
code_type!(
    /// Standardized status 0 (Common Table 29), a bit field.
    StandardizedStatus0,
    Meaning::Bits(&tables::STANDARDIZED_STATUS_0)
);
code_type!(
    /// Standardized status 1 (Common Table 30), a bit field.
    StandardizedStatus1,
    Meaning::Bits(&tables::STANDARDIZED_STATUS_1)
);
code_type!(
    /// Standardized status 2 (Common Table 31), a bit field.
    StandardizedStatus2,
    Meaning::Bits(&tables::STANDARDIZED_STATUS_2)
);
code_type!(
    /// Standardized status 3 (Common Table 32), a bit field.
    StandardizedStatus3,
    Meaning::Bits(&tables::STANDARDIZED_STATUS_3)
);
code_type!(
    /// Analog channel saturated (Common Table 27), one bit per extra channel.
    AnalogChannelSaturated,
    Meaning::Bits(&tables::ANALOG_CHANNEL_SATURATED)
);
code_type!(
    /// Analog channel fixed (Common Table 28), one bit per extra channel.
    AnalogChannelFixed,
    Meaning::Bits(&tables::ANALOG_CHANNEL_FIXED)
);
code_type!(
    /// Analog channel flags (Common Table 26).
    AnalogChannelFlags,
    Meaning::Bits(&tables::ANALOG_CHANNEL_FLAGS)
);
code_type!(
    /// Device variable status: process data status (bits 7–6), limit status (5–4),
    /// more status available (3), device-family status (2–0).
    VariableStatus,
    Meaning::VariableStatus
);

impl VariableStatus {
    /// Process data status, bits 7–6: 0 bad, 1 poor accuracy, 2 manual/fixed, 3 good.
    pub fn process_data(&self) -> u8 {
        self.0 >> 6
    }
    /// Limit status, bits 5–4: 0 not limited, 1 low, 2 high, 3 constant.
    pub fn limit(&self) -> u8 {
        (self.0 >> 4) & 3
    }
    /// Bit 3: more device variable status available.
    pub fn more_status(&self) -> bool {
        self.0 & 0x08 != 0
    }
    /// Bits 2–0: device-family specific.
    pub fn family_status(&self) -> u8 {
        self.0 & 7
    }
}

impl UnitCode {
    /// The unit's entry in Common Table 2, if defined.
    pub fn unit(&self) -> Option<&'static tables::Unit> {
        tables::unit(self.0)
    }
}

/// Command 0 byte 7: hardware revision (bits 7–3) and physical signaling code
/// (bits 2–0, Common Table 10). Described as two fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct HardwareRevision(pub u8);

impl HardwareRevision {
    /// Hardware revision, 0..=31.
    pub fn revision(&self) -> u8 {
        self.0 >> 3
    }
    /// Physical signaling code (Common Table 10).
    pub fn physical_signaling(&self) -> u8 {
        self.0 & 7
    }
    /// Combines the two parts.
    pub fn new(revision: u8, physical_signaling: u8) -> Self {
        HardwareRevision((revision << 3) | (physical_signaling & 7))
    }
}

impl Wire for HardwareRevision {
    const MIN_LEN: usize = 1;
    const MAX_LEN: usize = 1;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        Ok(HardwareRevision(r.u8()?))
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        w.u8(self.0)
    }
    fn encoded_len(&self) -> usize {
        1
    }
    fn describe(&self, _name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.field(Field {
            name: "hardware_revision",
            offset,
            len: 1,
            value: Value::Uint(self.revision().into()),
            meaning: Meaning::Plain,
        });
        v.field(Field {
            name: "physical_signaling",
            offset,
            len: 1,
            value: Value::Uint(self.physical_signaling().into()),
            meaning: Meaning::Code(&tables::PHYSICAL_SIGNALING),
        });
    }
    fn build(_name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let rev = u8::from_value(required(src, "hardware_revision")?, "hardware_revision")?;
        let sig = u8::from_value(required(src, "physical_signaling")?, "physical_signaling")?;
        if rev > 31 || sig > 7 {
            return Err(BuildError::Invalid {
                field: if rev > 31 {
                    "hardware_revision"
                } else {
                    "physical_signaling"
                },
                reason: "the hardware revision is 0 to 31 and the signaling code 0 to 7 (one byte, 5 + 3 bits)",
            });
        }
        Ok(HardwareRevision::new(rev, sig))
    }
}

/// A float in a fixed physical quantity (mA, %, s), for the annotated view.
macro_rules! quantity_type {
    ($(#[$m:meta])* $name:ident, $unit:expr) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        pub struct $name(pub f32);

        crate::newtype_wire!($name, f32, 4, Value::Float, Meaning::Quantity($unit));
    };
}

quantity_type!(
    /// A current in milliamperes.
    MilliAmps,
    "mA"
);
quantity_type!(
    /// A percentage.
    Percent,
    "%"
);
quantity_type!(
    /// A duration in seconds (e.g. damping).
    Seconds,
    "s"
);

/// A 16-bit command number (commands 105, 108 and the burst configuration).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct CommandNumber(pub u16);

crate::newtype_wire!(
    CommandNumber,
    u16,
    2,
    |x| Value::Uint(x.into()),
    Meaning::Command
);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_ascii_reference_examples() {
        // hart-reference.md §10.1 examples.
        assert_eq!(
            PackedString::<6>::new("").unwrap().0,
            [0x82, 0x08, 0x20, 0x82, 0x08, 0x20]
        );
        assert_eq!(
            PackedString::<6>::new("ABCDEFGH").unwrap().0,
            [0x04, 0x20, 0xC4, 0x14, 0x61, 0xC8]
        );
        assert_eq!(
            PackedString::<6>::new("PT-101").unwrap().0,
            [0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20]
        );
        assert_eq!(PackedString::<6>::new("????????").unwrap().0, [0xFF; 6]);
        assert_eq!(
            PackedString::<6>::new("pt-101").unwrap(),
            PackedString::<6>::new("PT-101").unwrap()
        );
        assert!(PackedString::<6>::new("TOO LONG!").is_err());
        assert!(PackedString::<6>::new("a~").is_err());
        let s = PackedString([0x41, 0x4B, 0x71, 0xC3, 0x18, 0x20]);
        assert_eq!(std::format!("{s}"), "PT-101");
    }

    #[test]
    fn every_packed_value_round_trips() {
        for v in 0u8..64 {
            let c = packed_ascii::decode_char(v);
            assert!((0x20..=0x5F).contains(&c));
            assert_eq!(packed_ascii::encode_char(char::from(c)), Some(v));
        }
    }

    #[test]
    fn date_and_time() {
        let d = Date {
            day: 21,
            month: 11,
            year_since_1900: 125,
        };
        assert_eq!(std::format!("{d}"), "2025-11-21");
        assert!(d.is_valid());
        assert!(!Date {
            day: 29,
            month: 2,
            year_since_1900: 125
        }
        .is_valid());
        assert!(Date {
            day: 29,
            month: 2,
            year_since_1900: 100
        }
        .is_valid());
        assert_eq!(HartTime(0x5265_C000).as_millis(), 12 * 3_600_000);
        assert_eq!(HartTime(0x5265_C000).as_micros(), 12 * 3_600_000_000);
        assert_eq!(HartTime(1).as_micros(), 31);
        assert_eq!(
            HartTime(u32::MAX).as_micros(),
            u64::from(u32::MAX) * 1000 / 32
        );
        // Noon on any day, from a Unix time in microseconds.
        assert_eq!(
            HartTime::time_of_day((20_000 * 86_400 + 12 * 3_600) * 1_000_000 + 999),
            HartTime(0x5265_C000)
        );
        assert_eq!(std::format!("{}", HartTime(0x5265_C000)), "12:00:00.000");
    }

    #[test]
    fn latin1() {
        let t = Latin1String::<32>::new("Düsseldorf line 3").unwrap();
        assert_eq!(t.0[1], 0xFC);
        assert_eq!(std::format!("{t}"), "Düsseldorf line 3");
        assert!(Latin1String::<4>::new("€").is_err());
    }

    #[test]
    fn hart_nan_bits_survive() {
        let mut buf = [0u8; 4];
        hart_nan().encode(&mut Writer::new(&mut buf)).unwrap();
        assert_eq!(buf, [0x7F, 0xA0, 0, 0]);
    }
}
