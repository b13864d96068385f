//! The field layer shared by every command layout: a bounds-checked [`Reader`] and
//! [`Writer`], the [`Wire`] trait each field type implements, and the [`Visitor`]
//! through which a decoded value describes itself field by field (used for the
//! annotated frame view and for JSON, so both always agree with the codec). The
//! reverse walk, [`Source`], builds a value from named fields (a request typed as JSON
//! or as a Python dict) through the same field list.

use core::fmt;

use crate::tables::{BitTable, CodeTable};

/// Reads fields from a byte slice; every read is bounds-checked.
#[derive(Debug, Clone)]
pub struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    /// Starts reading at the beginning of `buf`.
    pub fn new(buf: &'a [u8]) -> Self {
        Reader { buf, pos: 0 }
    }

    /// Bytes consumed so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// Bytes not yet consumed.
    pub fn remaining(&self) -> usize {
        self.buf.len() - self.pos
    }

    /// The unconsumed bytes.
    pub fn rest(&self) -> &'a [u8] {
        &self.buf[self.pos..]
    }

    /// Takes the next `n` bytes, or reports how many were missing.
    pub fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.remaining() < n {
            return Err(DecodeError::TooShort {
                offset: self.pos,
                needed: n,
                available: self.remaining(),
            });
        }
        let s = &self.buf[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    /// Takes exactly `N` bytes as an array.
    pub fn array<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let s = self.take(N)?;
        let mut a = [0u8; N];
        a.copy_from_slice(s);
        Ok(a)
    }

    /// Takes one byte.
    pub fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
}

/// Writes fields into a caller-provided buffer; every write is bounds-checked.
#[derive(Debug)]
pub struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl<'a> Writer<'a> {
    /// Starts writing at the beginning of `buf`.
    pub fn new(buf: &'a mut [u8]) -> Self {
        Writer { buf, pos: 0 }
    }

    /// Bytes written so far.
    pub fn position(&self) -> usize {
        self.pos
    }

    /// The bytes written so far.
    pub fn written(&self) -> &[u8] {
        &self.buf[..self.pos]
    }

    /// Appends bytes.
    pub fn put(&mut self, bytes: &[u8]) -> Result<(), EncodeError> {
        let end = self.pos + bytes.len();
        if end > self.buf.len() {
            return Err(EncodeError::BufferTooSmall {
                needed: end,
                capacity: self.buf.len(),
            });
        }
        self.buf[self.pos..end].copy_from_slice(bytes);
        self.pos = end;
        Ok(())
    }

    /// Appends one byte.
    pub fn u8(&mut self, b: u8) -> Result<(), EncodeError> {
        self.put(&[b])
    }
}

/// Why a field or a command body could not be decoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DecodeError {
    /// The data ended before a field was complete.
    TooShort {
        /// Offset (within the data) of the incomplete field.
        offset: usize,
        /// Bytes the field needs.
        needed: usize,
        /// Bytes that were left.
        available: usize,
    },
    /// A field holds a value its type cannot represent.
    Invalid {
        /// Offset (within the data) of the field.
        offset: usize,
        /// What was wrong.
        reason: &'static str,
    },
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DecodeError::TooShort {
                offset,
                needed,
                available,
            } => write!(
                f,
                "truncated at data byte {offset}: expected {needed} more byte(s), got {available}"
            ),
            DecodeError::Invalid { offset, reason } => {
                write!(f, "invalid value at data byte {offset}: {reason}")
            }
        }
    }
}

/// Why a value could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EncodeError {
    /// The output buffer is too small.
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes available.
        capacity: usize,
    },
    /// A value does not fit its field.
    Invalid(&'static str),
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            EncodeError::BufferTooSmall { needed, capacity } => {
                write!(
                    f,
                    "output buffer too small: need {needed} bytes, have {capacity}"
                )
            }
            EncodeError::Invalid(why) => f.write_str(why),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DecodeError {}
#[cfg(feature = "std")]
impl std::error::Error for EncodeError {}

/// A field value as seen by a [`Visitor`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value<'a> {
    /// An unsigned integer (8 to 32 bits).
    Uint(u32),
    /// An IEEE 754 single-precision float (may be NaN or infinite).
    Float(f32),
    /// Text (already decoded from packed ASCII or Latin-1, trailing padding removed).
    Str(&'a str),
    /// Raw bytes, shown as hexadecimal.
    Hex(&'a [u8]),
    /// A HART date.
    Date(crate::types::Date),
    /// A flag.
    Bool(bool),
}

/// How to explain a field's value to a person.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Meaning {
    /// Nothing beyond the value.
    Plain,
    /// An engineering unit code (Common Table 2).
    Unit,
    /// A code from an enumerated table.
    Code(&'static CodeTable),
    /// A bit field.
    Bits(&'static BitTable),
    /// A device variable status byte.
    VariableStatus,
    /// A HART time (1/32 ms units).
    Time,
    /// A float in a known unit (e.g. "mA", "s", "%").
    Quantity(&'static str),
    /// A command number.
    Command,
}

/// One decoded field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Field<'a> {
    /// Field name, `snake_case`; also the JSON key.
    pub name: &'static str,
    /// Offset of the field's first byte within the command data.
    pub offset: usize,
    /// Number of bytes the field occupies.
    pub len: usize,
    /// The value.
    pub value: Value<'a>,
    /// How to explain the value.
    pub meaning: Meaning,
}

/// Receives the fields of a decoded value in wire order.
///
/// Lists (e.g. the variables of command 3) are bracketed by [`Visitor::begin_list`] /
/// [`Visitor::end_list`], each element by [`Visitor::begin_item`] / [`Visitor::end_item`].
pub trait Visitor {
    /// A scalar field.
    fn field(&mut self, field: Field<'_>);
    /// Start of a list named `name`.
    fn begin_list(&mut self, name: &'static str);
    /// Start of element `index` of the current list.
    fn begin_item(&mut self, index: usize);
    /// End of the current element.
    fn end_item(&mut self);
    /// End of the current list.
    fn end_list(&mut self);
}

/// A type with a fixed wire layout: decode, encode and describe derive from one place.
pub trait Wire: Sized {
    /// Fewest bytes a complete value occupies.
    const MIN_LEN: usize;
    /// Most bytes a value occupies.
    const MAX_LEN: usize;

    /// Reads a value.
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError>;
    /// Writes the value.
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError>;
    /// Bytes [`Wire::encode`] writes for this value.
    fn encoded_len(&self) -> usize;
    /// Reports the value to `v` as field `name` starting at `offset`.
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor);
    /// Builds the value from field `name` of `src`: the reverse of
    /// [`Wire::describe`], with the same names.
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError>;
}

/// Why a value could not be built from named fields (see [`Source`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BuildError {
    /// A field the layout needs was not given.
    Missing {
        /// The field.
        field: &'static str,
    },
    /// A field was given a value of the wrong kind (text for a number, say).
    WrongKind {
        /// The field.
        field: &'static str,
        /// What the field takes.
        expected: &'static str,
    },
    /// A value does not fit its field.
    Invalid {
        /// The field.
        field: &'static str,
        /// Why.
        reason: &'static str,
    },
    /// An optional trailing field was given after one that was left out: HART's
    /// optional fields extend a layout at its end, so the later one has no place.
    Gap {
        /// The field left out.
        missing: &'static str,
        /// The later field that was given.
        given: &'static str,
    },
}

impl fmt::Display for BuildError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            BuildError::Missing { field } => write!(f, "field {field} is missing"),
            BuildError::WrongKind { field, expected } => {
                write!(f, "field {field} takes {expected}")
            }
            BuildError::Invalid { field, reason } => write!(f, "field {field}: {reason}"),
            BuildError::Gap { missing, given } => write!(
                f,
                "field {given} was given but {missing} was not; optional fields end the \
                 data, so give {missing} too or leave out {given}"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for BuildError {}

/// Supplies named field values to [`Wire::build`]: the reverse of a [`Visitor`], with
/// the same names, the same flattening of nested layouts and the same lists.
///
/// Scalars come as [`Value`]s; a field type takes the kinds that make sense for it
/// (a float takes [`Value::Uint`] too, a unit code its symbol as [`Value::Str`], a
/// date `"YYYY-MM-DD"`, raw bytes a hex string).
pub trait Source {
    /// The value of scalar field `name`; `Ok(None)` when it was not given.
    fn value(&mut self, name: &'static str) -> Result<Option<Value<'_>>, BuildError>;
    /// Enters list `name`; returns its number of items, `Ok(None)` when not given.
    fn begin_list(&mut self, name: &'static str) -> Result<Option<usize>, BuildError>;
    /// Enters item `index` of the current list. A list of scalars names each item
    /// `item`, as [`Visitor`] does.
    fn begin_item(&mut self, index: usize) -> Result<(), BuildError>;
    /// Leaves the current item.
    fn end_item(&mut self);
    /// Leaves the current list.
    fn end_list(&mut self);
}

/// Hex digits (spaces, `:` and `-` between bytes allowed) into `out`; the number of
/// bytes, or `None` when the text is not hex or does not fit.
pub fn hex_into(text: &str, out: &mut [u8]) -> Option<usize> {
    let mut n = 0;
    let mut high: Option<u8> = None;
    for c in text.chars() {
        if matches!(c, ' ' | ':' | '-') && high.is_none() {
            continue;
        }
        let d = c.to_digit(16)? as u8;
        match high.take() {
            None => high = Some(d),
            Some(h) => {
                *out.get_mut(n)? = h << 4 | d;
                n += 1;
            }
        }
    }
    high.is_none().then_some(n)
}

/// A [`Source`] that hides some fields of another: for a layout whose description adds
/// derived fields under names that are also real fields of a longer form (the HART 5
/// reading of command 0's `manufacturer_id`).
pub struct Hiding<'s> {
    /// The source read through.
    pub inner: &'s mut dyn Source,
    /// Fields reported as not given.
    pub hidden: &'static [&'static str],
}

impl Source for Hiding<'_> {
    fn value(&mut self, name: &'static str) -> Result<Option<Value<'_>>, BuildError> {
        if self.hidden.contains(&name) {
            return Ok(None);
        }
        self.inner.value(name)
    }
    fn begin_list(&mut self, name: &'static str) -> Result<Option<usize>, BuildError> {
        self.inner.begin_list(name)
    }
    fn begin_item(&mut self, index: usize) -> Result<(), BuildError> {
        self.inner.begin_item(index)
    }
    fn end_item(&mut self) {
        self.inner.end_item()
    }
    fn end_list(&mut self) {
        self.inner.end_list()
    }
}

/// The value of a required scalar field.
pub fn required<'s>(src: &'s mut dyn Source, name: &'static str) -> Result<Value<'s>, BuildError> {
    src.value(name)?.ok_or(BuildError::Missing { field: name })
}

/// Converts a [`Value`] to a field's Rust type (numbers range-checked).
pub trait FromValue: Sized {
    /// `v` as `Self`, or why not, naming `field`.
    fn from_value(v: Value<'_>, field: &'static str) -> Result<Self, BuildError>;
}

fn uint_of(v: Value<'_>, field: &'static str, max: u32) -> Result<u32, BuildError> {
    let out_of_range = BuildError::Invalid {
        field,
        reason: match max {
            0xFF => "out of range: the field is one byte (0 to 255)",
            0xFFFF => "out of range: the field is two bytes (0 to 65535)",
            0xFF_FFFF => "out of range: the field is three bytes (0 to 16777215)",
            _ => "out of range: the field is four bytes (0 to 4294967295)",
        },
    };
    let n = match v {
        Value::Uint(n) => n,
        // A whole float (a JSON 5.0) is taken; `as` saturates, so compare back.
        Value::Float(x) if (0.0..4_294_967_296.0).contains(&x) && (x as u32) as f32 == x => {
            x as u32
        }
        // A negative or too large whole number is a number out of range, not text.
        Value::Float(x) if x.is_finite() && x == (x as i64) as f32 => return Err(out_of_range),
        Value::Bool(b) => b.into(),
        _ => {
            return Err(BuildError::WrongKind {
                field,
                expected: "a whole number",
            })
        }
    };
    if n > max {
        return Err(out_of_range);
    }
    Ok(n)
}

impl FromValue for u8 {
    fn from_value(v: Value<'_>, field: &'static str) -> Result<Self, BuildError> {
        uint_of(v, field, 0xFF).map(|n| n as u8)
    }
}
impl FromValue for u16 {
    fn from_value(v: Value<'_>, field: &'static str) -> Result<Self, BuildError> {
        uint_of(v, field, 0xFFFF).map(|n| n as u16)
    }
}
impl FromValue for u32 {
    fn from_value(v: Value<'_>, field: &'static str) -> Result<Self, BuildError> {
        uint_of(v, field, u32::MAX)
    }
}
impl FromValue for f32 {
    fn from_value(v: Value<'_>, field: &'static str) -> Result<Self, BuildError> {
        match v {
            Value::Float(x) => Ok(x),
            Value::Uint(n) => Ok(n as f32),
            _ => Err(BuildError::WrongKind {
                field,
                expected: "a number",
            }),
        }
    }
}

/// A code field given by its meaning: a unit's symbol or name, or the name of a code in
/// the field's table; `None` when `meaning` has no names or none matches.
pub fn code_by_name(meaning: Meaning, text: &str) -> Option<u8> {
    match meaning {
        Meaning::Unit => crate::tables::UNITS
            .iter()
            .find(|u| u.symbol == text || u.name.eq_ignore_ascii_case(text))
            .map(|u| u.code),
        Meaning::Code(t) => t
            .entries
            .iter()
            .find(|e| e.name.eq_ignore_ascii_case(text))
            .map(|e| e.code),
        _ => None,
    }
}

/// Implements [`Wire`] for a big-endian number type.
macro_rules! number_wire {
    ($t:ty, $len:expr, $value:expr) => {
        impl Wire for $t {
            const MIN_LEN: usize = $len;
            const MAX_LEN: usize = $len;
            fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
                Ok(<$t>::from_be_bytes(r.array()?))
            }
            fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
                w.put(&self.to_be_bytes())
            }
            fn encoded_len(&self) -> usize {
                $len
            }
            fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
                <$t as FromValue>::from_value(required(src, name)?, name)
            }
            fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
                let value: fn($t) -> Value<'static> = $value;
                v.field(Field {
                    name,
                    offset,
                    len: $len,
                    value: value(*self),
                    meaning: Meaning::Plain,
                });
            }
        }
    };
}

number_wire!(u8, 1, |x| Value::Uint(x.into()));
number_wire!(u16, 2, |x| Value::Uint(x.into()));
number_wire!(u32, 4, Value::Uint);
// Floats keep their bit pattern (NaN payloads such as the HART NaN survive).
number_wire!(f32, 4, Value::Float);

/// Implements [`Wire`] for a newtype over a fixed-size [`Wire`] value, described with
/// its own [`Meaning`] (units, code tables, times, quantities...).
#[macro_export]
#[doc(hidden)]
macro_rules! newtype_wire {
    ($name:ident, $inner:ty, $len:expr, $value:expr, $meaning:expr) => {
        impl $crate::wire::Wire for $name {
            const MIN_LEN: usize = $len;
            const MAX_LEN: usize = $len;
            fn decode(r: &mut $crate::wire::Reader<'_>) -> Result<Self, $crate::wire::DecodeError> {
                Ok($name(<$inner as $crate::wire::Wire>::decode(r)?))
            }
            fn encode(
                &self,
                w: &mut $crate::wire::Writer<'_>,
            ) -> Result<(), $crate::wire::EncodeError> {
                $crate::wire::Wire::encode(&self.0, w)
            }
            fn encoded_len(&self) -> usize {
                $len
            }
            fn build(
                name: &'static str,
                src: &mut dyn $crate::wire::Source,
            ) -> Result<Self, $crate::wire::BuildError> {
                let v = $crate::wire::required(src, name)?;
                // A code may be given by its name or symbol (units: "kPa").
                if let $crate::wire::Value::Str(text) = v {
                    if let Some(code) = $crate::wire::code_by_name($meaning, text) {
                        return <$inner as $crate::wire::FromValue>::from_value(
                            $crate::wire::Value::Uint(code.into()),
                            name,
                        )
                        .map($name);
                    }
                    if matches!(
                        $meaning,
                        $crate::wire::Meaning::Unit | $crate::wire::Meaning::Code(_)
                    ) {
                        return Err($crate::wire::BuildError::Invalid {
                            field: name,
                            reason: "no code of this field's table has that name",
                        });
                    }
                }
                <$inner as $crate::wire::FromValue>::from_value(v, name).map($name)
            }
            fn describe(
                &self,
                name: &'static str,
                offset: usize,
                v: &mut dyn $crate::wire::Visitor,
            ) {
                let value: fn($inner) -> $crate::wire::Value<'static> = $value;
                v.field($crate::wire::Field {
                    name,
                    offset,
                    len: $len,
                    value: value(self.0),
                    meaning: $meaning,
                });
            }
        }
    };
}

/// An optional trailing field: decoded when the data still holds a complete value,
/// absent otherwise (how HART 6/7 extend HART 5 layouts). Encoding writes nothing
/// for `None`; once one optional field is `None`, the later ones should be too.
impl<T: Wire> Wire for Option<T> {
    const MIN_LEN: usize = 0;
    const MAX_LEN: usize = T::MAX_LEN;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        if r.remaining() < T::MIN_LEN || r.remaining() == 0 {
            return Ok(None);
        }
        let mut probe = r.clone();
        match T::decode(&mut probe) {
            Ok(v) => {
                *r = probe;
                Ok(Some(v))
            }
            Err(DecodeError::TooShort { .. }) => Ok(None),
            Err(e) => Err(e),
        }
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        match self {
            Some(v) => v.encode(w),
            None => Ok(()),
        }
    }
    fn encoded_len(&self) -> usize {
        self.as_ref().map_or(0, Wire::encoded_len)
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        if let Some(x) = self {
            x.describe(name, offset, v);
        }
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        match T::build(name, src) {
            Ok(x) => Ok(Some(x)),
            // Absent only when the field itself was left out: a missing part of a
            // larger optional value is still an error.
            Err(BuildError::Missing { field }) if field == name => Ok(None),
            Err(e) => Err(e),
        }
    }
}

/// Up to `N` repetitions of `T`, as many as the data holds (at least `MIN`).
///
/// Used for the repeated groups of commands 3, 9, 33 and for lists of device
/// variable codes. Storage is inline; nothing is allocated.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct List<T: Copy + Default, const N: usize, const MIN: usize = 0> {
    items: [T; N],
    len: usize,
}

impl<T: Copy + Default, const N: usize, const MIN: usize> Default for List<T, N, MIN> {
    fn default() -> Self {
        List {
            items: [T::default(); N],
            len: 0,
        }
    }
}

impl<T: Copy + Default + fmt::Debug, const N: usize, const MIN: usize> fmt::Debug
    for List<T, N, MIN>
{
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.as_slice()).finish()
    }
}

impl<T: Copy + Default, const N: usize, const MIN: usize> List<T, N, MIN> {
    /// Builds a list from a slice; fails when it has more than `N` or fewer than `MIN` items.
    pub fn from_slice(items: &[T]) -> Result<Self, EncodeError> {
        if items.len() > N {
            return Err(EncodeError::Invalid("too many list items for this command"));
        }
        if items.len() < MIN {
            return Err(EncodeError::Invalid("too few list items for this command"));
        }
        let mut l = Self::default();
        l.items[..items.len()].copy_from_slice(items);
        l.len = items.len();
        Ok(l)
    }

    /// The items.
    pub fn as_slice(&self) -> &[T] {
        &self.items[..self.len]
    }

    /// Number of items.
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when the list is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Adds an item; fails when the list is full.
    pub fn push(&mut self, item: T) -> Result<(), EncodeError> {
        if self.len == N {
            return Err(EncodeError::Invalid("list is full"));
        }
        self.items[self.len] = item;
        self.len += 1;
        Ok(())
    }
}

impl<T: Copy + Default + Wire, const N: usize, const MIN: usize> Wire for List<T, N, MIN> {
    const MIN_LEN: usize = T::MIN_LEN * MIN;
    const MAX_LEN: usize = T::MAX_LEN * N;
    fn decode(r: &mut Reader<'_>) -> Result<Self, DecodeError> {
        let mut l = Self::default();
        while l.len < N && r.remaining() >= T::MIN_LEN.max(1) {
            l.items[l.len] = T::decode(r)?;
            l.len += 1;
        }
        if l.len < MIN {
            return Err(DecodeError::TooShort {
                offset: r.position(),
                needed: T::MIN_LEN * (MIN - l.len),
                available: r.remaining(),
            });
        }
        Ok(l)
    }
    fn encode(&self, w: &mut Writer<'_>) -> Result<(), EncodeError> {
        self.as_slice().iter().try_for_each(|i| i.encode(w))
    }
    fn encoded_len(&self) -> usize {
        self.as_slice().iter().map(Wire::encoded_len).sum()
    }
    fn describe(&self, name: &'static str, offset: usize, v: &mut dyn Visitor) {
        v.begin_list(name);
        let mut off = offset;
        for (i, item) in self.as_slice().iter().enumerate() {
            v.begin_item(i);
            item.describe("item", off, v);
            off += item.encoded_len();
            v.end_item();
        }
        v.end_list();
    }
    fn build(name: &'static str, src: &mut dyn Source) -> Result<Self, BuildError> {
        let Some(n) = src.begin_list(name)? else {
            return if MIN == 0 {
                Ok(Self::default())
            } else {
                Err(BuildError::Missing { field: name })
            };
        };
        if n > N {
            return Err(BuildError::Invalid {
                field: name,
                reason: "too many items for this command",
            });
        }
        if n < MIN {
            return Err(BuildError::Invalid {
                field: name,
                reason: "too few items for this command",
            });
        }
        let mut l = Self::default();
        for i in 0..n {
            src.begin_item(i)?;
            l.items[i] = T::build("item", src)?;
            src.end_item();
        }
        l.len = n;
        src.end_list();
        Ok(l)
    }
}

/// Defines a struct whose fields are laid out on the wire in declaration order and
/// derives [`Wire`] for it: decoding, encoding, its length and its description all
/// come from the single field list. An optional `describe_extra` function adds
/// derived fields to the description (e.g. the HART 5 reading of command 0); an
/// optional `build_with` function builds the value from named fields in its place
/// (to set such derived fields aside), usually by calling `build_fields`.
#[macro_export]
macro_rules! wire_struct {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $( $(#[$fmeta:meta])* pub $field:ident : $ty:ty ),* $(,)?
        }
        $(describe_extra = $extra:path;)?
        $(build_with = $hook:path;)?
    ) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Copy, PartialEq, Default)]
        pub struct $name {
            $( $(#[$fmeta])* pub $field: $ty, )*
        }

        impl $crate::wire::Wire for $name {
            const MIN_LEN: usize = 0 $( + <$ty as $crate::wire::Wire>::MIN_LEN )*;
            const MAX_LEN: usize = 0 $( + <$ty as $crate::wire::Wire>::MAX_LEN )*;
            #[allow(unused_variables, unused_mut, unused_assignments)]
            fn decode(r: &mut $crate::wire::Reader<'_>) -> Result<Self, $crate::wire::DecodeError> {
                // Optional fields end a layout: once one is absent, so are the ones after
                // it, and the bytes left over are surplus (a 13-byte command 105 reply
                // has no trigger mode in its last byte).
                let mut ended = false;
                $(
                    let $field = if ended {
                        <$ty as $crate::wire::Wire>::decode(&mut $crate::wire::Reader::new(&[]))?
                    } else {
                        <$ty as $crate::wire::Wire>::decode(r)?
                    };
                    if <$ty as $crate::wire::Wire>::MIN_LEN == 0
                        && $crate::wire::Wire::encoded_len(&$field) == 0
                    {
                        ended = true;
                    }
                )*
                Ok($name { $( $field, )* })
            }
            #[allow(unused_variables)]
            fn encode(&self, w: &mut $crate::wire::Writer<'_>) -> Result<(), $crate::wire::EncodeError> {
                $( $crate::wire::Wire::encode(&self.$field, w)?; )*
                Ok(())
            }
            fn encoded_len(&self) -> usize {
                0 $( + $crate::wire::Wire::encoded_len(&self.$field) )*
            }
            #[allow(unused_variables, unused_mut, unused_assignments)]
            fn describe(&self, _name: &'static str, offset: usize, v: &mut dyn $crate::wire::Visitor) {
                let mut off = offset;
                $(
                    $crate::wire::Wire::describe(&self.$field, stringify!($field), off, v);
                    off += $crate::wire::Wire::encoded_len(&self.$field);
                )*
                $( $extra(self, offset, v); )?
            }
            fn build(
                _name: &'static str,
                src: &mut dyn $crate::wire::Source,
            ) -> Result<Self, $crate::wire::BuildError> {
                let hook: Option<
                    fn(&mut dyn $crate::wire::Source) -> Result<Self, $crate::wire::BuildError>,
                > = None $( .or(Some($hook)) )?;
                match hook {
                    Some(h) => h(src),
                    None => Self::build_fields(src),
                }
            }
        }

        impl $name {
            /// Builds the value from its fields in declaration order (what
            /// [`Wire::build`](crate::wire::Wire::build) does unless the layout has a
            /// `build_with` hook, which calls this after its own reading).
            #[allow(unused_variables, unused_mut, unused_assignments)]
            pub fn build_fields(
                src: &mut dyn $crate::wire::Source,
            ) -> Result<Self, $crate::wire::BuildError> {
                // Optional fields end a layout: once one is left out, none after it may
                // be given (its bytes would land in the earlier field's place).
                let mut left_out: Option<&'static str> = None;
                $(
                    let $field = <$ty as $crate::wire::Wire>::build(stringify!($field), src)?;
                    if $crate::wire::Wire::encoded_len(&$field) > 0 {
                        if let Some(missing) = left_out {
                            return Err($crate::wire::BuildError::Gap {
                                missing,
                                given: stringify!($field),
                            });
                        }
                    } else if <$ty as $crate::wire::Wire>::MIN_LEN == 0 && left_out.is_none() {
                        left_out = Some(stringify!($field));
                    }
                )*
                Ok($name { $( $field, )* })
            }
        }
    };
}
