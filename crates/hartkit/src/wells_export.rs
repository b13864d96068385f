//! `hartkit wells pc export` and `hartkit wells pc plot`: the PC's archive as CSV, as
//! GeoJSON points for a GIS, or as a PNG of the level and temperature trends
//! (docs/wells.md, "The PC: exports and plots"). Options are read here; the work is
//! `hart_wells::export`'s.

use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

use clap::Args;
use hart_wells::average::Every;
use hart_wells::export::{self, open_archive, parse_from, parse_to, read_wells};

/// The averaging periods `--every` takes.
const PERIODS: [&str; 6] = ["minute", "hour", "day", "5d", "10d", "month"];

/// Which data: the archive, the period, the averaging, the wells.
#[derive(Args, Debug, Clone)]
pub struct Selection {
    /// The PC's archive (SQLite) that `wells pc pull --db` keeps (DIR/pc.db after
    /// `wells sim --dir DIR`). It must exist.
    #[arg(long, value_name = "FILE")]
    pub db: PathBuf,
    /// Start, UTC: 2026-03-01, 2026-03-01T12:00 or 2026-03-01T12:00:00Z [default:
    /// the first stored minute].
    #[arg(long, value_name = "DATE")]
    pub from: Option<String>,
    /// End, UTC, not included; a date alone means the end of that day [default: the
    /// last stored minute, included].
    #[arg(long, value_name = "DATE")]
    pub to: Option<String>,
    /// Average over: minute (the stored minutes themselves), hour, day, 5d (pentads
    /// of the month: 1-5, 6-10, ..., 26-end), 10d (dekads: 1-10, 11-20, 21-end) or
    /// month; UTC.
    #[arg(long, default_value = "hour", value_parser = PERIODS)]
    pub every: String,
    /// Only this well, 1-15; repeat for more [default: every well in the archive].
    #[arg(long = "well", value_name = "N", value_parser = clap::value_parser!(u8).range(1..=15))]
    pub well: Vec<u8>,
}

/// `wells pc export`.
#[derive(Args, Debug, Clone)]
pub struct ExportArgs {
    #[command(flatten)]
    pub sel: Selection,
    /// csv: a row per well and period; geojson: a point per well and period, at the
    /// well's place from --wells (a layer for QGIS or another GIS).
    #[arg(long, default_value = "csv", value_parser = ["csv", "geojson"])]
    pub format: String,
    /// The wells file: CSV `well,name,latitude,longitude,elevation_m` (decimal
    /// degrees, WGS 84). Needed for geojson.
    #[arg(long, value_name = "FILE")]
    pub wells: Option<PathBuf>,
    /// Write to FILE [default: standard output].
    #[arg(long, value_name = "FILE")]
    pub output: Option<PathBuf>,
}

/// `wells pc plot`.
#[derive(Args, Debug, Clone)]
pub struct PlotArgs {
    #[command(flatten)]
    pub sel: Selection,
    /// The picture to write (PNG).
    #[arg(long, value_name = "FILE")]
    pub png: PathBuf,
    /// Size of the picture, pixels: WIDTHxHEIGHT, each 300-8000.
    #[arg(long, default_value = "1400x900", value_name = "WxH", value_parser = parse_size)]
    pub size: (u32, u32),
}

/// Reads `1400x900`.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{s}` is not a size: write WIDTHxHEIGHT in pixels, such as 1400x900");
    let (w, h) = s.trim().split_once(['x', 'X']).ok_or_else(bad)?;
    let w: u32 = w.trim().parse().map_err(|_| bad())?;
    let h: u32 = h.trim().parse().map_err(|_| bad())?;
    if !(300..=8000).contains(&w) || !(300..=8000).contains(&h) {
        return Err(format!(
            "{w}x{h}: give a width and a height of 300 to 8000 pixels"
        ));
    }
    Ok((w, h))
}

/// The range of minutes asked for: `from..=to`, open ends for everything stored.
fn range(from: Option<&str>, to: Option<&str>) -> Result<(u32, u32), String> {
    let f = from
        .map(parse_from)
        .transpose()
        .map_err(|e| format!("--from {e}"))?
        .unwrap_or(0);
    let t = to
        .map(parse_to)
        .transpose()
        .map_err(|e| format!("--to {e}"))?
        .unwrap_or(u32::MAX);
    if f > t {
        return Err(format!(
            "--from {} is not before --to {}; the end is not included (a date alone means \
             the end of that day)",
            from.unwrap_or(""),
            to.unwrap_or("")
        ));
    }
    Ok((f, t))
}

/// `wells 1, 2 and 3, 2026-03-01 00:00 to 2026-03-03 23:59 UTC` for a summary.
fn what(wells: &[u8], from: u32, to: u32) -> String {
    let wells = if wells.is_empty() {
        "every well".to_string()
    } else {
        let v: Vec<String> = wells.iter().map(|w| w.to_string()).collect();
        format!(
            "{} {}",
            if v.len() == 1 { "well" } else { "wells" },
            v.join(", ")
        )
    };
    let when = |m: u32| {
        let s = export::iso8601(m);
        format!("{} {}", &s[..10], &s[11..16])
    };
    match (from, to) {
        (0, u32::MAX) => format!("{wells}, everything stored"),
        (0, t) => format!("{wells}, up to {} UTC", when(t)),
        (f, u32::MAX) => format!("{wells}, from {} UTC", when(f)),
        (f, t) => format!("{wells}, {} to {} UTC", when(f), when(t)),
    }
}

/// Writes to `path` through a file beside it that takes its name only when all is
/// written (a failed export leaves no half file), or to standard output.
fn write_out<T>(
    path: Option<&Path>,
    write: impl FnOnce(Box<dyn Write + '_>) -> Result<T, export::ExportError>,
) -> Result<T, String> {
    let Some(path) = path else {
        let stdout = io::stdout();
        return write(Box::new(stdout.lock())).map_err(|e| e.to_string());
    };
    let mut part = path.as_os_str().to_owned();
    part.push(".part");
    let part = PathBuf::from(part);
    let file = File::create(&part).map_err(|e| {
        format!(
            "cannot write {}: {e}; check that the directory exists and is writable",
            path.display()
        )
    })?;
    match write(Box::new(&file)).and_then(|v| {
        file.sync_all()
            .map_err(|error| export::ExportError::Write {
                to: path.display().to_string(),
                error,
            })?;
        Ok(v)
    }) {
        Ok(v) => {
            std::fs::rename(&part, path).map_err(|e| {
                let _ = std::fs::remove_file(&part);
                format!("cannot write {}: {e}", path.display())
            })?;
            Ok(v)
        }
        Err(e) => {
            let _ = std::fs::remove_file(&part);
            Err(e.to_string())
        }
    }
}

/// `wells pc export`: writes the CSV or GeoJSON to --output or standard output.
/// Returns a one-line summary of what was written, meant for standard error (the
/// data itself may be on standard output).
pub fn export(a: &ExportArgs) -> Result<String, String> {
    let every = Every::parse(&a.sel.every)?;
    let (from, to) = range(a.sel.from.as_deref(), a.sel.to.as_deref())?;
    if a.format == "geojson" && a.wells.is_none() {
        return Err(
            "--format geojson needs --wells FILE: each well's place, CSV with the \
                    header well,name,latitude,longitude,elevation_m (see docs/wells.md)"
                .into(),
        );
    }
    let archive = open_archive(&a.sel.db)?;
    let dest = a
        .output
        .as_ref()
        .map_or("standard output".to_string(), |p| p.display().to_string());
    let scope = what(&a.sel.well, from, to);
    if a.format == "geojson" {
        let wells_path = a.wells.as_ref().expect("checked above");
        let text = std::fs::read_to_string(wells_path).map_err(|e| {
            format!(
                "cannot read the wells file {}: {e}; check the path",
                wells_path.display()
            )
        })?;
        let places = read_wells(&text).map_err(|e| format!("{}: {e}", wells_path.display()))?;
        let fc = export::geojson_wells(&archive, &places, &a.sel.well, from, to, every)
            .map_err(|e| e.to_string())?;
        let n = fc["features"].as_array().map_or(0, Vec::len);
        write_out(a.output.as_deref(), |w| export::write_geojson(&fc, w))?;
        Ok(format!(
            "{n} points of {} ({scope}) as GeoJSON to {dest}",
            every.describe()
        ))
    } else {
        let n = write_out(a.output.as_deref(), |w| {
            export::csv(&archive, &a.sel.well, from, to, every, w)
        })?;
        Ok(format!(
            "{n} rows of {} ({scope}) as CSV to {dest}",
            every.describe()
        ))
    }
}

/// `wells pc plot`: draws the trends to --png. Returns a one-line summary.
pub fn plot(a: &PlotArgs) -> Result<String, String> {
    let every = Every::parse(&a.sel.every)?;
    let (from, to) = range(a.sel.from.as_deref(), a.sel.to.as_deref())?;
    let archive = open_archive(&a.sel.db)?;
    export::plot_png(&archive, &a.sel.well, from, to, every, &a.png, a.size)
        .map_err(|e| e.to_string())?;
    Ok(format!(
        "drew {} ({}) in {} ({}x{} pixels)",
        every.describe(),
        what(&a.sel.well, from, to),
        a.png.display(),
        a.size.0,
        a.size.1
    ))
}
