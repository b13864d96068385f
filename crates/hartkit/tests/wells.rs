//! The well network's roles (`hartkit wells ...`) against an independent peer over
//! pseudo-terminals: `crates/hart-wells/tests/peer/wells_peer.py`, written from
//! docs/wells.md alone, plays the other end of each exchange (a concentrator polling
//! a sensor with the published frame, the two sensors of a bus, a requester of
//! command 144, a concentrator serving minutes). Skipped without socat or python3.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{hartkit, pty_pair, workspace, Kill};
use serde_json::Value;

fn peer() -> Option<PathBuf> {
    if Command::new("python3").arg("-V").output().is_err() {
        eprintln!("python3 not installed; skipping");
        return None;
    }
    Some(workspace().join("crates/hart-wells/tests/peer/wells_peer.py"))
}

fn spawn_peer(args: &[&str]) -> Kill {
    Kill(
        Command::new("python3")
            .arg(peer().unwrap())
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

fn run_peer(args: &[&str]) -> (i32, Vec<Value>, String) {
    let out = Command::new("python3")
        .arg(peer().unwrap())
        .args(args)
        .output()
        .unwrap();
    let events = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    (
        out.status.code().unwrap_or(-1),
        events,
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn spawn_hartkit(args: &[&str]) -> Kill {
    Kill(
        Command::new(env!("CARGO_BIN_EXE_hartkit"))
            .args(args)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

/// `hartkit wells pc pull --port PORT --well WELL --db DB --json EXTRA...`: the exit
/// status, the JSON summary when it succeeded, and standard error.
fn pc_pull(port: &Path, well: &str, db: &Path, extra: &[&str]) -> (i32, Value, String) {
    let mut args = vec![
        "wells",
        "pc",
        "pull",
        "--port",
        port.to_str().unwrap(),
        "--well",
        well,
        "--db",
        db.to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    let (code, out, err) = hartkit(&args);
    let v = if code == 0 {
        serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"))
    } else {
        Value::Null
    };
    (code, v, err)
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hartkit-wells-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The published example request, sent by the peer, answered by `wells sensor`.
#[test]
fn a_sensor_answers_the_published_request() {
    let Some(_) = peer() else { return };
    let Some(bus) = pty_pair() else { return };
    let _sensor = spawn_hartkit(&[
        "wells",
        "sensor",
        "--bus",
        bus.1.to_str().unwrap(),
        "--address",
        "1",
        "--kind",
        "temperature",
    ]);
    std::thread::sleep(Duration::from_millis(300));
    let (code, ev, err) = run_peer(&[
        "poll-sensor",
        bus.2.to_str().unwrap(),
        "--address",
        "1",
        "--count",
        "2",
        "--timeout",
        "3",
    ]);
    assert_eq!(code, 0, "{err}");
    let tx: Vec<&Value> = ev.iter().filter(|e| e["event"] == "tx").collect();
    assert_eq!(tx[0]["hex"], "FF FF 02 01 01 00 02");
    let rx: Vec<&Value> = ev.iter().filter(|e| e["event"] == "rx").collect();
    assert_eq!(rx.len(), 2, "{ev:?}");
    assert_eq!(rx[0]["byte_count"], 11);
    assert_eq!(rx[0]["status"], serde_json::json!([0, 0]));
    // Command 14 of a sensor with a converter fault; an unknown command gets 64.
    drop(_sensor);
    let _sensor = spawn_hartkit(&[
        "wells",
        "sensor",
        "--bus",
        bus.1.to_str().unwrap(),
        "--address",
        "2",
        "--kind",
        "level",
        "--fault",
        "adc",
    ]);
    std::thread::sleep(Duration::from_millis(300));
    let (code, ev, err) = run_peer(&[
        "poll-sensor",
        bus.2.to_str().unwrap(),
        "--address",
        "2",
        "--command",
        "14",
        "--timeout",
        "3",
    ]);
    assert_eq!(code, 0, "{err}");
    let rx = ev.iter().find(|e| e["event"] == "rx").unwrap();
    assert_eq!(rx["status"], serde_json::json!([14, 2]), "{rx}");
}

/// The concentrator polls the peer's two sensors, stores their minutes with its
/// clock, and hands them to the peer's requester; a requester that stops without
/// acknowledging its last batch gets that batch again, and nothing before it.
#[test]
fn a_concentrator_polls_peer_sensors_and_hands_over_to_a_peer() {
    let Some(_) = peer() else { return };
    let (Some(bus), Some(up)) = (pty_pair(), pty_pair()) else {
        return;
    };
    let dir = tmp("conc");
    let store = dir.join("c.db");
    let _sensors = spawn_peer(&["sensors", bus.2.to_str().unwrap()]);
    let _conc = spawn_hartkit(&[
        "wells",
        "concentrator",
        "--well",
        "3",
        "--bus",
        bus.1.to_str().unwrap(),
        "--uplink",
        up.1.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--poll-interval",
        "1s",
    ]);
    // Wait for a poll.
    let end = Instant::now() + Duration::from_secs(20);
    let records = loop {
        std::thread::sleep(Duration::from_millis(500));
        let (code, ev, err) = run_peer(&[
            "pull",
            up.2.to_str().unwrap(),
            "--well",
            "3",
            "--timeout",
            "3",
        ]);
        assert_eq!(code, 0, "{err}");
        let recs: Vec<Value> = ev.into_iter().filter(|e| e["event"] == "record").collect();
        if !recs.is_empty() {
            break recs;
        }
        assert!(Instant::now() < end, "the concentrator stored nothing");
    };
    // The peer's sensors send counts that say which minute they are: 8000000 +
    // minute % 1000 (temperature), 4000000 + minute % 1000 (level).
    for r in &records {
        let m = r["minute"].as_u64().unwrap();
        assert_eq!(r["t_raw"].as_u64().unwrap(), 8_000_000 + m % 1000, "{r}");
        assert_eq!(r["l_raw"].as_u64().unwrap(), 4_000_000 + m % 1000, "{r}");
        assert_eq!(r["ls_raw"], 3_000_000);
        assert_eq!(r["valid"], 7);
    }
    // Everything was acknowledged: a second pull gets only minutes after them.
    let last = records.last().unwrap()["minute"].as_u64().unwrap();
    let (_, ev, _) = run_peer(&[
        "pull",
        up.2.to_str().unwrap(),
        "--well",
        "3",
        "--timeout",
        "3",
    ]);
    assert!(ev
        .iter()
        .filter(|e| e["event"] == "record")
        .all(|r| r["minute"].as_u64().unwrap() > last));
}

/// The handheld collects from the peer's concentrator in batches, then serves the
/// PC, which gets every minute once.
#[test]
fn the_handheld_collects_from_a_peer_and_hands_over_to_the_pc() {
    let Some(_) = peer() else { return };
    let (Some(site), Some(bureau)) = (pty_pair(), pty_pair()) else {
        return;
    };
    let dir = tmp("hh");
    let (hh, pc) = (dir.join("hh.db"), dir.join("pc.db"));
    let start = 29_500_000u32;
    let _conc = spawn_peer(&[
        "concentrator",
        site.2.to_str().unwrap(),
        "--well",
        "2",
        "--minutes",
        &start.to_string(),
        "30",
    ]);
    std::thread::sleep(Duration::from_millis(300));
    let (code, out, err) = hartkit(&[
        "wells",
        "handheld",
        "collect",
        "--port",
        site.1.to_str().unwrap(),
        "--well",
        "2",
        "--store",
        hh.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        (v["new_minutes"].as_u64(), v["batches"].as_u64()),
        (Some(30), Some(3)),
        "{v}"
    );
    // Again: nothing new, nothing twice.
    let (code, out, err) = hartkit(&[
        "wells",
        "handheld",
        "collect",
        "--port",
        site.1.to_str().unwrap(),
        "--well",
        "2",
        "--store",
        hh.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        (v["new_minutes"].as_u64(), v["duplicated"].as_u64()),
        (Some(0), Some(0)),
        "{v}"
    );
    // At the bureau.
    let _serve = spawn_hartkit(&[
        "wells",
        "handheld",
        "serve",
        "--port",
        bureau.1.to_str().unwrap(),
        "--store",
        hh.to_str().unwrap(),
    ]);
    // The station has no ready line: the first pull is tried again while it starts (a
    // loaded machine takes more than the 300 ms waited first).
    std::thread::sleep(Duration::from_millis(300));
    let mut pulled = pc_pull(&bureau.2, "2", &pc, &["--handheld"]);
    for _ in 0..4 {
        if pulled.0 == 0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
        pulled = pc_pull(&bureau.2, "2", &pc, &["--handheld"]);
    }
    let (code, v, err) = pulled;
    assert_eq!(code, 0, "{err}");
    assert_eq!(v["new_minutes"], 30, "{v}");
    // A well the handheld holds nothing of: an empty hand-over, not silence.
    let (code, v, err) = pc_pull(&bureau.2, "5", &pc, &["--handheld"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(v["new_minutes"], 0, "{v}");
}

/// `wells sim`: two days with outages, restarts and lost frames lose nothing.
#[test]
fn the_simulated_network_loses_nothing() {
    let (code, out, err) = hartkit(&[
        "wells",
        "sim",
        "--wells",
        "2",
        "--days",
        "2",
        "--phone-outage-rate",
        "0.5",
        "--outage-mean-days",
        "0.6",
        "--handheld-every",
        "1",
        "--restart-rate",
        "1",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["lost"], 0, "{v}");
    assert_eq!(v["duplicated"], 0, "{v}");
    assert_eq!(v["values_mismatched"], 0, "{v}");
    assert!(v["minutes_sampled"].as_u64().unwrap() > 2 * 2 * 1400, "{v}");
    assert_eq!(v["minutes_sampled"], v["minutes_at_pc"]);
}

/// kill -9 of the concentrator while it polls and while it hands over (and of the
/// PC's pull): after each restart it goes on, and in the end the PC holds every
/// minute the store holds, once, with the same values.
#[test]
fn kill_9_loses_and_repeats_nothing() {
    use hart_wells::archive::Archive;
    use hart_wells::store::{Durability, Store};
    let Some(up) = pty_pair() else { return };
    let dir = tmp("kill");
    let (m, s1, s2) = (dir.join("bus"), dir.join("s1"), dir.join("s2"));
    let (store, pc) = (dir.join("c.db"), dir.join("pc.db"));
    let _bus = spawn_hartkit(&[
        "wells",
        "bus",
        "--master",
        m.to_str().unwrap(),
        "--drop",
        s1.to_str().unwrap(),
        "--drop",
        s2.to_str().unwrap(),
    ]);
    let end = Instant::now() + Duration::from_secs(10);
    while !(m.exists() && s1.exists() && s2.exists()) {
        assert!(Instant::now() < end, "the bus made no pseudo-terminals");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Two virtual minutes a second: the sensors' three minutes are 1.5 s, room for
    // a restart on a busy machine.
    let speed = "120";
    let _t = spawn_hartkit(&[
        "wells",
        "sensor",
        "--bus",
        s1.to_str().unwrap(),
        "--address",
        "1",
        "--kind",
        "temperature",
        "--speed",
        speed,
    ]);
    let _l = spawn_hartkit(&[
        "wells",
        "sensor",
        "--bus",
        s2.to_str().unwrap(),
        "--address",
        "2",
        "--kind",
        "level",
        "--speed",
        speed,
    ]);
    let conc_args = [
        "wells",
        "concentrator",
        "--well",
        "1",
        "--bus",
        m.to_str().unwrap(),
        "--uplink",
        up.1.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--speed",
        speed,
    ];
    let pull_args = [
        "wells",
        "pc",
        "pull",
        "--port",
        up.2.to_str().unwrap(),
        "--well",
        "1",
        "--db",
        pc.to_str().unwrap(),
        "--timeout-ms",
        "400",
        "--tries",
        "2",
    ];
    let mut conc = spawn_hartkit(&conc_args);
    for round in 0..8u64 {
        // Let it poll a while, then kill it: while polling (even rounds), or while the
        // PC is pulling (odd rounds; the pull is sometimes killed too).
        std::thread::sleep(Duration::from_millis(400 + 97 * round));
        if round % 2 == 1 {
            let mut pull = spawn_hartkit(&pull_args);
            std::thread::sleep(Duration::from_millis(5 + 7 * round));
            if round % 4 == 3 {
                let _ = pull.0.kill();
            }
            let _ = conc.0.kill();
            let _ = conc.0.wait();
            // Back at once (the sensors keep three minutes: 1.5 real seconds at this
            // speed); the pull may go on with the new process.
            conc = spawn_hartkit(&conc_args);
            let _ = pull.0.wait();
            continue;
        } else {
            let _ = conc.0.kill();
            let _ = conc.0.wait();
        }
        conc = spawn_hartkit(&conc_args);
    }
    std::thread::sleep(Duration::from_millis(500));
    let (code, _, err) = hartkit(&pull_args);
    assert_eq!(code, 0, "{err}");
    drop(conc);
    // Nothing the store holds is missing at the PC, nothing is there twice, and the
    // values are the store's (in the wire's single precision).
    let st = Store::open(&store, 1, 0, Durability::Process).unwrap();
    let a = Archive::open(&pc, Durability::Process).unwrap();
    let held = st.range(0, u32::MAX).unwrap();
    let at_pc = a.range(1, 0, u32::MAX).unwrap();
    assert!(held.len() > 8, "only {} minutes stored", held.len());
    assert_eq!(a.duplicated().unwrap(), 0);
    let handed = st.handed_over().unwrap();
    for r in held.iter().filter(|r| r.minute <= handed) {
        let p = at_pc
            .iter()
            .find(|p| p.minute == r.minute)
            .unwrap_or_else(|| panic!("minute {} handed over but not at the PC", r.minute));
        let w = r.wire_rounded();
        assert_eq!((p.t_raw, p.l_raw, p.valid), (w.t_raw, w.l_raw, w.valid));
        assert_eq!(p.temperature.to_bits(), w.temperature.to_bits());
    }
    // Everything stored before the last pull was handed over; the minutes are
    // contiguous: each restart polled at once and the sensors still held the minutes.
    assert!(
        at_pc.len() + 30 >= held.len(),
        "{} at the PC of {}",
        at_pc.len(),
        held.len()
    );
    for w in held.windows(2) {
        assert_eq!(
            w[1].minute,
            w[0].minute + 1,
            "a minute is missing after {}",
            w[0].minute
        );
    }
}

/// The PC dials through a Hayes modem (an independent fake modem on a pseudo-terminal,
/// `tests/peer/fake_modem.py`) whose call reaches the concentrator's uplink; the
/// schedule reports a busy well as unreachable and the faulty sensor of the other.
#[test]
fn the_pc_dials_pulls_and_reports_unreachable_wells_and_faulty_sensors() {
    let Some(_) = peer() else { return };
    let (Some(bus), Some(up), Some(modem)) = (pty_pair(), pty_pair(), pty_pair()) else {
        return;
    };
    let dir = tmp("dial");
    let (store, pc) = (dir.join("c.db"), dir.join("pc.db"));
    // Level sensor silent: the concentrator reports it not answering.
    let _sensors = spawn_peer(&["sensors", bus.2.to_str().unwrap(), "--silent", "2"]);
    let _conc = spawn_hartkit(&[
        "wells",
        "concentrator",
        "--well",
        "4",
        "--bus",
        bus.1.to_str().unwrap(),
        "--uplink",
        up.1.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--poll-interval",
        "1s",
        "--reply-timeout-ms",
        "150",
    ]);
    let fake_modem = workspace().join("crates/hart-wells/tests/peer/fake_modem.py");
    let _modem = Kill(
        Command::new("python3")
            .arg(&fake_modem)
            .arg(modem.2.to_str().unwrap())
            .arg("--connect")
            .arg(format!("5554004={}", up.2.display()))
            .args([
                "--busy",
                "5554005",
                "--ring-seconds",
                "0.2",
                "--guard",
                "0.3",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    std::thread::sleep(Duration::from_millis(2500));
    let (code, v, err) = pc_pull(&modem.1, "4", &pc, &["--dial", "555-4004"]);
    assert_eq!(code, 0, "{err}");
    assert!(v["new_minutes"].as_u64().unwrap() >= 3, "{v}");
    assert_eq!(v["status"]["sensors"][1]["state"], "not answering", "{v}");
    let (code, out, err) = hartkit(&[
        "wells",
        "pc",
        "schedule",
        "--port",
        modem.1.to_str().unwrap(),
        "--db",
        pc.to_str().unwrap(),
        "--well",
        "4=5554004",
        "--well",
        "5=5554005",
        "--retries",
        "1",
        "--retry-wait",
        "100ms",
        "--rounds",
        "1",
        "--json",
    ]);
    assert_ne!(code, 0, "a well was unreachable: {out}");
    assert!(err.contains("could not be reached"), "{err}");
    let v: Value = serde_json::from_str(out.lines().next().unwrap()).unwrap();
    assert_eq!(v["unreachable"], serde_json::json!([5]), "{v}");
    assert_eq!(v["wells"][0]["ok"], true, "{v}");
    assert_eq!(v["wells"][1]["attempts"], 2, "{v}");
    assert!(
        v["wells"][1]["error"].as_str().unwrap().contains("busy"),
        "{v}"
    );
    assert!(
        v["wells"][0]["sensor_faults"][0]
            .as_str()
            .unwrap()
            .contains("not answering"),
        "{v}"
    );
}

/// A calibration file goes to the concentrator with command 160 and is in force; a
/// corrupt file is refused whole before anything is sent; through the handheld, the
/// table waits in its store for the next visit and goes down with the collection.
#[test]
fn calibration_tables_reach_the_concentrator_directly_and_through_the_handheld() {
    use hart_wells::calibration::{CalibrationFile, Segment, Sensor, Table};
    use hart_wells::store::{Durability, Store};
    let Some(_) = peer() else { return };
    let (Some(bus), Some(up), Some(bureau)) = (pty_pair(), pty_pair(), pty_pair()) else {
        return;
    };
    let dir = tmp("cal");
    let (store, hh) = (dir.join("c.db"), dir.join("hh.db"));
    // A table that reads 1000 counts as 1 °C (linear), and a level table.
    let seg = |k: u32, a1: f64| Segment {
        raw_from: k * 1_677_721,
        raw_to: if k == 9 {
            0xFF_FFFE
        } else {
            (k + 1) * 1_677_721 - 1
        },
        a0: 0.0,
        a1,
        a2: 0.0,
    };
    let file = CalibrationFile {
        temperature: Some(Table::new((0..10).map(|k| seg(k, 0.001)).collect()).unwrap()),
        level: Some(Table::new((0..10).map(|k| seg(k, 0.0001)).collect()).unwrap()),
    };
    let good = dir.join("cal.csv");
    std::fs::write(&good, file.to_csv()).unwrap();
    let mut text = file.to_csv();
    text = text.replacen(",0.001,", ",NaN,", 1);
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, text).unwrap();
    let _sensors = spawn_peer(&["sensors", bus.2.to_str().unwrap()]);
    let conc_args = [
        "wells",
        "concentrator",
        "--well",
        "6",
        "--bus",
        bus.1.to_str().unwrap(),
        "--uplink",
        up.1.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--poll-interval",
        "1s",
    ];
    let conc = spawn_hartkit(&conc_args);
    std::thread::sleep(Duration::from_millis(500));
    let (code, _, err) = hartkit(&[
        "wells",
        "pc",
        "calibrate",
        "--port",
        up.2.to_str().unwrap(),
        "--well",
        "6",
        "--file",
        bad.to_str().unwrap(),
    ]);
    assert_ne!(code, 0);
    assert!(
        err.contains("line") && err.contains("nothing was sent"),
        "{err}"
    );
    let (code, out, err) = hartkit(&[
        "wells",
        "pc",
        "calibrate",
        "--port",
        up.2.to_str().unwrap(),
        "--well",
        "6",
        "--file",
        good.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("temperature and level table(s) in force"),
        "{out}"
    );
    drop(conc);
    let st = Store::open(&store, 6, 0, Durability::Process).unwrap();
    assert_eq!(
        st.calibration(Sensor::Level).unwrap().as_ref(),
        file.level.as_ref()
    );
    drop(st);
    // Through the handheld: the PC gives it the table at the bureau...
    let serve = spawn_hartkit(&[
        "wells",
        "handheld",
        "serve",
        "--port",
        bureau.1.to_str().unwrap(),
        "--store",
        hh.to_str().unwrap(),
    ]);
    std::thread::sleep(Duration::from_millis(300));
    let file2 = CalibrationFile {
        temperature: Some(Table::new((0..10).map(|k| seg(k, 0.002)).collect()).unwrap()),
        level: None,
    };
    let good2 = dir.join("cal2.csv");
    std::fs::write(&good2, file2.to_csv()).unwrap();
    let (code, out, err) = hartkit(&[
        "wells",
        "pc",
        "calibrate",
        "--handheld",
        "--port",
        bureau.2.to_str().unwrap(),
        "--well",
        "6",
        "--file",
        good2.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("kept by the handheld"), "{out}");
    drop(serve);
    // ...and it goes down on the next visit, with the collection (after a poll).
    let _conc = spawn_hartkit(&conc_args);
    std::thread::sleep(Duration::from_millis(2500));
    let (code, out, err) = hartkit(&[
        "wells",
        "handheld",
        "collect",
        "--port",
        up.2.to_str().unwrap(),
        "--well",
        "6",
        "--store",
        hh.to_str().unwrap(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(
        v["calibration_downloaded"],
        serde_json::json!(["temperature"]),
        "{v}"
    );
    assert!(v["new_minutes"].as_u64().unwrap() >= 3, "{v}");
    // Parameters online (command 161): changed, kept over a restart, refused when
    // out of range.
    let set = |extra: &[&str]| {
        let mut args = vec![
            "wells",
            "pc",
            "set",
            "--port",
            up.2.to_str().unwrap(),
            "--well",
            "6",
        ];
        args.extend_from_slice(extra);
        hartkit(&args)
    };
    let (code, out, err) = set(&["--poll-interval", "2m", "--retries", "1"]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.trim(), "well 6: poll interval 120 s, 1 retries");
    drop(_conc);
    let _conc = spawn_hartkit(&conc_args);
    std::thread::sleep(Duration::from_millis(500));
    let (code, out, err) = set(&[]);
    assert_eq!(code, 0, "{err}");
    assert_eq!(out.trim(), "well 6: poll interval 120 s, 1 retries");
    let (code, _, err) = set(&["--poll-interval", "10m"]);
    assert_ne!(code, 0);
    assert!(err.contains("1 s to 3 min"), "{err}");
}

/// The uplink vanishes (its line is gone: socat killed) while the concentrator runs:
/// it keeps polling, opens the uplink again when it is back, and the PC gets every
/// minute.
#[test]
fn the_concentrator_keeps_polling_when_its_uplink_vanishes() {
    use hart_wells::store::{Durability, Store};
    let Some(_) = peer() else { return };
    let Some(bus) = pty_pair() else { return };
    let dir = tmp("vanish");
    let (a, b) = (dir.join("up-conc"), dir.join("up-pc"));
    let (store, pc) = (dir.join("c.db"), dir.join("pc.db"));
    let socat = |a: &PathBuf, b: &PathBuf| {
        let k = Kill(
            Command::new("socat")
                .arg(format!("pty,raw,echo=0,link={}", a.display()))
                .arg(format!("pty,raw,echo=0,link={}", b.display()))
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        );
        let end = Instant::now() + Duration::from_secs(10);
        while !(a.exists() && b.exists()) {
            assert!(Instant::now() < end, "socat made no pseudo-terminals");
            std::thread::sleep(Duration::from_millis(20));
        }
        k
    };
    let up = socat(&a, &b);
    let _sensors = spawn_peer(&["sensors", bus.2.to_str().unwrap()]);
    let _conc = spawn_hartkit(&[
        "wells",
        "concentrator",
        "--well",
        "7",
        "--bus",
        bus.1.to_str().unwrap(),
        "--uplink",
        a.to_str().unwrap(),
        "--store",
        store.to_str().unwrap(),
        "--poll-interval",
        "1s",
    ]);
    std::thread::sleep(Duration::from_millis(1500));
    drop(up);
    // Without its uplink it goes on polling: the store's poll count grows.
    let polls = || {
        let st = Store::open(&store, 7, 0, Durability::Process).unwrap();
        st.sensors()
            .unwrap()
            .iter()
            .map(|s| s.last_good)
            .max()
            .unwrap_or(0)
    };
    std::thread::sleep(Duration::from_millis(2500));
    assert!(polls() > 0, "no poll stored");
    // The line comes back; the concentrator opens it again (within 5 s) and answers.
    let _up = socat(&a, &b);
    let end = Instant::now() + Duration::from_secs(20);
    loop {
        let (code, v, err) = pc_pull(&b, "7", &pc, &["--timeout-ms", "500", "--tries", "1"]);
        if code == 0 {
            assert!(v["new_minutes"].as_u64().unwrap() >= 3, "{v}");
            break;
        }
        assert!(Instant::now() < end, "the uplink never came back: {err}");
        std::thread::sleep(Duration::from_millis(500));
    }
    assert!(alive(&_conc), "the concentrator exited");
}

fn alive(k: &Kill) -> bool {
    // SAFETY: kill with signal 0 only checks that the process exists.
    unsafe { libc::kill(k.0.id() as i32, 0) == 0 }
}
