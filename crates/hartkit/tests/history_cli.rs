//! The historian as a user runs it: `hartkit serve --sim --history FILE` keeps the demo
//! plant's values, a gateway killed with SIGKILL leaves a readable file, and
//! `hartkit history devices|query` read it back (table, JSON, CSV, buckets); bad
//! arguments say what to give.

mod common;

use common::{hartkit, Kill};
use serde_json::Value;

/// `hartkit serve --sim --instant --history DB ARGS`, its first line read (it has
/// started).
fn serve_history(db: &std::path::Path, extra: &[&str]) -> Kill {
    use std::io::BufRead;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args([
            "serve",
            "--sim",
            "--instant",
            "--history",
            db.to_str().unwrap(),
        ])
        .args(extra)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    assert!(line.starts_with("history: "), "{line:?}");
    std::thread::spawn(move || {
        let mut sink = String::new();
        while out.read_line(&mut sink).is_ok_and(|n| n > 0) {
            sink.clear();
        }
    });
    Kill(child)
}

#[test]
fn the_demo_plant_is_kept_and_read_back_after_a_kill() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("plant.sqlite");
    let db_s = db.to_str().unwrap();
    let mut gw = serve_history(&db, &["--poll-period", "0.5"]);
    std::thread::sleep(std::time::Duration::from_secs(4));
    // No orderly stop: what the last committed batch holds must be there.
    let _ = gw.0.kill();
    let _ = gw.0.wait();

    let (code, out, err) = hartkit(&["history", "devices", "--db", db_s, "--json"]);
    assert_eq!(code, 0, "{err}");
    let devices: Vec<Value> = serde_json::from_str(&out).unwrap();
    let tags: Vec<&str> = devices.iter().filter_map(|d| d["tag"].as_str()).collect();
    for tag in ["PT-100", "TT-200", "FV-300"] {
        assert!(tags.contains(&tag), "{tag} in {tags:?}");
    }
    // TT-200's PV: raw rows, in time order, in degC, good.
    let (code, out, err) = hartkit(&[
        "history", "query", "--db", db_s, "--device", "TT-200", "--var", "pv", "--from", "-10m",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let rows: Vec<Value> = serde_json::from_str(&out).unwrap();
    assert!(rows.len() >= 2, "{rows:?}");
    let times: Vec<&str> = rows.iter().map(|r| r["time"].as_str().unwrap()).collect();
    assert!(times.windows(2).all(|w| w[0] <= w[1]), "{times:?}");
    assert!(rows.iter().all(|r| r["units"] == 32 && r["quality"] == 0));
    // Buckets: CSV with its header; the mean lies between min and max.
    let agg = |a: &str| {
        let (code, out, err) = hartkit(&[
            "history", "query", "--db", db_s, "--device", "TT-200", "--var", "pv", "--from",
            "-10m", "--every", "1h", "--agg", a, "--csv",
        ]);
        assert_eq!(code, 0, "{err}");
        let mut lines = out.lines();
        assert_eq!(lines.next(), Some("time,value,units,quality"));
        lines
            .map(|l| l.split(',').nth(1).unwrap().parse::<f64>().unwrap())
            .collect::<Vec<f64>>()
    };
    let (min, mean, max) = (agg("min"), agg("mean"), agg("max"));
    assert!(!mean.is_empty());
    for i in 0..mean.len() {
        assert!(
            min[i] <= mean[i] && mean[i] <= max[i],
            "{min:?} {mean:?} {max:?}"
        );
    }
    // The table shows unit symbols and quality names.
    let (code, out, _) = hartkit(&[
        "history", "query", "--db", db_s, "--device", "TT-200", "--var", "pv", "--from", "-10m",
    ]);
    assert_eq!(code, 0);
    assert!(
        out.lines().nth(1).is_some_and(|l| l.contains("good")),
        "{out}"
    );
}

#[test]
fn mistakes_say_what_to_give() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("none.sqlite");
    let m = missing.to_str().unwrap();
    let cases: &[(&[&str], i32, &str)] = &[
        (&["history", "devices", "--db", m], 5, "none.sqlite"),
        (
            &[
                "history", "query", "--db", m, "--device", "X", "--var", "xv",
            ],
            2,
            "xv",
        ),
        (
            &[
                "history",
                "query",
                "--db",
                m,
                "--device",
                "X",
                "--var",
                "pv",
                "--from",
                "yesterday-ish",
            ],
            2,
            "yesterday-ish",
        ),
    ];
    for (args, want, says) in cases {
        let (code, _, err) = hartkit(args);
        assert_eq!(code, *want, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    // A history file the gateway cannot use stops its start, saying so (exit 5).
    let junk = dir.path().join("junk.sqlite");
    std::fs::write(&junk, vec![0x5Au8; 8192]).unwrap();
    let (code, _, err) = hartkit(&[
        "serve",
        "--sim",
        "--instant",
        "--history",
        junk.to_str().unwrap(),
        "--run-for",
        "1",
    ]);
    assert_eq!(code, 5, "{err}");
    assert!(
        err.contains("--history") && err.contains("junk.sqlite"),
        "{err}"
    );
}

/// `rm` of the history file and its logs under a running gateway: the gateway opens a
/// new file at the path and goes on storing the plant there.
#[test]
fn a_history_file_removed_under_the_gateway_is_opened_anew() {
    let dir = tempfile::tempdir().unwrap();
    let db = dir.path().join("plant.sqlite");
    let db_s = db.to_str().unwrap();
    let mut gw = serve_history(&db, &["--poll-period", "0.5"]);
    std::thread::sleep(std::time::Duration::from_secs(2));
    for suffix in ["", "-wal", "-shm"] {
        std::fs::remove_file(format!("{db_s}{suffix}")).unwrap();
    }
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(20);
    let tags = loop {
        if db.exists() {
            let (code, out, _) = hartkit(&["history", "devices", "--db", db_s, "--json"]);
            if code == 0 {
                let devices: Vec<Value> = serde_json::from_str(&out).unwrap();
                let tags: Vec<String> = devices
                    .iter()
                    .filter_map(|d| d["tag"].as_str().map(str::to_string))
                    .collect();
                if tags.len() >= 3 {
                    break tags;
                }
            }
        }
        assert!(
            std::time::Instant::now() < deadline,
            "no new history file with the plant at {db_s}"
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    };
    let _ = gw.0.kill();
    let _ = gw.0.wait();
    assert!(tags.iter().any(|t| t == "TT-200"), "{tags:?}");
}
