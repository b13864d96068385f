//! End to end: `hartkit sim serve --pty` runs devices on a real pseudo-terminal and the
//! host commands talk to them through it, as they would through a USB HART modem.

use serde_json::Value;

mod common;
use common::{hartkit, sim_pty as serve};

#[test]
fn host_commands_over_a_pseudo_terminal() {
    let s = serve(&[
        "--profile",
        "pressure",
        "--poll",
        "1",
        "--profile",
        "temperature",
        "--poll",
        "2",
        "--profile",
        "valve",
        "--poll",
        "20",
    ]);
    let p = s.pty.as_str();

    // Scan finds every device, including one above polling address 15.
    let (code, out, err) = hartkit(&["scan", "-p", p, "--from", "0", "--to", "21", "--json"]);
    assert_eq!(code, 0, "{err}");
    // One JSON object per line and device, printed as each is found.
    let devices: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let polls: Vec<u64> = devices
        .iter()
        .map(|d| d["polling_address"].as_u64().unwrap())
        .collect();
    assert_eq!(polls, vec![1, 2, 20]);
    // The table view sums up the empty addresses.
    let (code, out, _) = hartkit(&["scan", "-p", p, "--from", "0", "--to", "3"]);
    assert_eq!(code, 0);
    assert!(
        out.contains("2 device(s)") && out.contains("no device at polling addresses 0, 3"),
        "{out}"
    );
    for key in [
        "unique_id",
        "expanded_device_type",
        "manufacturer_id",
        "device_id",
        "universal_revision",
        "device_revision",
        "tag",
        "long_tag",
        "descriptor",
    ] {
        assert!(devices[0].get(key).is_some(), "{key} in {}", devices[0]);
    }
    assert_eq!(devices[1]["tag"], "TT-200");

    // Reads.
    let (code, out, err) = hartkit(&["read", "-p", p, "--poll", "2", "dynamic", "--json"]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["variables"][0]["name"], "PV");
    assert_eq!(v["variables"][0]["units_symbol"], "°C");
    assert!(v["loop_current"].as_f64().unwrap() > 3.5);
    let (code, out, _) = hartkit(&[
        "read", "-p", p, "--tag", "FV-300", "vars", "0", "1", "--json",
    ]);
    assert_eq!(code, 0);
    assert_eq!(
        serde_json::from_str::<Value>(&out).unwrap()["variables"]
            .as_array()
            .unwrap()
            .len(),
        2
    );
    let (code, out, _) = hartkit(&["read", "-p", p, "--poll", "1", "status", "--json"]);
    assert_eq!(code, 0);
    let status = serde_json::from_str::<Value>(&out).unwrap();
    assert!(status["device_status_set"].is_array(), "{status}");
    // Command 48's parts as the frame view names them, each with its words.
    assert!(status["extended_status"].is_u64(), "{status}");
    assert!(status["extended_status_set"].is_array(), "{status}");
    assert!(status["additional_status"].is_string(), "{status}");

    // Writes confirm by reading back.
    let (code, out, err) = hartkit(&["write", "-p", p, "--poll", "1", "tag", "PT-777"]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("\"PT-777\""), "{out}");
    let (code, out, err) = hartkit(&["write", "-p", p, "--poll", "1", "range", "300", "0", "12"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("upper_range_value") && out.contains("300"),
        "{out}"
    );

    // Burst: configure command 1 every second, enable, and see BACKs on the line.
    let (code, _, err) = hartkit(&[
        "burst",
        "-p",
        p,
        "--poll",
        "1",
        "config",
        "--command",
        "1",
        "--period",
        "1",
    ]);
    assert_eq!(code, 0, "{err}");
    let (code, _, err) = hartkit(&["burst", "-p", p, "--poll", "1", "on"]);
    assert_eq!(code, 0, "{err}");
    let (code, out, err) = hartkit(&["monitor", "-p", p, "--duration", "3.5", "--json"]);
    assert_eq!(code, 0, "{err}");
    let backs = out
        .lines()
        .filter_map(|l| serde_json::from_str::<Value>(l).ok())
        .filter(|v| v["frame_type"] == "BACK")
        .count();
    assert!(backs >= 2, "BACK frames seen: {backs}\n{out}");
    let (code, _, _) = hartkit(&["burst", "-p", p, "--poll", "1", "off"]);
    assert_eq!(code, 0);

    // A device that does not answer: the clear error, exit status 3.
    let (code, _, err) = hartkit(&["read", "-p", p, "--poll", "9", "pv"]);
    assert_eq!(code, 3);
    assert!(
        err.contains("no reply from polling address 9 after 4 tries (STO 256 ms)"),
        "{err}"
    );
    assert!(err.contains("RTS"), "{err}");

    // A device error in words.
    let (code, _, err) = hartkit(&["command", "-p", p, "--poll", "2", "200"]);
    assert_eq!(code, 4);
    assert!(
        err.contains("device replied 'command not implemented' (64) to command 200"),
        "{err}"
    );
}

#[test]
fn demo_runs_on_the_builtin_plant() {
    // Virtual time: the whole scan (0-20) and a few rounds cost no wall time.
    let (code, out, err) = hartkit(&["demo", "--duration", "60", "--json", "-p", "sim?virtual"]);
    assert_eq!(code, 0, "{err}");
    let last: Value = serde_json::from_str(out.lines().last().unwrap()).unwrap();
    let polls: Vec<u64> = last["devices"]
        .as_array()
        .unwrap()
        .iter()
        .map(|d| d["polling_address"].as_u64().unwrap())
        .collect();
    assert_eq!(polls, vec![1, 2, 3, 17]);
    assert!(last["line"]["transactions"].as_u64().unwrap() >= 4);
}

/// The demo shows each fact as its reply comes in, not on a cadence: a device found is
/// shown, then read at once, so its first value is the very next update. On the demo
/// plant's 1200 bit/s line (in virtual time, so the figures are the line's, whatever
/// the machine does) the first device shows with its value before 4 s, and each of
/// the first three within a second of being found (the fixed cadence of earlier
/// versions took 6.2 s for the first value and 13.9 s for the third).
#[test]
fn demo_shows_values_as_they_arrive() {
    let (code, out, err) = hartkit(&["demo", "--duration", "12", "--json", "-p", "sim?virtual"]);
    assert_eq!(code, 0, "{err}");
    let lines: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let first = |poll: u64, with_pv: bool| {
        lines
            .iter()
            .find(|l| {
                l["devices"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|d| d["polling_address"] == poll && (!with_pv || d["pv"].is_number()))
            })
            .map(|l| l["t_s"].as_f64().unwrap())
            .unwrap_or_else(|| panic!("device {poll} never shown: {out}"))
    };
    assert!(first(1, true) < 4.0, "first PV at {} s", first(1, true));
    for poll in [1, 2, 3] {
        let (found, value) = (first(poll, false), first(poll, true));
        assert!(
            value - found < 1.0,
            "device {poll}: found {found} s, value {value} s"
        );
    }
    // Every update says something new: no two in a row alike but for the time.
    for w in lines.windows(2) {
        assert!(
            w[0]["devices"] != w[1]["devices"]
                || w[0]["scanning"] != w[1]["scanning"]
                || w[0]["line"] != w[1]["line"],
            "{} / {}",
            w[0],
            w[1]
        );
    }
}

/// An option after the values is an option, never part of the value (`--json` here), and
/// `write --json` prints JSON; negative numbers are still values.
#[test]
fn write_takes_options_after_its_values() {
    let (code, out, err) = hartkit(&[
        "write",
        "-p",
        "sim?virtual",
        "--poll",
        "1",
        "message",
        "HARTKIT INTEROP",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["command"], 17);
    assert_eq!(v["read_back"]["decoded"]["message"], "HARTKIT INTEROP");
    let (code, out, err) = hartkit(&[
        "write",
        "-p",
        "sim?virtual",
        "--poll",
        "1",
        "range",
        "100",
        "-10",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["command"], 35);
}

/// A typed command's request given as JSON fields: the decoded view of one reply,
/// edited, is the next request (command 13's tag, descriptor and date written back
/// with command 18), units go by symbol, and a misspelt field is refused with the list
/// of fields before anything is sent.
#[test]
fn command_takes_the_fields_of_its_request_as_json() {
    let p = "sim?virtual";
    let (code, out, err) = hartkit(&["command", "-p", p, "--poll", "1", "13", "--json"]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    let mut fields = v["decoded"].clone();
    assert!(fields["descriptor"].is_string(), "{v}");
    fields["tag"] = "FT-202".into();
    let (code, out, err) = hartkit(&[
        "command",
        "-p",
        p,
        "--poll",
        "1",
        "18",
        &fields.to_string(),
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["decoded"]["tag"], "FT-202", "{v}");
    assert_eq!(v["decoded"]["descriptor"], fields["descriptor"], "{v}");

    let (code, out, err) = hartkit(&[
        "command",
        "-p",
        p,
        "--poll",
        "1",
        "44",
        r#"{"pv_units": "kPa"}"#,
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["decoded"]["pv_units"], 12, "{v}");

    let (code, _, err) = hartkit(&[
        "command",
        "-p",
        p,
        "--poll",
        "1",
        "44",
        r#"{"pv_unit": "kPa"}"#,
    ]);
    assert_eq!(code, 2);
    assert!(
        err.contains("command 44: no field pv_unit; the fields are pv_units"),
        "{err}"
    );
}
