//! The command line's output: a text table, JSON or CSV.

use std::time::SystemTime;

use crate::{DeviceSummary, Error, Point};

/// An output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Format {
    /// An aligned table for people.
    #[default]
    Text,
    /// A JSON array of objects.
    Json,
    /// CSV with a header line.
    Csv,
}

impl std::str::FromStr for Format {
    type Err = Error;
    fn from_str(s: &str) -> Result<Format, Error> {
        match s.trim().to_ascii_lowercase().as_str() {
            "text" => Ok(Format::Text),
            "json" => Ok(Format::Json),
            "csv" => Ok(Format::Csv),
            _ => Err(Error::Usage(format!("format '{s}': use text, json or csv"))),
        }
    }
}

/// RFC 3339 in UTC, with as many fractional digits as the time needs (none, 3 or 6).
pub fn rfc3339(t: SystemTime) -> String {
    let us = crate::micros(t).rem_euclid(1_000_000);
    if us == 0 {
        humantime::format_rfc3339_seconds(t).to_string()
    } else if us % 1000 == 0 {
        humantime::format_rfc3339_millis(t).to_string()
    } else {
        humantime::format_rfc3339_micros(t).to_string()
    }
}

fn value_text(v: Option<f64>) -> String {
    v.map_or_else(String::new, |v| v.to_string())
}

/// The names of the engine's quality codes (`hart_poller::Quality::name`, by
/// `Quality::code`), as stored in the `quality` column; hart-recorder's tests check
/// that they are the engine's.
const QUALITY_NAMES: [&str; 7] = [
    "good",
    "stale",
    "no reply",
    "device malfunction",
    "configuration changed",
    "waiting for first data",
    "loop disturbed",
];

/// The name of a stored quality code (`hart_poller::Quality::code`), or the code.
pub fn quality_name(code: u8) -> String {
    QUALITY_NAMES
        .get(usize::from(code))
        .map_or_else(|| code.to_string(), |n| (*n).to_string())
}

fn units_text(u: Option<u8>) -> String {
    u.map_or_else(String::new, |u| u.to_string())
}

/// A query's rows: `--json` an array of {time (RFC 3339), value, units, quality};
/// `--csv` the header `time,value,units,quality` and a line per row; text a table.
pub fn format_points(points: &[Point], format: Format) -> String {
    match format {
        Format::Json => {
            let rows: Vec<serde_json::Value> = points
                .iter()
                .map(|p| {
                    serde_json::json!({
                        "time": rfc3339(p.time),
                        "value": p.value,
                        "units": p.units,
                        "quality": p.quality,
                    })
                })
                .collect();
            serde_json::Value::Array(rows).to_string()
        }
        Format::Csv => {
            let mut s = String::from("time,value,units,quality");
            for p in points {
                s.push('\n');
                s.push_str(&format!(
                    "{},{},{},{}",
                    rfc3339(p.time),
                    value_text(p.value),
                    units_text(p.units),
                    p.quality
                ));
            }
            s
        }
        Format::Text => {
            let mut s = format!(
                "{:<27} {:>14} {:<8} {}",
                "time", "value", "units", "quality"
            );
            for p in points {
                s.push('\n');
                // The units' symbol and the quality's name for a person; codes in
                // --csv and --json.
                let units = p.units.map_or(String::new(), |u| {
                    hart_proto::tables::unit_symbol(u).map_or(u.to_string(), str::to_string)
                });
                s.push_str(&format!(
                    "{:<27} {:>14} {:<8} {}",
                    rfc3339(p.time),
                    value_text(p.value),
                    units,
                    quality_name(p.quality)
                ));
            }
            if points.is_empty() {
                s.push_str("\n(no samples in that time range)");
            }
            s
        }
    }
}

/// The stored devices: unique ID, tag, loop, first and last sample times, samples.
pub fn format_devices(devices: &[DeviceSummary], format: Format) -> String {
    let t = |t: Option<SystemTime>| t.map(rfc3339);
    match format {
        Format::Json => serde_json::Value::Array(
            devices
                .iter()
                .map(|d| {
                    serde_json::json!({
                        "unique_id": d.unique_id,
                        "tag": d.tag,
                        "loop": d.loop_name,
                        "first": t(d.first),
                        "last": t(d.last),
                        "samples": d.samples,
                    })
                })
                .collect(),
        )
        .to_string(),
        Format::Csv => {
            let mut s = String::from("unique_id,tag,loop,first,last,samples");
            for d in devices {
                let q = |x: &str| {
                    if x.contains([',', '"', '\n']) {
                        format!("\"{}\"", x.replace('"', "\"\""))
                    } else {
                        x.to_string()
                    }
                };
                s.push_str(&format!(
                    "\n{},{},{},{},{},{}",
                    d.unique_id,
                    q(&d.tag),
                    q(&d.loop_name),
                    t(d.first).unwrap_or_default(),
                    t(d.last).unwrap_or_default(),
                    d.samples
                ));
            }
            s
        }
        Format::Text => {
            let w = devices
                .iter()
                .map(|d| d.tag.len())
                .max()
                .unwrap_or(0)
                .max(3);
            let lw = devices
                .iter()
                .map(|d| d.loop_name.len())
                .max()
                .unwrap_or(0)
                .max(4);
            let mut s = format!(
                "{:<10}  {:<w$}  {:<lw$}  {:<27} {:<27} {:>10}",
                "unique_id", "tag", "loop", "first", "last", "samples"
            );
            for d in devices {
                s.push_str(&format!(
                    "\n{:<10}  {:<w$}  {:<lw$}  {:<27} {:<27} {:>10}",
                    d.unique_id,
                    d.tag,
                    d.loop_name,
                    t(d.first).unwrap_or_else(|| "-".into()),
                    t(d.last).unwrap_or_else(|| "-".into()),
                    d.samples
                ));
            }
            if devices.is_empty() {
                s.push_str("\n(no devices stored yet)");
            }
            s
        }
    }
}
