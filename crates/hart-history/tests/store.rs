//! The same suite against both backends: SQLite in a temporary file, and PostgreSQL
//! started by the test in a temporary data directory on a free loopback port
//! (skipped with a printed reason when its server is not installed, unless
//! HARTKIT_REQUIRE_INTEROP=1).

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use hart_history::pgtest;
use hart_history::{
    Agg, DeviceKey, Error, Query, Sample, Store, Var, Writer, WriterConfig, SCHEMA_VERSION,
};

const DAY: u64 = 86_400;
/// A day boundary (UTC) in 2027.
const T0: u64 = 1_800_000_000 - 1_800_000_000 % DAY;

fn at(s: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_secs(s)
}

fn key(i: u32, tag: &str) -> DeviceKey {
    DeviceKey {
        unique_id: format!("26F1{i:06X}"),
        tag: tag.into(),
        loop_name: "loop1".into(),
    }
}

fn sample(k: &DeviceKey, var: Var, t: u64, value: f64) -> Sample {
    Sample {
        device: k.clone(),
        var,
        value,
        units: Some(12),
        quality: 0,
        time: at(t),
    }
}

/// PV of device 1 every second for an hour from T0: value = second number.
fn hour_of_pv(k: &DeviceKey) -> Vec<Sample> {
    (0..3600)
        .map(|s| sample(k, Var::Pv, T0 + s, s as f64))
        .collect()
}

fn q(device: &str, var: Var, from: u64, to: u64, every: Option<u64>, agg: Agg) -> Query {
    Query {
        device: device.into(),
        var,
        from: at(from),
        to: at(to),
        every: every.map(Duration::from_secs),
        agg,
    }
}

/// Schema, round trip, aggregation, devices, lookups.
fn round_trip(db: &str) {
    let mut s = Store::open(db, true).unwrap();
    let a = key(1, "PT-101");
    let b = key(2, "TT-102");
    let mut batch = hour_of_pv(&a);
    // A quality change and a value the device did not report.
    batch[10].quality = 2;
    batch[11].value = f64::NAN;
    batch.push(sample(&b, Var::Sv, T0 + 5, 21.5));
    batch.push(Sample {
        units: None,
        ..sample(&b, Var::DeviceStatus, T0 + 5, 64.0)
    });
    // In several transactions, as the writer commits them.
    for chunk in batch.chunks(1000) {
        s.insert(chunk).unwrap();
    }
    // The same device, variable and time again replaces the value.
    s.insert(&[sample(&a, Var::Pv, T0 + 3599, 3599.0)]).unwrap();
    // A sample that arrives twice (an MQTT QoS 1 message delivered again to `history
    // ingest`), even within one batch, is stored once.
    let again = sample(&b, Var::Pv, T0 + 7, 7.5);
    s.insert(&[again.clone(), again.clone()]).unwrap();
    s.insert(&[again]).unwrap();
    let rows = s
        .query(&q("TT-102", Var::Pv, T0, T0 + 3600, None, Agg::Mean))
        .unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].value, Some(7.5));

    // Raw rows: [from, to).
    let rows = s
        .query(&q("PT-101", Var::Pv, T0 + 5, T0 + 15, None, Agg::Mean))
        .unwrap();
    assert_eq!(rows.len(), 10);
    assert_eq!(rows[0].time, at(T0 + 5));
    assert_eq!(rows[0].value, Some(5.0));
    assert_eq!(rows[0].units, Some(12));
    assert_eq!(rows[5].quality, 2);
    assert_eq!(rows[6].value, None, "NaN is stored as no value");

    // Buckets of a minute against values computed here (seconds 0..59 of each minute,
    // second 11 without value).
    for agg in [Agg::Mean, Agg::Min, Agg::Max, Agg::Last] {
        let rows = s
            .query(&q("26f1000001", Var::Pv, T0, T0 + 3600, Some(60), agg))
            .unwrap();
        assert_eq!(rows.len(), 60, "{agg:?}");
        for (m, r) in rows.iter().enumerate() {
            let vals: Vec<f64> = (m as u64 * 60..m as u64 * 60 + 60)
                .filter(|&s| s != 11)
                .map(|s| s as f64)
                .collect();
            let want = match agg {
                Agg::Mean => vals.iter().sum::<f64>() / vals.len() as f64,
                Agg::Min => vals[0],
                Agg::Max | Agg::Last => *vals.last().unwrap(),
            };
            assert_eq!(r.time, at(T0 + m as u64 * 60), "{agg:?}");
            let got = r.value.unwrap();
            assert!(
                (got - want).abs() < 1e-9,
                "{agg:?} minute {m}: {got} != {want}"
            );
            assert_eq!(
                r.quality,
                if m == 0 { 2 } else { 0 },
                "worst quality of the bucket"
            );
        }
    }
    // Buckets are aligned on their width since 1970, not on --from.
    let rows = s
        .query(&q("PT-101", Var::Pv, T0 + 30, T0 + 150, Some(60), Agg::Min))
        .unwrap();
    let times: Vec<_> = rows.iter().map(|r| r.time).collect();
    assert_eq!(times, [at(T0), at(T0 + 60), at(T0 + 120)]);
    assert_eq!(rows[0].value, Some(30.0));

    // Devices.
    let d = s.devices().unwrap();
    assert_eq!(d.len(), 2);
    assert_eq!(d[0].tag, "PT-101");
    assert_eq!(d[0].unique_id, "26F1000001");
    assert_eq!(d[0].samples, 3600);
    assert_eq!(d[0].first, Some(at(T0)));
    assert_eq!(d[0].last, Some(at(T0 + 3599)));
    assert_eq!(d[1].samples, 3, "SV, device status, and the PV stored once");
    let st = s
        .query(&q(
            "TT-102",
            Var::DeviceStatus,
            T0,
            T0 + 10,
            None,
            Agg::Last,
        ))
        .unwrap();
    assert_eq!((st[0].value, st[0].units), (Some(64.0), None));

    // A tag that changed: the device keeps its identity.
    let renamed = DeviceKey {
        tag: "PT-101A".into(),
        ..a.clone()
    };
    s.insert(&[sample(&renamed, Var::Pv, T0 + 4000, 1.0)])
        .unwrap();
    assert_eq!(s.devices().unwrap().len(), 2);
    assert_eq!(
        s.query(&q("PT-101A", Var::Pv, T0, T0 + DAY, None, Agg::Last))
            .unwrap()
            .len(),
        3601
    );

    // Unknown device, and a tag two devices share.
    let e = s
        .query(&q("nope", Var::Pv, T0, T0 + 1, None, Agg::Last))
        .unwrap_err();
    assert!(matches!(e, Error::NoSuchDevice(_)), "{e:?}");
    assert!(e.to_string().contains("hartkit history devices"), "{e}");
    s.insert(&[sample(&key(3, "TT-102"), Var::Pv, T0, 1.0)])
        .unwrap();
    let e = s
        .query(&q("TT-102", Var::Pv, T0, T0 + 1, None, Agg::Last))
        .unwrap_err();
    assert!(e.to_string().contains("unique ID"), "{e}");
    assert!(
        e.to_string().contains("26F1000002") && e.to_string().contains("26F1000003"),
        "{e}"
    );

    // Opening again keeps everything (the schema is created once).
    drop(s);
    let mut s = Store::open(db, false).unwrap();
    assert_eq!(s.devices().unwrap().len(), 3);
    let _ = SCHEMA_VERSION;
}

/// Retention by age: samples older than the age go, the rest stay.
fn retention(db: &str) {
    let mut s = Store::open(db, true).unwrap();
    let a = key(1, "PT-101");
    // One sample a minute over three days.
    let batch: Vec<Sample> = (0..3 * 1440)
        .map(|m| sample(&a, Var::Pv, T0 + m * 60, m as f64))
        .collect();
    s.insert(&batch).unwrap();
    let now = at(T0 + 3 * DAY);
    let mut done = false;
    for _ in 0..100 {
        let o = s
            .retention(
                now,
                Some(Duration::from_secs(DAY + DAY / 2)),
                None,
                Duration::from_secs(5),
            )
            .unwrap();
        if o.done {
            done = true;
            break;
        }
    }
    assert!(done);
    let rows = s
        .query(&q("PT-101", Var::Pv, T0, T0 + 4 * DAY, None, Agg::Last))
        .unwrap();
    assert_eq!(rows.first().unwrap().time, at(T0 + DAY + DAY / 2));
    assert_eq!(rows.len(), 1440 + 720);
}

/// The writer against a database that goes away: samples wait in memory and are all
/// written when it is back.
fn writer_survives(db: &str, away: impl FnOnce(), back: impl FnOnce()) {
    let w = Writer::start(
        db,
        WriterConfig {
            batch: Duration::from_millis(50),
            ..WriterConfig::default()
        },
    )
    .unwrap();
    let a = key(1, "PT-101");
    w.submit_wait(hour_of_pv(&a)[..100].to_vec());
    w.flush().unwrap();
    away();
    w.submit_wait(hour_of_pv(&a)[100..200].to_vec());
    let e = w.flush().unwrap_err();
    eprintln!("while away: {e}");
    let st = w.stats();
    assert!(st.failures >= 1 && st.backlog == 100, "{st:?}");
    assert!(st.last_error.is_some());
    back();
    // The writer retries by itself; flush makes it try now.
    let mut ok = false;
    for _ in 0..50 {
        if w.flush().is_ok() {
            ok = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(ok, "{:?}", w.stats());
    let st = w.close();
    assert_eq!((st.written, st.dropped, st.backlog), (200, 0, 0), "{st:?}");
    assert_eq!(st.last_error, None);
    let mut s = Store::open(db, false).unwrap();
    assert_eq!(
        s.query(&q("PT-101", Var::Pv, T0, T0 + DAY, None, Agg::Last))
            .unwrap()
            .len(),
        200
    );
}

fn sqlite_path(dir: &tempfile::TempDir) -> String {
    dir.path().join("h.sqlite").display().to_string()
}

#[test]
fn sqlite_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    round_trip(&sqlite_path(&dir));
    // WAL mode and the schema version are in the file.
    let c = rusqlite_check(&sqlite_path(&dir));
    assert_eq!(c, ("wal".to_string(), SCHEMA_VERSION));
}

fn rusqlite_check(path: &str) -> (String, i64) {
    // Read with the sqlite3 rules through our own store's SQL would hide a wrong mode:
    // ask SQLite directly.
    let c = rusqlite::Connection::open(path).unwrap();
    let mode: String = c
        .query_row("PRAGMA journal_mode", [], |r| r.get(0))
        .unwrap();
    let v: i64 = c
        .query_row("SELECT version FROM schema_version", [], |r| r.get(0))
        .unwrap();
    (mode, v)
}

#[test]
fn sqlite_retention_by_age() {
    let dir = tempfile::tempdir().unwrap();
    retention(&sqlite_path(&dir));
}

#[test]
fn sqlite_retention_by_size_deletes_the_oldest_days() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let mut s = Store::open(&db, true).unwrap();
    let a = key(1, "PT-101");
    // Five days, a sample every 10 s.
    let batch: Vec<Sample> = (0..5 * 8640)
        .map(|i| sample(&a, Var::Pv, T0 + i * 10, i as f64))
        .collect();
    s.insert(&batch).unwrap();
    let Store::Sqlite(inner) = &s else {
        unreachable!()
    };
    let used = inner.used_bytes().unwrap();
    let o = s
        .retention(
            at(T0 + 5 * DAY),
            None,
            Some(used / 2),
            Duration::from_secs(10),
        )
        .unwrap();
    assert!(o.done && o.deleted > 0, "{o:?}");
    let Store::Sqlite(inner) = &s else {
        unreachable!()
    };
    assert!(inner.used_bytes().unwrap() <= used / 2 + 65_536);
    let rows = s
        .query(&q("PT-101", Var::Pv, T0, T0 + 6 * DAY, None, Agg::Last))
        .unwrap();
    // Whole days went, oldest first; the newest day stays.
    let first = hart_history::micros(rows[0].time);
    assert_eq!(first % (DAY as i64 * 1_000_000), 0, "starts on a day");
    assert_eq!(rows.last().unwrap().time, at(T0 + 5 * DAY - 10));
    // A limit today's data alone exceed deletes nothing of today.
    let o = s
        .retention(at(T0 + 5 * DAY), None, Some(1), Duration::from_secs(10))
        .unwrap();
    assert!(o.done);
    let rows = s
        .query(&q(
            "PT-101",
            Var::Pv,
            T0 + 4 * DAY,
            T0 + 5 * DAY,
            None,
            Agg::Last,
        ))
        .unwrap();
    assert_eq!(rows.len(), 8640);
}

#[test]
fn sqlite_corrupt_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    // Random bytes (a fixed pseudo-random sequence).
    let mut x: u32 = 12345;
    let junk: Vec<u8> = (0..8192)
        .map(|_| {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            (x >> 16) as u8
        })
        .collect();
    std::fs::write(&db, &junk).unwrap();
    let e = Store::open(&db, true).err().unwrap();
    assert!(matches!(e, Error::Corrupt(_)), "{e:?}");
    assert!(
        e.to_string().contains("not an SQLite database") && e.to_string().contains("move it aside"),
        "{e}"
    );
    let e = Writer::start(&db, WriterConfig::default()).err().unwrap();
    assert!(matches!(e, Error::Corrupt(_)), "{e:?}");
    assert_eq!(
        std::fs::read(&db).unwrap(),
        junk,
        "the file is left as it was"
    );
    // A missing file for a query.
    let e = Store::open(&dir.path().join("none.sqlite").display().to_string(), false)
        .err()
        .unwrap();
    assert!(e.to_string().contains("no such file"), "{e}");
}

#[test]
fn sqlite_full_disk_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let mut s = Store::open(&db, true).unwrap();
    let Store::Sqlite(inner) = &s else {
        unreachable!()
    };
    inner.set_max_page_count(8).unwrap();
    let e = s.insert(&hour_of_pv(&key(1, "PT-101"))).unwrap_err();
    assert!(matches!(e, Error::Full(_)), "{e:?}");
    assert!(e.to_string().contains("disk is full"), "{e}");
}

#[test]
fn sqlite_locked_file_keeps_samples_until_free() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    drop(Store::open(&db, true).unwrap());
    let other = rusqlite::Connection::open(&db).unwrap();
    let hold = std::cell::RefCell::new(Some(other));
    writer_survives(
        &db,
        || {
            hold.borrow()
                .as_ref()
                .unwrap()
                .execute_batch("BEGIN EXCLUSIVE")
                .unwrap()
        },
        || {
            let c = hold.borrow_mut().take().unwrap();
            c.execute_batch("COMMIT").unwrap();
        },
    );
}

#[test]
fn sqlite_backlog_is_bounded_and_counts_what_it_drops() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    drop(Store::open(&db, true).unwrap());
    let other = rusqlite::Connection::open(&db).unwrap();
    other.execute_batch("BEGIN EXCLUSIVE").unwrap();
    let w = Writer::start(
        &db,
        WriterConfig {
            backlog: 100,
            ..WriterConfig::default()
        },
    )
    .unwrap();
    w.submit_wait(hour_of_pv(&key(1, "PT-101"))[..250].to_vec());
    let e = w.flush().unwrap_err();
    assert!(matches!(e, Error::Locked(_)), "{e:?}");
    assert!(e.to_string().contains("locked by another program"), "{e}");
    let st = w.stats();
    assert_eq!((st.dropped, st.backlog), (150, 100), "{st:?}");
    other.execute_batch("COMMIT").unwrap();
    w.flush().unwrap();
    let st = w.close();
    assert_eq!(st.written, 100);
    // The newest were kept.
    let mut s = Store::open(&db, false).unwrap();
    let rows = s
        .query(&q("PT-101", Var::Pv, T0, T0 + DAY, None, Agg::Last))
        .unwrap();
    assert_eq!(rows[0].value, Some(150.0));
}

#[test]
fn sqlite_newer_schema_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    drop(Store::open(&db, true).unwrap());
    rusqlite::Connection::open(&db)
        .unwrap()
        .execute("UPDATE schema_version SET version = 99", [])
        .unwrap();
    let e = Store::open(&db, false).err().unwrap();
    assert!(matches!(e, Error::Schema(_)), "{e:?}");
    assert!(e.to_string().contains("newer hartkit"), "{e}");
}

#[test]
fn postgres_suite() {
    let Some(pg) = pgtest::for_test(false) else {
        return;
    };
    let url = pg.url();
    round_trip(&url);
    // Each day is a partition of its own.
    let mut c = postgres::Client::connect(&url, postgres::NoTls).unwrap();
    let parts: i64 = c
        .query_one(
            "SELECT count(*) FROM pg_inherits i JOIN pg_class p ON p.oid = i.inhparent WHERE p.relname = 'samples'",
            &[],
        )
        .unwrap()
        .get(0);
    assert_eq!(parts, 1, "one day of data");
    c.batch_execute("DROP TABLE samples, devices, schema_version")
        .unwrap();
    retention(&url);
    let parts: i64 = c
        .query_one(
            "SELECT count(*) FROM pg_inherits i JOIN pg_class p ON p.oid = i.inhparent WHERE p.relname = 'samples'",
            &[],
        )
        .unwrap()
        .get(0);
    assert_eq!(parts, 2, "the oldest day's partition was dropped");
    c.batch_execute("DROP TABLE samples, devices, schema_version")
        .unwrap();
    drop(c);
    // The server stops under the writer and comes back: nothing lost.
    writer_survives(&url, || pg.stop().unwrap(), || pg.start_again().unwrap());
    // A server that is not there at all.
    let e = Store::open("postgres://hartkit@127.0.0.1:1/postgres", true)
        .err()
        .unwrap();
    assert!(matches!(e, Error::Gone(_)), "{e:?}");
    assert!(e.to_string().contains("check that PostgreSQL runs"), "{e}");
    let e = Store::open("postgres://x@[bad", true).err().unwrap();
    assert!(matches!(e, Error::Usage(_)), "{e:?}");
}

/// Samples stored for device `tag`'s PV in the SQLite file at `db` (opened anew).
fn stored(db: &str, tag: &str) -> usize {
    let mut s = Store::open(db, false).unwrap();
    s.query(&q(tag, Var::Pv, T0, T0 + DAY, None, Agg::Last))
        .unwrap()
        .len()
}

fn remove_with_logs(db: &str) {
    for suffix in ["", "-wal", "-shm"] {
        let _ = std::fs::remove_file(format!("{db}{suffix}"));
    }
}

/// A writer that commits only when flushed (its batch period is long).
fn flushed_writer(db: &str, on_file_lost: hart_history::FileLost) -> Writer {
    Writer::start(
        db,
        WriterConfig {
            batch: Duration::from_secs(3600),
            on_file_lost,
            ..WriterConfig::default()
        },
    )
    .unwrap()
}

/// The reproduction of a review: `rm` of the file and its WAL under a running writer
/// left every later sample going to deleted files, with nothing logged. The writer
/// notices before its next transaction and opens a new file at the path.
#[test]
fn sqlite_file_removed_under_the_writer_is_opened_anew() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let w = flushed_writer(&db, hart_history::FileLost::Reopen);
    let hour = hour_of_pv(&key(1, "PT-101"));
    w.submit_wait(hour[..100].to_vec());
    w.flush().unwrap();
    remove_with_logs(&db);
    w.submit_wait(hour[100..200].to_vec());
    w.flush().unwrap();
    assert_eq!(
        stored(&db, "PT-101"),
        100,
        "the samples after the removal, in a new file"
    );
    w.submit_wait(hour[200..300].to_vec());
    w.flush().unwrap();
    assert_eq!(stored(&db, "PT-101"), 200, "and on after it");
    assert_eq!(w.close().dropped, 0);
}

/// Only the write-ahead log removed: the connection left open on it would make every
/// new one fail (SQLite shares the log's index within a process); the writer lets go
/// of it first, so the file is opened again and keeps what it held.
#[test]
fn sqlite_wal_removed_under_the_writer_is_recovered() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let w = flushed_writer(&db, hart_history::FileLost::Reopen);
    let hour = hour_of_pv(&key(1, "PT-101"));
    w.submit_wait(hour[..100].to_vec());
    w.flush().unwrap();
    std::fs::remove_file(format!("{db}-wal")).unwrap();
    w.submit_wait(hour[100..200].to_vec());
    w.flush().unwrap();
    w.submit_wait(hour[200..300].to_vec());
    w.flush().unwrap();
    let st = w.close();
    assert_eq!(st.dropped, 0, "{st:?}");
    assert!(
        stored(&db, "PT-101") >= 200,
        "the samples after the loss are in the file"
    );
}

/// A backup restored by moving it over the file (`mv`), the live -wal and -shm left
/// at the path: the writer writes the old log into the file moved away, so the
/// backup is not overwritten by it, and writes on into the backup.
#[test]
fn sqlite_backup_moved_over_the_file_is_kept_and_written_on() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let backup = dir.path().join("backup.sqlite").display().to_string();
    {
        let w = Writer::start(&backup, WriterConfig::default()).unwrap();
        w.submit_wait(hour_of_pv(&key(2, "TT-200"))[..50].to_vec());
        w.flush().unwrap();
        w.close();
    }
    let w = flushed_writer(&db, hart_history::FileLost::Reopen);
    let hour = hour_of_pv(&key(1, "PT-101"));
    w.submit_wait(hour[..100].to_vec());
    w.flush().unwrap();
    std::fs::rename(&backup, &db).unwrap();
    w.submit_wait(hour[100..200].to_vec());
    w.flush().unwrap();
    w.close();
    assert_eq!(stored(&db, "TT-200"), 50, "the backup's samples are kept");
    assert_eq!(
        stored(&db, "PT-101"),
        100,
        "the writer went on in the backup"
    );
}

/// With `on_file_lost = "stop"`, history stops with an error that stays, and every
/// later sample is counted as dropped; nothing is written anywhere.
#[test]
fn sqlite_file_removed_under_the_writer_can_stop_history() {
    let dir = tempfile::tempdir().unwrap();
    let db = sqlite_path(&dir);
    let w = flushed_writer(&db, hart_history::FileLost::Stop);
    let hour = hour_of_pv(&key(1, "PT-101"));
    w.submit_wait(hour[..100].to_vec());
    w.flush().unwrap();
    remove_with_logs(&db);
    w.submit_wait(hour[100..200].to_vec());
    let e = w.flush().unwrap_err();
    assert!(
        e.to_string().contains("was removed") && e.to_string().contains("history stopped"),
        "{e}"
    );
    w.submit_wait(hour[200..300].to_vec());
    assert!(w.flush().is_err(), "it stays stopped");
    let st = w.close();
    assert_eq!(st.dropped, 200, "{st:?}");
    assert!(st.last_error.unwrap().contains("history stopped"));
    assert!(!std::path::Path::new(&db).exists(), "no new file");
}
