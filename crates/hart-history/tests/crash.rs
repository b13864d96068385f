//! kill -9 of a process in the middle of writing loses at most the last batch: the
//! test runs itself as the writer process (HART_HISTORY_CRASH_CHILD=db), which
//! prints the count of samples committed after each commit; the test kills it with
//! SIGKILL mid-write, then opens the file: intact, and holding every sample the child
//! reported committed, in order.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use hart_history::{Agg, DeviceKey, Query, Sample, Store, Var, Writer, WriterConfig};

const T0: u64 = 1_800_000_000;
const BATCH: Duration = Duration::from_millis(50);

fn key() -> DeviceKey {
    DeviceKey {
        unique_id: "26F1000001".into(),
        tag: "PT-101".into(),
        loop_name: "loop1".into(),
    }
}

/// The child: writes sample i with value i, one millisecond apart in time, as fast
/// as the writer takes them, for ever.
fn child(db: &str) -> ! {
    let w = Writer::start(
        db,
        WriterConfig {
            batch: BATCH,
            max_batch: 5_000,
            ..WriterConfig::default()
        },
    )
    .unwrap();
    let mut i = 0u64;
    let mut last = 0;
    loop {
        let batch: Vec<Sample> = (i..i + 100)
            .map(|n| Sample {
                device: key(),
                var: Var::Pv,
                value: n as f64,
                units: Some(12),
                quality: 0,
                time: UNIX_EPOCH + Duration::from_secs(T0) + Duration::from_millis(n),
            })
            .collect();
        i += 100;
        w.submit_wait(batch);
        let written = w.stats().written;
        if written != last {
            last = written;
            println!("committed {written}");
        }
    }
}

#[test]
fn kill_9_loses_at_most_the_last_batch() {
    if let Ok(db) = std::env::var("HART_HISTORY_CRASH_CHILD") {
        child(&db);
    }
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("h.sqlite").display().to_string();
    let mut c = Command::new(std::env::current_exe().unwrap())
        .args([
            "--exact",
            "kill_9_loses_at_most_the_last_batch",
            "--nocapture",
        ])
        .env("HART_HISTORY_CRASH_CHILD", &db)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(c.stdout.take().unwrap()).lines();
    let mut committed = 0u64;
    let mut commits = 0;
    let end = Instant::now() + Duration::from_secs(60);
    // Let it commit a few batches, then kill it at once, whatever it is doing.
    while commits < 8 && Instant::now() < end {
        let Some(Ok(l)) = lines.next() else { break };
        if let Some(n) = l.strip_prefix("committed ") {
            committed = n.trim().parse().unwrap();
            commits += 1;
        }
    }
    let _ = Command::new("kill")
        .args(["-9", &c.id().to_string()])
        .status();
    let _ = c.wait();
    assert!(
        commits >= 8,
        "the child committed {commits} batches in 60 s"
    );

    // The file opens, passes SQLite's check and holds a gap-free prefix that covers
    // everything reported committed.
    let conn = rusqlite::Connection::open(&db).unwrap();
    let ok: String = conn
        .query_row("PRAGMA integrity_check", [], |r| r.get(0))
        .unwrap();
    assert_eq!(ok, "ok");
    drop(conn);
    let mut s = Store::open(&db, false).unwrap();
    let rows = s
        .query(&Query {
            device: "PT-101".into(),
            var: Var::Pv,
            from: UNIX_EPOCH + Duration::from_secs(T0),
            to: SystemTime::now() + Duration::from_secs(86_400 * 3650),
            every: None,
            agg: Agg::Last,
        })
        .unwrap();
    let n = rows.len() as u64;
    assert!(
        n >= committed,
        "{n} rows stored, {committed} reported committed"
    );
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.value, Some(i as f64), "row {i}: a gap");
    }
    eprintln!("killed after {committed} reported committed; {n} in the file");
}
