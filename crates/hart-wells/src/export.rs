//! The PC's exports and plots (docs/wells.md, "The PC: exports and plots"): the
//! archive's minutes, or their averages over a period ([`crate::average`]), as CSV,
//! as GeoJSON points for a GIS (each well at its place, read from a wells file), and
//! as a PNG of the level and temperature trends.
//!
//! Ranges are of minutes (Unix time / 60), `from` and `to` both included, as
//! [`Archive::range`] takes them; `from = 0` and `to = u32::MAX` ask for everything
//! stored. Times in the outputs are ISO 8601 UTC (`2026-03-01T00:00:00Z`), each row
//! or feature at the start of its period.

use std::fmt;
use std::io::{self, BufWriter, Write};
use std::path::Path;

use chrono::{NaiveDate, NaiveDateTime, NaiveTime, Timelike};
use serde_json::{json, Map, Value};

use crate::archive::Archive;
use crate::average::{averages, date_of, minute_of_date, period_of, Average, Every};
use crate::store::StoreError;

/// Why an export or a plot failed.
#[derive(Debug)]
pub enum ExportError {
    /// The archive could not be read.
    Store(StoreError),
    /// The output could not be written.
    Write {
        /// Where it was going.
        to: String,
        /// What happened.
        error: io::Error,
    },
    /// A line of the wells file is wrong.
    WellsFile {
        /// The line, counting from 1.
        line: usize,
        /// What is wrong and how to put it right.
        problem: String,
    },
    /// Wells to put on a map have no place in the wells file.
    NoPlace {
        /// The wells.
        wells: Vec<u8>,
    },
    /// A well asked for has no minutes in the archive.
    NoSuchWell {
        /// The well.
        well: u8,
        /// The wells the archive has minutes of.
        held: Vec<u8>,
    },
    /// The wells asked for have no minutes in the range (nothing to plot).
    NoData {
        /// The wells.
        wells: Vec<u8>,
        /// The range's first minute.
        from: u32,
        /// Its last minute.
        to: u32,
    },
    /// `from` is after `to`.
    BadRange {
        /// The range's first minute.
        from: u32,
        /// Its last minute.
        to: u32,
    },
    /// The plot could not be drawn (its size, or the drawing library).
    Plot(String),
}

fn list(wells: &[u8]) -> String {
    let v: Vec<String> = wells.iter().map(|w| w.to_string()).collect();
    match v.len() {
        0 => "none".into(),
        1 => v[0].clone(),
        _ => format!("{} and {}", v[..v.len() - 1].join(", "), v[v.len() - 1]),
    }
}

/// `2026-03-01 00:00`.
fn when(minute: u32) -> String {
    let s = iso8601(minute);
    format!("{} {}", &s[..10], &s[11..16])
}

impl fmt::Display for ExportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ExportError::Store(e) => write!(
                f,
                "cannot read the archive: {e}; check that the file is the PC's archive \
                 (written by `wells pc pull` or `wells sim`)"
            ),
            ExportError::Write { to, error } => write!(
                f,
                "cannot write {to}: {error}; check that the directory exists, is writable \
                 and has room"
            ),
            ExportError::WellsFile { line, problem } => {
                write!(f, "wells file, line {line}: {problem}")
            }
            ExportError::NoPlace { wells } => write!(
                f,
                "{} {} minutes in the archive but no place in the wells file (a point on a \
                 map needs coordinates): add a line `well,name,latitude,longitude` for {}, \
                 or choose the wells to export",
                if wells.len() == 1 { "well" } else { "wells" },
                if wells.len() == 1 {
                    format!("{} has", wells[0])
                } else {
                    format!("{} have", list(wells))
                },
                if wells.len() == 1 { "it" } else { "each" }
            ),
            ExportError::NoSuchWell { well, held } => write!(
                f,
                "the archive has no minutes of well {well} (it holds wells {}); check the \
                 well number and that the archive is the right one",
                list(held)
            ),
            ExportError::NoData { wells, from, to } => write!(
                f,
                "no minutes of {} {} between {} and {} UTC; check the range against what \
                 the archive holds",
                if wells.len() == 1 { "well" } else { "wells" },
                list(wells),
                when(*from),
                when(*to)
            ),
            ExportError::BadRange { from, to } => write!(
                f,
                "the range starts ({} UTC) after it ends ({} UTC); check the order of the \
                 dates",
                when(*from),
                when(*to)
            ),
            ExportError::Plot(e) => write!(f, "cannot draw the plot: {e}"),
        }
    }
}

impl std::error::Error for ExportError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            ExportError::Store(e) => Some(e),
            ExportError::Write { error, .. } => Some(error),
            _ => None,
        }
    }
}

impl From<StoreError> for ExportError {
    fn from(e: StoreError) -> Self {
        ExportError::Store(e)
    }
}

/// Opens an existing archive (the PC's, or the handheld's) to export from, refusing
/// what is not one: a path that does not exist (instead of creating an empty
/// archive there), a directory, an empty file, a file that is not SQLite, or an
/// SQLite file without the archive's table of minutes (such as a concentrator's
/// store). The message says what to check.
pub fn open_archive(path: &Path) -> Result<Archive, String> {
    let shown = path.display();
    let hint = "the PC's archive is the file `wells pc pull --db FILE` writes \
                (DIR/pc.db after `wells sim --dir DIR`)";
    let meta = match std::fs::metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(format!("no archive at {shown}: {hint}; check the path"))
        }
        Err(e) => return Err(format!("cannot read {shown}: {e}")),
    };
    if meta.is_dir() {
        return Err(format!("{shown} is a directory; {hint}"));
    }
    let mut head = [0u8; 16];
    let n = std::fs::File::open(path)
        .and_then(|mut f| io::Read::read(&mut f, &mut head))
        .map_err(|e| format!("cannot read {shown}: {e}"))?;
    if n == 0 {
        return Err(format!("{shown} is empty, not an archive; {hint}"));
    }
    if n < 16 || &head != b"SQLite format 3\0" {
        return Err(format!("{shown} is not an SQLite database; {hint}"));
    }
    // A look without writing: Archive::open would add its tables to any database.
    if let Ok(c) =
        rusqlite::Connection::open_with_flags(path, rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY)
    {
        if let Err(e) =
            c.prepare("SELECT well, minute, valid, temperature, level FROM minutes LIMIT 0")
        {
            let e = e.to_string();
            if e.contains("no such table") || e.contains("no such column") {
                return Err(format!(
                    "{shown} is an SQLite database but not an archive (it has no minutes of \
                     wells: a concentrator's store?); {hint}"
                ));
            }
        }
    }
    Archive::open(path, crate::store::Durability::Process)
        .map_err(|e| format!("{}", ExportError::Store(e)))
}

/// A minute (Unix time / 60) as ISO 8601 UTC: `2026-03-01T00:00:00Z`.
pub fn iso8601(minute: u32) -> String {
    let d = date_of(minute);
    let m = minute % 1440;
    format!("{}T{:02}:{:02}:00Z", d.format("%Y-%m-%d"), m / 60, m % 60)
}

/// Reads a time a person wrote (UTC): `2026-03-01`, `2026-03-01T12:00`,
/// `2026-03-01T12:00:00Z` (a space for the `T`, and `Z` or nothing at the end).
/// Returns the minute (seconds are dropped) and whether it was a date alone.
fn parse_time(s: &str) -> Result<(u32, bool), String> {
    let t = s.trim();
    let body = t
        .strip_suffix('Z')
        .or_else(|| t.strip_suffix('z'))
        .unwrap_or(t);
    let body = body.replacen(' ', "T", 1);
    let bad = || {
        format!(
            "`{s}` is not a date: write 2026-03-01, 2026-03-01T12:00 or \
             2026-03-01T12:00:00Z (UTC)"
        )
    };
    if body.len() > 19 && (body.contains('+') || body.get(10..).is_some_and(|t| t.contains('-'))) {
        return Err(format!(
            "`{s}`: times are UTC here; write the time in UTC with Z or nothing at the end"
        ));
    }
    let dt = if let Ok(d) = NaiveDate::parse_from_str(&body, "%Y-%m-%d") {
        (d.and_time(NaiveTime::MIN), true)
    } else if let Ok(dt) = NaiveDateTime::parse_from_str(&body, "%Y-%m-%dT%H:%M") {
        (dt, false)
    } else if let Ok(dt) = NaiveDateTime::parse_from_str(&body, "%Y-%m-%dT%H:%M:%S") {
        (dt, false)
    } else {
        return Err(bad());
    };
    let minute =
        i64::from(minute_of_date(dt.0.date())) + i64::from(dt.0.hour() * 60 + dt.0.minute());
    if dt.0.date() < NaiveDate::from_ymd_opt(1970, 1, 1).expect("a date")
        || minute > i64::from(u32::MAX)
    {
        return Err(format!("`{s}` is outside the times the network can store"));
    }
    Ok((minute as u32, dt.1))
}

/// The first minute of a range from a time a person wrote (UTC): `2026-03-01` (its
/// midnight), `2026-03-01T12:00`, `2026-03-01T12:00:00Z`.
pub fn parse_from(s: &str) -> Result<u32, String> {
    parse_time(s).map(|(m, _)| m)
}

/// The last minute of a range from the time a person wrote for its end (UTC): the
/// end is not included, and a date alone means the end of that day. So `2026-03-03`
/// gives 2026-03-03 23:59, and `2026-03-03T12:00` gives 11:59.
pub fn parse_to(s: &str) -> Result<u32, String> {
    let (m, date_only) = parse_time(s)?;
    let end = if date_only { m.saturating_add(1440) } else { m };
    end.checked_sub(1)
        .ok_or_else(|| format!("`{s}` ends before the first minute that can be stored"))
}

/// A well's place, from the wells file.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct WellInfo {
    /// The well, 1-15.
    pub well: u8,
    /// Its name (`well N` if the file leaves it empty).
    pub name: String,
    /// Latitude, decimal degrees north (WGS 84).
    pub latitude: f64,
    /// Longitude, decimal degrees east (WGS 84).
    pub longitude: f64,
    /// Elevation of the wellhead, m above sea level, if known.
    pub elevation_m: Option<f64>,
}

/// The columns of a wells file.
pub const WELLS_HEADER: &str = "well,name,latitude,longitude,elevation_m";

/// Splits a CSV line into fields: commas, double quotes around a field that holds
/// commas, `""` for a quote inside one.
fn csv_fields(line: &str) -> Result<Vec<String>, String> {
    let mut out = Vec::new();
    let mut chars = line.chars().peekable();
    loop {
        while chars.next_if(|c| *c == ' ' || *c == '\t').is_some() {}
        let field = if chars.next_if_eq(&'"').is_some() {
            let mut f = String::new();
            loop {
                match chars.next() {
                    None => {
                        return Err(
                            "a quote is not closed; close it (\") at the end of the field".into(),
                        )
                    }
                    Some('"') if chars.next_if_eq(&'"').is_some() => f.push('"'),
                    Some('"') => break,
                    Some(c) => f.push(c),
                }
            }
            while chars.next_if(|c| c.is_whitespace()).is_some() {}
            if chars.peek().is_some_and(|c| *c != ',') {
                return Err(
                    "text after a closing quote; put the whole field in quotes, \
                            with \"\" for a quote inside it"
                        .into(),
                );
            }
            f
        } else {
            let mut f = String::new();
            while let Some(c) = chars.next_if(|c| *c != ',') {
                f.push(c);
            }
            f.trim().to_string()
        };
        out.push(field);
        if chars.next().is_none() {
            return Ok(out);
        }
    }
}

/// Reads a wells file: CSV with the header `well,name,latitude,longitude,elevation_m`
/// (columns in any order; `elevation_m` may be left out, or left empty on a line),
/// one line per well; blank lines and lines starting with `#` are skipped. Wells are
/// 1-15 and each appears once; latitudes run from -90 to 90 and longitudes from -180
/// to 180, in decimal degrees (WGS 84). Errors name the line and what to fix.
pub fn read_wells(text: &str) -> Result<Vec<WellInfo>, ExportError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let err = |line: usize, problem: String| ExportError::WellsFile { line, problem };
    let mut columns: Option<[Option<usize>; 5]> = None;
    let mut ncols = 0;
    let mut out: Vec<(WellInfo, usize)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let n = i + 1;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields = csv_fields(line).map_err(|p| err(n, p))?;
        let Some(cols) = columns else {
            let mut c = [None; 5];
            for (j, f) in fields.iter().enumerate() {
                let name = f.trim().to_ascii_lowercase();
                let Some(k) = WELLS_HEADER.split(',').position(|h| h == name) else {
                    return Err(err(
                        n,
                        if name.parse::<f64>().is_ok() {
                            format!(
                                "the file starts without its header; put the line \
                                 `{WELLS_HEADER}` first"
                            )
                        } else {
                            format!(
                                "unknown column `{f}`; the columns are {WELLS_HEADER} \
                                 (elevation_m may be left out)"
                            )
                        },
                    ));
                };
                if c[k].is_some() {
                    return Err(err(n, format!("the column `{name}` appears twice")));
                }
                c[k] = Some(j);
            }
            for (k, h) in WELLS_HEADER.split(',').enumerate().take(4) {
                if c[k].is_none() {
                    return Err(err(
                        n,
                        format!(
                            "the header has no `{h}` column; the header is `{WELLS_HEADER}` \
                             (elevation_m may be left out)"
                        ),
                    ));
                }
            }
            columns = Some(c);
            ncols = fields.len();
            continue;
        };
        if fields.len() > ncols {
            return Err(err(
                n,
                format!(
                    "{} fields where the header has {ncols}; a name with a comma goes in \
                     double quotes",
                    fields.len()
                ),
            ));
        }
        let get = |k: usize| -> &str {
            cols[k]
                .and_then(|j| fields.get(j))
                .map(|s| s.as_str())
                .unwrap_or("")
        };
        let well_s = get(0);
        let well = match well_s.parse::<u8>() {
            Ok(w @ 1..=15) => w,
            _ if well_s.is_empty() => {
                return Err(err(n, "the well number is missing; write 1-15".into()))
            }
            _ => {
                return Err(err(
                    n,
                    format!("well `{well_s}` is not a well number; wells are 1-15"),
                ))
            }
        };
        if let Some((_, first)) = out.iter().find(|(w, _)| w.well == well) {
            return Err(err(
                n,
                format!("well {well} is already on line {first}; give each well one line"),
            ));
        }
        let number = |k: usize, what: &str, example: &str| -> Result<Option<f64>, ExportError> {
            let s = get(k);
            if s.is_empty() {
                return Ok(None);
            }
            match s.parse::<f64>() {
                Ok(v) if v.is_finite() => Ok(Some(v)),
                _ => Err(err(
                    n,
                    format!(
                        "{what} `{s}` is not a number; write decimal degrees or metres such \
                         as {example}"
                    ),
                )),
            }
        };
        let need = |v: Option<f64>, what: &str| {
            v.ok_or_else(|| {
                err(
                    n,
                    format!("the {what} of well {well} is missing; a point on a map needs it"),
                )
            })
        };
        let latitude = need(
            number(2, "latitude", "39.9042 (not 39°54'15\")")?,
            "latitude",
        )?;
        let longitude = need(number(3, "longitude", "116.4074")?, "longitude")?;
        let elevation_m = number(4, "elevation_m", "43.5 (metres)")?;
        if !(-90.0..=90.0).contains(&latitude) {
            let swapped = (-90.0..=90.0).contains(&longitude) && latitude.abs() <= 180.0;
            return Err(err(
                n,
                format!(
                    "latitude {latitude} is out of range; latitudes run from -90 (south) to \
                     90 (north){}",
                    if swapped {
                        "; are latitude and longitude swapped?"
                    } else {
                        ""
                    }
                ),
            ));
        }
        if !(-180.0..=180.0).contains(&longitude) {
            return Err(err(
                n,
                format!(
                    "longitude {longitude} is out of range; longitudes run from -180 (west) \
                     to 180 (east)"
                ),
            ));
        }
        let name = match get(1) {
            "" => format!("well {well}"),
            s => s.to_string(),
        };
        out.push((
            WellInfo {
                well,
                name,
                latitude,
                longitude,
                elevation_m,
            },
            n,
        ));
    }
    if columns.is_none() {
        return Err(err(
            1,
            format!("the file is empty; it starts with the header `{WELLS_HEADER}`"),
        ));
    }
    Ok(out.into_iter().map(|(w, _)| w).collect())
}

/// The wells to export: `wells`, each checked to be in the archive, or every well the
/// archive holds if `wells` is empty.
fn select_wells(archive: &Archive, wells: &[u8]) -> Result<Vec<u8>, ExportError> {
    let held = archive.wells()?;
    if wells.is_empty() {
        return Ok(held);
    }
    let mut out = Vec::new();
    for &w in wells {
        if !held.contains(&w) {
            return Err(ExportError::NoSuchWell { well: w, held });
        }
        if !out.contains(&w) {
            out.push(w);
        }
    }
    Ok(out)
}

fn check_range(from: u32, to: u32) -> Result<(), ExportError> {
    if from > to {
        Err(ExportError::BadRange { from, to })
    } else {
        Ok(())
    }
}

/// The averages of each well over `from..=to`.
fn series(
    archive: &Archive,
    wells: &[u8],
    from: u32,
    to: u32,
    every: Every,
) -> Result<Vec<(u8, Vec<Average>)>, ExportError> {
    check_range(from, to)?;
    wells
        .iter()
        .map(|&w| Ok((w, averages(archive.range(w, from, to)?, every))))
        .collect()
}

fn fixed4(v: Option<f64>) -> String {
    match v {
        // `+ 0.0` turns -0.0 into 0.0.
        Some(x) => format!("{:.4}", x + 0.0),
        None => String::new(),
    }
}

/// Writes `wells` (every well in the archive if empty) over `from..=to` as CSV with
/// the header `well,time,temperature_c,level_m,temperature_n,level_n`: one row per
/// well and period holding at least one stored minute (with [`Every::Minute`], one
/// per stored minute), wells in the order given, periods oldest first. `time` is the
/// period's start in ISO 8601 UTC; the values are the means of the valid minutes with
/// 4 decimals (°C and m), empty where the period has none; the `_n` columns count the
/// valid minutes (1 or 0 for single minutes). Returns the rows written (the header
/// not counted).
pub fn csv<W: Write>(
    archive: &Archive,
    wells: &[u8],
    from: u32,
    to: u32,
    every: Every,
    out: W,
) -> Result<usize, ExportError> {
    let wells = select_wells(archive, wells)?;
    check_range(from, to)?;
    let mut out = BufWriter::new(out);
    let werr = |error| ExportError::Write {
        to: "the CSV".into(),
        error,
    };
    writeln!(out, "well,time,temperature_c,level_m,temperature_n,level_n").map_err(werr)?;
    let mut rows = 0;
    for w in wells {
        for a in averages(archive.range(w, from, to)?, every) {
            writeln!(
                out,
                "{w},{},{},{},{},{}",
                iso8601(a.start),
                fixed4(a.temperature),
                fixed4(a.level),
                a.temperature_n,
                a.level_n
            )
            .map_err(werr)?;
            rows += 1;
        }
    }
    out.flush().map_err(werr)?;
    Ok(rows)
}

fn round4(v: Option<f64>) -> Value {
    match v {
        Some(x) => json!((x * 1e4).round() / 1e4 + 0.0),
        None => Value::Null,
    }
}

/// Every well in the archive over `from..=to` as a GeoJSON FeatureCollection
/// (RFC 7946): one Point feature per well and period holding at least one stored
/// minute, at the well's place from `places` (coordinates `[longitude, latitude]`,
/// or `[longitude, latitude, elevation]` when the elevation is known), with flat
/// properties `well`, `name`, `time` and `time_end` (ISO 8601 UTC: the period's start
/// and the start of the next), `temperature_c`, `level_m` (rounded to 4 decimals;
/// null where the period has no valid value) and `temperature_n`, `level_n`. A GIS
/// reads `time` as a date-time (QGIS: a point layer its temporal controller can
/// animate). Wells in the archive without a place are an error naming them.
pub fn geojson(
    archive: &Archive,
    places: &[WellInfo],
    from: u32,
    to: u32,
    every: Every,
) -> Result<Value, ExportError> {
    geojson_wells(archive, places, &[], from, to, every)
}

/// [`geojson`] for some of the wells (all of the archive's if `wells` is empty);
/// only those need a place.
pub fn geojson_wells(
    archive: &Archive,
    places: &[WellInfo],
    wells: &[u8],
    from: u32,
    to: u32,
    every: Every,
) -> Result<Value, ExportError> {
    let wells = select_wells(archive, wells)?;
    let missing: Vec<u8> = wells
        .iter()
        .copied()
        .filter(|w| !places.iter().any(|p| p.well == *w))
        .collect();
    if !missing.is_empty() {
        return Err(ExportError::NoPlace { wells: missing });
    }
    let mut features = Vec::new();
    for (w, avgs) in series(archive, &wells, from, to, every)? {
        let p = places
            .iter()
            .find(|p| p.well == w)
            .expect("every well has a place");
        let mut coordinates = vec![json!(p.longitude), json!(p.latitude)];
        if let Some(e) = p.elevation_m {
            coordinates.push(json!(e));
        }
        for a in avgs {
            let mut props = Map::new();
            props.insert("well".into(), json!(w));
            props.insert("name".into(), json!(p.name));
            props.insert("time".into(), json!(iso8601(a.start)));
            props.insert("time_end".into(), json!(iso8601(a.end)));
            props.insert("temperature_c".into(), round4(a.temperature));
            props.insert("level_m".into(), round4(a.level));
            props.insert("temperature_n".into(), json!(a.temperature_n));
            props.insert("level_n".into(), json!(a.level_n));
            features.push(json!({
                "type": "Feature",
                "id": features.len() + 1,
                "geometry": {"type": "Point", "coordinates": coordinates},
                "properties": props,
            }));
        }
    }
    Ok(json!({
        "type": "FeatureCollection",
        "name": format!("wells_{}", every.name()),
        "features": features,
    }))
}

/// Writes a FeatureCollection from [`geojson`] as JSON with one feature per line
/// (valid GeoJSON that stays readable and diffable).
pub fn write_geojson<W: Write>(collection: &Value, out: W) -> Result<(), ExportError> {
    let mut out = BufWriter::new(out);
    let werr = |error| ExportError::Write {
        to: "the GeoJSON".into(),
        error,
    };
    let jerr = |e: serde_json::Error| werr(io::Error::other(e));
    let features = collection
        .get("features")
        .and_then(Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or(&[]);
    let mut head = collection.clone();
    if let Some(o) = head.as_object_mut() {
        o.remove("features");
    }
    let head = serde_json::to_string(&head).map_err(jerr)?;
    // `{"type":...,"name":...` then the features.
    write!(out, "{},\"features\":[", head.trim_end_matches('}')).map_err(werr)?;
    for (i, f) in features.iter().enumerate() {
        out.write_all(if i == 0 { b"\n" } else { b",\n" })
            .map_err(werr)?;
        serde_json::to_writer(&mut out, f).map_err(jerr)?;
    }
    out.write_all(b"\n]}\n").map_err(werr)?;
    out.flush().map_err(werr)
}

/// Draws the trends of `wells` (every well in the archive if empty) over
/// `from..=to` as a PNG of `size` pixels (width, height; each 300-8000): a panel of
/// the water level (m) above a panel of the water temperature (°C), sharing a time
/// axis with dates (UTC); one coloured line per well, named in a legend; the
/// averages of `every` (each drawn at the middle of its period; a line breaks where
/// periods have no value). The time axis spans `from` to `to`, or the data where
/// they are open (`from = 0`, `to = u32::MAX`). The text is drawn with the embedded
/// DejaVu Sans: no system font is needed.
pub fn plot_png(
    archive: &Archive,
    wells: &[u8],
    from: u32,
    to: u32,
    every: Every,
    path: &Path,
    size: (u32, u32),
) -> Result<(), ExportError> {
    let wells = select_wells(archive, wells)?;
    let data = series(archive, &wells, from, to, every)?;
    let first = data
        .iter()
        .filter_map(|(_, a)| a.first())
        .map(|a| a.start)
        .min();
    let last = data
        .iter()
        .filter_map(|(_, a)| a.last())
        .map(|a| a.end)
        .max();
    let (Some(first), Some(last)) = (first, last) else {
        return Err(ExportError::NoData { wells, from, to });
    };
    let lo = if from == 0 { first } else { from };
    let hi = if to == u32::MAX {
        last
    } else {
        to.saturating_add(1)
    };
    let picture = plot::draw(&data, lo, hi.max(lo.saturating_add(1)), every, size)?;
    plot::write_png(&picture, size, path)
}

/// The drawing behind [`plot_png`].
mod plot {
    use std::fs::File;
    use std::io::BufWriter;
    use std::path::Path;
    use std::sync::OnceLock;

    use chrono::Datelike;
    use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
    use plotters::element::DashedPathElement;
    use plotters::prelude::*;
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    use plotters::style::{FontStyle, RGBColor};

    use super::{date_of, iso8601, period_of, Average, Every, ExportError};

    /// DejaVu Sans 2.37 (Bitstream Vera licence; assets/LICENSE-DejaVu.txt).
    static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
    /// The family the font is registered under (plotters' default labels use it).
    const FAMILY: &str = "sans-serif";

    /// Supersampling: drawn at this many times the size, then averaged down, so lines
    /// come out smooth.
    const S: u32 = 2;

    /// Colours for the wells (Tableau 10: told apart by most colour-blind readers).
    const PALETTE: [RGBColor; 10] = [
        RGBColor(0x4E, 0x79, 0xA7),
        RGBColor(0xF2, 0x8E, 0x2B),
        RGBColor(0x59, 0xA1, 0x4F),
        RGBColor(0xE1, 0x57, 0x59),
        RGBColor(0xB0, 0x7A, 0xA1),
        RGBColor(0x76, 0xB7, 0xB2),
        RGBColor(0xED, 0xC9, 0x48),
        RGBColor(0x9C, 0x75, 0x5F),
        RGBColor(0xFF, 0x9D, 0xA7),
        RGBColor(0x59, 0x59, 0x59),
    ];
    const INK: RGBColor = RGBColor(0x22, 0x22, 0x22);
    const MUTED: RGBColor = RGBColor(0x55, 0x55, 0x55);
    const AXIS: RGBColor = RGBColor(0x88, 0x88, 0x88);
    const GRID: RGBColor = RGBColor(0xE4, 0xE4, 0xE4);

    /// A well's colour: the same well has the same colour in every plot.
    fn colour(well: u8) -> RGBColor {
        PALETTE[usize::from(well.saturating_sub(1)) % PALETTE.len()]
    }

    /// Wells 11-15 take the colours of wells 1-5 with dashed lines.
    fn dashed(well: u8) -> bool {
        usize::from(well) > PALETTE.len()
    }

    fn font() -> Result<(), ExportError> {
        static DONE: OnceLock<bool> = OnceLock::new();
        if *DONE
            .get_or_init(|| plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok())
        {
            Ok(())
        } else {
            Err(ExportError::Plot("the embedded font did not load".into()))
        }
    }

    fn perr<E: std::fmt::Display>(e: E) -> ExportError {
        ExportError::Plot(e.to_string())
    }

    /// A linear axis with the ticks we choose (plotters' own would not fall on
    /// midnights, pentads or months).
    struct Ticked {
        lo: f64,
        hi: f64,
        ticks: Vec<f64>,
    }

    impl Ranged for Ticked {
        type FormatOption = DefaultFormatting;
        type ValueType = f64;

        fn map(&self, v: &f64, limit: (i32, i32)) -> i32 {
            let f = (v - self.lo) / (self.hi - self.lo);
            limit.0 + (f64::from(limit.1 - limit.0) * f).round() as i32
        }

        fn key_points<H: KeyPointHint>(&self, hint: H) -> Vec<f64> {
            if hint.weight().allow_light_points() {
                Vec::new()
            } else {
                self.ticks.clone()
            }
        }

        fn range(&self) -> std::ops::Range<f64> {
            self.lo..self.hi
        }
    }

    /// Steps of the time axis' ticks.
    #[derive(Clone, Copy, Debug)]
    enum Step {
        Minutes(u32),
        Days(u32),
        Pentad,
        Dekad,
        Months(u32),
    }

    const STEPS: [Step; 21] = [
        Step::Minutes(1),
        Step::Minutes(2),
        Step::Minutes(5),
        Step::Minutes(10),
        Step::Minutes(15),
        Step::Minutes(30),
        Step::Minutes(60),
        Step::Minutes(120),
        Step::Minutes(180),
        Step::Minutes(360),
        Step::Minutes(720),
        Step::Days(1),
        Step::Days(2),
        Step::Pentad,
        Step::Dekad,
        Step::Months(1),
        Step::Months(2),
        Step::Months(3),
        Step::Months(6),
        Step::Months(12),
        Step::Months(60),
    ];

    impl Step {
        /// Roughly how long a step is, minutes.
        fn minutes(self) -> f64 {
            match self {
                Step::Minutes(n) => f64::from(n),
                Step::Days(n) => f64::from(n) * 1440.0,
                Step::Pentad => 5.0 * 1440.0,
                Step::Dekad => 10.0 * 1440.0,
                Step::Months(n) => f64::from(n) * 43_830.0,
            }
        }

        /// The ticks in `lo..=hi`.
        fn ticks(self, lo: u32, hi: u32) -> Vec<u32> {
            let mut out = Vec::new();
            match self {
                Step::Minutes(n) | Step::Days(n) => {
                    let n = if let Step::Days(_) = self {
                        n * 1440
                    } else {
                        n
                    };
                    let mut t = lo.div_ceil(n) * n;
                    while t <= hi {
                        out.push(t);
                        t = match t.checked_add(n) {
                            Some(t) => t,
                            None => break,
                        };
                    }
                }
                Step::Pentad | Step::Dekad | Step::Months(_) => {
                    let every = match self {
                        Step::Pentad => Every::Pentad,
                        Step::Dekad => Every::Dekad,
                        _ => Every::Month,
                    };
                    let (mut t, mut end) = period_of(lo, every);
                    loop {
                        if t >= lo && t <= hi {
                            let keep = match self {
                                Step::Months(k) => {
                                    let d = date_of(t);
                                    (d.year() as u32 * 12 + d.month0()) % k == 0
                                }
                                _ => true,
                            };
                            if keep {
                                out.push(t);
                            }
                        }
                        if end > hi || end == u32::MAX {
                            break;
                        }
                        t = end;
                        end = period_of(t, every).1;
                    }
                }
            }
            out
        }

        fn label(self, t: u32) -> String {
            let d = date_of(t);
            let day_month = d.format("%-d %b").to_string();
            match self {
                Step::Minutes(_) if t % 1440 != 0 => iso8601(t)[11..16].to_string(),
                Step::Months(k) if k >= 12 => d.format("%Y").to_string(),
                Step::Months(_) if d.month() == 1 => d.format("%b %Y").to_string(),
                Step::Months(_) => d.format("%b").to_string(),
                _ if d.month() == 1 && d.day() == 1 => d.format("%-d %b %Y").to_string(),
                _ => day_month,
            }
        }
    }

    /// Time ticks for an axis `lo..hi` with room for about `max` labels.
    fn time_ticks(lo: u32, hi: u32, max: usize) -> (Step, Vec<u32>) {
        let span = f64::from(hi - lo);
        for step in STEPS {
            if span / step.minutes() > max as f64 + 1.0 {
                continue;
            }
            let t = step.ticks(lo, hi);
            if t.len() <= max {
                return (step, t);
            }
        }
        let step = Step::Months(120);
        (step, step.ticks(lo, hi))
    }

    /// Round steps for a value axis: about `max` ticks over `lo..hi`, and the
    /// decimals their labels need.
    fn value_ticks(lo: f64, hi: f64, max: usize) -> (Vec<f64>, usize) {
        let raw = (hi - lo) / max as f64;
        let mag = 10f64.powf(raw.log10().floor());
        let step = [1.0, 2.0, 2.5, 5.0, 10.0]
            .iter()
            .map(|m| m * mag)
            .find(|s| *s >= raw)
            .unwrap_or(10.0 * mag);
        let decimals = (-(step.log10().floor())).max(0.0) as usize
            + usize::from((step / 10f64.powf(step.log10().floor()) - 2.5).abs() < 1e-9);
        // Counted first, not stepped to the end: at values far above the step (a
        // corrupt archive's 1e16 m) adding 1 to the tick index changes nothing, and a
        // loop waiting for it to pass `hi` would never end.
        let first = (lo / step).ceil();
        let count = ((hi + step * 1e-9) / step).floor() - first;
        let count = if count.is_finite() {
            count.clamp(-1.0, 4.0 * max as f64) as i64
        } else {
            -1
        };
        let out = (0..=count).map(|k| (first + k as f64) * step).collect();
        (out, decimals)
    }

    /// The range of a panel's values with a margin, never empty.
    fn value_range(values: impl Iterator<Item = f64>) -> (f64, f64) {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for v in values {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() {
            return (0.0, 1.0);
        }
        let span = hi - lo;
        let pad = if span < 1e-9 {
            0.01_f64.max(lo.abs() * 1e-4)
        } else {
            span * 0.08
        };
        (lo - pad, hi + pad)
    }

    /// Pieces of a line: runs of periods that follow each other and have a value.
    fn runs(avgs: &[Average], value: fn(&Average) -> Option<f64>) -> Vec<Vec<(f64, f64)>> {
        let mut out: Vec<Vec<(f64, f64)>> = Vec::new();
        let mut prev_end = None;
        for a in avgs {
            match value(a) {
                Some(v) => {
                    let x = (f64::from(a.start) + f64::from(a.end)) / 2.0;
                    if prev_end != Some(a.start) || out.is_empty() {
                        out.push(Vec::new());
                    }
                    out.last_mut().expect("a run").push((x, v));
                    prev_end = Some(a.end);
                }
                None => prev_end = None,
            }
        }
        out
    }

    /// `2026-03-01 to 2026-03-10` (whole days) or `2026-03-01 06:00 to ... UTC`.
    fn range_text(lo: u32, hi: u32) -> String {
        if lo % 1440 == 0 && hi % 1440 == 0 {
            let a = date_of(lo).format("%Y-%m-%d").to_string();
            let b = date_of(hi - 1).format("%Y-%m-%d").to_string();
            if a == b {
                a
            } else {
                format!("{a} to {b}")
            }
        } else {
            let f = |m: u32| {
                let s = iso8601(m);
                format!("{} {}", &s[..10], &s[11..16])
            };
            format!("{} to {} UTC", f(lo), f(hi))
        }
    }

    /// Draws the picture: RGB, `size` pixels.
    pub(super) fn draw(
        data: &[(u8, Vec<Average>)],
        lo: u32,
        hi: u32,
        every: Every,
        size: (u32, u32),
    ) -> Result<Vec<u8>, ExportError> {
        let (w, h) = size;
        if !(300..=8000).contains(&w) || !(300..=8000).contains(&h) {
            return Err(ExportError::Plot(format!(
                "a picture of {w}x{h} pixels; give a width and a height of 300 to 8000"
            )));
        }
        font()?;
        let (sw, sh) = (w * S, h * S);
        // Sizes are set for 1400 x 900 and follow the picture's size.
        let k = (f64::from(w) / 1400.0)
            .min(f64::from(h) / 900.0)
            .clamp(0.6, 2.5)
            * f64::from(S);
        let px = |v: f64| (v * k).round() as i32;
        let fs = |v: f64| v * k;
        let stroke = |v: f64| ((v * k).round() as u32).max(1);
        let mut buf = vec![0u8; (sw * sh * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, (sw, sh)).into_drawing_area();
            root.fill(&WHITE).map_err(perr)?;
            let width = |text: &str, style: &TextStyle| -> Result<i32, ExportError> {
                Ok(root.estimate_text_size(text, style).map_err(perr)?.0 as i32)
            };

            // Title (made smaller if it would not fit), what the values are, the
            // legend (on more rows if need be).
            let wells: Vec<u8> = data.iter().map(|(w, _)| *w).collect();
            let title = format!(
                "{} {}: water level and temperature, {}",
                if wells.len() == 1 { "Well" } else { "Wells" },
                super::list(&wells),
                range_text(lo, hi)
            );
            let left = px(24.0);
            let room = sw as i32 - 2 * left;
            let mut title_size = fs(22.0);
            let full = width(&title, &(FAMILY, title_size).into_font().color(&INK))?;
            if full > room {
                title_size *= f64::from(room) / f64::from(full);
            }
            root.draw(&Text::new(
                title,
                (left, px(16.0)),
                (FAMILY, title_size).into_font().color(&INK),
            ))
            .map_err(perr)?;
            root.draw(&Text::new(
                format!("{}, times UTC", every.describe()),
                (left, px(46.0)),
                (FAMILY, fs(14.0)).into_font().color(&MUTED),
            ))
            .map_err(perr)?;
            let legend = (FAMILY, fs(15.0))
                .into_font()
                .color(&INK)
                .pos(Pos::new(HPos::Left, VPos::Center));
            let legend_left = px(24.0 + 90.0).min(sw as i32 / 6);
            let (mut x, mut y) = (legend_left, px(80.0));
            for well in &wells {
                let label = format!("Well {well}");
                let item = px(34.0) + width(&label, &legend)?;
                if x > legend_left && x + item > sw as i32 - left {
                    x = legend_left;
                    y += px(24.0);
                }
                let sample = vec![(x, y), (x + px(26.0), y)];
                let style = colour(*well).stroke_width(stroke(3.0));
                if dashed(*well) {
                    root.draw(&DashedPathElement::new(sample, px(7.0), px(4.0), style))
                } else {
                    root.draw(&PathElement::new(sample, style))
                }
                .map_err(perr)?;
                root.draw(&Text::new(label, (x + px(34.0), y), legend.clone()))
                    .map_err(perr)?;
                x += item + px(28.0);
            }

            let header = y + px(20.0);
            let (right, bottom_margin, y_labels) = (px(36.0), px(14.0), px(100.0));
            let body = root.margin(header, bottom_margin, px(10.0), right);
            let plot_w = sw as i32 - px(10.0) - right - y_labels;
            let (step, ticks) = time_ticks(lo, hi, (plot_w / px(90.0)).max(2) as usize);
            let top_x_labels = px(10.0);
            let bottom_x_labels = px(56.0);
            let panel = (sh as i32 - header - bottom_margin - top_x_labels - bottom_x_labels) / 2;
            let (top, bottom) = body.split_vertically(panel + top_x_labels);

            type Panel<'a> = (&'a str, fn(&Average) -> Option<f64>);
            let panels: [(Panel, _, bool); 2] = [
                (("Water level (m)", |a| a.level), top, false),
                (("Water temperature (°C)", |a| a.temperature), bottom, true),
            ];
            for ((desc, value), area, is_bottom) in panels {
                let (y0, y1) =
                    value_range(data.iter().flat_map(|(_, a)| a.iter().filter_map(value)));
                let (yticks, decimals) =
                    value_ticks(y0, y1, (panel / px(40.0)).clamp(5, 10) as usize);
                let xs: Vec<f64> = ticks.iter().map(|t| f64::from(*t)).collect();
                let mut chart = ChartBuilder::on(&area)
                    .margin_top(px(6.0))
                    .x_label_area_size(if is_bottom {
                        bottom_x_labels
                    } else {
                        top_x_labels
                    })
                    .y_label_area_size(y_labels)
                    .build_cartesian_2d(
                        Ticked {
                            lo: f64::from(lo),
                            hi: f64::from(hi),
                            ticks: xs,
                        },
                        Ticked {
                            lo: y0,
                            hi: y1,
                            ticks: yticks,
                        },
                    )
                    .map_err(perr)?;
                let label_font = (FAMILY, fs(14.0)).into_font().color(&MUTED);
                let xfmt = |x: &f64| {
                    if is_bottom {
                        step.label(x.round() as u32)
                    } else {
                        String::new()
                    }
                };
                let yfmt = |y: &f64| format!("{:.*}", decimals, y + 0.0);
                chart
                    .configure_mesh()
                    .bold_line_style(GRID.stroke_width(stroke(1.0)))
                    .light_line_style(TRANSPARENT)
                    .axis_style(AXIS.stroke_width(stroke(1.0)))
                    .set_all_tick_mark_size(px(5.0))
                    .label_style(label_font)
                    .axis_desc_style((FAMILY, fs(15.0)).into_font().color(&INK))
                    .x_label_formatter(&xfmt)
                    .y_label_formatter(&yfmt)
                    .y_desc(desc)
                    .x_desc(match (is_bottom, step) {
                        (false, _) => "",
                        (true, Step::Minutes(_)) => "Time (UTC)",
                        (true, _) => "Date (UTC)",
                    })
                    .draw()
                    .map_err(perr)?;
                for (well, avgs) in data {
                    let c = colour(*well);
                    for run in runs(avgs, value) {
                        if run.len() == 1 {
                            chart
                                .draw_series(std::iter::once(Circle::new(
                                    run[0],
                                    px(2.0),
                                    c.filled(),
                                )))
                                .map_err(perr)?;
                        } else if dashed(*well) {
                            chart
                                .draw_series(DashedLineSeries::new(
                                    run,
                                    px(8.0),
                                    px(5.0),
                                    c.stroke_width(stroke(2.0)),
                                ))
                                .map_err(perr)?;
                        } else {
                            chart
                                .draw_series(LineSeries::new(run, c.stroke_width(stroke(2.0))))
                                .map_err(perr)?;
                        }
                    }
                }
            }
            root.present().map_err(perr)?;
        }
        // Average each S x S block.
        let mut out = vec![0u8; (w * h * 3) as usize];
        for y in 0..h as usize {
            for x in 0..w as usize {
                for c in 0..3 {
                    let mut sum = 0u32;
                    for dy in 0..S as usize {
                        for dx in 0..S as usize {
                            let i =
                                ((y * S as usize + dy) * sw as usize + x * S as usize + dx) * 3 + c;
                            sum += u32::from(buf[i]);
                        }
                    }
                    out[(y * w as usize + x) * 3 + c] = ((sum + S * S / 2) / (S * S)) as u8;
                }
            }
        }
        Ok(out)
    }

    /// Writes an RGB picture as PNG.
    pub(super) fn write_png(
        rgb: &[u8],
        (w, h): (u32, u32),
        path: &Path,
    ) -> Result<(), ExportError> {
        let werr = |error| ExportError::Write {
            to: path.display().to_string(),
            error,
        };
        let file = File::create(path).map_err(werr)?;
        let mut enc = png::Encoder::new(BufWriter::new(file), w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let perr = |e: png::EncodingError| match e {
            png::EncodingError::IoError(e) => werr(e),
            e => ExportError::Plot(e.to_string()),
        };
        let mut wr = enc.write_header().map_err(perr)?;
        wr.write_image_data(rgb).map_err(perr)?;
        wr.finish().map_err(perr)
    }

    #[cfg(test)]
    mod tests {
        use super::*;
        use crate::average::minute_of_date;

        fn day(y: i32, m: u32, d: u32) -> u32 {
            minute_of_date(chrono::NaiveDate::from_ymd_opt(y, m, d).unwrap())
        }

        #[test]
        fn time_ticks_fit_and_align() {
            // Ten days on a wide axis: a tick a day, at midnight.
            let (step, t) = time_ticks(day(2026, 3, 1), day(2026, 3, 11), 11);
            assert!(matches!(step, Step::Days(1)), "{step:?}");
            assert_eq!(t.len(), 11);
            assert!(t.iter().all(|t| t % 1440 == 0));
            assert_eq!(step.label(t[0]), "1 Mar");
            // A day: hours, midnight shown as the date.
            let (step, t) = time_ticks(day(2026, 3, 1), day(2026, 3, 2), 10);
            assert!(matches!(step, Step::Minutes(180)), "{step:?}");
            assert_eq!(step.label(t[0]), "1 Mar");
            assert_eq!(step.label(t[1]), "03:00");
            // Two months: pentads or dekads, on their first days.
            let (step, t) = time_ticks(day(2026, 3, 1), day(2026, 5, 1), 8);
            assert!(matches!(step, Step::Dekad), "{step:?}");
            assert_eq!(step.label(t[1]), "11 Mar");
            // Years.
            let (step, t) = time_ticks(day(2020, 1, 1), day(2026, 1, 1), 10);
            assert!(matches!(step, Step::Months(12)), "{step:?}");
            assert_eq!(step.label(t[0]), "2020");
        }

        #[test]
        fn value_ticks_are_round() {
            let (t, d) = value_ticks(9.61, 10.43, 6);
            assert_eq!(d, 1);
            assert!(
                (t[0] - 9.8).abs() < 1e-9 || (t[0] - 9.7).abs() < 1e-9,
                "{t:?}"
            );
            let (t, d) = value_ticks(15.2001, 15.2312, 6);
            assert_eq!(d, 2, "{t:?}");
            assert_eq!(t.len(), 3, "{t:?}");
            let (t, d) = value_ticks(15.7159, 15.7172, 5);
            assert_eq!(d, 4, "{t:?}"); // a step of 0.0005
            assert_eq!(format!("{:.*}", d, t[0]), "15.7160");
            let (_, d) = value_ticks(0.0, 1.0, 4);
            assert_eq!(d, 2); // a step of 0.25
        }

        /// Values far above their spread (a corrupt archive) still give a finite,
        /// short list of ticks: counting them once ends where stepping 1e16 by 1 would
        /// not.
        #[test]
        fn value_ticks_end_for_values_far_above_their_spread() {
            for (lo, hi) in [
                (1e16, 1e16 + 2.0),
                (1e7, 1e7 + 3.7e-9),
                (0.0, 0.0),
                (5.0, 5.0),
            ] {
                let (t, _) = value_ticks(lo, hi, 6);
                assert!(t.len() <= 24, "{lo} {hi}: {} ticks", t.len());
            }
        }

        #[test]
        fn lines_break_at_gaps() {
            let a = |start: u32, v: Option<f64>| Average {
                start,
                end: start + 60,
                temperature: v,
                level: None,
                temperature_n: 0,
                level_n: 0,
                temperature_min: None,
                temperature_max: None,
                level_min: None,
                level_max: None,
            };
            let avgs = vec![
                a(0, Some(1.0)),
                a(60, Some(2.0)),
                a(180, Some(3.0)),
                a(240, None),
                a(300, Some(4.0)),
            ];
            let r = runs(&avgs, |a| a.temperature);
            assert_eq!(r.len(), 3);
            assert_eq!(r[0], vec![(30.0, 1.0), (90.0, 2.0)]);
            assert_eq!(r[1], vec![(210.0, 3.0)]);
            assert_eq!(r[2], vec![(330.0, 4.0)]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn iso_times() {
        assert_eq!(iso8601(0), "1970-01-01T00:00:00Z");
        assert_eq!(
            iso8601((crate::sim::START / 60_000) as u32),
            "2026-03-01T00:00:00Z"
        );
        assert_eq!(iso8601(29_538_720 + 61), "2026-03-01T01:01:00Z");
    }

    #[test]
    fn times_people_write() {
        let m = 29_538_720; // 2026-03-01 00:00
        assert_eq!(parse_from("2026-03-01"), Ok(m));
        assert_eq!(parse_from("2026-03-01T12:00"), Ok(m + 720));
        assert_eq!(parse_from("2026-03-01T12:00:00Z"), Ok(m + 720));
        assert_eq!(parse_from("2026-03-01 12:05"), Ok(m + 725));
        assert_eq!(parse_from(" 2026-03-01T12:00:59 "), Ok(m + 720));
        // An end: a date alone means the whole day; a time is not included.
        assert_eq!(parse_to("2026-03-01"), Ok(m + 1439));
        assert_eq!(parse_to("2026-03-01T12:00"), Ok(m + 719));
        assert_eq!(parse_to("2026-03-01T12:00:00Z"), Ok(m + 719));
        for bad in [
            "2026-02-30",
            "01/03/2026",
            "2026-03-01T25:00",
            "yesterday",
            "",
        ] {
            let e = parse_from(bad).unwrap_err();
            assert!(e.contains("2026-03-01T12:00"), "{bad}: {e}");
        }
        assert!(parse_from("2026-03-01T12:00:00+08:00")
            .unwrap_err()
            .contains("UTC"));
        assert!(parse_from("1969-12-31").is_err());
        assert!(parse_from("2026-03-01T12:00:00é").is_err());
        assert!(parse_from("ééééééééééééééééééééé").is_err());
        assert!(parse_to("1970-01-01T00:00").is_err());
    }

    #[test]
    fn a_wells_file() {
        let text = "\u{feff}# wells of the network\n\
                    well,name,latitude,longitude,elevation_m\n\
                    \n\
                    1,Baijiatuan,40.0196,116.2483,52.0\n\
                    2,\"Tangshan, deep\",39.6306,118.1802,\n\
                    # well 3 has no elevation column value\n\
                    3,,31.2304,121.4737\n";
        let w = read_wells(text).unwrap();
        assert_eq!(w.len(), 3);
        assert_eq!(w[0].name, "Baijiatuan");
        assert_eq!(w[0].elevation_m, Some(52.0));
        assert_eq!(w[1].name, "Tangshan, deep");
        assert_eq!(w[1].elevation_m, None);
        assert_eq!(w[2].name, "well 3");
        assert_eq!((w[2].latitude, w[2].longitude), (31.2304, 121.4737));
        // Columns in another order, no elevation column.
        let w = read_wells("name,well,longitude,latitude\nA,7,-70.5,-33.4\n").unwrap();
        assert_eq!(
            (w[0].well, w[0].latitude, w[0].longitude),
            (7, -33.4, -70.5)
        );
        assert!(read_wells("well,name,latitude,longitude\n")
            .unwrap()
            .is_empty());
    }

    fn wells_error(text: &str) -> (usize, String) {
        match read_wells(text) {
            Err(ExportError::WellsFile { line, problem }) => (line, problem),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn wells_file_errors_name_the_line_and_the_fix() {
        let h = "well,name,latitude,longitude,elevation_m\n";
        let (l, p) = wells_error(&format!("{h}1,a,40,116\n16,b,40,116\n"));
        assert_eq!(l, 3);
        assert!(p.contains("1-15"), "{p}");
        let (l, p) = wells_error(&format!("{h}1,a,40,116\n\n1,b,41,116\n"));
        assert_eq!(l, 4);
        assert!(p.contains("already on line 2"), "{p}");
        let (l, p) = wells_error(&format!("{h}1,a,116.4,39.9\n"));
        assert_eq!(l, 2);
        assert!(p.contains("-90") && p.contains("swapped"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,a,39.9,190\n"));
        assert!(p.contains("-180"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,a,NaN,116\n"));
        assert!(p.contains("not a number"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,a,inf,116\n"));
        assert!(p.contains("not a number"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,a,,116\n"));
        assert!(p.contains("latitude") && p.contains("missing"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,a,40,116,1,2\n"));
        assert!(p.contains("6 fields") && p.contains("quotes"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,\"a,40,116\n"));
        assert!(p.contains("quote"), "{p}");
        let (_, p) = wells_error(&format!("{h}1,\"a\"b,40,116\n"));
        assert!(p.contains("after a closing quote"), "{p}");
        let w = read_wells(&format!("{h}1, \"The \"\"old\"\" well\" ,40,116\n")).unwrap();
        assert_eq!(w[0].name, "The \"old\" well");
        let (l, p) = wells_error("1,a,40,116\n");
        assert_eq!(l, 1);
        assert!(p.contains("header"), "{p}");
        let (_, p) = wells_error("well,name,lat,lon\n");
        assert!(p.contains("`lat`"), "{p}");
        let (_, p) = wells_error("well,name,latitude\n");
        assert!(p.contains("longitude"), "{p}");
        let (_, p) = wells_error("# nothing\n");
        assert!(p.contains("empty"), "{p}");
        let (_, p) = wells_error(&format!("{h}x,a,40,116\n"));
        assert!(p.contains("`x`"), "{p}");
    }

    #[test]
    fn errors_say_what_to_check() {
        let e = ExportError::NoPlace { wells: vec![2, 3] };
        assert!(e.to_string().contains("wells 2 and 3 have"), "{e}");
        let e = ExportError::NoSuchWell {
            well: 4,
            held: vec![1, 2, 3],
        };
        assert!(e.to_string().contains("1, 2 and 3"), "{e}");
        let e = ExportError::BadRange {
            from: 29_538_720 + 1440,
            to: 29_538_720,
        };
        assert!(e.to_string().contains("2026-03-02 00:00"), "{e}");
    }
}
