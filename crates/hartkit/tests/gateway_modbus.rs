//! The gateway's Modbus front end against an outside client: pymodbus (BSD), run as a
//! separate process by `scripts/interop/pymodbus_client.py` against `hartkit serve
//! --sim --modbus ...` on defaults (the demo plant on a simulated 1200 bit/s loop).
//! It reads every unit's registers with its own float decoder, meets the exceptions a
//! SCADA meets, and writes a damping value, which HART (over the gateway's own HART-IP
//! front end) then reads back from the device.
//!
//! Without the interop venv (`scripts/interop/setup`) the pymodbus checks say so and
//! pass, unless `HARTKIT_REQUIRE_INTEROP=1`. The checks without Python (the printed
//! map, the terminal view) always run.

use std::path::PathBuf;

mod common;
use common::{gateway, hartkit, pty_pair};

fn python() -> Option<PathBuf> {
    common::interop_python("pymodbus")
}

fn port_of(addr: &str) -> String {
    addr.rsplit(':').next().unwrap().to_string()
}

fn run_client(py: &std::path::Path, port: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["--port", port, "--units", "4"];
    args.extend_from_slice(extra);
    common::interop_json(py, "pymodbus_client.py", &args)
}

#[test]
fn pymodbus_reads_the_demo_plant_and_a_write_lands_on_the_device() {
    let Some(py) = python() else { return };
    let gw = gateway(
        &[
            "--sim",
            "--modbus",
            "127.0.0.1:0",
            "--hart-ip",
            "127.0.0.1:0",
        ],
        2,
    );
    let r = run_client(&py, &port_of(&gw.1["modbus"]), &["--damping", "2.5"]);
    assert_eq!(r["qualities"], serde_json::json!([0, 0, 0, 0]), "{r}");
    let units = r["units"].as_array().unwrap();
    // The demo plant: pressure (kPa, 12) at 1, temperature (degC, 32) at 2, valve
    // positioner (%, 57) at 3, pressure at 17.
    let expect = [(1, 12), (2, 32), (3, 57), (17, 12)];
    for (u, (poll, pv_units)) in units.iter().zip(expect) {
        assert_eq!(u["polling_address"], poll, "{u}");
        assert_eq!(u["pv_units"], pv_units, "{u}");
        assert_eq!(u["quality"], 0, "{u}");
        assert!(u["pv"].as_f64().is_some_and(f64::is_finite), "{u}");
        assert!(
            u["loop_current"]
                .as_f64()
                .is_some_and(|c| (3.5..=22.0).contains(&c)),
            "{u}"
        );
        // Percent of range from the range values: linear transmitters (the valve
        // positioner's characterised PV has none).
        if poll != 3 {
            assert!(u["percent_range"].as_f64().is_some(), "{u}");
        }
        assert!(u["age"].as_u64().is_some_and(|a| a < 30), "{u}");
        assert_eq!(u["manufacturer_id"], 240, "{u}");
    }
    // Same HART identity as the HART-IP side reports.
    assert_eq!(units[0]["device_id"], 0x010002);
    assert_eq!(r["unknown_unit"], 10, "gateway path unavailable");
    assert_eq!(r["outside_map"], 2, "illegal data address");
    assert_eq!(r["read_coils"], 1, "illegal function");
    assert_eq!(r["half_float"], 2, "half a float");
    assert_eq!(r["write_input"], 2, "not a writable register");
    assert_eq!(r["bad_damping"], 3, "the device refuses a negative damping");
    assert_eq!(r["write_damping"], "ok");
    assert_eq!(r["damping_read_back"], 2.5);
    // Through HART: the device holds the new damping.
    let hip = format!("udp://{}", gw.1["hart-ip"]);
    let (code, out, err) = hartkit(&["read", "--port", &hip, "--poll", "1", "info", "--json"]);
    assert_eq!(code, 0, "{err}");
    let info: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(info["damping"], 2.5, "{info}");
}

#[test]
fn word_swapped_floats_for_plcs_that_want_them() {
    let Some(py) = python() else { return };
    let gw = gateway(
        &[
            "--sim",
            "--instant",
            "--modbus",
            "127.0.0.1:0",
            "--float-order",
            "cdab",
        ],
        1,
    );
    let r = run_client(
        &py,
        &port_of(&gw.1["modbus"]),
        &["--word-order", "little", "--wait", "20"],
    );
    assert_eq!(r["qualities"], serde_json::json!([0, 0, 0, 0]), "{r}");
    assert_eq!(r["units"][0]["upper_range"], 250.0, "{r}");
    assert_eq!(r["units"][2]["loop_current"], 12.0, "{r}");
    assert_eq!(r["damping_read_back"], 2.5);
}

#[test]
fn the_printed_map_lists_units_and_registers() {
    let (code, out, err) = hartkit(&["serve", "--sim", "--print-map", "--json"]);
    assert_eq!(code, 0, "{err}");
    let m: serde_json::Value = serde_json::from_str(&out).unwrap();
    let units = m["units"].as_array().unwrap();
    let polls: Vec<_> = units.iter().map(|u| u["polling_address"].clone()).collect();
    assert_eq!(polls, [1, 2, 3, 17]);
    assert_eq!(units[0]["unit"], 1);
    assert_eq!(units[0]["name"], "PT-100");
    assert_eq!(m["float_order"], "abcd");
    let regs = m["registers"].as_array().unwrap();
    let find = |table: &str, register: u64| {
        regs.iter()
            .find(|r| r["table"] == table && r["register"] == register)
            .unwrap_or_else(|| panic!("{table} {register} not in {m}"))
    };
    // The fixed part of the map (docs/gateway.md).
    for (register, value) in [
        (0, "pv"),
        (2, "sv"),
        (4, "tv"),
        (6, "qv"),
        (8, "loop_current"),
        (10, "pv_units"),
        (11, "device_status"),
        (12, "extended_status"),
        (13, "quality"),
        (14, "age"),
    ] {
        assert_eq!(find("input", register)["value"], value);
    }
    assert_eq!(find("holding", 4)["value"], "damping");
    assert_eq!(find("holding", 4)["writable"], true);
    let (code, text, _) = hartkit(&["serve", "--sim", "--instant", "--print-map"]);
    assert_eq!(code, 0);
    assert!(
        text.contains("unit   1") && text.contains("PT-100"),
        "{text}"
    );
    assert!(
        text.lines().any(|l| l
            .split_whitespace()
            .take(4)
            .eq(["input", "0-1", "float", "pv"])),
        "{text}"
    );
}

#[test]
fn configuration_file_and_its_errors() {
    let dir = std::env::temp_dir().join(format!("hartkit-gw-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("gateway.toml");
    std::fs::write(
        &cfg,
        r#"
[poll]
period = "500ms"

[[loop]]
name = "north"
port = "sim"
scan = false
[[loop.device]]
poll = 17
name = "PT-017"
[[loop.device]]
poll = 1

[modbus]
float_order = "cdab"
[[modbus.register]]
table = "input"
register = 100
value = "pv"
[[modbus.register]]
table = "input"
register = 102
value = "quality"
"#,
    )
    .unwrap();
    let (code, out, err) = hartkit(&[
        "serve",
        "--config",
        cfg.to_str().unwrap(),
        "--print-map",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let m: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(m["float_order"], "cdab");
    assert_eq!(m["units"][0]["name"], "PT-017");
    assert_eq!(m["units"][0]["loop"], "north");
    assert_eq!(m["units"][1]["polling_address"], 1);
    assert_eq!(m["units"].as_array().unwrap().len(), 2);
    assert_eq!(m["registers"].as_array().unwrap().len(), 2);
    // Mistakes are named.
    std::fs::write(&cfg, "[[loop]]\nport = \"sim\"\nread = 7\n").unwrap();
    let (code, _, err) = hartkit(&["serve", "--config", cfg.to_str().unwrap(), "--print-map"]);
    assert_eq!(code, 2);
    assert!(err.contains("command 3"), "{err}");
    std::fs::write(
        &cfg,
        "[modbus]\n[[modbus.register]]\ntable = \"input\"\nregister = 0\nvalue = \"pv\"\n[[modbus.register]]\ntable = \"input\"\nregister = 1\nvalue = \"sv\"\n[[loop]]\nport = \"sim\"\n",
    )
    .unwrap();
    let (code, _, err) = hartkit(&["serve", "--config", cfg.to_str().unwrap(), "--print-map"]);
    assert_eq!(code, 2);
    assert!(err.contains("overlaps"), "{err}");
    let (code, _, err) = hartkit(&["serve", "--print-map"]);
    assert_eq!(code, 2);
    assert!(err.contains("no loop"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn with_no_front_end_the_gateway_shows_the_devices() {
    let (code, out, err) = hartkit(&["serve", "--sim", "--instant", "--json", "--run-for", "6"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(lines.len() >= 4, "{out}");
    let last: Vec<_> = lines.iter().rev().take(4).collect();
    assert!(last.iter().all(|l| l["quality"] == "good"), "{out}");
}

#[test]
fn pymodbus_rtu_master_on_a_serial_line() {
    let Some(py) = python() else { return };
    let Some(pty) = pty_pair() else { return };
    // A pseudo-terminal has no parity: 8N1.
    let _gw = gateway(
        &[
            "--sim",
            "--instant",
            "--modbus-rtu",
            pty.1.to_str().unwrap(),
            "--modbus-parity",
            "N",
        ],
        1,
    );
    let r = common::interop_json(
        &py,
        "pymodbus_rtu_client.py",
        &["--device", pty.2.to_str().unwrap()],
    );
    assert_eq!(r["pv_units"], 12, "{r}");
    assert_eq!(r["quality"], 0, "{r}");
    assert_eq!(r["unknown_unit"], "silent", "{r}");
    assert_eq!(r["damping"], serde_json::json!({"1": 3.0, "2": 3.0}), "{r}");
    // Broadcast writes do not hold up the next frame (they took 2 s before).
    assert!(
        r["after_broadcast_s"].as_f64().is_some_and(|t| t < 1.0),
        "{r}"
    );
}

/// Issue 30 on a serial line (socat pseudo-terminals, pymodbus the master, a second
/// handle writing the bad bytes): a function-16 frame cut short after its byte count,
/// another slave's valid reply frame (unit 5, function 3), 1000 random bytes, each
/// followed by good requests every 0.4 s; then 4 s of junk bursts between good
/// requests. Every good request is answered, within a second (tokio-modbus's framing
/// left 33 unanswered after the cut frame and stopped the port on the other two).
#[test]
fn rtu_slave_answers_through_cut_frames_other_slaves_and_garbage() {
    let Some(py) = python() else { return };
    let Some(pty) = pty_pair() else { return };
    let _gw = gateway(
        &[
            "--sim",
            "--instant",
            "--modbus-rtu",
            pty.1.to_str().unwrap(),
            "--modbus-parity",
            "N",
        ],
        1,
    );
    let r = common::interop_json(
        &py,
        "pymodbus_rtu_faults.py",
        &["--device", pty.2.to_str().unwrap(), "--flood", "4"],
    );
    for fault in ["cut_function_16", "foreign_reply", "random_1000", "flood"] {
        let f = &r[fault];
        assert!(f["sent"].as_u64() >= Some(5), "{fault}: {r}");
        assert_eq!(f["answered"], f["sent"], "{fault}: {r}");
        assert!(
            f["slowest_s"].as_f64().is_some_and(|t| t < 1.0),
            "{fault}: {r}"
        );
    }
}

#[test]
fn sub_devices_of_an_upstream_io_system_are_found_and_polled() {
    // Upstream: a HART-IP I/O system with the demo plant behind it. The gateway's loop
    // is that server: its scan finds the I/O system at polling address 0 and lists its
    // sub-devices (commands 74, 84), polled by their unique IDs through it.
    let upstream = gateway(&["--sim", "--instant", "--hart-ip", "127.0.0.1:0"], 1);
    let loop_target = format!("udp://{}", upstream.1["hart-ip"]);
    let (code, out, err) = hartkit(&[
        "serve",
        "--port",
        &loop_target,
        "--scan-to",
        "0",
        "--print-map",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let m: serde_json::Value = serde_json::from_str(&out).unwrap();
    let units = m["units"].as_array().unwrap();
    let ids: Vec<_> = units
        .iter()
        .map(|u| u["unique_id"].as_str().unwrap())
        .collect();
    // The I/O system first (polling address 0), then its four sub-devices.
    assert_eq!(ids[0], "26FF000001", "{m}");
    for id in ["26F1010002", "26F2020003", "26F3030004", "26F1010012"] {
        assert!(ids.contains(&id), "{id} not listed: {m}");
    }
    // Polled through the I/O system: every device good.
    let (code, out, err) = hartkit(&[
        "serve",
        "--port",
        &loop_target,
        "--scan-to",
        "0",
        "--json",
        "--run-for",
        "11",
    ]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let last = &lines[lines.len().saturating_sub(5)..];
    assert_eq!(last.len(), 5, "{out}");
    assert!(
        last.iter()
            .all(|l| l["quality"] == "good" && l["polls"].as_u64() > Some(1)),
        "{out}"
    );
}

/// Writes only from the clients listed (`--modbus-write-from`): a write from another
/// address is answered "illegal function" and the device keeps its damping; one from a
/// listed address lands and is in the audit file, with the client's address.
#[test]
fn modbus_writes_only_from_listed_clients() {
    let Some(py) = python() else { return };
    let audit = std::env::temp_dir().join(format!("hartkit-mb-audit-{}.jsonl", std::process::id()));
    let _ = std::fs::remove_file(&audit);
    let gw = gateway(
        &[
            "--sim",
            "--instant",
            "--modbus",
            "127.0.0.1:0",
            "--modbus-write-from",
            "127.0.0.2",
            "--audit-file",
            audit.to_str().unwrap(),
        ],
        1,
    );
    let port = port_of(&gw.1["modbus"]);
    let write = |source: &str, damping: &str| {
        common::interop_json(
            &py,
            "pymodbus_write.py",
            &["--port", &port, "--source", source, "--damping", damping],
        )
    };
    let refused = write("127.0.0.1", "4.5");
    assert_eq!(refused["exception"], 1, "illegal function: {refused}");
    assert_eq!(refused["after"], refused["before"], "{refused}");
    let done = write("127.0.0.2", "4.5");
    assert_eq!(done["exception"], serde_json::Value::Null, "{done}");
    assert_eq!(done["after"], 4.5, "{done}");
    assert_eq!(
        done["at_once"], 4.5,
        "the write shows in the registers at once: {done}"
    );
    drop(gw);
    let log = std::fs::read_to_string(&audit).unwrap_or_default();
    let all: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    // One write let through: its record, then its outcome (the same id).
    let lines: Vec<&serde_json::Value> = all.iter().filter(|l| l["outcome"].is_null()).collect();
    assert_eq!(lines.len(), 1, "one write let through: {log}");
    assert!(
        all.iter()
            .any(|o| o["id"] == lines[0]["id"] && o["outcome"] == "done"),
        "{log}"
    );
    assert_eq!(lines[0]["front_end"], "modbus-tcp");
    assert_eq!(lines[0]["command"], 34);
    assert_eq!(lines[0]["operation"], "damping 4.5 s");
    assert!(
        lines[0]["peer"].as_str().unwrap().starts_with("127.0.0.2:"),
        "{log}"
    );
    let _ = std::fs::remove_file(&audit);
}

/// The gateway's write policy holds for Modbus as for every front end: with
/// `--allow-commands 0-33` a damping write (command 34) from a client that may write is
/// answered "illegal function", the device keeps its damping and the audit has only
/// the refusal (nothing sent); with `--read-only`, the same.
#[test]
fn modbus_writes_follow_the_allow_list_and_read_only() {
    let Some(py) = python() else { return };
    for (flags, why) in [
        (&["--allow-commands", "0-33"][..], "allow-list"),
        (&["--read-only"][..], "read-only"),
    ] {
        let audit = std::env::temp_dir().join(format!(
            "hartkit-mb-policy-{}-{why}.jsonl",
            std::process::id()
        ));
        let _ = std::fs::remove_file(&audit);
        let mut args = vec![
            "--sim",
            "--instant",
            "--modbus",
            "127.0.0.1:0",
            "--audit-file",
            audit.to_str().unwrap(),
        ];
        args.extend_from_slice(flags);
        let gw = gateway(&args, 1);
        let port = port_of(&gw.1["modbus"]);
        let r = common::interop_json(
            &py,
            "pymodbus_write.py",
            &["--port", &port, "--source", "127.0.0.1", "--damping", "4.5"],
        );
        assert_eq!(r["exception"], 1, "{why}: illegal function: {r}");
        assert_eq!(r["after"], r["before"], "{why}: {r}");
        drop(gw);
        let log = std::fs::read_to_string(&audit).unwrap_or_default();
        assert!(
            !log.is_empty()
                && log
                    .lines()
                    .all(|l| l.contains("\"outcome\":\"not-permitted\"")),
            "{why}: only the refusal audited: {log}"
        );
        let _ = std::fs::remove_file(&audit);
    }
}

/// The port under abuse (separate processes): 100 connections that never send a byte
/// and 50 that send half a request, from ten loopback addresses, reopened as soon as
/// they are closed, while a SCADA client (pymodbus, from 127.0.0.1) polls every half
/// second. The pool of 64 is full at once; the half requests are closed after the
/// request time-out, the silent ones after the first-request time-out or when a new
/// connection needs the room (the oldest idle first), and the SCADA's connection, in
/// use, is kept: every one of its polls is answered within its time-out.
#[test]
fn the_scada_is_served_while_its_port_is_flooded() {
    let Some(py) = python() else { return };
    let dir = std::env::temp_dir().join(format!("hartkit-mbflood-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("gateway.toml");
    std::fs::write(
        &cfg,
        "[modbus]\nbind = \"127.0.0.1:0\"\nfirst_request = \"2s\"\nrequest = \"1s\"\n",
    )
    .unwrap();
    let gw = gateway(
        &["--sim", "--instant", "--config", cfg.to_str().unwrap()],
        1,
    );
    let port = port_of(&gw.1["modbus"]);
    let flood = std::process::Command::new(&py)
        .arg(common::workspace().join("scripts/interop/modbus_flood.py"))
        .args([
            "--port",
            &port,
            "--idle",
            "100",
            "--partial",
            "50",
            "--seconds",
            "14",
        ])
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_secs(2));
    let scada = common::interop_json(
        &py,
        "pymodbus_poll.py",
        &["--port", &port, "--seconds", "10", "--every", "0.5"],
    );
    let out = flood.wait_with_output().unwrap();
    let flood: serde_json::Value =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("{e}: {out:?}"));
    assert_eq!(
        scada["answered"], scada["polls"],
        "every poll answered: {scada}"
    );
    assert!(scada["polls"].as_u64().unwrap() >= 15, "{scada}");
    assert!(
        flood["closed_by_server"].as_u64().unwrap() >= 100,
        "the abusers were closed: {flood}"
    );
    drop(gw);
    let _ = std::fs::remove_dir_all(&dir);
}
