//! Calibration tables (docs/wells.md, "Raw counts", "Calibration file" and "Uplink
//! command 160"): 10-segment piecewise quadratics from 24-bit raw counts to °C or
//! metres of water, their CSV file, and the built-in tables that undo the simulated
//! sensors' bowed transfer function ([`sensor_counts`]).

use std::fmt;
use std::path::{Path, PathBuf};

/// Which measured quantity a table converts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Sensor {
    /// Water temperature, °C (command 160 sensor code 0).
    Temperature,
    /// Water level, metres of water above the sensor (command 160 sensor code 1).
    Level,
}

impl Sensor {
    /// Both sensors, in the order of their codes (and of a calibration file's rows).
    pub const ALL: [Sensor; 2] = [Sensor::Temperature, Sensor::Level];

    /// The sensor's name in a calibration file: `"temperature"` or `"level"`.
    pub fn name(self) -> &'static str {
        match self {
            Sensor::Temperature => "temperature",
            Sensor::Level => "level",
        }
    }

    /// The sensor a calibration file's name stands for (exact, lower case), if any.
    pub fn from_name(s: &str) -> Option<Self> {
        match s {
            "temperature" => Some(Sensor::Temperature),
            "level" => Some(Sensor::Level),
            _ => None,
        }
    }

    /// The sensor's code in byte 0 of command 160: 0 temperature, 1 level.
    pub fn code(self) -> u8 {
        match self {
            Sensor::Temperature => 0,
            Sensor::Level => 1,
        }
    }

    /// The sensor a command 160 code stands for, if any.
    pub fn from_code(c: u8) -> Option<Self> {
        match c {
            0 => Some(Sensor::Temperature),
            1 => Some(Sensor::Level),
            _ => None,
        }
    }

    /// The unit of the converted value: `"°C"` or `"m"`.
    pub fn unit(self) -> &'static str {
        match self {
            Sensor::Temperature => "°C",
            Sensor::Level => "m",
        }
    }

    /// The measuring range `(lo, hi)` that counts 0 to [`MAX_COUNT`] span:
    /// -10 to 40 °C, or 0 to 20 m of water.
    pub fn range(self) -> (f64, f64) {
        match self {
            Sensor::Temperature => (-10.0, 40.0),
            Sensor::Level => (0.0, 20.0),
        }
    }
}

impl fmt::Display for Sensor {
    /// Writes [`Sensor::name`].
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Number of segments in a table.
pub const SEGMENTS: usize = 10;

/// Largest count a reading can have; 0xFFFFFF marks "no value".
pub const MAX_COUNT: u32 = 0xFF_FFFE;

/// The bow of the simulated sensors' transfer function: counts/full scale =
/// u + B·u·(1 − u), 0.4 % of full scale at mid-range.
const BOW: f64 = 0.016;

/// One segment of a table: raw counts `raw_from..=raw_to` convert to
/// `a0 + a1·raw + a2·raw²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// First count of the segment.
    pub raw_from: u32,
    /// Last count of the segment (inclusive).
    pub raw_to: u32,
    /// Constant coefficient.
    pub a0: f64,
    /// Linear coefficient (per count).
    pub a1: f64,
    /// Quadratic coefficient (per count squared).
    pub a2: f64,
}

impl Segment {
    /// `a0 + a1·raw + a2·raw²`, in f64 (whether or not `raw` lies in the segment).
    pub fn eval(&self, raw: u32) -> f64 {
        let r = f64::from(raw);
        self.a0 + self.a1 * r + self.a2 * r * r
    }
}

/// A checked calibration table: exactly [`SEGMENTS`] contiguous segments with finite
/// coefficients.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    segments: [Segment; SEGMENTS],
}

impl Table {
    /// Checks and builds a table. Checks: exactly 10 segments; each
    /// `raw_from <= raw_to`; `raw_to <= MAX_COUNT`; segment k+1 starts at segment k's
    /// `raw_to + 1` (no gap, no overlap); all coefficients finite. Segment 1 need not
    /// start at 0.
    ///
    /// The errors carry no line and no sensor (the segment number is the 1-based
    /// position in `segments`).
    pub fn new(segments: Vec<Segment>) -> Result<Table, CalibrationError> {
        let found = segments.len();
        let segments: [Segment; SEGMENTS] = segments
            .try_into()
            .map_err(|_| CalibrationError::SegmentCount { found })?;
        check_segments(&segments, None, None)?;
        Ok(Table { segments })
    }

    /// The 10 segments, in order of raw counts.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// Value of counts `raw`: the polynomial of the segment containing it; below the
    /// first segment or above the last, that end segment's polynomial (extrapolated).
    pub fn eval(&self, raw: u32) -> f64 {
        let i = self
            .segments
            .partition_point(|s| s.raw_to < raw)
            .min(SEGMENTS - 1);
        self.segments[i].eval(raw)
    }

    /// The built-in table of `sensor`: it undoes [`sensor_counts`] to within 1e-6 of
    /// the range's span everywhere in `0..=MAX_COUNT`.
    ///
    /// Segment k (0-based) covers counts `floor(k·(MAX_COUNT+1)/10)` to
    /// `floor((k+1)·(MAX_COUNT+1)/10) − 1`; its quadratic passes through the exact
    /// inverse of the transfer function at the segment's two ends and its middle.
    pub fn builtin(sensor: Sensor) -> Table {
        let n = u64::from(MAX_COUNT) + 1;
        let segments = std::array::from_fn(|k| {
            let k = k as u64;
            // Both fit in u32: they are at most MAX_COUNT.
            let raw_from = (k * n / SEGMENTS as u64) as u32;
            let raw_to = ((k + 1) * n / SEGMENTS as u64 - 1) as u32;
            fit_segment(sensor, raw_from, raw_to)
        });
        Table { segments }
    }
}

/// The exact inverse of [`sensor_counts`] (without its rounding) at counts `c`.
fn inverse_counts(sensor: Sensor, c: f64) -> f64 {
    let (lo, hi) = sensor.range();
    let y = c / f64::from(MAX_COUNT);
    // B·u² − (1+B)·u + y = 0, the root in [0, 1], in the form that does not cancel.
    let b1 = 1.0 + BOW;
    let disc = (b1 * b1 - 4.0 * BOW * y).max(0.0);
    let u = 2.0 * y / (b1 + disc.sqrt());
    lo + u * (hi - lo)
}

/// The quadratic through the exact inverse at `raw_from`, `raw_to` and their middle.
fn fit_segment(sensor: Sensor, raw_from: u32, raw_to: u32) -> Segment {
    let r0 = f64::from(raw_from);
    let r2 = f64::from(raw_to);
    let rm = 0.5 * (r0 + r2);
    let h = 0.5 * (r2 - r0);
    let (f0, fm, f2) = (
        inverse_counts(sensor, r0),
        inverse_counts(sensor, rm),
        inverse_counts(sensor, r2),
    );
    // In t = raw − rm: c0 + c1·t + c2·t², through t = −h, 0, h.
    let (c0, c1, c2) = if h > 0.0 {
        (
            fm,
            (f2 - f0) / (2.0 * h),
            (f2 - 2.0 * fm + f0) / (2.0 * h * h),
        )
    } else {
        (fm, 0.0, 0.0)
    };
    Segment {
        raw_from,
        raw_to,
        a0: c0 - c1 * rm + c2 * rm * rm,
        a1: c1 - 2.0 * c2 * rm,
        a2: c2,
    }
}

/// The simulated sensors' transfer function: counts for a physical value `x` (°C or
/// m).
///
/// `u = (x − lo)/(hi − lo)` with `(lo, hi) = sensor.range()`;
/// `counts = MAX_COUNT · (u + B·u·(1 − u))` with B = 0.016 (a bow of 0.4 % of full
/// scale at mid-range), rounded to nearest and clamped to `0..=MAX_COUNT`. `u` is
/// clamped to 0..=1 first (the same result inside the range and just outside it, and
/// it keeps far-out values at the ends where the bow would fold back); NaN gives 0.
pub fn sensor_counts(sensor: Sensor, x: f64) -> u32 {
    let (lo, hi) = sensor.range();
    let u = (x - lo) / (hi - lo);
    if u.is_nan() || u <= 0.0 {
        return 0;
    }
    if u >= 1.0 {
        return MAX_COUNT;
    }
    let c = (f64::from(MAX_COUNT) * (u + BOW * u * (1.0 - u))).round();
    // c is in 0..=MAX_COUNT here; the clamp only guards the cast.
    c.clamp(0.0, f64::from(MAX_COUNT)) as u32
}

/// The CSV header of a calibration file.
const HEADER: [&str; 7] = ["sensor", "segment", "raw_from", "raw_to", "a0", "a1", "a2"];

/// A calibration file: a table for each sensor it names (at least one, when parsed).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CalibrationFile {
    /// The water-temperature table, if the file has one.
    pub temperature: Option<Table>,
    /// The water-level table, if the file has one.
    pub level: Option<Table>,
}

/// One parsed row of a calibration file.
struct Row {
    line: usize,
    segment: Segment,
}

impl CalibrationFile {
    /// The table of sensor `s`, if the file has one.
    pub fn table(&self, s: Sensor) -> Option<&Table> {
        match s {
            Sensor::Temperature => self.temperature.as_ref(),
            Sensor::Level => self.level.as_ref(),
        }
    }

    /// Parses the CSV text of a calibration file.
    ///
    /// The header is exactly `sensor,segment,raw_from,raw_to,a0,a1,a2`; every other
    /// line is a row `sensor,segment,raw_from,raw_to,a0,a1,a2`. Whitespace around
    /// lines and fields, blank lines, lines starting with `#`, CRLF line ends and a
    /// leading byte-order mark are tolerated; numbers may use exponent notation; raw
    /// counts are non-negative integers. The rows of a sensor may come in any order,
    /// but segments 1 to 10 must each appear exactly once for each sensor named, and
    /// at least one sensor must be named. The file is refused whole on the first error
    /// (in line order; then missing segments; then each table's checks, temperature
    /// first), which names its line (1-based) where there is one.
    pub fn parse(text: &str) -> Result<CalibrationFile, CalibrationError> {
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut header_seen = false;
        // rows[sensor code][segment - 1]
        let mut rows: [[Option<Row>; SEGMENTS]; 2] = Default::default();
        let mut named = [false; 2];
        for (i, line) in text.lines().enumerate() {
            let line_no = i + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if !header_seen {
                if fields != HEADER {
                    return Err(CalibrationError::Header {
                        line: line_no,
                        found: line.to_string(),
                    });
                }
                header_seen = true;
                continue;
            }
            let (sensor, number, row) = parse_row(line_no, &fields)?;
            let slot = &mut rows[usize::from(sensor.code())][number - 1];
            if let Some(first) = slot {
                return Err(CalibrationError::DuplicateSegment {
                    line: line_no,
                    sensor,
                    segment: number,
                    first_line: first.line,
                });
            }
            *slot = Some(row);
            named[usize::from(sensor.code())] = true;
        }
        if !header_seen {
            return Err(CalibrationError::Empty);
        }
        if !named.contains(&true) {
            return Err(CalibrationError::NoRows);
        }
        let mut file = CalibrationFile::default();
        for sensor in Sensor::ALL {
            let code = usize::from(sensor.code());
            if !named[code] {
                continue;
            }
            let mut segments = Vec::with_capacity(SEGMENTS);
            let mut lines = Vec::with_capacity(SEGMENTS);
            for (k, row) in rows[code].iter().enumerate() {
                let Some(row) = row else {
                    return Err(CalibrationError::MissingSegment {
                        sensor,
                        segment: k + 1,
                    });
                };
                segments.push(row.segment);
                lines.push(row.line);
            }
            check_segments(&segments, Some(sensor), Some(&lines))?;
            let segments: [Segment; SEGMENTS] = segments
                .try_into()
                .map_err(|_| CalibrationError::SegmentCount { found: 0 })?;
            let table = Some(Table { segments });
            match sensor {
                Sensor::Temperature => file.temperature = table,
                Sensor::Level => file.level = table,
            }
        }
        Ok(file)
    }

    /// Reads and parses the calibration file at `path` (see [`CalibrationFile::parse`]);
    /// an error reading it is wrapped with the path.
    pub fn read(path: &Path) -> Result<CalibrationFile, CalibrationError> {
        let text = std::fs::read_to_string(path).map_err(|source| CalibrationError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text)
    }

    /// The CSV text: the header, then the temperature rows, then the level rows (the
    /// tables the file has), `\n` line ends, numbers in Rust's shortest round-trip
    /// form, so that [`CalibrationFile::parse`] reads it back to an equal value. A file
    /// with no table gives the header alone, which `parse` refuses.
    pub fn to_csv(&self) -> String {
        let mut out = HEADER.join(",");
        out.push('\n');
        for sensor in Sensor::ALL {
            let Some(table) = self.table(sensor) else {
                continue;
            };
            for (k, s) in table.segments().iter().enumerate() {
                out.push_str(&format!(
                    "{},{},{},{},{:?},{:?},{:?}\n",
                    sensor.name(),
                    k + 1,
                    s.raw_from,
                    s.raw_to,
                    s.a0,
                    s.a1,
                    s.a2
                ));
            }
        }
        out
    }

    /// The built-in tables of both sensors ([`Table::builtin`]).
    pub fn builtin() -> CalibrationFile {
        CalibrationFile {
            temperature: Some(Table::builtin(Sensor::Temperature)),
            level: Some(Table::builtin(Sensor::Level)),
        }
    }
}

/// Parses one row (its fields already split and trimmed): the sensor, the segment
/// number (1..=10) and the segment.
fn parse_row(line: usize, fields: &[&str]) -> Result<(Sensor, usize, Row), CalibrationError> {
    if fields.len() != HEADER.len() {
        return Err(CalibrationError::Syntax {
            line,
            what: format!(
                "expected {} comma-separated fields ({}), found {}",
                HEADER.len(),
                HEADER.join(","),
                fields.len()
            ),
        });
    }
    let sensor = Sensor::from_name(fields[0]).ok_or_else(|| CalibrationError::UnknownSensor {
        line,
        name: fields[0].to_string(),
    })?;
    let number = match fields[1].parse::<usize>() {
        Ok(n) if (1..=SEGMENTS).contains(&n) => n,
        _ => {
            return Err(CalibrationError::BadSegmentNumber {
                line,
                sensor,
                found: fields[1].to_string(),
            })
        }
    };
    let raw = |column: usize| -> Result<u32, CalibrationError> {
        let text = fields[column];
        let bad = || {
            CalibrationError::Syntax {
            line,
            what: format!(
                "{} of segment {number} of {sensor} is `{text}`, not a whole number of counts from 0 to {MAX_COUNT}",
                HEADER[column]
            ),
        }
        };
        if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad());
        }
        let value: u64 = text.parse().map_err(|_| bad())?;
        if value > u64::from(MAX_COUNT) {
            return Err(CalibrationError::RawOutOfRange {
                line: Some(line),
                sensor: Some(sensor),
                segment: number,
                column: HEADER[column],
                value,
            });
        }
        u32::try_from(value).map_err(|_| bad())
    };
    let raw_from = raw(2)?;
    let raw_to = raw(3)?;
    let coefficient = |column: usize| -> Result<f64, CalibrationError> {
        let text = fields[column];
        let value: f64 = text.parse().map_err(|_| CalibrationError::Syntax {
            line,
            what: format!(
                "{} of segment {number} of {sensor} is `{text}`, not a number",
                HEADER[column]
            ),
        })?;
        if !value.is_finite() {
            return Err(CalibrationError::NotFinite {
                line: Some(line),
                sensor: Some(sensor),
                segment: number,
                column: HEADER[column],
            });
        }
        Ok(value)
    };
    let segment = Segment {
        raw_from,
        raw_to,
        a0: coefficient(4)?,
        a1: coefficient(5)?,
        a2: coefficient(6)?,
    };
    Ok((sensor, number, Row { line, segment }))
}

/// The checks of [`Table::new`] on segments in order (segment numbers are 1-based
/// positions); `sensor` and `lines` (one per segment) go into the errors when known.
fn check_segments(
    segments: &[Segment],
    sensor: Option<Sensor>,
    lines: Option<&[usize]>,
) -> Result<(), CalibrationError> {
    for (k, s) in segments.iter().enumerate() {
        let segment = k + 1;
        let line = lines.and_then(|l| l.get(k).copied());
        for (column, value) in [("a0", s.a0), ("a1", s.a1), ("a2", s.a2)] {
            if !value.is_finite() {
                return Err(CalibrationError::NotFinite {
                    line,
                    sensor,
                    segment,
                    column,
                });
            }
        }
        for (column, value) in [("raw_from", s.raw_from), ("raw_to", s.raw_to)] {
            if value > MAX_COUNT {
                return Err(CalibrationError::RawOutOfRange {
                    line,
                    sensor,
                    segment,
                    column,
                    value: u64::from(value),
                });
            }
        }
        // Finite coefficients may still overflow: the polynomial must be finite over
        // every count it converts (the end segments also convert the counts beyond
        // them). A quadratic is largest at its ends or its vertex.
        if s.raw_from <= s.raw_to {
            let from = if k == 0 { 0 } else { s.raw_from };
            let to = if k + 1 == segments.len() {
                MAX_COUNT
            } else {
                s.raw_to
            };
            let mut points = vec![from, to];
            if s.a2 != 0.0 {
                let vertex = -s.a1 / (2.0 * s.a2);
                if vertex.is_finite() && vertex > f64::from(from) && vertex < f64::from(to) {
                    points.push(vertex as u32);
                }
            }
            if let Some(&raw) = points.iter().find(|&&r| !s.eval(r).is_finite()) {
                return Err(CalibrationError::NotFiniteOver {
                    line,
                    sensor,
                    segment,
                    raw,
                });
            }
        }
        if s.raw_from > s.raw_to {
            return Err(CalibrationError::Reversed {
                line,
                sensor,
                segment,
                raw_from: s.raw_from,
                raw_to: s.raw_to,
            });
        }
        if let Some(prev) = k.checked_sub(1).and_then(|p| segments.get(p)) {
            // prev.raw_to <= MAX_COUNT, so the sum does not overflow.
            let expected = prev.raw_to + 1;
            if s.raw_from > expected {
                return Err(CalibrationError::Gap {
                    line,
                    sensor,
                    segment,
                    raw_from: s.raw_from,
                    prev_raw_to: prev.raw_to,
                });
            }
            if s.raw_from < expected {
                return Err(CalibrationError::Overlap {
                    line,
                    sensor,
                    segment,
                    raw_from: s.raw_from,
                    prev_raw_to: prev.raw_to,
                });
            }
        }
    }
    Ok(())
}

/// Why a calibration table or file was refused.
///
/// `line` is the 1-based line of the file (absent for a table not read from a file,
/// as from [`Table::new`] or command 160); `sensor` is absent likewise; `segment` is
/// the 1-based segment number.
#[derive(Debug)]
pub enum CalibrationError {
    /// The file could not be read.
    Io {
        /// The file.
        path: PathBuf,
        /// The error reading it.
        source: std::io::Error,
    },
    /// The file has no header (nothing but blank lines and comments).
    Empty,
    /// The file has a header but no rows.
    NoRows,
    /// The first line that is not blank or a comment is not the header.
    Header {
        /// Its line.
        line: usize,
        /// The line found (trimmed).
        found: String,
    },
    /// A row is not well formed: the wrong number of fields, or a field that is not a
    /// number.
    Syntax {
        /// Its line.
        line: usize,
        /// What is wrong.
        what: String,
    },
    /// A row names a sensor that is neither `temperature` nor `level`.
    UnknownSensor {
        /// Its line.
        line: usize,
        /// The name found.
        name: String,
    },
    /// A row's segment number is not 1 to 10.
    BadSegmentNumber {
        /// Its line.
        line: usize,
        /// The sensor of the row.
        sensor: Sensor,
        /// The segment field found.
        found: String,
    },
    /// A sensor has a second row for the same segment.
    DuplicateSegment {
        /// The line of the second row.
        line: usize,
        /// The sensor.
        sensor: Sensor,
        /// The segment.
        segment: usize,
        /// The line of the first row.
        first_line: usize,
    },
    /// A sensor named in the file has no row for a segment.
    MissingSegment {
        /// The sensor.
        sensor: Sensor,
        /// The missing segment.
        segment: usize,
    },
    /// A table does not have exactly 10 segments.
    SegmentCount {
        /// How many it has.
        found: usize,
    },
    /// A coefficient is infinite or not a number.
    NotFinite {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// The column: `a0`, `a1` or `a2`.
        column: &'static str,
    },
    /// A segment's polynomial is not finite somewhere over the counts it converts
    /// (finite coefficients whose products overflow a double).
    NotFiniteOver {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// A count where it is not finite.
        raw: u32,
    },
    /// A raw count is above [`MAX_COUNT`].
    RawOutOfRange {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// The column: `raw_from` or `raw_to`.
        column: &'static str,
        /// The count found.
        value: u64,
    },
    /// A segment ends before it starts (`raw_from > raw_to`).
    Reversed {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// Its first count.
        raw_from: u32,
        /// Its last count.
        raw_to: u32,
    },
    /// A segment starts after the count following the previous segment's end.
    Gap {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// Its first count.
        raw_from: u32,
        /// The previous segment's last count.
        prev_raw_to: u32,
    },
    /// A segment starts at or before the previous segment's end.
    Overlap {
        /// Its line.
        line: Option<usize>,
        /// The sensor.
        sensor: Option<Sensor>,
        /// The segment.
        segment: usize,
        /// Its first count.
        raw_from: u32,
        /// The previous segment's last count.
        prev_raw_to: u32,
    },
}

impl CalibrationError {
    /// The 1-based line of the file the error is on, if there is one.
    pub fn line(&self) -> Option<usize> {
        use CalibrationError as E;
        match self {
            E::Header { line, .. }
            | E::Syntax { line, .. }
            | E::UnknownSensor { line, .. }
            | E::BadSegmentNumber { line, .. }
            | E::DuplicateSegment { line, .. } => Some(*line),
            E::NotFinite { line, .. }
            | E::NotFiniteOver { line, .. }
            | E::RawOutOfRange { line, .. }
            | E::Reversed { line, .. }
            | E::Gap { line, .. }
            | E::Overlap { line, .. } => *line,
            E::Io { .. }
            | E::Empty
            | E::NoRows
            | E::MissingSegment { .. }
            | E::SegmentCount { .. } => None,
        }
    }
}

/// "segment 4 of level", or "segment 4" when the sensor is not known.
struct Subject(usize, Option<Sensor>);

impl fmt::Display for Subject {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.1 {
            Some(sensor) => write!(f, "segment {} of {sensor}", self.0),
            None => write!(f, "segment {}", self.0),
        }
    }
}

impl fmt::Display for CalibrationError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        use CalibrationError as E;
        if let Some(line) = self.line() {
            write!(f, "line {line}: ")?;
        }
        let header = HEADER.join(",");
        match self {
            E::Io { path, source } => write!(
                f,
                "cannot read calibration file {}: {source} (check the path, that it is a readable UTF-8 text file)",
                path.display()
            ),
            E::Empty => write!(
                f,
                "the calibration file is empty: it needs the header `{header}` and the rows of at least one sensor"
            ),
            E::NoRows => write!(
                f,
                "the calibration file has a header but no rows: it needs segments 1 to 10 of at least one sensor (temperature or level)"
            ),
            E::Header { found, .. } => write!(
                f,
                "expected the header `{header}`, found `{found}` (the first line that is not blank or a # comment must be the header)"
            ),
            E::Syntax { what, .. } => f.write_str(what),
            E::UnknownSensor { name, .. } => write!(
                f,
                "unknown sensor `{name}`: the sensor must be `temperature` or `level`"
            ),
            E::BadSegmentNumber { sensor, found, .. } => write!(
                f,
                "segment `{found}` of {sensor} is not a segment number: segments are numbered 1 to {SEGMENTS}"
            ),
            E::DuplicateSegment {
                sensor,
                segment,
                first_line,
                ..
            } => write!(
                f,
                "segment {segment} of {sensor} appears again (first on line {first_line}): each segment may appear only once per sensor"
            ),
            E::MissingSegment { sensor, segment } => write!(
                f,
                "segment {segment} of {sensor} is missing: a sensor named in the file needs each of segments 1 to {SEGMENTS}"
            ),
            E::SegmentCount { found } => write!(
                f,
                "a table has exactly {SEGMENTS} segments, this one has {found}"
            ),
            E::NotFinite {
                sensor,
                segment,
                column,
                ..
            } => write!(
                f,
                "{column} of {} is not finite (infinite or NaN, or too large for a double): check the coefficient",
                Subject(*segment, *sensor)
            ),
            E::NotFiniteOver {
                sensor,
                segment,
                raw,
                ..
            } => write!(
                f,
                "the polynomial of {} is not finite at count {raw} (its terms overflow a double): check the coefficients",
                Subject(*segment, *sensor)
            ),
            E::RawOutOfRange {
                sensor,
                segment,
                column,
                value,
                ..
            } => write!(
                f,
                "{column} of {} is {value}, above the largest count {MAX_COUNT} (counts are 24 bits, and {} marks \"no value\")",
                Subject(*segment, *sensor),
                MAX_COUNT + 1
            ),
            E::Reversed {
                sensor,
                segment,
                raw_from,
                raw_to,
                ..
            } => write!(
                f,
                "{} starts at {raw_from} but ends at {raw_to}: raw_from must not be above raw_to",
                Subject(*segment, *sensor)
            ),
            E::Gap {
                sensor,
                segment,
                raw_from,
                prev_raw_to,
                ..
            }
            | E::Overlap {
                sensor,
                segment,
                raw_from,
                prev_raw_to,
                ..
            } => write!(
                f,
                "{} starts at {raw_from}, but segment {} ends at {prev_raw_to}: segment {segment} must start at {} ({})",
                Subject(*segment, *sensor),
                segment.saturating_sub(1),
                u64::from(*prev_raw_to) + 1,
                if matches!(self, E::Gap { .. }) {
                    "a gap"
                } else {
                    "an overlap"
                }
            ),
        }
    }
}

impl std::error::Error for CalibrationError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            CalibrationError::Io { source, .. } => Some(source),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn span(sensor: Sensor) -> f64 {
        let (lo, hi) = sensor.range();
        hi - lo
    }

    /// 10 001 evenly spaced counts, plus every segment boundary and its neighbours.
    fn test_counts(table: &Table) -> Vec<u32> {
        let mut v: Vec<u32> = (0..=10_000u64)
            .map(|i| (i * u64::from(MAX_COUNT) / 10_000) as u32)
            .collect();
        for s in table.segments() {
            for r in [s.raw_from, s.raw_to] {
                v.extend([r.saturating_sub(1), r, (r + 1).min(MAX_COUNT)]);
            }
        }
        v
    }

    #[test]
    fn sensor_names_and_codes() {
        for s in Sensor::ALL {
            assert_eq!(Sensor::from_name(s.name()), Some(s));
            assert_eq!(Sensor::from_code(s.code()), Some(s));
            assert_eq!(s.to_string(), s.name());
        }
        assert_eq!(Sensor::Temperature.code(), 0);
        assert_eq!(Sensor::Level.code(), 1);
        assert_eq!(Sensor::Temperature.unit(), "°C");
        assert_eq!(Sensor::Level.unit(), "m");
        assert_eq!(Sensor::Temperature.range(), (-10.0, 40.0));
        assert_eq!(Sensor::Level.range(), (0.0, 20.0));
        assert_eq!(Sensor::from_name("Level"), None);
        assert_eq!(Sensor::from_code(2), None);
    }

    #[test]
    fn sensor_counts_ends_bow_and_clamping() {
        for s in Sensor::ALL {
            let (lo, hi) = s.range();
            assert_eq!(sensor_counts(s, lo), 0);
            assert_eq!(sensor_counts(s, hi), MAX_COUNT);
            assert_eq!(sensor_counts(s, lo - 1.0), 0);
            assert_eq!(sensor_counts(s, hi + 1.0), MAX_COUNT);
            assert_eq!(sensor_counts(s, f64::INFINITY), MAX_COUNT);
            assert_eq!(sensor_counts(s, f64::NEG_INFINITY), 0);
            assert_eq!(sensor_counts(s, f64::NAN), 0);
            assert_eq!(sensor_counts(s, 1e300), MAX_COUNT);
            // Mid-range: the bow is 0.4 % of full scale.
            let mid = sensor_counts(s, 0.5 * (lo + hi));
            let linear = f64::from(MAX_COUNT) * 0.5;
            let bow = (f64::from(mid) - linear) / f64::from(MAX_COUNT);
            assert!((bow - 0.004).abs() < 1e-7, "{bow}");
        }
        // The published example's temperature counts 0x7AE148 (14.0 °C if linear) are
        // 13.80 °C through the bow.
        let x = Table::builtin(Sensor::Temperature).eval(0x7A_E148);
        assert!((x - 13.8005).abs() < 1e-3, "{x}");
    }

    #[test]
    fn builtin_undoes_sensor_counts() {
        for sensor in Sensor::ALL {
            let table = Table::builtin(sensor);
            let tol = 1e-6 * span(sensor);
            let mut worst = 0.0f64;
            for raw in test_counts(&table) {
                let exact = inverse_counts(sensor, f64::from(raw));
                let x = table.eval(raw);
                worst = worst.max((x - exact).abs());
                assert!(
                    (x - exact).abs() <= tol,
                    "{sensor} raw {raw}: {x} vs {exact}"
                );
                // Through the transfer function and back.
                let back = table.eval(sensor_counts(sensor, exact));
                assert!(
                    (back - exact).abs() <= tol,
                    "{sensor} raw {raw}: {back} vs {exact}"
                );
            }
            let (lo, hi) = sensor.range();
            for i in 0..=10_000 {
                let x = lo + (hi - lo) * f64::from(i) / 10_000.0;
                let back = table.eval(sensor_counts(sensor, x));
                worst = worst.max((back - x).abs());
                assert!((back - x).abs() <= tol, "{sensor} {x}: {back}");
            }
            assert!(worst <= tol, "{sensor}: {worst}");
        }
    }

    #[test]
    fn builtin_layout() {
        for sensor in Sensor::ALL {
            let table = Table::builtin(sensor);
            let segs = table.segments();
            assert_eq!(segs.len(), SEGMENTS);
            assert_eq!(segs[0].raw_from, 0);
            assert_eq!(segs[0].raw_to, 1_677_720);
            assert_eq!(segs[1].raw_from, 1_677_721);
            assert_eq!(segs[9].raw_to, MAX_COUNT);
            assert_eq!(Table::new(segs.to_vec()).unwrap(), table);
        }
    }

    #[test]
    fn table_new_accepts_builtin_and_other_start() {
        let mut segs = Table::builtin(Sensor::Level).segments().to_vec();
        assert_eq!(
            Table::new(segs.clone()).unwrap(),
            Table::builtin(Sensor::Level)
        );
        segs[0].raw_from = 1000;
        let t = Table::new(segs).unwrap();
        // Extrapolated below the first and evaluated at the ends.
        assert_eq!(t.eval(0), t.segments()[0].eval(0));
        assert_eq!(t.eval(MAX_COUNT), t.segments()[9].eval(MAX_COUNT));
    }

    #[test]
    fn table_eval_picks_segment_and_extrapolates() {
        let segs: Vec<Segment> = (0..10u32)
            .map(|k| Segment {
                raw_from: 100 + 10 * k,
                raw_to: 109 + 10 * k,
                a0: f64::from(k),
                a1: 0.0,
                a2: 0.0,
            })
            .collect();
        let t = Table::new(segs).unwrap();
        assert_eq!(t.eval(0), 0.0);
        assert_eq!(t.eval(100), 0.0);
        assert_eq!(t.eval(109), 0.0);
        assert_eq!(t.eval(110), 1.0);
        assert_eq!(t.eval(199), 9.0);
        assert_eq!(t.eval(200), 9.0);
        assert_eq!(t.eval(u32::MAX), 9.0);
        let s = Segment {
            raw_from: 0,
            raw_to: 0,
            a0: 1.0,
            a1: 2.0,
            a2: 3.0,
        };
        assert_eq!(s.eval(10), 321.0);
    }

    #[test]
    fn table_new_errors() {
        let good = Table::builtin(Sensor::Temperature).segments().to_vec();
        let err = Table::new(good[..9].to_vec()).unwrap_err();
        assert!(
            matches!(err, CalibrationError::SegmentCount { found: 9 }),
            "{err}"
        );
        let mut v = good.clone();
        v.push(good[9]);
        assert!(matches!(
            Table::new(v).unwrap_err(),
            CalibrationError::SegmentCount { found: 11 }
        ));

        let mut v = good.clone();
        v[3].a1 = f64::NAN;
        let err = Table::new(v).unwrap_err();
        assert!(
            matches!(
                err,
                CalibrationError::NotFinite {
                    line: None,
                    sensor: None,
                    segment: 4,
                    column: "a1"
                }
            ),
            "{err}"
        );
        assert!(!err.to_string().contains("line"));

        let mut v = good.clone();
        v[9].raw_to = MAX_COUNT + 1;
        let err = Table::new(v).unwrap_err();
        assert!(
            matches!(err, CalibrationError::RawOutOfRange { segment: 10, .. }),
            "{err}"
        );

        let mut v = good.clone();
        v[2].raw_to = v[2].raw_from - 1;
        let err = Table::new(v).unwrap_err();
        assert!(
            matches!(err, CalibrationError::Reversed { segment: 3, .. }),
            "{err}"
        );

        let mut v = good.clone();
        v[4].raw_from += 1;
        let err = Table::new(v).unwrap_err();
        assert!(
            matches!(err, CalibrationError::Gap { segment: 5, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("(a gap)"), "{err}");

        let mut v = good.clone();
        v[4].raw_from -= 1;
        let err = Table::new(v).unwrap_err();
        assert!(
            matches!(err, CalibrationError::Overlap { segment: 5, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("(an overlap)"), "{err}");
    }

    #[test]
    fn csv_round_trip() {
        let file = CalibrationFile::builtin();
        let text = file.to_csv();
        assert!(
            text.starts_with("sensor,segment,raw_from,raw_to,a0,a1,a2\ntemperature,1,0,1677720,")
        );
        assert_eq!(text.lines().count(), 21);
        assert_eq!(CalibrationFile::parse(&text).unwrap(), file);

        // Awkward numbers survive too.
        let mut segs = Table::builtin(Sensor::Level).segments().to_vec();
        segs[0].a0 = -0.0;
        segs[1].a1 = 1e-300;
        segs[2].a2 = f64::MIN_POSITIVE / 4.0; // subnormal
        segs[3].a0 = f64::MAX;
        segs[4].a0 = 0.1 + 0.2;
        let file = CalibrationFile {
            temperature: None,
            level: Some(Table::new(segs).unwrap()),
        };
        let back = CalibrationFile::parse(&file.to_csv()).unwrap();
        assert_eq!(back, file);
        for (a, b) in back
            .level
            .unwrap()
            .segments()
            .iter()
            .zip(file.level.unwrap().segments())
        {
            assert_eq!(a.a0.to_bits(), b.a0.to_bits());
            assert_eq!(a.a1.to_bits(), b.a1.to_bits());
            assert_eq!(a.a2.to_bits(), b.a2.to_bits());
        }
    }

    #[test]
    fn one_sensor_file() {
        let only_level = CalibrationFile {
            temperature: None,
            level: Some(Table::builtin(Sensor::Level)),
        };
        let text = only_level.to_csv();
        assert!(!text.contains("temperature"));
        let parsed = CalibrationFile::parse(&text).unwrap();
        assert_eq!(parsed, only_level);
        assert!(parsed.table(Sensor::Temperature).is_none());
        assert_eq!(
            parsed.table(Sensor::Level),
            Some(&Table::builtin(Sensor::Level))
        );
    }

    #[test]
    fn crlf_comments_whitespace_any_order_exponents() {
        let file = CalibrationFile::builtin();
        let csv = file.to_csv();
        let mut lines: Vec<&str> = csv.lines().collect();
        let header = lines.remove(0);
        lines.reverse(); // rows in any order, sensors interleaved
        let mut text = String::from("\u{feff}# calibration of well 3\r\n\r\n   \r\n");
        text.push_str(&format!("  {}  \r\n", header.replace(',', " , ")));
        for (i, l) in lines.iter().enumerate() {
            if i % 3 == 0 {
                text.push_str("# a comment\r\n\t\r\n");
            }
            text.push_str(&format!("\t{} \r\n", l.replace(',', ", ")));
        }
        assert_eq!(CalibrationFile::parse(&text).unwrap(), file);

        // Exponent notation and plain integers as coefficients.
        let mut text = String::from("sensor,segment,raw_from,raw_to,a0,a1,a2\n");
        for k in 0..10u32 {
            text.push_str(&format!(
                "level,{},{},{},-1E1,2.98e-6,12\n",
                k + 1,
                k * 100,
                k * 100 + 99
            ));
        }
        let f = CalibrationFile::parse(&text).unwrap();
        let s = f.level.unwrap().segments()[0];
        assert_eq!((s.a0, s.a1, s.a2), (-10.0, 2.98e-6, 12.0));
    }

    #[test]
    fn read_file_and_io_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cal.csv");
        std::fs::write(&path, CalibrationFile::builtin().to_csv()).unwrap();
        assert_eq!(
            CalibrationFile::read(&path).unwrap(),
            CalibrationFile::builtin()
        );
        let missing = dir.path().join("nope.csv");
        let err = CalibrationFile::read(&missing).unwrap_err();
        assert!(matches!(err, CalibrationError::Io { .. }));
        assert!(err.to_string().contains("nope.csv"), "{err}");
        assert!(std::error::Error::source(&err).is_some());
        assert_eq!(err.line(), None);
    }

    /// The builtin file's text with row `line` (1-based, header is line 1) replaced.
    fn with_line(line: usize, new: &str) -> String {
        let csv = CalibrationFile::builtin().to_csv();
        let mut lines: Vec<String> = csv.lines().map(String::from).collect();
        lines[line - 1] = new.to_string();
        lines.join("\n")
    }

    /// A level row with the builtin coefficients and the given fields.
    fn level_row(segment: &str, raw_from: &str, raw_to: &str) -> String {
        format!("level,{segment},{raw_from},{raw_to},1.5,2e-6,3e-15")
    }

    fn assert_err(text: &str, line: Option<usize>, check: impl Fn(&CalibrationError) -> bool) {
        let err = CalibrationFile::parse(text).unwrap_err();
        assert!(check(&err), "unexpected error: {err:?}");
        assert_eq!(err.line(), line, "{err}");
        let msg = err.to_string();
        match line {
            Some(l) => assert!(msg.starts_with(&format!("line {l}: ")), "{msg}"),
            None => assert!(!msg.starts_with("line "), "{msg}"),
        }
    }

    #[test]
    fn parse_errors_name_their_line() {
        use CalibrationError as E;
        // Line 1 header, lines 2-11 temperature 1-10, lines 12-21 level 1-10.
        assert_err("", None, |e| matches!(e, E::Empty));
        assert_err("# only\n\n  \r\n", None, |e| matches!(e, E::Empty));
        assert_err(
            "sensor,segment,raw_from,raw_to,a0,a1,a2\n# none\n",
            None,
            |e| matches!(e, E::NoRows),
        );
        assert_err(
            "\n# x\nsensor,segment,raw_from,raw_to,a0,a1\n",
            Some(3),
            |e| matches!(e, E::Header { line: 3, .. }),
        );
        assert_err("Sensor,segment,raw_from,raw_to,a0,a1,a2\n", Some(1), |e| {
            matches!(e, E::Header { .. })
        });
        // Wrong field count, bad integers, bad floats.
        assert_err(&with_line(5, "temperature,4,0,1"), Some(5), |e| {
            matches!(e, E::Syntax { line: 5, .. })
        });
        assert_err(
            &with_line(12, &level_row("1", "-0", "1677720")),
            Some(12),
            |e| matches!(e, E::Syntax { .. }),
        );
        assert_err(
            &with_line(12, &level_row("1", "0", "1.5e6")),
            Some(12),
            |e| matches!(e, E::Syntax { .. }),
        );
        assert_err(&with_line(12, &level_row("1", "0", "")), Some(12), |e| {
            matches!(e, E::Syntax { .. })
        });
        assert_err(
            &with_line(12, &level_row("1", "0", "99999999999999999999999")),
            Some(12),
            |e| matches!(e, E::Syntax { .. }),
        );
        assert_err(
            &with_line(13, "level,2,1677721,3355441,1.5,x,0"),
            Some(13),
            |e| matches!(e, E::Syntax { .. }),
        );
        // Unknown sensor, bad segment numbers, duplicates, missing segments.
        assert_err(
            &with_line(7, "pressure,6,0,1,0,0,0"),
            Some(7),
            |e| matches!(e, E::UnknownSensor { line: 7, name } if name == "pressure"),
        );
        for bad in ["0", "11", "x", "-1", "1.0", ""] {
            assert_err(&with_line(8, &level_row(bad, "0", "1")), Some(8), |e| {
                matches!(
                    e,
                    E::BadSegmentNumber {
                        line: 8,
                        sensor: Sensor::Level,
                        ..
                    }
                )
            });
        }
        let csv = CalibrationFile::builtin().to_csv();
        let lines: Vec<&str> = csv.lines().collect();
        let dup = with_line(20, lines[13]); // level segment 3 again on line 20
        assert_err(&dup, Some(20), |e| {
            matches!(
                e,
                E::DuplicateSegment {
                    line: 20,
                    sensor: Sensor::Level,
                    segment: 3,
                    first_line: 14
                }
            )
        });
        assert!(CalibrationFile::parse(&dup)
            .unwrap_err()
            .to_string()
            .contains("line 14"));
        let missing = with_line(6, "# segment 5 removed");
        assert_err(&missing, None, |e| {
            matches!(
                e,
                E::MissingSegment {
                    sensor: Sensor::Temperature,
                    segment: 5
                }
            )
        });
        // Not finite.
        for bad in ["inf", "-inf", "NaN", "1e999"] {
            assert_err(
                &with_line(12, &format!("level,1,0,1677720,0,{bad},0")),
                Some(12),
                |e| {
                    matches!(
                        e,
                        E::NotFinite {
                            line: Some(12),
                            sensor: Some(Sensor::Level),
                            segment: 1,
                            column: "a1"
                        }
                    )
                },
            );
        }
        // Raw above MAX_COUNT.
        assert_err(
            &with_line(21, &level_row("10", "15099494", "16777215")),
            Some(21),
            |e| {
                matches!(
                    e,
                    E::RawOutOfRange {
                        line: Some(21),
                        segment: 10,
                        column: "raw_to",
                        value: 16_777_215,
                        ..
                    }
                )
            },
        );
        // Reversed.
        assert_err(
            &with_line(15, &level_row("4", "5033163", "5033162")),
            Some(15),
            |e| {
                matches!(
                    e,
                    E::Reversed {
                        line: Some(15),
                        segment: 4,
                        ..
                    }
                )
            },
        );
    }

    #[test]
    fn gap_and_overlap_messages() {
        // Level segment 4 (line 15) starts at 5033164 in the builtin table.
        let gap = with_line(15, &level_row("4", "5033170", "6710885"));
        let err = CalibrationFile::parse(&gap).unwrap_err();
        assert_eq!(
            err.to_string(),
            "line 15: segment 4 of level starts at 5033170, but segment 3 ends at 5033163: \
             segment 4 must start at 5033164 (a gap)"
        );
        let overlap = with_line(15, &level_row("4", "5033100", "6710885"));
        let err = CalibrationFile::parse(&overlap).unwrap_err();
        assert!(matches!(
            err,
            CalibrationError::Overlap { line: Some(15), .. }
        ));
        assert_eq!(
            err.to_string(),
            "line 15: segment 4 of level starts at 5033100, but segment 3 ends at 5033163: \
             segment 4 must start at 5033164 (an overlap)"
        );
        // The line named is the file's, even when rows are out of order.
        let csv = CalibrationFile::builtin().to_csv();
        let mut lines: Vec<String> = csv.lines().map(String::from).collect();
        lines[14] = level_row("4", "5033170", "6710885");
        lines.swap(14, 20); // segment 4 now on line 21
        let err = CalibrationFile::parse(&lines.join("\n")).unwrap_err();
        assert!(
            matches!(
                err,
                CalibrationError::Gap {
                    line: Some(21),
                    segment: 4,
                    ..
                }
            ),
            "{err}"
        );
        assert!(
            err.to_string().starts_with("line 21: segment 4 of level"),
            "{err}"
        );
    }

    #[test]
    fn every_error_displays() {
        let errs = [
            CalibrationError::Empty,
            CalibrationError::NoRows,
            CalibrationError::SegmentCount { found: 3 },
            CalibrationError::MissingSegment {
                sensor: Sensor::Level,
                segment: 2,
            },
        ];
        for e in errs {
            assert!(!e.to_string().is_empty());
            assert_eq!(e.line(), None);
            assert!(std::error::Error::source(&e).is_none());
        }
    }

    /// A mutation of a text, chosen by proptest.
    #[derive(Debug, Clone)]
    enum Mutation {
        Delete(usize, usize),
        Insert(usize, String),
        ReplaceLine(usize, String),
        SwapLines(usize, usize),
        DuplicateLine(usize),
        ReplaceField(usize, usize, String),
    }

    fn mutation() -> impl Strategy<Value = Mutation> {
        let text = prop_oneof![
            "\\PC{0,12}",
            "[0-9eE+\\-.,#\\r\\n ]{0,12}",
            Just("inf".to_string()),
            Just("NaN".to_string()),
            Just("16777215".to_string()),
            Just("18446744073709551616".to_string()),
            Just("level".to_string()),
            Just("temperature".to_string()),
            Just("0".to_string()),
            Just("11".to_string()),
        ];
        prop_oneof![
            (any::<usize>(), 0usize..20).prop_map(|(a, n)| Mutation::Delete(a, n)),
            (any::<usize>(), text.clone()).prop_map(|(a, s)| Mutation::Insert(a, s)),
            (any::<usize>(), text.clone()).prop_map(|(a, s)| Mutation::ReplaceLine(a, s)),
            (any::<usize>(), any::<usize>()).prop_map(|(a, b)| Mutation::SwapLines(a, b)),
            any::<usize>().prop_map(Mutation::DuplicateLine),
            (any::<usize>(), 0usize..8, text).prop_map(|(a, f, s)| Mutation::ReplaceField(a, f, s)),
        ]
    }

    fn apply(text: &str, m: &Mutation) -> String {
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        let n = lines.len().max(1);
        match m {
            Mutation::Delete(at, len) => {
                let chars: Vec<char> = text.chars().collect();
                let at = at % (chars.len() + 1);
                let end = (at + len).min(chars.len());
                return chars[..at].iter().chain(&chars[end..]).collect();
            }
            Mutation::Insert(at, s) => {
                let chars: Vec<char> = text.chars().collect();
                let at = at % (chars.len() + 1);
                let mut out: String = chars[..at].iter().collect();
                out.push_str(s);
                out.extend(&chars[at..]);
                return out;
            }
            Mutation::ReplaceLine(i, s) => {
                if let Some(l) = lines.get_mut(i % n) {
                    *l = s.clone();
                }
            }
            Mutation::SwapLines(a, b) => {
                if !lines.is_empty() {
                    lines.swap(a % n, b % n);
                }
            }
            Mutation::DuplicateLine(i) => {
                if let Some(l) = lines.get(i % n).cloned() {
                    lines.insert(i % n, l);
                }
            }
            Mutation::ReplaceField(i, f, s) => {
                if let Some(l) = lines.get_mut(i % n) {
                    let mut fields: Vec<String> = l.split(',').map(String::from).collect();
                    let f = f % fields.len().max(1);
                    if let Some(x) = fields.get_mut(f) {
                        *x = s.clone();
                    }
                    *l = fields.join(",");
                }
            }
        }
        lines.join("\n")
    }

    proptest! {
        #[test]
        fn parse_never_panics_on_arbitrary_text(s in any::<String>()) {
            let _ = CalibrationFile::parse(&s);
        }

        #[test]
        fn parse_never_panics_on_csv_like_text(s in "[a-z0-9,.eE+\\-#\\r\\n ]{0,400}") {
            let _ = CalibrationFile::parse(&s);
        }

        #[test]
        fn parse_never_panics_on_mutated_files(
            ms in proptest::collection::vec(mutation(), 1..6),
            only_level in any::<bool>(),
        ) {
            let file = if only_level {
                CalibrationFile { temperature: None, level: Some(Table::builtin(Sensor::Level)) }
            } else {
                CalibrationFile::builtin()
            };
            let mut text = file.to_csv();
            for m in &ms {
                text = apply(&text, m);
            }
            match CalibrationFile::parse(&text) {
                // Whatever is accepted is a valid file that round-trips.
                Ok(f) => {
                    prop_assert!(f.temperature.is_some() || f.level.is_some());
                    prop_assert_eq!(CalibrationFile::parse(&f.to_csv()).unwrap(), f);
                }
                Err(e) => {
                    let _ = e.to_string();
                }
            }
        }

        #[test]
        fn table_new_never_panics(
            segs in proptest::collection::vec(
                (any::<u32>(), any::<u32>(), any::<f64>(), any::<f64>(), any::<f64>()),
                0..12,
            ),
            raw in any::<u32>(),
        ) {
            let segs: Vec<Segment> = segs
                .into_iter()
                .map(|(raw_from, raw_to, a0, a1, a2)| Segment { raw_from, raw_to, a0, a1, a2 })
                .collect();
            if let Ok(t) = Table::new(segs) {
                let _ = t.eval(raw);
            }
        }

        #[test]
        fn sensor_counts_never_panics_and_is_monotonic(x in any::<f64>(), d in 0.0f64..1.0) {
            for s in Sensor::ALL {
                let c = sensor_counts(s, x);
                prop_assert!(c <= MAX_COUNT);
                if x.is_finite() {
                    prop_assert!(sensor_counts(s, x + d) >= c);
                }
            }
        }
    }

    #[test]
    fn finite_coefficients_whose_terms_overflow_are_refused() {
        let mut segs = Table::builtin(Sensor::Temperature).segments().to_vec();
        segs[3].a1 = 1e308;
        segs[3].a2 = -1e308;
        let e = Table::new(segs).unwrap_err();
        assert!(
            matches!(e, CalibrationError::NotFiniteOver { segment: 4, .. }),
            "{e:?}"
        );
        assert!(e.to_string().contains("segment 4"), "{e}");
        // The end segments convert the counts beyond them too.
        let mut segs = Table::builtin(Sensor::Level).segments().to_vec();
        segs[9].a2 = 1e300;
        assert!(matches!(
            Table::new(segs),
            Err(CalibrationError::NotFiniteOver { segment: 10, .. })
        ));
    }
}
