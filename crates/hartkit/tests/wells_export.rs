//! The options and functions behind `hartkit wells pc export` and `wells pc plot`
//! (hartkit::wells_export), on an archive the simulation wrote.

mod common;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use clap::Parser;
use hartkit::wells_export::{export, parse_size, plot, ExportArgs, PlotArgs};

#[derive(Parser)]
struct Export {
    #[command(flatten)]
    a: ExportArgs,
}

#[derive(Parser)]
struct Plot {
    #[command(flatten)]
    a: PlotArgs,
}

/// A day of two wells, simulated once.
fn sim_dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        hart_wells::sim::run(hart_wells::sim::SimConfig {
            dir: Some(dir.path().to_path_buf()),
            wells: 2,
            days: 1.0,
            ..Default::default()
        })
        .unwrap();
        dir
    })
    .path()
}

fn db() -> String {
    sim_dir().join("pc.db").display().to_string()
}

fn export_args(args: &[&str]) -> ExportArgs {
    Export::try_parse_from(std::iter::once("export").chain(args.iter().copied()))
        .unwrap()
        .a
}

fn out_dir() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn defaults() {
    let a = export_args(&["--db", "x.db"]);
    assert_eq!((a.format.as_str(), a.sel.every.as_str()), ("csv", "hour"));
    assert!(a.sel.well.is_empty() && a.output.is_none() && a.wells.is_none());
    let p = Plot::try_parse_from(["plot", "--db", "x.db", "--png", "p.png", "--well", "2"])
        .unwrap()
        .a;
    assert_eq!(p.size, (1400, 900));
    assert_eq!(p.sel.well, vec![2]);
    assert!(Export::try_parse_from(["export", "--db", "x", "--every", "week"]).is_err());
    assert!(Export::try_parse_from(["export", "--db", "x", "--well", "16"]).is_err());
    assert_eq!(parse_size("800x600"), Ok((800, 600)));
    assert!(parse_size("800").unwrap_err().contains("WIDTHxHEIGHT"));
    assert!(parse_size("100x100").unwrap_err().contains("300 to 8000"));
}

#[test]
fn csv_to_a_file() {
    let out = out_dir();
    let path = out.path().join("day.csv");
    let a = export_args(&[
        "--db",
        &db(),
        "--from",
        "2026-03-01",
        "--to",
        "2026-03-01T12:00",
        "--well",
        "2",
        "--output",
        path.to_str().unwrap(),
    ]);
    let summary = export(&a).unwrap();
    assert!(
        summary.starts_with("12 rows of hourly means (well 2"),
        "{summary}"
    );
    let text = std::fs::read_to_string(&path).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 13);
    assert!(
        lines[1].starts_with("2,2026-03-01T00:00:00Z,"),
        "{}",
        lines[1]
    );
    assert!(
        lines[12].starts_with("2,2026-03-01T11:00:00Z,"),
        "{}",
        lines[12]
    );
    let leftovers: Vec<PathBuf> = std::fs::read_dir(out.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(leftovers, vec![path]);
}

#[test]
fn geojson_needs_the_wells_file() {
    let out = out_dir();
    let e = export(&export_args(&["--db", &db(), "--format", "geojson"])).unwrap_err();
    assert!(e.contains("--wells FILE"), "{e}");
    let wells = out.path().join("wells.csv");
    std::fs::write(
        &wells,
        "well,name,latitude,longitude,elevation_m\n1,North,40.0,116.0,50\n",
    )
    .unwrap();
    let path = out.path().join("w.geojson");
    let args = |w: &str| {
        export_args(&[
            "--db",
            &db(),
            "--format",
            "geojson",
            "--every",
            "day",
            "--wells",
            wells.to_str().unwrap(),
            "--output",
            path.to_str().unwrap(),
            "--well",
            w,
        ])
    };
    // Well 2 has no place: an error, and no file.
    let e = export(&args("2")).unwrap_err();
    assert!(e.contains("well 2 has") && e.contains("no place"), "{e}");
    assert!(!path.exists());
    let summary = export(&args("1")).unwrap();
    assert!(summary.contains("points of daily means"), "{summary}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(v["type"], "FeatureCollection");
    let f = &v["features"][0];
    assert_eq!(
        f["geometry"]["coordinates"],
        serde_json::json!([116.0, 40.0, 50.0])
    );
    assert_eq!(f["properties"]["name"], "North");
    // A bad wells file names its line.
    std::fs::write(&wells, "well,name,latitude,longitude\n1,North,95,116\n").unwrap();
    let e = export(&args("1")).unwrap_err();
    assert!(e.contains("line 2") && e.contains("latitude"), "{e}");
}

#[test]
fn refuses_what_is_not_an_archive() {
    let out = out_dir();
    let missing = out.path().join("nothing.db");
    let e = export(&export_args(&["--db", missing.to_str().unwrap()])).unwrap_err();
    assert!(e.contains("no archive at"), "{e}");
    assert!(!missing.exists(), "an empty database was created");
    let e = export(&export_args(&["--db", out.path().to_str().unwrap()])).unwrap_err();
    assert!(e.contains("is a directory"), "{e}");
    let text = out.path().join("notes.txt");
    std::fs::write(&text, "well,name\n").unwrap();
    let e = export(&export_args(&["--db", text.to_str().unwrap()])).unwrap_err();
    assert!(e.contains("not an SQLite database"), "{e}");
    // A concentrator's store is SQLite but not an archive; it is left as it was.
    let store = sim_dir().join("well1.db");
    let before = std::fs::read(&store).unwrap();
    let e = export(&export_args(&["--db", store.to_str().unwrap()])).unwrap_err();
    assert!(e.contains("not an archive"), "{e}");
    assert_eq!(std::fs::read(&store).unwrap(), before);
    let e = export(&export_args(&["--db", &db(), "--from", "March"])).unwrap_err();
    assert!(e.starts_with("--from `March` is not a date"), "{e}");
    let e = export(&export_args(&[
        "--db",
        &db(),
        "--from",
        "2026-03-02",
        "--to",
        "2026-03-01",
    ]))
    .unwrap_err();
    assert!(e.contains("not before"), "{e}");
    let e = export(&export_args(&["--db", &db(), "--well", "9"])).unwrap_err();
    assert!(e.contains("no minutes of well 9"), "{e}");
}

#[test]
fn a_plot() {
    let out = out_dir();
    let png = out.path().join("t.png");
    let a = Plot::try_parse_from([
        "plot",
        "--db",
        &db(),
        "--png",
        png.to_str().unwrap(),
        "--size",
        "900x600",
        "--every",
        "10d",
    ])
    .unwrap()
    .a;
    let s = plot(&a).unwrap();
    assert!(s.contains("dekad") && s.contains("900x600"), "{s}");
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    assert_eq!(u32::from_be_bytes(bytes[16..20].try_into().unwrap()), 900);
    let a = Plot::try_parse_from([
        "plot",
        "--db",
        &db(),
        "--png",
        png.to_str().unwrap(),
        "--from",
        "2027-01-01",
    ])
    .unwrap()
    .a;
    let e = plot(&a).unwrap_err();
    assert!(e.contains("no minutes of wells 1 and 2"), "{e}");
}

/// GDAL, the library under QGIS and most GIS tools (through pyogrio, a separate process
/// from the interop venv), opens the export as a point layer: every feature, the
/// coordinates in WGS 84 with the elevation, times as date-times and the means as
/// numbers.
#[test]
fn a_gis_opens_the_geojson() {
    let Some(py) = common::interop_python("pyogrio") else {
        return;
    };
    let out = out_dir();
    let wells = out.path().join("wells.csv");
    std::fs::write(
        &wells,
        "well,name,latitude,longitude,elevation_m\n1,North,40.0,116.0,50\n2,South,39.5,116.25,48\n",
    )
    .unwrap();
    let path = out.path().join("w.geojson");
    export(&export_args(&[
        "--db",
        &db(),
        "--format",
        "geojson",
        "--every",
        "hour",
        "--wells",
        wells.to_str().unwrap(),
        "--output",
        path.to_str().unwrap(),
    ]))
    .unwrap();
    let ours: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/gis/read_with_gdal.py");
    let run = std::process::Command::new(py)
        .arg(&script)
        .arg(&path)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "GDAL could not read the export: {}",
        String::from_utf8_lossy(&run.stderr)
    );
    let gis: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    assert_eq!(gis["driver"], "GeoJSON", "{gis}");
    assert_eq!(
        gis["features"].as_u64(),
        Some(ours["features"].as_array().unwrap().len() as u64),
        "{gis}"
    );
    assert!(gis["features"].as_u64().unwrap() >= 2 * 24, "{gis}");
    assert_eq!(gis["geometry_type"], "Point Z", "{gis}");
    // WGS 84 (GDAL names the 3D form when points carry an elevation).
    assert!(
        ["EPSG:4326", "EPSG:4979", "OGC:CRS84"].contains(&gis["crs"].as_str().unwrap_or("")),
        "{gis}"
    );
    let fields = &gis["fields"];
    assert_eq!(fields["well"], "int32", "{gis}");
    assert_eq!(fields["name"], "object", "{gis}");
    assert!(
        fields["time"].as_str().unwrap().starts_with("datetime64"),
        "time is a date-time to a GIS: {gis}"
    );
    assert_eq!(fields["level_m"], "float64", "{gis}");
    assert_eq!(fields["temperature_c"], "float64", "{gis}");
    let first = &ours["features"][0]["properties"];
    assert_eq!(gis["first"]["well"], first["well"], "{gis}");
    assert_eq!(gis["first"]["name"], first["name"], "{gis}");
    assert_eq!(gis["first"]["level_m"], first["level_m"], "{gis}");
    // A 3D point as WKB: byte order, type, three doubles.
    assert_eq!(gis["first_wkb_bytes"], 29, "{gis}");
}
