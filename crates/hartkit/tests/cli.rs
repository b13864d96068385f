//! The `hartkit frame` command line as a user runs it: output, JSON contract, exit codes.

use serde_json::Value;

mod common;
use common::hartkit;

fn decode_json(hex: &str) -> Value {
    let (code, out, err) = hartkit(&["frame", "decode", "--json", hex]);
    assert_eq!(code, 0, "{err}");
    serde_json::from_str(&out).unwrap()
}

#[test]
fn decode_json_hart7_cmd0_reply() {
    let v = decode_json("FF FF FF FF FF 06 80 00 18 00 00 FE 26 06 05 07 01 02 18 00 12 34 56 05 04 00 01 00 00 26 00 26 01 28");
    assert_eq!(v["preambles"], 5);
    assert_eq!(v["delimiter"], 6);
    assert_eq!(v["frame_type"], "ACK");
    assert_eq!(
        v["address"],
        serde_json::json!({"type": "short", "master": "primary", "burst": false, "polling_address": 0})
    );
    assert_eq!(v["expansion"], "");
    assert_eq!(v["command"], 0);
    assert_eq!(v["byte_count"], 24);
    assert_eq!(v["response_code"], 0);
    assert_eq!(v["device_status"], 0);
    assert_eq!(v["communication_error"], false);
    assert_eq!(v["checksum_ok"], true);
    assert_eq!(v["trailing"], "");
    let d = &v["decoded"];
    for (k, want) in [
        ("expanded_device_type", 0x2606),
        ("min_request_preambles", 5),
        ("universal_revision", 7),
        ("device_revision", 1),
        ("software_revision", 2),
        ("hardware_revision", 3),
        ("physical_signaling", 0),
        ("flags", 0),
        ("min_response_preambles", 5),
        ("max_device_variables", 4),
        ("config_change_counter", 1),
        ("extended_status", 0),
        ("manufacturer_id", 0x26),
        ("private_label_distributor", 0x26),
        ("device_profile", 1),
    ] {
        assert_eq!(d[k], want, "{k}");
    }
    assert_eq!(d["device_id"], "123456");
}

#[test]
fn decode_json_hart5_cmd0_reply_names_manufacturer_and_device_type() {
    let v = decode_json("FF FF FF FF FF 06 80 00 0E 00 00 FE 26 06 05 05 01 02 03 00 12 34 56 26");
    let d = &v["decoded"];
    assert_eq!(d["universal_revision"], 5);
    assert_eq!(d["manufacturer_id"], 0x26);
    assert_eq!(d["device_type"], 6);
    assert!(d.get("min_response_preambles").is_none());
}

#[test]
fn decode_json_long_frame_nan_and_trailing() {
    let v = decode_json("FF FF FF FF 86 A6 06 12 34 56 03 1A 00 00 41 40 00 00 06 42 48 00 00 21 42 91 00 00 FA 7F A0 00 00 FA 7F A0 00 00 B0 00 13");
    assert_eq!(v["preambles"], 4);
    assert_eq!(v["address"]["unique_id"], "2606123456");
    assert_eq!(v["address"]["expanded_device_type"], 0x2606);
    assert_eq!(v["address"]["device_id"], "123456");
    assert_eq!(v["address"]["broadcast"], false);
    assert_eq!(v["trailing"], "0013");
    let vars = v["decoded"]["variables"].as_array().unwrap();
    assert_eq!(v["decoded"]["loop_current"], 12.0);
    assert_eq!(vars[1], serde_json::json!({"units": 33, "value": 72.5}));
    assert_eq!(vars[2]["value"], Value::Null, "HART NaN is null");
}

#[test]
fn decode_json_requests_and_extended_commands() {
    let v = decode_json("FF FF FF FF FF 82 A6 06 12 34 56 09 02 00 F5 AC");
    assert_eq!(v["decoded"]["slots"], serde_json::json!([0, 245]));
    let v = decode_json("82 80 00 00 00 00 0B 06 41 4B 71 C3 18 20 8F");
    assert_eq!(v["preambles"], 0);
    assert_eq!(v["address"]["broadcast"], true);
    assert_eq!(v["decoded"]["tag"], "PT-101");
    let v = decode_json("FF:FF:FF:FF:FF:82:A6:06:12:34:56:06:02:03:00:55");
    assert_eq!(
        v["decoded"],
        serde_json::json!({"polling_address": 3, "loop_current_mode": 0})
    );
    let v = decode_json("FF FF FF FF FF 86 A6 06 12 34 56 1F 05 00 00 04 00 AA E2");
    assert_eq!(
        (
            v["command"].as_u64(),
            v["command_byte"].as_u64(),
            v["data"].as_str()
        ),
        (Some(1024), Some(31), Some("AA"))
    );
    let v = decode_json("FF FF FF FF FF 86 A6 06 12 34 56 0D 17 00 00 41 4B 71 C3 18 20 08 F2 4C 15 28 06 14 51 20 41 53 50 15 0B 7D 05");
    assert_eq!(
        v["decoded"],
        serde_json::json!({"tag": "PT-101", "descriptor": "BOILER FEED PUMP", "date": "2025-11-21"})
    );
    let v = decode_json("FF FF FF FF FF 86 A6 06 12 34 56 01 02 88 00 DD");
    assert_eq!(v["communication_error"], true);
    assert!(v.get("decoded").is_none());
}

#[test]
fn annotated_view_names_every_field() {
    let (code, out, _) = hartkit(&[
        "frame",
        "decode",
        "FF FF FF FF FF 86 A6 06 12 34 56 01 07 00 00 06 41 48 00 00 5F",
    ]);
    assert_eq!(code, 0);
    for needle in [
        "delimiter",
        "ACK, long address",
        "unique ID 2606123456",
        "byte count",
        "pv_units",
        "psi",
        "12.5",
        "check byte",
        "ok",
    ] {
        assert!(out.contains(needle), "missing {needle:?} in:\n{out}");
    }
}

#[test]
fn bad_input_is_one_line_exit_2_no_panic() {
    for (args, needle) in [
        (
            vec!["frame", "decode", "FF FF FF FF FF 02 80 00 05 01"],
            "truncated",
        ),
        (
            vec!["frame", "decode", "FF FF 03 80 00 00 83"],
            "delimiter at byte 2",
        ),
        (vec!["frame", "decode", "FF 02 80 00 00 82"], "preamble"),
        (vec!["frame", "decode", "02 8"], "odd number"),
        (vec!["frame", "decode", "GG"], "not a hex digit"),
        (vec!["frame", "decode", "FF FF FF"], "no delimiter"),
        (
            vec!["frame", "decode", "FF FF 06 80 00 01 00 87"],
            "byte count at byte 5",
        ),
        (
            vec!["frame", "encode", "--short", "64", "--command", "0"],
            "0-63",
        ),
        (
            vec!["frame", "encode", "--long", "XYZ", "--command", "0"],
            "--long",
        ),
    ] {
        let (code, out, err) = hartkit(&args);
        assert_eq!(code, 2, "{args:?}: {out}{err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
}

#[test]
fn encode_examples() {
    let enc = |args: &[&str]| {
        let mut a = vec!["frame", "encode"];
        a.extend_from_slice(args);
        let (code, out, err) = hartkit(&a);
        assert_eq!(code, 0, "{err}");
        out.trim().to_string()
    };
    assert_eq!(
        enc(&["--short", "0", "--command", "0"]),
        "FF FF FF FF FF 02 80 00 00 82"
    );
    assert_eq!(
        enc(&["--short", "0", "--command", "0", "--secondary"]),
        "FF FF FF FF FF 02 00 00 00 02"
    );
    assert_eq!(
        enc(&["--long", "264E0000D2", "--command", "3"]),
        "FF FF FF FF FF 82 A6 4E 00 00 D2 03 00 BB"
    );
    assert_eq!(
        enc(&["--long", "2606123456", "--command", "9", "--data", "00 F5"]),
        "FF FF FF FF FF 82 A6 06 12 34 56 09 02 00 F5 AC"
    );
    assert_eq!(
        enc(&[
            "--long",
            "2606123456",
            "--command",
            "35",
            "--ack",
            "--rc",
            "9",
            "--status",
            "64"
        ]),
        "FF FF FF FF FF 86 A6 06 12 34 56 23 02 09 40 3E"
    );
    assert_eq!(
        enc(&[
            "--long",
            "2606123456",
            "--command",
            "1",
            "--back",
            "--secondary",
            "--burst",
            "--data",
            "0641480000"
        ]),
        "FF FF FF FF FF 81 66 06 12 34 56 01 07 00 00 06 41 48 00 00 98"
    );
    assert_eq!(
        enc(&[
            "--long",
            "2606123456",
            "--command",
            "1024",
            "--preambles",
            "0"
        ]),
        "82 A6 06 12 34 56 1F 02 04 00 4B"
    );
    assert_eq!(
        enc(&["--short", "5", "--command", "0", "--preambles", "2"]),
        "FF FF 02 85 00 00 87"
    );
}

#[test]
fn sim_bench_json_contract_and_trace() {
    let trace = std::env::temp_dir().join(format!("hartkit-trace-{}.jsonl", std::process::id()));
    let (code, out, err) = hartkit(&[
        "sim",
        "bench",
        "--devices",
        "3",
        "--secondary",
        "--burst",
        "--duration",
        "60",
        "--json",
        "--trace",
        trace.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    for key in [
        "virtual_seconds",
        "wall_seconds",
        "burst_frames",
        "failed",
        "retries",
        "collisions",
        "wrong_data",
        "line_utilization",
        "theoretical_transactions_per_s",
        "efficiency",
    ] {
        assert!(
            v.get(key).is_some_and(|x| x.is_number()),
            "{key} missing in {v}"
        );
    }
    assert!(v["transactions"]["primary"].as_u64().unwrap() > 10);
    assert!(v["transactions"]["secondary"].as_u64().unwrap() > 5);
    assert_eq!(v["virtual_seconds"], 60.0);
    let text = std::fs::read_to_string(&trace).unwrap();
    let _ = std::fs::remove_file(&trace);
    let lines: Vec<Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert!(lines.len() > 50);
    for l in &lines {
        assert!(l["t0_us"].as_u64().unwrap() < l["t1_us"].as_u64().unwrap());
        let src = l["src"].as_str().unwrap();
        assert!(
            src == "primary" || src == "secondary" || src.starts_with("dev:"),
            "{src}"
        );
        assert!(l["hex"].as_str().unwrap().starts_with("FFFFFFFFFF"));
        assert_eq!(l["collided"], false);
    }
    assert!(
        lines
            .iter()
            .any(|l| l["src"] == "dev:1" && l["hex"].as_str().unwrap()[10..12] == *"81"),
        "a BACK from the burst device"
    );
}

#[test]
fn sim_bench_on_the_analog_loop() {
    // Three devices, a handheld and a burst device on 1 km of cable, sample by sample.
    let (code, out, err) = hartkit(&[
        "sim",
        "bench",
        "--medium",
        "analog",
        "--devices",
        "3",
        "--secondary",
        "--burst",
        "--cable-m",
        "1000",
        "--duration",
        "40",
        "--json",
    ]);
    assert_eq!(code, 0, "{err}");
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["medium"]["kind"], "analog");
    assert_eq!(v["medium"]["cable_m"], 1000.0);
    assert_eq!(v["devices_found"], 3);
    assert!(v["transactions"]["primary"].as_u64().unwrap() > 5, "{v}");
    assert!(v["transactions"]["secondary"].as_u64().unwrap() > 3, "{v}");
    assert!(v["burst_frames"].as_u64().unwrap() > 5, "{v}");
    assert_eq!(v["wrong_data"], 0);
    assert!(v["frames_sent"].as_u64().unwrap() > 40, "{v}");
    assert!(v["frame_error_rate"].as_f64().unwrap() < 0.05, "{v}");
    let moved = v["analog_disturbance_ua"]["peak"].as_f64().unwrap();
    assert!(moved > 0.0 && moved < 50.0, "{v}");
    // The digital medium says so too.
    let (_, out, _) = hartkit(&[
        "sim",
        "bench",
        "--devices",
        "2",
        "--duration",
        "5",
        "--json",
    ]);
    let v: Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["medium"]["kind"], "digital");
}

#[test]
fn sim_bench_rejects_bad_options() {
    for (args, needle) in [
        (vec!["sim", "bench", "--phy", "rs485:abc"], "baud"),
        (vec!["sim", "bench", "--phy", "modem"], "expected fsk"),
        (vec!["sim", "bench", "--ber", "0.9"], "bit error rate"),
        (vec!["sim", "bench", "--duration", "0"], "--duration"),
        (
            vec!["sim", "bench", "--medium", "analog", "--phy", "rs485:19200"],
            "FSK loop",
        ),
        (
            vec!["sim", "bench", "--medium", "analog", "--loop-ohm", "nan"],
            "--loop-ohm",
        ),
        (
            vec!["sim", "bench", "--medium", "analog", "--sample-rate", "100"],
            "--sample-rate",
        ),
    ] {
        let (code, _, err) = hartkit(&args);
        assert_eq!(code, 2, "{args:?}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

/// Shell completions and manual pages come from the command line's own definitions:
/// every shell gets a script naming the commands, and every command a page.
#[test]
fn completions_and_manual_pages() {
    for shell in ["bash", "zsh", "fish", "elvish", "powershell"] {
        let (code, out, err) = hartkit(&["completions", shell]);
        assert_eq!(code, 0, "{shell}: {err}");
        for word in ["serve", "wells", "modem", "--psk-file"] {
            assert!(out.contains(word), "{shell} completions lack {word}");
        }
    }
    let (code, _, err) = hartkit(&["completions", "tcsh"]);
    assert_eq!(code, 2, "{err}");
    let dir = std::env::temp_dir().join(format!("hartkit-man-{}", std::process::id()));
    let (code, out, err) = hartkit(&["manual", "--dir", dir.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("manual pages in"), "{out}");
    for page in [
        "hartkit.1",
        "hartkit-serve.1",
        "hartkit-wells.1",
        "hartkit-frame-decode.1",
    ] {
        let text =
            std::fs::read_to_string(dir.join(page)).unwrap_or_else(|e| panic!("{page}: {e}"));
        assert!(text.contains(".TH") && text.contains(".SH NAME"), "{page}");
    }
    let serve = std::fs::read_to_string(dir.join("hartkit-serve.1")).unwrap();
    assert!(
        serve.contains("plain\\-rights"),
        "the options are in the page"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// One log for every diagnostic: `--log-level debug` shows the raw traffic through it,
/// `--log-format json` makes each line a JSON object, and a bad level is a usage error.
#[test]
fn logs_go_through_one_log_with_levels_and_json() {
    let (code, out, err) = hartkit(&[
        "read",
        "-p",
        "sim?virtual",
        "--poll",
        "1",
        "pv",
        "--log-level",
        "debug",
        "--log-format",
        "json",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(!out.is_empty(), "the result on standard output");
    let lines: Vec<Value> = err
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert!(
        lines.iter().any(|l| l["level"] == "DEBUG"
            && l["fields"]["message"]
                .as_str()
                .unwrap()
                .contains(" tx FF FF")),
        "{err}"
    );
    let (code, _, err) = hartkit(&[
        "read",
        "-p",
        "sim?virtual",
        "--poll",
        "1",
        "pv",
        "--log-level",
        "loud",
    ]);
    assert_eq!(code, 2);
    assert!(
        err.contains("expected error, warn, info, debug or trace"),
        "{err}"
    );
    // Without --log-level (nor RUST_LOG, HARTKIT_LOG) a command says only warnings.
    if std::env::var_os("RUST_LOG").is_none() && std::env::var_os("HARTKIT_LOG").is_none() {
        let (code, _, err) = hartkit(&["read", "-p", "sim?virtual", "--poll", "1", "pv"]);
        assert_eq!(code, 0);
        assert!(err.is_empty(), "{err}");
    }
}
