//! `hartkit serve --sim --instant` and the load generator `hartkit hart-ip bench`, as a
//! user runs them: two processes on loopback. Only that the load gets through without
//! errors is checked; how fast is a benchmark (docs/benchmarks.md), never a test.

use std::process::Command;

use serde_json::Value;

mod common;
use common::{hartkit, serve};

fn bench(args: &[&str]) -> (i32, String, String) {
    hartkit(&[&["hart-ip", "bench"], args].concat())
}

#[test]
fn load_generator_against_the_instant_server_over_udp_and_tcp() {
    let server = serve(&["--sim", "--instant", "--max-sessions", "100"]);
    for scheme in ["udp", "tcp"] {
        let target = format!("{scheme}://127.0.0.1:{}", server.1);
        let (code, out, err) = bench(&[
            "-p",
            &target,
            "--sessions",
            "4",
            "--duration",
            "1",
            "--json",
        ]);
        assert_eq!(code, 0, "{scheme}: {err}");
        let v: Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}"));
        assert_eq!(v["transport"], scheme);
        assert_eq!(v["sessions"], 4);
        assert_eq!(v["sessions_open"], 4, "{v}");
        assert_eq!(v["command"], 1);
        assert_eq!(v["poll"], 1);
        assert!(v["transactions"].as_u64().unwrap() > 0, "{v}");
        assert_eq!(v["errors"], 0, "{v}");
        for k in ["p50", "p99", "max", "mean"] {
            assert!(v["latency_us"][k].as_f64().unwrap() > 0.0, "{k}: {v}");
        }
        assert!(v["transactions_per_s"].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn instant_serves_the_profiles_given() {
    let server = serve(&["--sim", "valve", "temperature", "--instant", "--udp"]);
    let target = format!("udp://127.0.0.1:{}", server.1);
    // The temperature transmitter at polling address 2, command 3.
    let (code, out, err) = bench(&[
        "-p",
        &target,
        "--poll",
        "2",
        "--command",
        "3",
        "--duration",
        "0.3",
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(out.contains("command 3 to"), "{out}");
    assert!(out.contains("errors: 0 "), "{out}");
    // Nothing at polling address 3: the set-up fails and says what to check.
    let (code, _, err) = bench(&["-p", &target, "--poll", "3", "--duration", "0.3"]);
    assert_eq!(code, 3, "{err}");
    assert!(
        err.contains("no device found at polling address 3"),
        "{err}"
    );
    assert!(err.contains("--poll"), "{err}");
}

#[test]
fn instant_without_sim_is_a_usage_error() {
    let out = Command::new(env!("CARGO_BIN_EXE_hartkit"))
        .args([
            "serve",
            "--hart-ip",
            "127.0.0.1:0",
            "--instant",
            "--run-for",
            "1",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--instant"), "{err}");
    assert!(err.contains("needs --sim"), "{err}");
    assert!(out.stdout.is_empty(), "no server started");
}

#[test]
fn bench_rejects_targets_that_are_not_hart_ip() {
    let (code, _, err) = bench(&["-p", "sim", "--duration", "1"]);
    assert_eq!(code, 2);
    assert!(
        err.contains("udp://HOST[:PORT] or tcp://HOST[:PORT]"),
        "{err}"
    );
    let (code, _, err) = bench(&["-p", "udp://127.0.0.1:9", "--sessions", "0"]);
    assert_eq!(code, 2);
    assert!(err.contains("--sessions 0"), "{err}");
}
