//! The PC's exports and plots on an archive the simulation wrote: CSV rows and their
//! averages, GeoJSON checked by serde, by Python's json and by GDAL's ogrinfo when
//! they are installed, and the trend plot's PNG.
//!
//! `cargo test -p hart-wells --test export -- --ignored docs_example_plot` draws
//! docs/wells-trends.png again (10 days, 3 wells).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use hart_wells::archive::Archive;
use hart_wells::average::{averages, Every};
use hart_wells::export::{
    csv, geojson, geojson_wells, iso8601, parse_from, plot_png, read_wells, write_geojson,
    ExportError, WellInfo,
};
use hart_wells::proto::{VALID_LEVEL, VALID_TEMPERATURE};
use hart_wells::sim::{self, SimConfig};
use hart_wells::store::Durability;

/// Two days of the default network (3 wells), simulated once for all the tests.
fn archive_dir() -> &'static Path {
    static DIR: OnceLock<tempfile::TempDir> = OnceLock::new();
    DIR.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let r = sim::run(SimConfig {
            dir: Some(dir.path().to_path_buf()),
            days: 2.0,
            ..Default::default()
        })
        .unwrap();
        assert_eq!(r.lost, 0, "{r:?}");
        dir
    })
    .path()
}

fn open() -> Archive {
    Archive::open(&archive_dir().join("pc.db"), Durability::Process).unwrap()
}

const WELLS: &str = "# the simulated network's wells\n\
    well,name,latitude,longitude,elevation_m\n\
    1,Baijiatuan,40.0196,116.2483,52.0\n\
    2,\"Tangshan, deep\",39.6306,118.1802,\n\
    3,Hongshan,41.8005,123.4328,48.5\n";

fn places() -> Vec<WellInfo> {
    read_wells(WELLS).unwrap()
}

/// A scratch directory of the test's own.
fn scratch() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

#[test]
fn hourly_csv_has_a_row_per_stored_hour() {
    let a = open();
    let wells = a.wells().unwrap();
    assert_eq!(wells, vec![1, 2, 3]);
    let mut out = Vec::new();
    let n = csv(&a, &[], 0, u32::MAX, Every::Hour, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some("well,time,temperature_c,level_m,temperature_n,level_n")
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), n);
    // The hours the archive holds minutes of, per well.
    let mut expected = 0;
    for &w in &wells {
        let hours: BTreeSet<u32> = a
            .range(w, 0, u32::MAX)
            .unwrap()
            .iter()
            .map(|r| r.minute / 60)
            .collect();
        // Two days: 48 hours (the PC's last pull may leave the newest minutes at
        // the wells).
        assert!((46..=49).contains(&hours.len()), "{}", hours.len());
        expected += hours.len();
        let mine: Vec<&Vec<&str>> = rows.iter().filter(|r| r[0] == w.to_string()).collect();
        assert_eq!(mine.len(), hours.len());
        for (row, h) in mine.iter().zip(&hours) {
            assert_eq!(row.len(), 6);
            assert_eq!(row[1], iso8601(h * 60));
            assert_eq!(parse_from(row[1]), Ok(h * 60));
        }
    }
    assert_eq!(n, expected);
    for r in &rows {
        let t: f64 = r[2].parse().unwrap();
        let l: f64 = r[3].parse().unwrap();
        assert!((14.5..16.0).contains(&t), "{r:?}");
        assert!((9.0..11.0).contains(&l), "{r:?}");
        assert_eq!(r[2].split('.').nth(1).unwrap().len(), 4, "{r:?}");
        assert_eq!(r[3].split('.').nth(1).unwrap().len(), 4, "{r:?}");
        let tn: u32 = r[4].parse().unwrap();
        assert!(tn <= 60);
    }
}

#[test]
fn minute_csv_is_the_stored_minutes_and_averages_agree() {
    let a = open();
    let mut out = Vec::new();
    let n = csv(&a, &[2], 0, u32::MAX, Every::Minute, &mut out).unwrap();
    assert_eq!(n as u32, a.count(2).unwrap());
    let text = String::from_utf8(out).unwrap();
    // Mean of the printed minute values per hour against the printed hourly means.
    let mut sums: BTreeMap<String, (f64, u32)> = BTreeMap::new();
    for l in text.lines().skip(1) {
        let f: Vec<&str> = l.split(',').collect();
        assert_eq!(f[0], "2");
        let n: u32 = f[5].parse().unwrap();
        assert!(n <= 1);
        assert_eq!(f[3].is_empty(), n == 0, "{l}");
        if n == 1 {
            let hour = format!("{}:00:00Z", &f[1][..13]);
            let e = sums.entry(hour).or_default();
            e.0 += f[3].parse::<f64>().unwrap();
            e.1 += 1;
        }
    }
    let mut out = Vec::new();
    csv(&a, &[2], 0, u32::MAX, Every::Hour, &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    for l in text.lines().skip(1) {
        let f: Vec<&str> = l.split(',').collect();
        let (sum, n) = sums[f[1]];
        assert_eq!(n, f[5].parse::<u32>().unwrap(), "{l}");
        let mean: f64 = f[3].parse().unwrap();
        // The minute values are printed to 0.1 mm, so their mean is within 0.05 mm.
        assert!((mean - sum / f64::from(n)).abs() < 6e-5, "{l}");
    }
}

#[test]
fn longer_periods_count_every_valid_minute() {
    let a = open();
    for w in a.wells().unwrap() {
        let records = a.range(w, 0, u32::MAX).unwrap();
        let t = records
            .iter()
            .filter(|r| r.valid & VALID_TEMPERATURE != 0)
            .count() as u32;
        let l = records
            .iter()
            .filter(|r| r.valid & VALID_LEVEL != 0)
            .count() as u32;
        for e in Every::ALL {
            let avg = averages(records.clone(), e);
            assert_eq!(avg.iter().map(|x| x.temperature_n).sum::<u32>(), t, "{e}");
            assert_eq!(avg.iter().map(|x| x.level_n).sum::<u32>(), l, "{e}");
        }
        // The sensors hold the three minutes before the start (23:57-23:59 on
        // 28 February) when the simulation starts; then two days from 1 March.
        assert_eq!(iso8601(records[0].minute), "2026-02-28T23:57:00Z");
        assert_eq!(averages(records.clone(), Every::Pentad).len(), 2);
        assert_eq!(averages(records.clone(), Every::Month).len(), 2);
        let march = parse_from("2026-03-01").unwrap();
        let records = a.range(w, march, u32::MAX).unwrap();
        assert_eq!(averages(records.clone(), Every::Pentad).len(), 1);
        assert_eq!(averages(records.clone(), Every::Dekad).len(), 1);
        assert_eq!(averages(records.clone(), Every::Month).len(), 1);
        let day = averages(records, Every::Day);
        assert!(day.len() == 2 || day.len() == 3, "{day:?}");
    }
}

#[test]
fn a_range_and_a_well() {
    let a = open();
    let from = parse_from("2026-03-01T06:00").unwrap();
    let to = parse_from("2026-03-01T11:59").unwrap();
    let mut out = Vec::new();
    let n = csv(&a, &[1, 3], from, to, Every::Hour, &mut out).unwrap();
    assert_eq!(n, 12);
    let text = String::from_utf8(out).unwrap();
    let first = text.lines().nth(1).unwrap();
    assert!(first.starts_with("1,2026-03-01T06:00:00Z,"), "{first}");
    assert!(first.ends_with(",60,60"), "{first}");
    let last = text.lines().last().unwrap();
    assert!(last.starts_with("3,2026-03-01T11:00:00Z,"), "{last}");
    // Errors say what to check.
    let e = csv(&a, &[7], 0, u32::MAX, Every::Hour, Vec::new()).unwrap_err();
    assert!(matches!(e, ExportError::NoSuchWell { well: 7, .. }), "{e}");
    assert!(e.to_string().contains("1, 2 and 3"), "{e}");
    let e = csv(&a, &[], to, from, Every::Hour, Vec::new()).unwrap_err();
    assert!(matches!(e, ExportError::BadRange { .. }), "{e}");
}

#[test]
fn geojson_points_for_a_gis() {
    let a = open();
    let fc = geojson(&a, &places(), 0, u32::MAX, Every::Day).unwrap();
    assert_eq!(fc["type"], "FeatureCollection");
    let features = fc["features"].as_array().unwrap();
    let days: usize = [1, 2, 3]
        .iter()
        .map(|&w| averages(a.range(w, 0, u32::MAX).unwrap(), Every::Day).len())
        .sum();
    assert_eq!(features.len(), days);
    for f in features {
        assert_eq!(f["type"], "Feature");
        assert_eq!(f["geometry"]["type"], "Point");
        let c = f["geometry"]["coordinates"].as_array().unwrap();
        let p = &f["properties"];
        let keys: Vec<&str> = p.as_object().unwrap().keys().map(|k| k.as_str()).collect();
        assert_eq!(
            keys,
            [
                "well",
                "name",
                "time",
                "time_end",
                "temperature_c",
                "level_m",
                "temperature_n",
                "level_n"
            ]
        );
        // [longitude, latitude(, elevation)]
        match p["well"].as_u64().unwrap() {
            1 => {
                assert_eq!(c.len(), 3);
                assert_eq!(
                    (c[0].as_f64(), c[1].as_f64()),
                    (Some(116.2483), Some(40.0196))
                );
                assert_eq!(p["name"], "Baijiatuan");
            }
            2 => {
                assert_eq!(c.len(), 2);
                assert_eq!(c[0].as_f64(), Some(118.1802));
                assert_eq!(p["name"], "Tangshan, deep");
            }
            _ => assert_eq!(c[1].as_f64(), Some(41.8005)),
        }
        let t = p["time"].as_str().unwrap();
        let t_end = p["time_end"].as_str().unwrap();
        assert_eq!(parse_from(t_end).unwrap() - parse_from(t).unwrap(), 1440);
        assert!(p["level_m"].is_f64() && p["temperature_c"].is_f64());
    }
    // Wells without a place.
    let e = geojson(&a, &places()[..1], 0, u32::MAX, Every::Day).unwrap_err();
    assert!(
        matches!(&e, ExportError::NoPlace { wells } if wells == &[2, 3]),
        "{e}"
    );
    assert!(e.to_string().contains("wells 2 and 3"), "{e}");
    // Choosing the wells: only those need a place.
    let march = parse_from("2026-03-01").unwrap();
    let fc = geojson_wells(&a, &places()[..1], &[1], march, u32::MAX, Every::Month).unwrap();
    let f = fc["features"].as_array().unwrap();
    assert_eq!(f.len(), 1);
    assert_eq!(f[0]["properties"]["time"], "2026-03-01T00:00:00Z");
    assert_eq!(f[0]["properties"]["time_end"], "2026-04-01T00:00:00Z");
}

#[test]
fn geojson_file_opens_elsewhere() {
    let a = open();
    let dir = scratch();
    let path = dir.path().join("wells.geojson");
    let fc = geojson(&a, &places(), 0, u32::MAX, Every::Hour).unwrap();
    write_geojson(&fc, std::fs::File::create(&path).unwrap()).unwrap();
    let back: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(back, fc);
    let n = fc["features"].as_array().unwrap().len();

    // Python's json, which shares nothing with serde.
    let py = format!(
        "import json, sys\n\
         d = json.load(open(sys.argv[1]))\n\
         assert d['type'] == 'FeatureCollection', d['type']\n\
         fs = d['features']\n\
         assert len(fs) == {n}, len(fs)\n\
         f = fs[0]\n\
         assert f['geometry']['type'] == 'Point'\n\
         lon, lat = f['geometry']['coordinates'][:2]\n\
         assert (lon, lat) == (116.2483, 40.0196), (lon, lat)\n\
         p = f['properties']\n\
         assert p['well'] == 1 and p['time'] == '2026-02-28T23:00:00Z', p\n\
         assert fs[1]['properties']['time'] == '2026-03-01T00:00:00Z', fs[1]\n\
         assert 14 < p['temperature_c'] < 17 and 9 < p['level_m'] < 11, p\n\
         assert all(isinstance(x['properties']['level_n'], int) for x in fs)\n\
         print('python ok', len(fs))\n"
    );
    match Command::new("python3")
        .arg("-c")
        .arg(&py)
        .arg(&path)
        .output()
    {
        Ok(o) if o.status.success() => {
            assert!(String::from_utf8_lossy(&o.stdout).contains("python ok"));
        }
        Ok(o) => panic!(
            "python3 rejected the GeoJSON:\n{}",
            String::from_utf8_lossy(&o.stderr)
        ),
        Err(e) => eprintln!("skipping the Python check: no python3 ({e})"),
    }

    // GDAL, which QGIS reads GeoJSON with.
    match Command::new("ogrinfo")
        .args(["-ro", "-al", "-so"])
        .arg(&path)
        .output()
    {
        Ok(o) => {
            let s = String::from_utf8_lossy(&o.stdout);
            assert!(
                o.status.success(),
                "{s}{}",
                String::from_utf8_lossy(&o.stderr)
            );
            assert!(s.contains("Geometry: Point"), "{s}");
            assert!(s.contains(&format!("Feature Count: {n}")), "{s}");
            assert!(s.contains("time: DateTime"), "{s}");
        }
        Err(_) => eprintln!("skipping the GDAL check: ogrinfo is not installed"),
    }
}

/// Width, height and distinct colours of a PNG, after checking its signature and
/// header by hand.
fn look_at_png(path: &Path) -> (u32, u32, usize) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    assert_eq!(&bytes[12..16], b"IHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (w, h));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let colours: BTreeSet<[u8; 3]> = buf[..info.buffer_size()]
        .chunks(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    (w, h, colours.len())
}

#[test]
fn trend_plot_is_a_picture() {
    let a = open();
    let dir = scratch();
    let path = dir.path().join("trends.png");
    plot_png(&a, &[], 0, u32::MAX, Every::Hour, &path, (1000, 640)).unwrap();
    let (w, h, colours) = look_at_png(&path);
    assert_eq!((w, h), (1000, 640));
    // White, text, grid, three wells' colours and their smoothed edges.
    assert!(colours > 50, "{colours} colours");
    // One well, minute values, part of a day.
    let from = parse_from("2026-03-01T06:00").unwrap();
    let path = dir.path().join("one.png");
    plot_png(&a, &[2], from, from + 359, Every::Minute, &path, (800, 500)).unwrap();
    assert_eq!(look_at_png(&path).0, 800);
    // Nothing in the range, and a size too small.
    let e = plot_png(&a, &[1], 100, 200, Every::Hour, &path, (800, 500)).unwrap_err();
    assert!(matches!(e, ExportError::NoData { .. }), "{e}");
    let e = plot_png(&a, &[], 0, u32::MAX, Every::Hour, &path, (100, 50)).unwrap_err();
    assert!(e.to_string().contains("300 to 8000"), "{e}");
    let e = plot_png(
        &a,
        &[],
        0,
        u32::MAX,
        Every::Hour,
        Path::new("/nonexistent-dir/x.png"),
        (800, 500),
    )
    .unwrap_err();
    assert!(matches!(e, ExportError::Write { .. }), "{e}");
}

/// Draws docs/wells-trends.png: 10 days of 3 wells, hourly means.
#[test]
#[ignore = "writes docs/wells-trends.png; run it to draw the picture again"]
fn docs_example_plot() {
    let dir = scratch();
    sim::run(SimConfig {
        dir: Some(dir.path().to_path_buf()),
        days: 10.0,
        wells: 3,
        ..Default::default()
    })
    .unwrap();
    let a = Archive::open(&dir.path().join("pc.db"), Durability::Process).unwrap();
    let out: PathBuf = [
        env!("CARGO_MANIFEST_DIR"),
        "..",
        "..",
        "docs",
        "wells-trends.png",
    ]
    .iter()
    .collect();
    let from = parse_from("2026-03-01").unwrap();
    let to = parse_from("2026-03-11").unwrap() - 1;
    plot_png(&a, &[], from, to, Every::Hour, &out, (1400, 900)).unwrap();
    eprintln!("wrote {}", out.display());
}
