//! The register map, as data: which value of a device's image each register holds, in
//! which format, and which holding registers write to the device. The default map
//! (docs/gateway.md) is [`RegisterMap::default`]; a gateway configuration may give its
//! own (`[[modbus.register]]`). `hartkit serve --print-map` prints it from here.

use std::time::Instant;

use hart_poller::DeviceImage;
/// The values the registers hold and their numbers: the front ends' shared model.
pub use hart_values::{number, Value};
use serde::{Deserialize, Serialize};
use tokio_modbus::ExceptionCode;

/// Modbus register tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Table {
    /// Input registers (function 4), read only.
    Input,
    /// Holding registers (function 3 to read, 6 and 16 to write).
    Holding,
}

/// How a value is put in registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Format {
    /// IEEE-754 single precision in two registers, in the gateway's float order.
    Float,
    /// Unsigned 16-bit integer, one register.
    U16,
    /// Unsigned 32-bit integer in two registers, in the gateway's word order.
    U32,
}

impl Format {
    /// The format `value` has unless the map says otherwise: floats for the process
    /// values, currents, ranges and damping; 32 bits for the age and the device ID; one
    /// register for codes and the rest.
    pub fn default_for(value: Value) -> Format {
        use Value::*;
        match value {
            Pv | Sv | Tv | Qv | LoopCurrent | PercentRange | UpperRange | LowerRange | Damping
            | FixedCurrent => Format::Float,
            Age | DeviceId => Format::U32,
            _ => Format::U16,
        }
    }

    /// Registers the format takes.
    pub fn words(self) -> u16 {
        match self {
            Format::U16 => 1,
            Format::Float | Format::U32 => 2,
        }
    }
}

/// One entry of the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Entry {
    /// Input or holding registers.
    pub table: Table,
    /// First register (0-based protocol address).
    pub register: u16,
    /// What it holds.
    pub value: Value,
    /// Format; default per value.
    #[serde(default)]
    pub format: Option<Format>,
}

impl Entry {
    /// The format in effect.
    pub fn format(&self) -> Format {
        self.format.unwrap_or(Format::default_for(self.value))
    }

    /// Registers `register..end`.
    pub fn end(&self) -> u32 {
        u32::from(self.register) + u32::from(self.format().words())
    }
}

/// How a 32-bit value is laid out in two registers: bytes A B C D of the big-endian
/// value, in the order sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FloatOrder {
    /// High word first, each word high byte first (Modbus's own big-endian order).
    #[default]
    Abcd,
    /// Low word first (word swap), as many PLCs expect.
    Cdab,
    /// High word first with the bytes of each word swapped.
    Badc,
    /// Fully little-endian.
    Dcba,
}

impl std::str::FromStr for FloatOrder {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "abcd" => Ok(FloatOrder::Abcd),
            "cdab" => Ok(FloatOrder::Cdab),
            "badc" => Ok(FloatOrder::Badc),
            "dcba" => Ok(FloatOrder::Dcba),
            _ => Err(format!(
                "float order {s:?}: give abcd (high word first), cdab (low word first), \
                 badc or dcba"
            )),
        }
    }
}

impl FloatOrder {
    /// The two registers of the 32-bit value `v`.
    pub fn split(self, v: u32) -> [u16; 2] {
        let [a, b, c, d] = v.to_be_bytes();
        let w = |x: u8, y: u8| u16::from_be_bytes([x, y]);
        match self {
            FloatOrder::Abcd => [w(a, b), w(c, d)],
            FloatOrder::Cdab => [w(c, d), w(a, b)],
            FloatOrder::Badc => [w(b, a), w(d, c)],
            FloatOrder::Dcba => [w(d, c), w(b, a)],
        }
    }

    /// The 32-bit value of two registers.
    pub fn join(self, r: [u16; 2]) -> u32 {
        let [p, q] = r[0].to_be_bytes();
        let [s, t] = r[1].to_be_bytes();
        let bytes = match self {
            FloatOrder::Abcd => [p, q, s, t],
            FloatOrder::Cdab => [s, t, p, q],
            FloatOrder::Badc => [q, p, t, s],
            FloatOrder::Dcba => [t, s, q, p],
        };
        u32::from_be_bytes(bytes)
    }

    /// The name (`abcd`...).
    pub fn name(self) -> &'static str {
        match self {
            FloatOrder::Abcd => "abcd",
            FloatOrder::Cdab => "cdab",
            FloatOrder::Badc => "badc",
            FloatOrder::Dcba => "dcba",
        }
    }
}

/// The register map of every device (each device is one Modbus unit).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RegisterMap {
    entries: Vec<Entry>,
}

/// The most registers one read may ask for (Modbus application protocol, 6.3/6.4).
pub const MAX_READ: u16 = 125;

impl Default for RegisterMap {
    /// The default map: input registers 0-25, holding registers 0-8.
    fn default() -> Self {
        use Value::*;
        let input = [
            (0, Pv),
            (2, Sv),
            (4, Tv),
            (6, Qv),
            (8, LoopCurrent),
            (10, PvUnits),
            (11, DeviceStatus),
            (12, ExtendedStatus),
            (13, Quality),
            (14, Age),
            (16, PercentRange),
            (18, SvUnits),
            (19, TvUnits),
            (20, QvUnits),
            (21, PollingAddress),
            (22, DeviceId),
            (24, ManufacturerId),
            (25, DeviceType),
        ];
        let holding = [
            (0, UpperRange),
            (2, LowerRange),
            (4, Damping),
            (6, FixedCurrent),
            (8, RangeUnits),
        ];
        let entry = |table| {
            move |(register, value)| Entry {
                table,
                register,
                value,
                format: None,
            }
        };
        RegisterMap {
            entries: input
                .into_iter()
                .map(entry(Table::Input))
                .chain(holding.into_iter().map(entry(Table::Holding)))
                .collect(),
        }
    }
}

impl RegisterMap {
    /// A map of `entries`; refuses overlapping registers, and writable values in the
    /// input table are simply read-only there.
    pub fn new(mut entries: Vec<Entry>) -> Result<Self, String> {
        entries.sort_by_key(|e| (e.table == Table::Holding, e.register));
        for pair in entries.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            if a.table == b.table && a.end() > u32::from(b.register) {
                return Err(format!(
                    "register map: {:?} register {} ({}) overlaps register {} ({}); \
                     a float or u32 takes two registers",
                    a.table,
                    a.register,
                    a.value.name(),
                    b.register,
                    b.value.name()
                ));
            }
        }
        if let Some(e) = entries.iter().find(|e| e.end() > 65_536) {
            return Err(format!(
                "register map: register {} ({}) runs past 65535",
                e.register,
                e.value.name()
            ));
        }
        Ok(RegisterMap { entries })
    }

    /// Every entry, input registers first, by register.
    pub fn entries(&self) -> &[Entry] {
        &self.entries
    }

    /// The entry covering `register` of `table`.
    pub fn entry_at(&self, table: Table, register: u16) -> Option<&Entry> {
        self.entries.iter().find(|e| {
            e.table == table
                && u32::from(e.register) <= u32::from(register)
                && u32::from(register) < e.end()
        })
    }

    /// Registers `start..start + count` of `table` for device `d` at `now`: every
    /// register must be in the map (else "illegal data address"), at most
    /// [`MAX_READ`] (else "illegal data value").
    pub fn read(
        &self,
        table: Table,
        start: u16,
        count: u16,
        d: &DeviceImage,
        now: Instant,
        order: FloatOrder,
    ) -> Result<Vec<u16>, ExceptionCode> {
        if count == 0 || count > MAX_READ {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let end = u32::from(start) + u32::from(count);
        if end > 65_536 {
            return Err(ExceptionCode::IllegalDataAddress);
        }
        let mut out = Vec::with_capacity(usize::from(count));
        let mut r = u32::from(start);
        while r < end {
            let e = self
                .entry_at(table, r as u16)
                .ok_or(ExceptionCode::IllegalDataAddress)?;
            let words = encode(e, d, now, order);
            let skip = (r - u32::from(e.register)) as usize;
            for w in words.iter().skip(skip) {
                if r >= end {
                    break;
                }
                out.push(*w);
                r += 1;
            }
        }
        Ok(out)
    }

    /// Decodes a write of `words` at `start` of the holding table into the values it
    /// sets. Every register must belong to a writable entry, and each entry must be
    /// written whole (both registers of a float).
    pub fn decode_write(
        &self,
        start: u16,
        words: &[u16],
        order: FloatOrder,
    ) -> Result<Vec<(Value, f32)>, ExceptionCode> {
        if words.is_empty() {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let mut out = vec![];
        let mut i = 0usize;
        while i < words.len() {
            let r = u32::from(start) + i as u32;
            if r > 65_535 {
                return Err(ExceptionCode::IllegalDataAddress);
            }
            let e = self
                .entry_at(Table::Holding, r as u16)
                .ok_or(ExceptionCode::IllegalDataAddress)?;
            if !e.value.writable() || u32::from(e.register) != r {
                return Err(ExceptionCode::IllegalDataAddress);
            }
            let n = usize::from(e.format().words());
            let Some(w) = words.get(i..i + n) else {
                return Err(ExceptionCode::IllegalDataAddress);
            };
            let v = match e.format() {
                Format::U16 => f32::from(w[0]),
                Format::U32 => order.join([w[0], w[1]]) as f32,
                Format::Float => f32::from_bits(order.join([w[0], w[1]])),
            };
            if !v.is_finite() {
                return Err(ExceptionCode::IllegalDataValue);
            }
            out.push((e.value, v));
            i += n;
        }
        Ok(out)
    }
}

/// The registers of entry `e` for device `d`.
fn encode(e: &Entry, d: &DeviceImage, now: Instant, order: FloatOrder) -> Vec<u16> {
    let number = number(e.value, d, now);
    match e.format() {
        Format::Float => order
            .split(number.map_or(f32::NAN, |x| x as f32).to_bits())
            .to_vec(),
        Format::U16 => vec![number
            .filter(|x| x.is_finite())
            .map_or(0xFFFF, |x| x.clamp(0.0, 65_535.0) as u16)],
        Format::U32 => order
            .split(
                number
                    .filter(|x| x.is_finite())
                    .map_or(u32::MAX, |x| x.clamp(0.0, f64::from(u32::MAX)) as u32),
            )
            .to_vec(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 123.456 as IEEE-754 is 0x42F6E979 (sign 0, exponent 133, mantissa 0x76E979),
    /// bytes A=42 B=F6 C=E9 D=79, sent in the four orders.
    #[test]
    fn float_orders() {
        let v = 123.456f32.to_bits();
        assert_eq!(v, 0x42F6_E979);
        assert_eq!(FloatOrder::Abcd.split(v), [0x42F6, 0xE979]);
        assert_eq!(FloatOrder::Cdab.split(v), [0xE979, 0x42F6]);
        assert_eq!(FloatOrder::Badc.split(v), [0xF642, 0x79E9]);
        assert_eq!(FloatOrder::Dcba.split(v), [0x79E9, 0xF642]);
        for o in [
            FloatOrder::Abcd,
            FloatOrder::Cdab,
            FloatOrder::Badc,
            FloatOrder::Dcba,
        ] {
            assert_eq!(o.join(o.split(v)), v);
        }
    }

    fn device() -> DeviceImage {
        let mut d = DeviceImage::new(0, 0, "loop1", std::time::Duration::from_secs(10));
        let data = [0x41, 0x40, 0, 0, 12, 0x42, 0x48, 0, 0];
        d.apply_reply(3, 0, 0, &data, Instant::now(), std::time::SystemTime::now());
        d
    }

    #[test]
    fn reads_the_default_map() {
        let m = RegisterMap::default();
        let d = device();
        let now = Instant::now();
        let r = m
            .read(Table::Input, 0, 16, &d, now, FloatOrder::Abcd)
            .unwrap();
        assert_eq!(&r[0..2], &[0x4248, 0x0000]); // PV 50.0
        assert!(f32::from_bits(FloatOrder::Abcd.join([r[2], r[3]])).is_nan());
        assert_eq!(&r[8..10], &[0x4140, 0x0000]); // 12 mA
        assert_eq!(r[10], 12); // kPa
        assert_eq!(r[13], 0); // good
        assert_eq!(&r[14..16], &[0, 0]); // 0 s
                                         // The second half of PV alone.
        assert_eq!(
            m.read(Table::Input, 1, 1, &d, now, FloatOrder::Abcd)
                .unwrap(),
            [0]
        );
        assert_eq!(
            m.read(Table::Input, 26, 1, &d, now, FloatOrder::Abcd),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            m.read(Table::Input, 0, 126, &d, now, FloatOrder::Abcd),
            Err(ExceptionCode::IllegalDataValue)
        );
        assert_eq!(
            m.read(Table::Input, 65_535, 2, &d, now, FloatOrder::Abcd),
            Err(ExceptionCode::IllegalDataAddress)
        );
    }

    #[test]
    fn decodes_writes() {
        let m = RegisterMap::default();
        let o = FloatOrder::Abcd;
        let [a, b] = o.split(2.5f32.to_bits());
        assert_eq!(
            m.decode_write(4, &[a, b], o),
            Ok(vec![(Value::Damping, 2.5)])
        );
        // Half a float.
        assert_eq!(
            m.decode_write(4, &[a], o),
            Err(ExceptionCode::IllegalDataAddress)
        );
        assert_eq!(
            m.decode_write(5, &[b], o),
            Err(ExceptionCode::IllegalDataAddress)
        );
        // Range units is one register.
        assert_eq!(
            m.decode_write(8, &[12], o),
            Ok(vec![(Value::RangeUnits, 12.0)])
        );
        // Outside the map.
        assert_eq!(
            m.decode_write(9, &[1], o),
            Err(ExceptionCode::IllegalDataAddress)
        );
        let nan = o.split(f32::NAN.to_bits());
        assert_eq!(
            m.decode_write(4, &nan, o),
            Err(ExceptionCode::IllegalDataValue)
        );
    }

    #[test]
    fn custom_maps_are_checked() {
        let e = |register, value| Entry {
            table: Table::Input,
            register,
            value,
            format: None,
        };
        assert!(RegisterMap::new(vec![e(0, Value::Pv), e(1, Value::Sv)]).is_err());
        let m = RegisterMap::new(vec![e(10, Value::Quality), e(0, Value::Pv)]).unwrap();
        assert_eq!(m.entries()[0].value, Value::Pv);
        assert!(RegisterMap::new(vec![e(65_535, Value::Pv)]).is_err());
        let t: Entry =
            toml::from_str("table = \"holding\"\nregister = 100\nvalue = \"damping\"").unwrap();
        assert_eq!(t.format(), Format::Float);
    }

    proptest::proptest! {
        /// Any read or write request is answered or refused, never a panic, and a read
        /// answers exactly the registers asked for.
        #[test]
        fn any_request(start: u16, count in 0u16..200,
                       words in proptest::collection::vec(proptest::num::u16::ANY, 0..130)) {
            let m = RegisterMap::default();
            let d = device();
            if let Ok(r) = m.read(Table::Input, start, count, &d, Instant::now(), FloatOrder::Cdab) {
                proptest::prop_assert_eq!(r.len(), usize::from(count));
            }
            let _ = m.read(Table::Holding, start, count, &d, Instant::now(), FloatOrder::Abcd);
            let _ = m.decode_write(start, &words, FloatOrder::Dcba);
        }
    }
}
